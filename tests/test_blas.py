"""fnsi_lab.blas: every OpenBLAS of the process is limited, also scipy's (loaded late)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHECK = """
import ctypes, json
from fnsi_lab.blas import limit_blas_threads
limit_blas_threads(1)   # first thing: before anything imported scipy.linalg
counts = {}
for line in open('/proc/self/maps'):
    path = line.split()[-1]
    if 'openblas' in path.lower() and '.so' in path and path not in counts:
        lib = ctypes.CDLL(path)
        for name in ('scipy_openblas_get_num_threads64_', 'scipy_openblas_get_num_threads',
                     'openblas_get_num_threads64_', 'openblas_get_num_threads'):
            getter = getattr(lib, name, None)
            if getter is not None:
                getter.restype = ctypes.c_int
                counts[path] = getter()
                break
print(json.dumps(sorted(counts.values())))
"""


def test_every_openblas_library_gets_one_thread():
    env_free = {k: v for k, v in os.environ.items()
                if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    counts = json.loads(subprocess.run([sys.executable, "-c", CHECK], capture_output=True,
                                       text=True, env=env_free, check=True).stdout)
    if not counts:
        import pytest
        pytest.skip("no OpenBLAS library in this numpy/scipy build")
    assert set(counts) == {1}
