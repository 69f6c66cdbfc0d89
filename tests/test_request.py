"""ident.request: one identification request, resolved once (issue 28), validated like the CLI."""

from __future__ import annotations

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.errors import FnsiLabError
from fnsi_lab.ident.request import DEFAULT_ORDERS, check_order, resolve_request


def _arrays() -> dict:
    """A 1-DOF oscillator (20 Hz, 2 %), 4 periods of a multisine over 2-40 Hz."""
    from scipy import signal
    fs, n = 256.0, 256
    t = np.arange(6 * n) / fs
    u = sum(np.cos(2 * np.pi * k * t + k ** 2) for k in range(2, 40))
    sysd = signal.cont2discrete(([1.0], [1.0, 2 * 0.02 * 2 * np.pi * 20, (2 * np.pi * 20) ** 2]),
                                1 / fs, method="zoh")
    y = signal.lfilter(sysd[0][0], sysd[1], np.tile(u[:n], 30))[-6 * n:]
    return {"u": u, "y": y, "fs": fs, "N": n}


@pytest.mark.parametrize("bad", ["x", 6.7, 0, -3, True])
def test_the_api_refuses_an_order_that_is_not_a_positive_integer(bad):
    with pytest.raises(FnsiLabError, match=r"order must be a positive integer.*fix"):
        fnsi_lab.identify(_arrays(), {"band_hz": [2, 40]}, order=bad)


def test_max_order_below_order_is_refused_before_any_work():
    with pytest.raises(FnsiLabError, match="max_order 3 is below order 6"):
        fnsi_lab.identify(_arrays(), {"band_hz": [2, 40]}, order=6, max_order=3)


def test_the_sweep_comes_from_the_caller_then_the_config_then_the_default():
    from fnsi_lab.api import _as_input, load_config
    inp = _as_input(_arrays(), None)
    plain = load_config({"band_hz": [2, 40]})
    assert resolve_request(inp, plain).orders == DEFAULT_ORDERS == tuple(range(2, 61))
    with_auto = load_config({"band_hz": [2, 40], "auto": {"orders": "2:8"}})
    assert resolve_request(inp, with_auto).orders == tuple(range(2, 9))
    assert resolve_request(inp, with_auto, orders="4,6").orders == (4, 6)
    req = resolve_request(inp, plain, order=4.0)
    assert req.order == 4 and not req.auto
    with pytest.raises(Exception):                      # frozen: resolved once, never patched
        req.order = 6  # type: ignore[misc]
    assert check_order(np.int64(7)) == 7


def test_the_api_runs_with_one_blas_thread_and_gives_the_process_its_count_back():
    """fnsi_lab.identify limits OpenBLAS to one thread for its own work (the README example:
    23 s with the default threads, 1.3 s with one, on a loaded 2-core machine) and restores
    the caller's count afterwards."""
    from fnsi_lab.blas import blas_threads, limit_blas_threads, restored_blas_threads
    seen = []
    import fnsi_lab.ident.pipeline as pipeline
    original = pipeline.identify_request

    def spy(*args, **kwargs):
        seen.append(blas_threads())
        return original(*args, **kwargs)

    with restored_blas_threads():
        if limit_blas_threads(2) is None:
            pytest.skip("no OpenBLAS library to count threads of")
        pipeline.identify_request = spy
        try:
            fnsi_lab.identify(_arrays(), {"band_hz": [2, 40]}, order=2)
        finally:
            pipeline.identify_request = original
        assert seen == [1] and blas_threads() == 2
