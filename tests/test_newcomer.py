"""A newcomer's first hour (issue 27): a fresh clone, the README's commands as written.

A fresh clone of this repository gets its own virtual environment; the README's set-up
command (``python -m pip install -e . && fnsi-lab run ...``) runs there as written, then
every command of the README's "What you can do" table runs on the main job's outputs and
must exit 0, or give the documented refusal (status 2 and one line naming the fix). The
table is read from the README: a command added to it without a case here fails the test.

The clone's environment sees the test environment's packages through a ``.pth`` line (the
dependencies are those of ``pip install -e .``, already installed by the README's test
command; fetching them again would cost minutes and the network), so ``pip install -e .``
installs fnsi-lab itself from the clone, with an empty numba cache: the first run compiles
the simulator as a newcomer's does. About 2 minutes on 2 cores.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

pytestmark = pytest.mark.slow


def _setup_command(readme: str) -> str:
    """The README's first bash block (the two-command set-up with the main job)."""
    block = re.search(r"## Set-up.*?```bash\n(.*?)\n```", readme, re.S)
    assert block, "README.md has no bash block under '## Set-up'"
    return block.group(1).strip()


def _table_commands(readme: str) -> list[str]:
    """Subcommands of the README's 'What you can do' table, in order."""
    section = readme.split("## What you can do", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `fnsi-lab (\w+)", section, re.M)


def _lab_csv(path: Path, drive_csv: Path) -> None:
    """A lab tool's CSV export (force and one response, units in the header) from the
    exported drive: what `fnsi-lab import` reads (docs/formats.md)."""
    data = np.loadtxt(drive_csv, delimiter=",", skiprows=1)
    t, force = data[:, 0], data[:, 1]
    response = 1e-3 * np.roll(force, 3)  # any response will do: import does not identify
    with open(path, "w") as fh:
        fh.write("# samples_per_period: 8192\n# transient_periods: 1\n")
        fh.write("time,F [N],X [mm]\n")
        for row in zip(t, force, response):
            fh.write(",".join(repr(float(v)) for v in row) + "\n")


#: One concrete invocation per row of the README's table, on the main job's outputs
#: (smallsat.mcap, smallsat.rrd) and on what earlier rows wrote. `live` and `replay` are
#: paced at 25x real time (the README's `--speed X`) to keep the test short.
TABLE_CASES: dict[str, list[list[str]]] = {
    "run": [],  # the set-up command ran it; its second run is the refusal below
    "acquire": [["acquire", "--out", "acquired.mcap"]],
    "info": [["info", "smallsat.mcap"], ["info", "smallsat.mcap", "--json"]],
    "excitation": [["excitation", "--out", "drive.csv"]],
    "recover": [["recover", "smallsat.mcap", "recovered.mcap"]],
    "ident": [["ident", "smallsat.mcap", "--config", "smallsat39", "--auto", "--json",
               "result.json"]],
    "live": [["live", "--out", "live.mcap", "--rrd", "live.rrd", "--speed", "25"]],
    "replay": [["replay", "smallsat.mcap", "--speed", "25", "--rrd", "replay.rrd"]],
    "view": [["view", "smallsat.rrd", "--list"]],  # serving it: tests/test_viewer.py
    "batch": [["batch", "smallsat.mcap", "--config", "smallsat39", "--auto", "--out",
               "campaign.parquet", "--workers", "1"]],
    "campaign": [["campaign", "campaign.parquet", "--rrd", "campaign.rrd"]],
    "report": [["report", "result.json", "--out", "report.html"]],
    "import": [["import", "lab.csv", "--out", "imported.mcap", "--inputs", "F"]],
    "export": [["export", "result.json", "--uff", "result.uff", "--csv", "tables"]],
    "validate": [["validate", "result.json", "acquired.mcap", "--json", "validation.json"]],
    "analyse": [["analyse", "smallsat.mcap"]],
    "locate": [["locate", "smallsat.mcap", "--config", "smallsat39", "--json", "where.json"]],
}


def test_a_fresh_clone_runs_the_readme_as_written(tmp_path):
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    readme = README.read_text()
    table = _table_commands(readme)
    assert set(table) == set(TABLE_CASES), (
        f"README table commands {table} != cases {sorted(TABLE_CASES)}: add a case")

    clone, venv = tmp_path / "clone", tmp_path / "venv"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=120)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    site = next((venv / "lib").glob("python*/site-packages"))
    (site / "_test_environment.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "PYTHONPATH", "NUMBA_CACHE_DIR", "DISPLAY",
                        "WAYLAND_DISPLAY")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}", MPLBACKEND="Agg",
               OPENBLAS_NUM_THREADS="1")
    log: list[str] = []

    def shell(command: str, timeout: float = 300) -> subprocess.CompletedProcess:
        t0 = time.monotonic()
        done = subprocess.run(["bash", "-c", command], cwd=clone, env=env, text=True,
                              capture_output=True, timeout=timeout)
        log.append(f"{time.monotonic() - t0:6.1f} s  exit {done.returncode}  {command}")
        return done

    # the README's set-up command, as written: install, then the main job
    setup = shell(_setup_command(readme), timeout=600)
    assert setup.returncode == 0, setup.stdout[-3000:] + setup.stderr[-3000:]
    assert "compiling the simulator (first run only" in setup.stderr  # a fresh clone
    assert "selected order (IC)" in setup.stdout and "N/mm" in setup.stdout
    for name in ("smallsat.mcap", "smallsat.rrd", "smallsat.html"):
        assert (clone / name).is_file(), name
    # run again: refused, nothing overwritten, the fix named (README: "status 2 ... --force")
    main_job = _setup_command(readme).split("&&")[-1].strip()
    again = shell(main_job)
    assert again.returncode == 2 and "--force" in again.stderr, again.stderr

    for command in table:
        for args in TABLE_CASES[command]:
            if command == "import":
                _lab_csv(clone / "lab.csv", clone / "drive.csv")
            done = shell("fnsi-lab " + " ".join(f"'{a}'" for a in args))
            assert done.returncode == 0, (f"fnsi-lab {' '.join(args)}:\n"
                                          f"{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    print("\n".join(log))
