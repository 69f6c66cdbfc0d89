"""One vocabulary for a pole's fate (issue 27): the JSON, the terminal, the report, the viewer."""

from __future__ import annotations

from fnsi_lab.ident.robust.pole_fate import FATES, fate_caption, pole_fates, result_fates
from fnsi_lab.viewer.log import FATE_STYLE as VIEWER_STYLE
from fnsi_lab.viewer.report import FATE_STYLE as REPORT_STYLE, mdi_caption, mode_rows


def _row(f, physical, in_band=True, stable=True, mdi=1.0):
    return {"frequency_hz": f, "physical": physical, "in_band": in_band, "stable": stable,
            "mdi_h2": mdi, "damping_ratio": 0.02, "stabilisation": "stable"}


ROWS = [_row(11.01, True), _row(24.1, False, mdi=1e-8), _row(37.47, False, mdi=1e-3),
        _row(38.26, True), _row(40.0, False), _row(50.0, False, stable=False),
        _row(120.0, False, in_band=False), _row(45.0, True, mdi=1e-5)]
CONFIDENCE = {"below_residual": [37.47], "vetoed_not_stabilised": [40.0],
              "rescued_by_stabilisation": [45.0]}


def test_each_decision_of_the_pipeline_has_its_own_fate():
    fates = pole_fates(ROWS, CONFIDENCE, left_out_hz=[38.27])
    # the 37.47 Hz pole: above the MDI threshold, dropped as not detectable above
    # the residual, not "spurious (removed)"
    assert fates == ["physical", "spurious", "not_detectable", "split", "not_stabilised",
                     "unstable", "out_of_band", "rescued"]


def test_every_fate_is_drawn_distinctly_and_explained():
    assert set(REPORT_STYLE) == set(VIEWER_STYLE) == set(FATES)
    assert len({c for c, _ in REPORT_STYLE.values()}) == len(FATES)   # one colour each
    assert len({m for _, m in REPORT_STYLE.values()}) == len(FATES)   # one marker each
    assert len({c for c, _ in VIEWER_STYLE.values()}) == len(FATES)
    caption = fate_caption(["not_detectable", "physical"])
    assert caption.startswith("physical: ") and "not detectable: " in caption
    assert "spurious by MDI" not in caption  # only the fates present


def test_the_report_uses_the_json_fate_words():
    result = {"method": "auto", "mdi": [dict(r, fate=f) for r, f in
                                        zip(ROWS, pole_fates(ROWS, CONFIDENCE))],
              "confidence": CONFIDENCE}
    assert result_fates(result) == [r["fate"] for r in result["mdi"]]
    table = {r["f (Hz)"]: r["fate"] for r in mode_rows(result)}
    assert table["37.47"] == "not detectable" and table["11.01"] == "physical"
    assert "not detectable: above the MDI threshold but dropped" in mdi_caption(result)


def test_stabilisation_classes_and_fates_are_far_apart_in_colour():
    """Two classes must not read as one (issue 27: '+ damping' and 'unstable' were two
    oranges, 'new pole' grey on the grey grid): every pair differs by >= 100 in RGB L1."""
    from itertools import combinations

    from fnsi_lab.viewer.log import POLE_STYLE

    for style in (POLE_STYLE, VIEWER_STYLE):
        for (a, (ca, _)), (b, (cb, _)) in combinations(style.items(), 2):
            assert sum(abs(x - y) for x, y in zip(ca, cb)) >= 100, (a, b)
    grid = (225, 225, 225)
    assert sum(abs(x - y) for x, y in zip(POLE_STYLE["new"][0], grid)) >= 300
