"""Every tab of the fnsi-lab blueprint shows its plots in the web viewer (headless Chromium).

The time panel stays on ``acq_time`` (what the blueprint selects; Rerun has one global
timeline). For each tab the test selects it (a new blueprint with ``active_tab``, as a click
would) and checks the pixels of the tab's plot areas: the series colours of the data must
cover a real area there, not only a legend entry. Two sources:

- the README's main command, ``fnsi-lab run --out smallsat.mcap --rrd smallsat.rrd`` (the
  simulated SmallSat, one identification update), run as a user runs it; its ``.rrd`` is read
  back and served as ``fnsi-lab view smallsat.rrd --serve-web`` serves it;
- content logged through the real ``viewer.log`` functions into a served stream while the
  viewer is connected (live streaming).

Needs the Debian ``chromium`` package (``/usr/bin/chromium``), ``playwright`` (its driver
only) and Pillow; skipped, with the reason, when one is missing.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import pytest
import rerun as rr

from fnsi_lab.viewer import log as vlog
from fnsi_lab.viewer.blueprint import blueprint
from fnsi_lab.viewer.cli import APP_ID, rrd_entities, signal_groups, signal_layout

CHROMIUM = os.environ.get("FNSI_LAB_CHROMIUM", "/usr/bin/chromium")
FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--ignore-gpu-blocklist"]
GROUPS = ("force", "displacement")
WIDTH, HEIGHT = 1600, 1000
#: The views' area in the screenshot: right of the blueprint panel, above the time panel.
LEFT, TOP, BOTTOM = 220, 70, 840

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _requirements() -> str | None:
    if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
        return f"no Chromium at {CHROMIUM} (apt-get install -y chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install playwright; no browser download needed)"
    try:
        import PIL  # noqa: F401
    except ImportError:
        return "Pillow is not installed (pip install pillow), needed to read the screenshot"
    return None


# ---------------------------------------------------------------------------- content
def log_example(rec: rr.RecordingStream) -> None:
    """A run of a 2-DOF structure with one cubic spring, through the real ``log_*`` functions."""
    groups = {"force": [0], "displacement": [1, 2]}
    vlog.log_signal_styles(rec, groups, ["F", "x1", "x2"])
    t = np.arange(3000) / 1000.0
    data = np.c_[np.sin(2 * np.pi * 5 * t), 0.5 * np.cos(2 * np.pi * 3 * t),
                 0.3 * np.sin(2 * np.pi * 7 * t)]
    vlog.log_signals(rec, data, 0.0, 1000.0, groups)
    f = np.linspace(2.0, 40.0, 400)
    s = 2j * np.pi * f
    modes = ((9.8, 0.02), (25.7, 0.03))
    h = sum(1.0 / ((2 * np.pi * fn) ** 2 + 2 * z * (2 * np.pi * fn) * s + s ** 2)
            for fn, z in modes)
    rng = np.random.default_rng(0)
    orders = np.arange(2, 31)
    order, freq, cls = [], [], []
    for n in orders:
        for fn, _ in modes[:min(n // 2, 2)]:
            order.append(n)
            freq.append(fn * (1 + 1e-4 * rng.standard_normal()))
            cls.append("stable" if n > 6 else "new")
    crit = 10.0 ** (-np.minimum(orders, 6) + 0.01 * orders)
    vlog.log_identification(rec, {
        "frf": {"frequency_hz": f, "measured": h * (1 + 0.05 * rng.standard_normal(f.size)),
                "linear": h * 1.6, "model": h * 0.8},
        "stabilisation": {"order": order, "frequency_hz": freq, "pole_class": cls},
        "criterion": {"orders": orders, "criterion": crit, "selected_order": 6},
        "mdi": {"frequency_hz": [9.8, 25.7, 31.0, 35.0], "mdi": [3.0, 1.5, 1e-5, 1e-6],
                "kept": [True, True, False, False], "threshold": 1e-3},
        "coefficients": {"frequency_hz": f,
                         "full": {"k3": 1e9 * (1 + 0.01 * np.sin(f))},
                         "reduced": {"k3": 1e9 * (1 + 0.003 * np.sin(f))},
                         "exact": {"k3": 1e9, "k_other": 5.0}},
        "convergence": {"update": 1, "acq_time_s": 3.0,
                        "values": {"natural_frequency_hz": [9.8, 25.7]},
                        "coefficients": {"k3": 1.001e9}},
        "summary": vlog.summary_markdown("web test", [("selected order", "6")]),
    }, update=1)
    vlog.log_status(rec, 3.0, {"updates": 1, "latency_s": 0.4}, "update 1")


#: What ``log_example`` draws, tab -> [(region name, (x0, y0, x1, y1) as fractions of the
#: views' area, colour, pixels)]: each region must hold at least ``pixels`` pixels of
#: ``colour`` (legend entries are a few dozen pixels at most, so the thresholds need the data
#: drawn).
CHECKS = {
    0: [("force signal", (0.0, 0.0, 0.55, 0.45), vlog.SIGNAL_PALETTE[0], 1500),
        ("displacement signals", (0.0, 0.5, 0.55, 1.0), vlog.SIGNAL_PALETTE[1], 1500),
        # the one update: both modes in the modes figure (top right) and as markers at 3 s
        # on the per-update view's 0-8 s axis (issue 27: not on the view's edge)
        ("modes figure after one update", (0.62, 0.04, 0.93, 0.26), vlog.SIGNAL_PALETTE[:2],
         25),
        ("modes after one update", (0.7, 0.3, 0.85, 0.45), vlog.SIGNAL_PALETTE[:2], 25)],
    1: [("stabilisation diagram", (0.0, 0.0, 0.58, 1.0), vlog.POLE_STYLE["stable"][0], 400),
        ("information criterion", (0.62, 0.0, 1.0, 1.0), (0, 114, 178), 300)],
    2: [("FRF model", (0.0, 0.0, 0.40, 0.62), vlog.FRF_STYLE["model"][0], 300),
        ("FRF underlying linear", (0.0, 0.0, 0.40, 0.62), vlog.FRF_STYLE["linear"][0], 400),
        ("MDI", (0.0, 0.66, 0.40, 1.0), (0, 158, 115), 30),
        ("coefficient Re", (0.57, 0.0, 0.87, 0.5), vlog.COEFFICIENT_PALETTE[0], 300),
        ("coefficient Im (dashed)", (0.57, 0.52, 0.87, 1.0), vlog.COEFFICIENT_PALETTE[0],
         300)],
}


#: Series colours of the per-update views (one per mode or status quantity; the palette's
#: grey is left out: the anti-aliased edge of the time cursor line is grey too).
_UPDATE_COLOURS = tuple(c for c in vlog.SIGNAL_PALETTE if len(set(c)) > 1)

#: What the README's main command draws (simulated SmallSat: 1 force and 39 displacement
#: channels, one update, 417 poles, 10 physical modes, two coefficients NC2-Z:neg and
#: NC2-Z:pos), tab -> [(region, box, colours, pixels)]. Boxes are fractions of the views'
#: area and stop short of the legends (written right of each figure; at the left of the
#: per-update views), so a legend alone counts 0: with every data series removed from the
#: .rrd (axes, legends, summary kept) each region below held 0 pixels of its colours, while
#: a legend entry outside them holds 21-106. Counts of the run on 2026-11-25 (threshold):
#: force 12555 (1500) and displacement 7032 (1500): the signal curves over 20 s;
#: stabilisation 3791 (400: a pole is ~10 px, 363 are fully stable), information criterion
#: 1204 (300). Counts of 2026-11-27 (layout of issue 27: the modes figure, the per-update
#: views over the whole recording and 5 s past the cursor, the coefficients' Re over Im in
#: the Frequency tab's right column; besides the data, these regions hold only the greys of
#: frames, grids and label boxes): modes figure 158 (80: 10 markers of ~40 px, pairs
#: overlapping); per-update markers, whole and inside the view at 49 s of 0-54 s (the
#: region right of 0.9; left of it 0: the update is not drawn elsewhere), natural
#: frequencies 207 (100), coefficients 64 (40: ~30 px a marker), status 221 (100); FRF
#: model 1663, measured 7388, underlying linear 890 (400 each), MDI of the physical poles
#: 214 (60), coefficient spectra Re 1102 and 1135, Im (dashed) 537 and 832 (300 each).
MAIN_CHECKS = {
    0: [("force signal", (0.0, 0.0, 0.55, 0.45), vlog.SIGNAL_PALETTE[0], 1500),
        # 39 displacement channels in three colour families, one per direction
        ("displacement signals", (0.0, 0.5, 0.55, 1.0),
         [c for p in vlog.DIRECTION_PALETTES.values() for c in p], 1500),
        ("modes figure of the update", (0.62, 0.04, 0.93, 0.26), _UPDATE_COLOURS, 80),
        ("natural frequencies of the update", (0.9, 0.3, 1.0, 0.45), _UPDATE_COLOURS, 100),
        ("coefficients of the update", (0.9, 0.47, 1.0, 0.6), vlog.COEFFICIENT_PALETTE[:2],
         40),
        ("status of the update", (0.9, 0.63, 1.0, 0.77), _UPDATE_COLOURS, 100)],
    1: [("stabilisation diagram", (0.0, 0.0, 0.49, 1.0), vlog.POLE_STYLE["stable"][0], 400),
        # each class in its own colour, the few "+ damping" (9) and "new" (~20) poles too:
        # a marker is ~10 px (issue 27: they were orange like "unstable", grey on grey)
        ("+ damping poles", (0.0, 0.0, 0.49, 1.0), vlog.POLE_STYLE["damping"][0], 30),
        ("new poles", (0.0, 0.0, 0.49, 1.0), vlog.POLE_STYLE["new"][0], 30),
        ("information criterion", (0.6, 0.0, 0.92, 1.0), (0, 114, 178), 300)],
    2: [("FRF model", (0.0, 0.0, 0.40, 0.62), vlog.FRF_STYLE["model"][0], 400),
        # the measured markers drawn on top of the model line (issue 27: hidden under it)
        ("FRF measured", (0.0, 0.0, 0.40, 0.62), vlog.FRF_STYLE["measured"][0], 400),
        ("FRF underlying linear", (0.0, 0.0, 0.40, 0.62), vlog.FRF_STYLE["linear"][0], 400),
        ("MDI of the physical poles", (0.0, 0.66, 0.40, 1.0), (0, 158, 115), 60),
        # Re over Im of each coefficient, as in the HTML report (issue 27: Re only)
        ("Re NC2-Z:neg", (0.57, 0.0, 0.87, 0.27), vlog.COEFFICIENT_PALETTE[0], 300),
        ("Im NC2-Z:neg", (0.57, 0.28, 0.87, 0.5), vlog.COEFFICIENT_PALETTE[0], 300),
        ("Re NC2-Z:pos", (0.57, 0.5, 0.87, 0.72), vlog.COEFFICIENT_PALETTE[1], 300),
        ("Im NC2-Z:pos", (0.57, 0.74, 0.87, 1.0), vlog.COEFFICIENT_PALETTE[1], 300)],
}


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def colour_count(px: np.ndarray, box: tuple[float, float, float, float],
                 colour: tuple[int, int, int] | Sequence[tuple[int, int, int]],
                 tol: int = 45) -> int:
    """Pixels of ``colour`` (L1 distance <= tol) in a fractional box of the views' area.

    ``colour`` is one RGB triple or a sequence of them (a pixel near any of them counts once).
    """
    h, w = BOTTOM - TOP, px.shape[1] - LEFT
    x0, y0, x1, y1 = box
    region = px[TOP + int(y0 * h):TOP + int(y1 * h), LEFT + int(x0 * w):LEFT + int(x1 * w)]
    colours = np.array(colour, dtype=np.int16).reshape(-1, 3)
    near = np.zeros(region.shape[:2], dtype=bool)
    for c in colours:
        near |= np.abs(region - c).sum(axis=-1) <= tol
    return int(near.sum())


def _failures(png: bytes, checks: Sequence[tuple]) -> list[str]:
    px = _pixels(png)
    out = []
    for name, box, colour, need in checks:
        got = colour_count(px, box, colour)
        if got < need:
            out.append(f"{name}: {got} pixels of {colour} < {need}")
    return out


# ---------------------------------------------------------------------------- test
def _serve(rec: rr.RecordingStream, groups: Sequence[str] = GROUPS,
           layout: dict | None = None) -> tuple[str, int]:
    grpc_port, web_port = _free_port(), _free_port()
    url = rec.serve_grpc(grpc_port=grpc_port,
                         default_blueprint=blueprint(groups, **(layout or {})))
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=url)
    return url, web_port


def _open_every_tab(rec: rr.RecordingStream, url: str, web_port: int,
                    checks: dict[int, list[tuple]], groups: Sequence[str],
                    shots: Path, layout: dict | None = None) -> dict[int, list[str]]:
    """Open the web viewer on ``url``, select each tab, return its failed checks.

    Screenshots are kept as ``shots/tab<k>.png``.
    """
    from playwright.sync_api import sync_playwright

    problems: dict[int, list[str]] = {}
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        page = browser.new_page(viewport={"width": WIDTH, "height": HEIGHT})
        page.goto(f"http://127.0.0.1:{web_port}/?url={url}", timeout=60_000)
        page.wait_for_selector("canvas", timeout=60_000)
        for tab in checks:
            if tab:  # select the tab; the timeline stays the blueprint's acq_time
                rec.send_blueprint(blueprint(groups, active_tab=tab, **(layout or {})),
                                   make_active=True)
            deadline = time.monotonic() + 120  # a software rasterizer on a busy machine
            while True:
                page.wait_for_timeout(3000)
                png = page.screenshot(timeout=120_000)
                problems[tab] = _failures(png, checks[tab])
                if not problems[tab] or time.monotonic() > deadline:
                    break
            (shots / f"tab{tab}.png").write_bytes(png)
        browser.close()
    return problems


def _blueprint_views(path: Path) -> list[tuple[str, str, str]]:
    """(kind, name, origin) of every view of the blueprint stored in an .rrd or .rbl."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    views = []
    for chunk in reader.stream(store=reader.blueprints()[0]).collect().stream():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:space_origin" not in batch.schema.names:
            continue
        row = [batch.column(f"ViewBlueprint:{k}").to_pylist()[-1]
               for k in ("class_identifier", "display_name", "space_origin")]
        views.append(tuple(v[0] if isinstance(v, list) else v for v in row))
    return sorted(views)


