"""The package installs cleanly: one import namespace, package data in the wheel, and the
README's main job from a wheel installed (not editable) in a fresh virtual environment.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GENERIC = ("daq", "ident", "replay", "viewer")


def test_no_code_imports_the_generic_top_level_names():
    # in a source checkout `import daq` would work (the folder is on sys.path) and hide a
    # module that breaks once installed: every import goes through fnsi_lab
    pattern = re.compile(rf"^\s*(from|import)\s+({'|'.join(GENERIC)})(\.|\s|$)", re.M)
    offenders = []
    for folder in ("fnsi_lab", *GENERIC, "tests", "bench"):
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            offenders += [f"{path.relative_to(ROOT)}: {m.group(0).strip()}"
                          for m in pattern.finditer(text)]
    assert not offenders, offenders


def test_every_subpackage_is_listed_for_setuptools():
    import tomllib

    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(conf["packages"])
    mapping = conf["package-dir"]
    found = set()
    for name, folder in mapping.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            found.add(".".join([name, *rel.parts]) if rel.parts else name)
    assert found <= listed, f"sub-packages missing from pyproject.toml: {sorted(found - listed)}"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out),
                           str(ROOT)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (whl,) = out.glob("fnsi_lab-*.whl")
    return whl


def test_wheel_holds_only_fnsi_lab_and_its_data(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert tops == {"fnsi_lab", next(t for t in tops if t.endswith(".dist-info"))}
    for data in ("fnsi_lab/ident/data/smallsat39.yaml", "fnsi_lab/ident/data/smallsat3.yaml",
                 "fnsi_lab/daq/data/smallsat.yaml", "fnsi_lab/daq/data/example_can.dbc",
                 "fnsi_lab/py.typed"):   # PEP 561: the type hints are for users' checkers
        assert data in names, data


@pytest.mark.slow
def test_main_job_from_the_wheel_in_a_fresh_venv(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    proc = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-compile", str(wheel)],
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    work = tmp_path / "work"      # outside the checkout: nothing of the source tree is importable
    work.mkdir()
    site = subprocess.run([str(py), "-c", "import fnsi_lab, sys; print(fnsi_lab.__file__)"],
                          capture_output=True, text=True, cwd=work, env=env, check=True)
    assert str(venv) in site.stdout and str(ROOT) not in site.stdout
    for generic in GENERIC:
        probe = subprocess.run([str(py), "-c", f"import {generic}"], cwd=work, env=env,
                               capture_output=True, text=True)
        assert probe.returncode != 0, f"the wheel installed a top-level {generic!r}"
    run = subprocess.run([str(venv / "bin" / "fnsi-lab"), "run", "--out", "x.mcap",
                          "--rrd", "x.rrd"], capture_output=True, text=True, cwd=work, env=env,
                         timeout=900)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert "NC2-Z" in run.stdout and (work / "x.mcap").stat().st_size > 0
    code = ("import fnsi_lab; r = fnsi_lab.identify('x.mcap', config='smallsat39'); "
            "print(r.to_json()['order'])")
    ident = subprocess.run([str(py), "-c", code], capture_output=True, text=True, cwd=work,
                           env=env, timeout=900)
    assert ident.returncode == 0, ident.stderr[-2000:]
    assert int(ident.stdout.strip().splitlines()[-1]) >= 10
    cli = subprocess.run([str(venv / "bin" / "fnsi-lab"), "ident", "x.mcap", "--config",
                          "smallsat39", "--auto", "--quiet", "--json", "r.json"],
                         capture_output=True, text=True, cwd=work, env=env, timeout=900)
    assert cli.returncode == 0, cli.stderr[-2000:]
