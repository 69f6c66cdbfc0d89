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
