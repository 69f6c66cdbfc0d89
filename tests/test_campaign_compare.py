"""Campaign comparison across force levels (pure part: rows and results in, numbers out)."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.campaign.compare import compare_campaign, format_comparison, match_modes


def _frf(freq, fn_hz, zeta, gain=1.0):
    """Receptance of one mode, shape (n_lines, 1, 1) as re/im lists."""
    w, wn = 2 * np.pi * freq, 2 * np.pi * fn_hz
    h = gain / (wn ** 2 - w ** 2 + 2j * zeta * wn * w)
    return {"re": h.real[:, None, None].tolist(), "im": h.imag[:, None, None].tolist()}


def _run(file, level, k, k_std, contact, modes_hz, gain=1.0, status="ok"):
    freq = np.linspace(5, 50, 91)
    result = {"order": 2 * len(modes_hz),
              "modes": [{"frequency_hz": f, "damping_ratio": 0.02} for f in modes_hz],
              "frf": {"frequency_hz": freq.tolist(), "outputs": ["A", "B"], "inputs": ["F-B"],
                      "underlying_linear": {
                          "re": np.concatenate([np.array(_frf(freq, 20, 0.02, gain)["re"])] * 2,
                                               axis=1).tolist(),
                          "im": np.concatenate([np.array(_frf(freq, 20, 0.02, gain)["im"])] * 2,
                                               axis=1).tolist()}}}
    row = {"file": file, "status": status, "error": None, "force_rms": level,
           "result": file + ".json", "stop:neg": k, "stop:neg:std": k_std,
           "stop:neg:contact": contact}
    return row, result


def _campaign(runs, **kw):
    rows = [r for r, _ in runs]
    results = {r["result"]: res for r, res in runs}
    return compare_campaign(rows, results=results, driving_points={"F-B": "B"}, **kw)


def test_levels_means_scatter_and_frequencies():
    runs = [_run("a", 10.0, 100.0, 1.0, 0.2, [10.0, 30.0]),
            _run("b", 10.0, 102.0, 3.0, 0.3, [10.2, 30.1]),
            _run("c", 1.0, 99.0, 2.0, 0.1, [10.1, 30.2]),
            _run("d", 5.0, 101.0, 2.0, 0.1, [10.05])]
    c = _campaign(runs)
    assert c.levels == [1.0, 5.0, 10.0]
    at10 = c.coefficients["stop:neg"][2]
    assert at10.level == 10.0 and at10.runs == [100.0, 102.0]
    assert at10.mean == pytest.approx(101.0)
    assert at10.scatter == pytest.approx(np.std([100.0, 102.0], ddof=1))
    assert at10.spread == pytest.approx(2.0)  # mean of the runs' own spreads
    assert at10.contact == 0.2  # the smallest: the least favourable run decides
    assert c.coefficients["stop:neg"][0].scatter is None  # one run at level 1
    # reference: the lowest level among the runs with the most modes
    assert c.reference_frequencies_hz == [10.1, 30.2]
    mode1 = {v.level: v.mean for v in c.frequencies[0]}
    assert mode1 == pytest.approx({1.0: 10.1, 5.0: 10.05, 10.0: 10.1})
    mode2 = {v.level: v.mean for v in c.frequencies[1]}
    assert set(mode2) == {1.0, 10.0}  # run d has no second mode
    assert c.output == "B" and not c.warnings
    assert "stop:neg" in format_comparison(c)


def test_not_identifiable_by_contact_or_spread_and_failures():
    runs = [_run("never", 1.0, 5.0, 0.5, 0.0, [10.0]),
            _run("noisy", 2.0, 100.0, 30.0, 0.05, [10.0]),
            _run("good", 10.0, 100.0, 1.0, 0.3, [10.0])]
    bad_row = {"file": "broken", "status": "error", "error": "DataFileError: bad chunk",
               "force_rms": 10.0, "result": None}
    c = compare_campaign([r for r, _ in runs] + [bad_row],
                         results={r["result"]: res for r, res in runs},
                         max_relative_spread=0.1, min_contact=0.001)
    by_level = {v.level: v for v in c.coefficients["stop:neg"]}
    assert "closed 0 %" in by_level[1.0].not_identifiable
    assert "30% of |mean|" in by_level[2.0].not_identifiable
    assert by_level[10.0].not_identifiable is None
    assert len(c.warnings) == 3 and "broken (level 10): identification failed" in c.warnings[2]
    assert c.failed == [("broken", "DataFileError: bad chunk")]


def test_not_identifiable_when_the_runs_say_so():
    """A level whose every run gave the coefficient the verdict `not identifiable` (e.g. the
    nested test kept the linear fit there) is flagged with the result's own reason, even when
    its contact and spread would pass."""
    runs = [_run("lin", 1.0, 100.0, 1.0, 0.3, [10.0]), _run("ok", 10.0, 100.0, 1.0, 0.3, [10.0])]
    runs[0][1]["coefficients"] = [{"name": "stop:neg", "verdict": "not identifiable",
                                   "verdict_reason": "the nonlinear terms are not supported "
                                                     "by the data (residual 2x); more"}]
    runs[1][1]["coefficients"] = [{"name": "stop:neg", "verdict": "identified"}]
    c = _campaign(runs)
    by_level = {v.level: v for v in c.coefficients["stop:neg"]}
    assert by_level[1.0].not_identifiable == ("the result's verdict: the nonlinear terms are "
                                              "not supported by the data")
    assert by_level[10.0].not_identifiable is None and len(c.warnings) == 1


def test_frf_deviation_is_zero_for_one_linear_system_and_measures_a_change():
    same = _campaign([_run("a", 1.0, 1, 0.01, 0.5, [20.0]), _run("b", 2.0, 1, 0.01, 0.5, [20.0])])
    assert [r.deviation for r in same.frfs] == pytest.approx([0.0, 0.0], abs=1e-12)
    # one run's underlying linear FRF 10 % higher: each deviates by 5 % from the mean
    diff = _campaign([_run("a", 1.0, 1, 0.01, 0.5, [20.0]),
                      _run("b", 2.0, 1, 0.01, 0.5, [20.0], gain=1.1)])
    assert [r.deviation for r in diff.frfs] == pytest.approx([0.05 / 1.05] * 2, rel=1e-9)
    assert diff.frfs[0].frf.shape == (91, 1)


def test_match_modes_never_confuses_close_modes():
    ref = [10.0, 10.5, 30.0]
    assert match_modes(ref, [10.1, 10.45, 29.0, 50.0]) == [0, 1, 2, None]
    assert match_modes(ref, [10.25]) == [None]  # halfway between two modes: ambiguous
    assert match_modes(ref, [10.01, 10.02]) == [0, None]  # one frequency per mode
    assert match_modes([], [1.0]) == [None]


def test_the_comparison_carries_the_runs_units_to_its_plots():
    """Axes in the recording's units (issue 27): force level in N, stiffness in N/mm."""
    from fnsi_lab.campaign.view import coefficient_panels, frf_panels

    runs = [_run("a", 10.0, 100.0, 1.0, 0.2, [10.0]), _run("b", 50.0, 101.0, 1.0, 0.2, [10.0])]
    for _, result in runs:
        result["units"] = {"force": "N", "frf": "mm/N", "coefficients": {"stop:neg": "N/mm"}}
    c = _campaign(runs)
    assert c.units["coefficients"] == {"stop:neg": "N/mm"} and c.to_json()["units"] == c.units
    (panel,) = coefficient_panels(c)
    assert panel.x.label == "force level (RMS, N)" and panel.y.label == "stop:neg (N/mm)"
    assert all("dB re 1 mm/N" in p.title for p in frf_panels(c))
    assert _campaign([_run("c", 1.0, 99.0, 1.0, 0.2, [10.0])]).units == {}  # older results
