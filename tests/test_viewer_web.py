"""The web viewer renders the fnsi-lab blueprint in headless Chromium.

Needs the Debian ``chromium`` package (``/usr/bin/chromium``) and the ``playwright`` Python
package (its driver only; the browser is the system one). Skipped, with the reason, when
either is missing.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import time

import numpy as np
import pytest
import rerun as rr

from fnsi_lab.viewer import log as vlog
from fnsi_lab.viewer.blueprint import blueprint

CHROMIUM = os.environ.get("FNSI_LAB_CHROMIUM", "/usr/bin/chromium")
FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--ignore-gpu-blocklist"]

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


def test_web_viewer_renders_the_blueprint(tmp_path):
    reason = _requirements()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    grpc_port, web_port = _free_port(), _free_port()
    rec = rr.RecordingStream("fnsi-lab-web-test", recording_id="web")
    bp = blueprint(("force", "displacement"))
    url = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=bp)
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=url)
    try:
        groups = {"force": [0], "displacement": [1, 2]}
        vlog.log_signal_styles(rec, groups, ["F", "x1", "x2"])
        t = np.arange(2000) / 1000.0
        data = np.c_[np.sin(2 * np.pi * 5 * t), np.cos(2 * np.pi * 3 * t), 0.5 * t]
        vlog.log_signals(rec, data, 0.0, 1000.0, groups)
        vlog.log_summary(rec, vlog.summary_markdown("web test", [("selected order", "4")]))
        vlog.log_convergence(rec, 1, 2.0, {"natural_frequency_hz": [9.8, 25.7]})
        rec.flush()
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(f"http://127.0.0.1:{web_port}/?url={url}", timeout=60_000)
            page.wait_for_selector("canvas", timeout=60_000)
            shots = []
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                page.wait_for_timeout(4000)
                png = page.screenshot()
                shots.append(png)
                if _colours(png) > 200:  # the app UI and plots are drawn, not the splash
                    break
            browser.close()
        (tmp_path / "web.png").write_bytes(shots[-1])
        n_colours = _colours(shots[-1])
        assert n_colours > 200, f"blank or splash-only screenshot ({n_colours} colours)"
        assert _std(shots[-1]) > 10
    finally:
        rec.disconnect()


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def _colours(png: bytes) -> int:
    px = _pixels(png).reshape(-1, 3).astype(np.int64)
    return int(np.unique(px[:, 0] * 65536 + px[:, 1] * 256 + px[:, 2]).size)


def _std(png: bytes) -> float:
    return float(_pixels(png).std())
