"""OpenBLAS thread count of the running process (numpy/scipy), without extra dependencies."""

from __future__ import annotations

__all__ = ["limit_blas_threads"]

_BLAS_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
             "openblas_set_num_threads64_", "openblas_set_num_threads")
_BLAS_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
             "openblas_get_num_threads64_", "openblas_get_num_threads")


def limit_blas_threads(n: int = 1) -> int | None:
    """Set the OpenBLAS thread count of the loaded numpy/scipy libraries (process-wide).

    The live service runs identification next to acquisition, assembly and Rerun's own
    threads; a multi-threaded BLAS on top of that oversubscribes a small machine badly
    (measured on 2 cores: one SmallSat identification 10 s with OpenBLAS threads, 0.55 s
    with one). The same effect as ``OPENBLAS_NUM_THREADS=1`` set after numpy was imported
    (what ``threadpoolctl`` does, without the dependency).

    Returns
    -------
    int or None
        The previous thread count, or None when no OpenBLAS library was found (other BLAS
        libraries are left alone).
    """
    import ctypes
    import sys

    # numpy and scipy wheels each bundle their own OpenBLAS, and scipy's is loaded only
    # with scipy.linalg: load both now, or the first identification of a process would
    # run scipy's solves multi-threaded (slower, and not bit-identical to the next ones)
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401

    if not sys.platform.startswith("linux"):
        return None
    try:
        with open("/proc/self/maps") as f:
            libs = {line.split()[-1] for line in f if "openblas" in line.lower()
                    and line.rstrip().endswith(".so") or ".so." in line and "openblas" in line.lower()}
    except OSError:
        return None
    previous = None
    for path in sorted(libs):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get_name, set_name in zip(_BLAS_GET, _BLAS_SET):
            setter = getattr(lib, set_name, None)
            if setter is None:
                continue
            getter = getattr(lib, get_name, None)
            if getter is not None and previous is None:
                getter.restype = ctypes.c_int
                previous = int(getter())
            setter.argtypes = [ctypes.c_int]
            setter(int(n))
            break
    return previous
