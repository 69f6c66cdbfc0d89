"""A newcomer's first run: the simulator compiles once, says so, and not for long."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

NOTICE = "compiling the simulator (first run only"


def _acquire(out: Path, cache: Path) -> tuple[subprocess.CompletedProcess, float]:
    """`fnsi-lab acquire` in a child with its own numba cache; (process, child CPU s)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), OPENBLAS_NUM_THREADS="1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "fnsi_lab", "acquire", "--out", str(out),
                           "--no-info"], env=env, capture_output=True, text=True, timeout=120)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return proc, cpu


@pytest.mark.slow
def test_the_first_acquire_compiles_the_simulator_once_with_a_notice(tmp_path: Path) -> None:
    # two fresh clones' worth (empty caches): the compilation's cost is the better of the
    # two, so that one run slowed by a busy shared machine does not decide
    costs = []
    for k in range(2):
        cache = tmp_path / f"numba-cache-{k}"  # empty: what a fresh clone has
        first, cpu_first = _acquire(tmp_path / f"first-{k}.mcap", cache)
        assert first.returncode == 0, first.stderr
        assert first.stderr.count(NOTICE) == 1, first.stderr
        assert any(cache.rglob("*.nbi")), "the compiled kernel was not cached"
        later, cpu_later = _acquire(tmp_path / f"later-{k}.mcap", cache)
        assert later.returncode == 0, later.stderr
        assert NOTICE not in later.stderr
        costs.append((cpu_first - cpu_later, cpu_first, cpu_later))
    # Compilation costs ~2.4 s of CPU on the 2-core reference machine (it was ~4.6 s with
    # np.linalg.solve in the kernel); CPU time, not wall, so a loaded CI machine does not
    # flip the test. 4 s separates the two with margin either way; one CI run on a machine
    # shared with benchmarks measured 4.0 s once (5.86 - 1.85), hence the better of two.
    assert min(costs)[0] < 4.0, costs
