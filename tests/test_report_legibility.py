"""The HTML report's plots read (issue 27, point 6), on the README's SmallSat result.

Two kinds of checks: the geometry of the matplotlib figures (no legend box over a plot
area, axis titles clear of tick labels, y-limits from the excited band) and the pixels of
the report as headless Chromium shows it (each stabilisation class and each pole fate in
its own colour, the Im line and the measured FRF markers visible).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fnsi_lab.viewer import report as R

CHROMIUM = os.environ.get("FNSI_LAB_CHROMIUM", "/usr/bin/chromium")


@pytest.fixture(scope="module")
def smallsat(tmp_path_factory) -> dict:
    """The README's SmallSat recording identified by the robust pipeline (its JSON)."""
    d = tmp_path_factory.mktemp("legible")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    for args in (["acquire", "--out", "s.mcap", "--quiet"],
                 ["ident", "s.mcap", "--config", "smallsat39", "--auto", "--json", "s.json",
                  "--quiet"]):
        done = subprocess.run([sys.executable, "-m", "fnsi_lab", *args], cwd=d, env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
    return json.loads((d / "s.json").read_text())


def _drawn(fig):
    """Draw a figure (Agg) and return its renderer: bounding boxes are then final."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


FIGURES = {"stabilisation": R.figure_stabilisation, "criterion": R.figure_criterion,
           "mdi": R.figure_mdi, "coefficients": R.figure_coefficients, "frf": R.figure_frf}


@pytest.mark.parametrize("name", list(FIGURES))
def test_no_legend_over_a_plot_and_axis_titles_clear_of_ticks(smallsat, name):
    fig = FIGURES[name](smallsat)
    renderer = _drawn(fig)
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    assert legends, name
    for ax in fig.axes:
        area = ax.get_window_extent(renderer)
        for leg in legends:
            assert not _overlap(leg.get_window_extent(renderer), area), (name, ax.get_title())
        label = ax.xaxis.label
        if label.get_text() and label.get_visible():
            box = label.get_window_extent(renderer)
            for tick in ax.get_xticklabels():
                if tick.get_text():
                    assert not _overlap(box, tick.get_window_extent(renderer)), (name, tick)


def test_coefficient_scales_come_from_the_excited_band(smallsat):
    fig = R.figure_coefficients(smallsat)
    spectra = smallsat["coefficient_spectra"]
    f = np.asarray(spectra["frequency_hz"])
    band = np.asarray(spectra["excited"], bool)
    axes = fig.axes
    assert len(axes) == 2 * len(spectra["names"])  # Re and Im each in their own row
    # the x range is the excited band (the extrapolated lines beyond it are not drawn)
    lo, hi = axes[0].get_xlim()
    assert lo >= f[band].min() - 0.05 * np.ptp(f[band]) and hi <= f[band].max() + 0.05 * np.ptp(f[band])
    for k, name in enumerate(spectra["names"]):
        c = np.asarray(spectra["values"][name]["re"]) + 1j * np.asarray(spectra["values"][name]["im"])
        for ax, part in ((axes[2 * k], c.real[band]), (axes[2 * k + 1], c.imag[band])):
            y0, y1 = ax.get_ylim()
            # the band's values fill the axis: its span is within 2x of theirs (padding 30 %
            # each side and the 1-99 % percentiles; the exact value or 0 may widen it)
            span = np.ptp(np.r_[part, 0.0] if ax is axes[2 * k + 1] else part)
            assert y1 - y0 <= 2.5 * span and y0 <= np.percentile(part, 50) <= y1, (name, y0, y1)


def test_ic_gaps_and_fates_are_explained(smallsat):
    ic = smallsat["information_criterion"]
    gaps = [r["order"] for r in ic if r.get("value") is None]
    labels = [t.get_text() for leg in R.figure_criterion(smallsat).legends for t in leg.get_texts()]
    if gaps:
        assert any(t.startswith("order not fitted: unstable") for t in labels), labels
    from fnsi_lab.ident.robust.pole_fate import fate_label

    caption = R.mdi_caption(smallsat)
    for fate in {r["fate"] for r in smallsat["mdi"] if (r.get("mdi_h2") or 0) > 0}:
        assert f"{fate_label(fate)}: " in caption, (fate, caption)


def _colour_count(px: np.ndarray, colour: str, tol: int = 40) -> int:
    rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.int16)
    return int((np.abs(px - rgb).sum(axis=-1) <= tol).sum())


def test_the_report_in_chromium_draws_each_class_and_line_visibly(smallsat, tmp_path):
    if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install -y chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    Image = pytest.importorskip("PIL.Image", reason="Pillow is not installed")
    page_file = tmp_path / "report.html"
    page_file.write_text(R.render_report(smallsat), encoding="utf-8")
    shots = {}
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"],
                                     headless=True)
        page = browser.new_page(viewport={"width": 1100, "height": 900})
        page.goto(page_file.as_uri())
        for fig in ("fig-stabilisation", "fig-mdi", "fig-coefficients", "fig-frf"):
            png = page.locator(f"#{fig} svg").screenshot()
            (tmp_path / f"{fig}.png").write_bytes(png)
            shots[fig] = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)
        browser.close()
    # stabilisation: every class the result has is visible in its own colour (a marker is
    # ~15-40 px; the legend swatch alone ~10-20), and no two classes share a colour
    from collections import Counter

    classes = Counter(p.get("class") if not p.get("unstable") else "unstable"
                      for o in smallsat["stabilisation"] for p in o["poles"])
    colours = [c for c, _, _ in R.STAB_STYLE.values()]
    assert len(set(colours)) == len(colours)
    px = shots["fig-stabilisation"]
    for cls in set(classes) & set(R.STAB_STYLE):  # a marker ~8-30 px (a "new" dot ~5)
        need = min(40, (3 if cls == "new" else 6) * classes[cls])
        assert _colour_count(px, R.STAB_STYLE[cls][0]) >= need, (cls, tmp_path)
    # MDI: every fate present in its own colour
    px = shots["fig-mdi"]
    for fate in {r["fate"] for r in smallsat["mdi"] if (r.get("mdi_h2") or 0) > 0}:
        assert _colour_count(px, R.FATE_STYLE[fate][0]) >= 20, (fate, tmp_path)
    # coefficients: the Im rows hold a curve (rows 2 and 4 of 4, the colour of their Re)
    px = shots["fig-coefficients"]
    rows = np.array_split(px, 4, axis=0)
    for k in (1, 3):
        colour = R.COEFF_COLOURS[k // 2]
        assert _colour_count(rows[k], colour) >= 300, (k, tmp_path)
    # FRF: the measured markers (dark) show on top of the model line (orange) in the
    # magnitude half, and the model line shows between them
    top = shots["fig-frf"][: shots["fig-frf"].shape[0] // 2]
    assert _colour_count(top, R.FRF_STYLE["measured"], tol=60) >= 1500, tmp_path
    assert _colour_count(top, R.FRF_STYLE["model"]) >= 300, tmp_path
