"""Independent numerical work on a few threads: the QR/SVD, FFT and solve calls of this
package release the interpreter lock, so two threads use two cores (with BLAS itself held
to one thread, the setting the tools run under) and give the same numbers as one."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence, TypeVar

__all__ = ["parallel_map", "default_workers"]

T = TypeVar("T")
R = TypeVar("R")


def default_workers() -> int:
    """Threads for independent work: ``min(4, cores)``."""
    return min(4, os.cpu_count() or 1)


def parallel_map(fn: Callable[[T], R], items: Sequence[T], workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` on up to ``workers`` threads (default
    :func:`default_workers`), in the items' order; one thread when there is one item or one
    worker."""
    workers = default_workers() if workers is None else int(workers)
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(workers, len(items))) as pool:
        return list(pool.map(fn, items))