def test_the_main_commands_rrd_shows_every_tab(tmp_path):
    """``fnsi-lab run`` (the README's main command): its .rrd, every tab populated."""
    reason = _requirements()
    if reason:
        pytest.skip(reason)
    from rerun.chunk import RrdReader

    # the README's main command, as a user runs it (the simulated SmallSat: ~15 s on 2 cores)
    cmd = [sys.executable, "-m", "fnsi_lab", "run", "--out", "smallsat.mcap",
           "--rrd", "smallsat.rrd"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"{' '.join(cmd)}: {done.stdout[-2000:]}{done.stderr[-2000:]}"
    rrd = tmp_path / "smallsat.rrd"
    assert (tmp_path / "smallsat.html").is_file()

    # served as `fnsi-lab view smallsat.rrd --serve-web` serves it: the layout of the file's
    # groups, which is the one the .rrd opens with (its stored default blueprint)
    groups = signal_groups(rrd_entities(rrd))
    assert groups == ("force", "displacement")
    sizes, units = signal_layout(rrd)
    layout = {"group_sizes": sizes, "group_units": units}
    assert sizes == {"force": 1, "displacement": 39} and units["displacement"] == "mm"
    blueprint(groups, **layout).save(APP_ID, str(tmp_path / "served.rbl"))
    assert _blueprint_views(rrd) == _blueprint_views(tmp_path / "served.rbl")
    rec = rr.RecordingStream(APP_ID, recording_id="web-main-command")
    try:
        url, web_port = _serve(rec, groups, layout)
        rr.send_chunks(RrdReader(str(rrd)).stream().collect(), recording=rec)
        rec.flush()
        problems = _open_every_tab(rec, url, web_port, MAIN_CHECKS, groups, tmp_path,
                                   layout)
    finally:
        rec.disconnect()
    assert not any(problems.values()), f"{problems} (screenshots in {tmp_path})"


def test_every_tab_shows_its_plots_while_streaming_live(tmp_path):
    """Content logged while the viewer is connected: every tab, on the default timeline."""
    reason = _requirements()
    if reason:
        pytest.skip(reason)
    rec = rr.RecordingStream(APP_ID, recording_id="web-live")
    try:
        url, web_port = _serve(rec)
        log_example(rec)
        rec.flush()
        problems = _open_every_tab(rec, url, web_port, CHECKS, GROUPS, tmp_path)
    finally:
        rec.disconnect()
    assert not any(problems.values()), f"{problems} (screenshots in {tmp_path})"
