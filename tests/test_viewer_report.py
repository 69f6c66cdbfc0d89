"""``fnsi-lab report`` and the report ``fnsi-lab run`` writes: one offline HTML file.

A real chain: the packaged lumped experiment (3-DOF chain, cubic spring 1e9 N/m^3) recorded
by ``fnsi-lab run``, identified by the robust pipeline, reported from the JSON and from the
recording; the page is opened in headless Chromium (skipped with the reason without it).
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil

import numpy as np
import pytest

from fnsi_lab.cli import main
from fnsi_lab.outputs import write_json

CHROMIUM = os.environ.get("FNSI_LAB_CHROMIUM", "/usr/bin/chromium")
FIGURES = ("fig-stabilisation", "fig-criterion", "fig-mdi", "fig-coefficients", "fig-frf")


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """``fnsi-lab run`` on the lumped experiment: recording, .rrd and the HTML report."""
    d = tmp_path_factory.mktemp("report")
    mcap, rrd = d / "lumped.mcap", d / "lumped.rrd"
    assert main(["run", "--config", "lumped.yaml", "--orders", "2:10", "--out", str(mcap),
                 "--rrd", str(rrd), "--quiet"]) == 0
    return d, mcap, rrd


def _figures(page: str) -> dict[str, str]:
    """figure id -> its inline SVG text."""
    return dict(re.findall(r"<figure id='([^']+)'>(<svg.*?</svg>)", page, flags=re.S))


def test_run_writes_the_report_next_to_the_rrd(chain):
    d, mcap, rrd = chain
    page = (d / "lumped.html").read_text(encoding="utf-8")
    figs = _figures(page)
    assert set(figs) == set(FIGURES)
    for name, text in figs.items():
        assert text.count("<path") > 10, name  # drawn, not an empty axes box
    # nothing is fetched: the page stands alone
    assert not re.search(r"""(src|href)=["']?(https?:|//)""", page)
    # Table-2-like summary with the estimate against the truth (1e9 N/m^3 within 0.5 %)
    row = re.search(r"X2-X3-cubic, (full|reduced) model</td><td>([-+0-9.e]+) ± .*?"
                    r"\(error ([-+0-9.]+) %\)", page)
    assert row and abs(float(row.group(3))) < 0.5
    assert "selected order (IC)" in page and "acquisition start (UTC)" in page


def test_report_from_json_and_from_the_recording(chain, capsys):
    from fnsi_lab.viewer.report_cli import load_report_input

    d, mcap, _ = chain
    result, _ = load_report_input(mcap, orders="2:10")
    write_json(result, d / "result.json")
    out = d / "from_json.html"
    assert result["input"] == str(mcap)
    # the JSON names its recording: the report finds the metadata without --recording
    assert main(["report", str(d / "result.json"), "--out", str(out)]) == 0
    assert "report written to" in capsys.readouterr().out
    page = out.read_text(encoding="utf-8")
    assert set(_figures(page)) == set(FIGURES)
    assert "acquisition start (UTC)" in page and "lumped" in page
    # every pole of the stabilisation diagram is drawn: one marker per pole
    n_poles = sum(len(o["poles"]) for o in result["stabilisation"])
    assert f"Stabilisation diagram ({n_poles} poles)" in page
    # the mode table lists the three modes of the chain as physical (the fate's words)
    assert page.count("<td>physical</td>") + page.count("<td>physical (stabilisation)</td>") >= 3
    # the MDI caption explains every fate drawn
    assert "drawn by its fate" in page and "physical: above the MDI threshold" in page
    # the report of the recording identifies it the same way (same stabilisation title)
    assert main(["report", str(mcap), "--orders", "2:10", "--out", str(d / "from_mcap.html"),
                 "--quiet"]) == 0
    assert f"({n_poles} poles)" in (d / "from_mcap.html").read_text(encoding="utf-8")


def test_report_refuses_to_overwrite_and_bad_inputs_give_one_line(chain, capsys):
    d, mcap, _ = chain
    existing = d / "lumped.html"
    before = existing.read_bytes()
    assert main(["report", str(d / "lumped.mcap"), "--out", str(existing)]) == 2
    err = capsys.readouterr().err
    assert "--force" in err and len(err.strip().splitlines()) == 1
    assert existing.read_bytes() == before
    bad = d / "bad.json"
    bad.write_text("{not json")
    assert main(["report", str(bad), "--out", str(d / "bad.html")]) == 2
    err = capsys.readouterr().err
    assert "not a readable JSON result" in err and len(err.strip().splitlines()) == 1
    assert main(["report", str(d / "missing.json")]) == 2
    (d / "x.txt").write_text("x")
    assert main(["report", str(d / "x.txt")]) == 2
    assert "unsupported file type" in capsys.readouterr().err
    write_json({"order": 4, "frf": {"outputs": ["a"]}}, d / "tiny.json")
    assert main(["report", str(d / "tiny.json"), "--output", "zz"]) == 2
    assert "--output" in capsys.readouterr().err


def test_report_renders_in_chromium_without_errors(chain, tmp_path):
    if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install -y chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    Image = pytest.importorskip("PIL.Image", reason="Pillow is not installed")
    d, _, _ = chain
    page_file = d / "lumped.html"
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"],
                                     headless=True)
        # offline: any request other than the file itself fails the test
        context = browser.new_context(offline=True, viewport={"width": 1100, "height": 900})
        page = context.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("requestfailed", lambda r: errors.append(f"request {r.url}"))
        page.goto(page_file.as_uri())
        boxes = {}
        for fig in FIGURES:
            el = page.locator(f"#{fig} svg")
            boxes[fig] = el.bounding_box()
            png = el.screenshot()
            px = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=float)
            # a plot, not a blank box: a fair share of non-white pixels and real contrast
            ink = float(np.mean(px < 200))
            assert ink > 0.01 and px.std() > 20, (fig, ink, px.std())
            (tmp_path / f"{fig}.png").write_bytes(png)
        page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        browser.close()
    assert errors == []
    for fig, box in boxes.items():
        assert box and box["width"] > 500 and box["height"] > 200, (fig, box)


def test_report_json_keys_the_report_reads_are_in_the_result(chain):
    """The sections the report draws come from the identification JSON, one row per pole."""
    from fnsi_lab.viewer.report import stabilisation_rows
    from fnsi_lab.viewer.report_cli import load_report_input

    d, mcap, _ = chain
    result, _ = load_report_input(mcap, orders="2:10")
    result = json.loads(json.dumps(result))  # as read back from a file
    rows = stabilisation_rows(result)
    assert len(rows) == sum(len(o["poles"]) for o in result["stabilisation"])
    assert {r["order"] for r in rows} <= set(range(2, 11))
    assert len(result["mdi"]) >= 3 and "frf" in result and result["coefficient_spectra"]
    assert result["coefficient_spectra"]["exact"] == {"X2-X3-cubic": 1e9}
