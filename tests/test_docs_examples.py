"""Every ```python example in README.md and docs/*.md runs as written.

Each file's blocks run in order in one namespace, in a folder that holds what the docs
refer to: ``run.mcap`` (the default SmallSat experiment, as ``fnsi-lab acquire`` records
it) and ``run.rrd`` (its replay through the viewer). A block that is only an excerpt must
be fenced as ```text, not ```python. The docstring examples of the public API
(:mod:`fnsi_lab.api`) run too.
"""

from __future__ import annotations

import doctest
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def _blocks(path: Path) -> list[str]:
    return BLOCK.findall(path.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    from fnsi_lab.cli import main

    d = tmp_path_factory.mktemp("docs")
    assert main(["acquire", "--out", str(d / "run.mcap"), "--quiet", "--no-info"]) == 0
    assert main(["replay", str(d / "run.mcap"), "--method", "frf", "--rrd", str(d / "run.rrd"),
                 "--quiet"]) == 0
    return d


@pytest.mark.parametrize("path", [p for p in DOCS if _blocks(p)], ids=lambda p: p.name)
def test_doc_examples_run_as_written(path, workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": f"docs_{path.stem}"}
    for i, code in enumerate(_blocks(path)):
        try:
            exec(compile(code, f"{path.name}[python block {i + 1}]", "exec"), namespace)
        except Exception as exc:  # noqa: BLE001 - report which block of which file
            pytest.fail(f"{path.relative_to(ROOT)} python block {i + 1} failed: "
                        f"{type(exc).__name__}: {exc}")


def test_api_docstring_examples():
    import fnsi_lab.api

    res = doctest.testmod(fnsi_lab.api, optionflags=doctest.ELLIPSIS)
    assert res.attempted > 0 and res.failed == 0


def test_every_doc_example_is_checked():
    # the docs keep runnable examples: at least the API page and the recording format
    names = {p.name for p in DOCS if _blocks(p)}
    assert {"api.md", "recording-format.md"} <= names


def test_result_json_spectra_layout_as_documented():
    """``coefficient_spectra`` and ``frf`` of a result file have the layout docs/robust.md
    ("JSON") describes: keys, shapes and {re, im} for complex arrays (issue 14)."""
    import json

    import numpy as np
    from scipy import signal

    import fnsi_lab

    doc = (ROOT / "docs" / "robust.md").read_text(encoding="utf-8")
    section = doc.split("## JSON", 1)[1].split("\n## ", 1)[0]
    for key in ("`coefficient_spectra`", "`frf`", "frequency_hz", "excited", "names", "values",
                "exact", "outputs", "inputs", "underlying_linear", "measured", "model",
                "[F_e][p][m]"):
        assert key in section, key
    fs, n = 256.0, 256  # a 1-DOF oscillator with a (small) cubic basis column, 5 periods
    t = np.arange(5 * n) / fs
    u = sum(np.cos(2 * np.pi * k * t + k ** 2) for k in range(2, 40))
    w = 2 * np.pi * 20
    sys = signal.cont2discrete(([1.0], [1.0, 2 * 0.02 * w, w ** 2]), 1 / fs, method="zoh")
    y = signal.lfilter(sys[0][0], sys[1], np.tile(u[:n], 30))[-5 * n:]
    cfg = {"band_hz": [2, 60], "inputs": [{"name": "u0", "driving_point": "y0"}],
           "nonlinearities": [{"name": "k3", "kind": "polynomial", "exponent": 3,
                               "channels": {"y0": 1}, "truth": 0.0}]}
    res = json.loads(json.dumps(fnsi_lab.identify({"u": u, "y": y, "fs": fs, "N": n}, cfg,
                                                  order=2).to_json()))
    cs, frf = res["coefficient_spectra"], res["frf"]
    assert set(cs) == {"frequency_hz", "excited", "names", "values", "exact"}
    n_lines = len(cs["frequency_hz"])
    assert n_lines == res["n_lines"] and len(cs["excited"]) == n_lines
    assert sum(cs["excited"]) == res["n_excited_lines"]
    assert cs["names"] == ["k3"] and cs["exact"] == {"k3": 0.0}
    assert set(cs["values"]["k3"]) == {"re", "im"}
    assert len(cs["values"]["k3"]["re"]) == len(cs["values"]["k3"]["im"]) == n_lines
    assert set(frf) == {"frequency_hz", "outputs", "inputs", "underlying_linear", "measured",
                        "model"}
    f_e = len(frf["frequency_hz"])
    assert f_e == res["n_excited_lines"] and frf["outputs"] == ["y0"] and frf["inputs"] == ["u0"]
    for k in ("underlying_linear", "measured", "model"):
        for part in ("re", "im"):
            arr = np.array(frf[k][part], dtype=float)
            assert arr.shape == (f_e, 1, 1), (k, part, arr.shape)


def test_docs_stand_alone():
    """The docs cite only the repository's own files (and public web pages), never a path
    of the machine they were written on."""
    for path in DOCS:
        text = path.read_text(encoding="utf-8")
        for bad in ("/work/", "/home/", "/tmp/"):
            assert bad not in text, f"{path.relative_to(ROOT)} cites {bad}..."
