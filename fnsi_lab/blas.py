"""OpenBLAS thread count of the running process (numpy/scipy), without extra dependencies."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__ = ["limit_blas_threads", "blas_threads", "restored_blas_threads"]

_BLAS_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
             "openblas_set_num_threads64_", "openblas_set_num_threads")
_BLAS_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
             "openblas_get_num_threads64_", "openblas_get_num_threads")


def _openblas_libraries() -> list[tuple]:
    """``(getter, setter)`` ctypes functions of every OpenBLAS loaded in this process.

    numpy and scipy wheels each bundle their own OpenBLAS, and scipy's is loaded only with
    scipy.linalg: both are loaded first, or the first identification of a process would
    run scipy's solves multi-threaded (slower, and not bit-identical to the next ones).
    Other BLAS libraries, and platforms without ``/proc/self/maps``, give an empty list.
    """
    import ctypes
    import sys

    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401

    if not sys.platform.startswith("linux"):
        return []
    try:
        with open("/proc/self/maps") as f:
            libs = {line.split()[-1] for line in f if "openblas" in line.lower()
                    and line.rstrip().endswith(".so") or ".so." in line and "openblas" in line.lower()}
    except OSError:
        return []
    found = []
    for path in sorted(libs):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get_name, set_name in zip(_BLAS_GET, _BLAS_SET):
            setter = getattr(lib, set_name, None)
            if setter is None:
                continue
            setter.argtypes = [ctypes.c_int]
            getter = getattr(lib, get_name, None)
            if getter is not None:
                getter.restype = ctypes.c_int
            found.append((getter, setter))
            break
    return found


def blas_threads() -> int | None:
    """The OpenBLAS thread count of the process (the first library's), or None if unknown."""
    for getter, _ in _openblas_libraries():
        if getter is not None:
            return int(getter())
    return None


def limit_blas_threads(n: int = 1) -> int | None:
    """Set the OpenBLAS thread count of the loaded numpy/scipy libraries (process-wide).

    The live service runs identification next to acquisition, assembly and Rerun's own
    threads; a multi-threaded BLAS on top of that oversubscribes a small machine badly
    (measured on 2 cores: one SmallSat identification 10 s with OpenBLAS threads, 0.55 s
    with one). The same effect as ``OPENBLAS_NUM_THREADS=1`` set after numpy was imported
    (what ``threadpoolctl`` does, without the dependency). Callers that run inside another
    program (the CLI's ``main`` called in-process, tests) restore the previous count with
    :func:`restored_blas_threads`.

    Returns
    -------
    int or None
        The previous thread count, or None when no OpenBLAS library was found (other BLAS
        libraries are left alone).
    """
    previous = blas_threads()
    for _, setter in _openblas_libraries():
        setter(int(n))
    return previous


@contextlib.contextmanager
def restored_blas_threads() -> Iterator[None]:
    """Restore the process's OpenBLAS thread count when the block ends.

    ``fnsi-lab`` commands set one BLAS thread for their own work; called in-process (a test,
    a notebook) they must not leave that setting to the code that runs next.
    """
    previous = blas_threads()
    try:
        yield
    finally:
        if previous is not None:
            for _, setter in _openblas_libraries():
                setter(previous)
