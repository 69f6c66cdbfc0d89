"""First and later `fnsi-lab acquire` in a fresh environment (empty numba cache).

Runs the default SmallSat acquisition as a child process with its own, empty
``NUMBA_CACHE_DIR`` (what a fresh clone has), then again with the cache filled, and
prints wall and CPU seconds of each. ``python bench/first_run.py [--repeat N]``;
figures go to bench/RESULTS.md ("First run").
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _acquire(out: Path, cache: Path) -> tuple[float, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), OPENBLAS_NUM_THREADS="1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fnsi_lab", "acquire", "--out", str(out), "--force",
                    "--quiet", "--no-info"], env=env, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2, help="fresh caches to try (default 2)")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    for i in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            cache = Path(tmp) / "numba"
            first = _acquire(Path(tmp) / "a.mcap", cache)
            later = _acquire(Path(tmp) / "a.mcap", cache)
        print(f"run {i + 1}: first acquire {first[0]:.2f} s wall ({first[1]:.2f} s CPU), "
              f"later {later[0]:.2f} s wall ({later[1]:.2f} s CPU)")


if __name__ == "__main__":
    main()
