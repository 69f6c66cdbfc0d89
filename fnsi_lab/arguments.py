"""Command-line options validated where they are parsed: one rule per option, every command.

Each numeric option of the ``fnsi-lab`` commands has one rule here (an argparse ``type``),
and every command that takes the option uses it, so ``--harmonics 0`` is refused the same
way by ``report``, ``replay``, ``live`` and ``run``: by argparse, before any work, exit 2,
with the option, the value and the fix in one line::

    fnsi-lab replay: error: argument --harmonics: must be >= 1, got 0 (fix: 1 processes
    the excited band, 5 up to five times its highest frequency)

Rules a Python caller must meet too (the model order of :func:`fnsi_lab.identify`) are
plain functions raising the project's errors (``check_order``: the one order rule of
:mod:`fnsi_lab.ident.request`), wrapped for argparse. This module imports nothing numerical (``fnsi-lab --help`` and
``acquire`` stay light); ``--orders`` loads the order syntax only when given.
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Callable
from urllib.parse import urlsplit

from fnsi_lab.errors import ConfigError

__all__ = ["whole", "real", "check_order", "check_orders", "check_order_options",
           "ORDER", "MAX_ORDER", "BLOCK_ROWS", "BLAS_THREADS", "HARMONICS", "EVERY",
           "SAMPLES_PER_PERIOD", "TRANSIENT_PERIODS", "STEADY_TOLERANCE", "DECIMATION",
           "WEB_WAIT", "SPEED", "FOLLOW_TIMEOUT", "QUEUE_BLOCKS", "WORKERS",
           "RELATIVE_SPREAD", "CONTACT_FRACTION", "SAMPLE_RATE", "PERIODS", "POSITIVE_SCALE",
           "ORDERS", "CONNECT_URL", "INPUT"]


def whole(minimum: int, fix: str, *, name: str) -> Callable[[str], int]:
    """An argparse type: a whole number ``>= minimum`` (``fix`` says what to give)."""
    def parse(text: str) -> int:
        try:
            value = int(str(text).strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected a whole number, got {text!r} (fix: {fix})") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value} (fix: {fix})")
        return value

    parse.__name__ = name
    return parse


def real(fix: str, *, name: str, above: float | None = None, minimum: float | None = None,
         maximum: float | None = None) -> Callable[[str], float]:
    """An argparse type: a finite number ``> above`` / ``>= minimum`` / ``<= maximum``."""
    def parse(text: str) -> float:
        try:
            value = float(str(text).strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected a number, got {text!r} (fix: {fix})") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r} "
                                             f"(fix: {fix})")
        if above is not None and not value > above:
            raise argparse.ArgumentTypeError(f"must be > {above:g}, got {value:g} (fix: {fix})")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum:g}, got {value:g} "
                                             f"(fix: {fix})")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum:g}, got {value:g} "
                                             f"(fix: {fix})")
        return value

    parse.__name__ = name
    return parse


# ---------------------------------------------------------------------------- model orders
def check_order(value: Any, field: str = "order") -> int | None:
    """A model order as the API and the command line accept it: a positive integer.

    The one rule is :func:`fnsi_lab.ident.request.check_order` (``6.0`` is 6; ``6.7``,
    ``'x'``, ``True`` and ``0`` are refused, naming ``field`` and the fix); ``None`` passes
    (no order given). Imported when called: ``fnsi-lab --help`` loads no numerical module.
    """
    if value is None:
        return None
    from fnsi_lab.ident.request import check_order as rule

    return rule(value, field)


def check_orders(value: Any, field: str = "orders") -> Any:
    """An order sweep (``'2:60'``, ``'2:60:2'``, ``'4,6,8'`` or a sequence), validated by
    the one order syntax (:func:`fnsi_lab.ident.robust.options.parse_orders`); returned as given."""
    if value is None:
        return None
    from fnsi_lab.ident.robust.options import parse_orders

    try:
        parse_orders(value)
    except ValueError as exc:  # IdentError is a ValueError
        raise ConfigError(str(exc), field=field,
                          fix="give whole numbers >= 1, FIRST <= LAST") from None
    return value


def check_order_options(*, order: Any = None, max_order: Any = None, block_rows: Any = None,
                        reduce_at: Any = None, orders: Any = None,
                        prefix: str = "") -> dict[str, Any]:
    """Every order option of an identification, each by its rule, and their relations
    (``max_order >= order``); ``prefix`` is ``'--'`` for command-line names.

    Returns
    -------
    dict
        ``order``, ``max_order``, ``block_rows``, ``reduce_at`` as ints (or None) and
        ``orders`` as given.
    """
    def name(key: str) -> str:
        return prefix + (key.replace("_", "-") if prefix else key)

    out = {key: check_order(value, name(key)) for key, value in
           (("order", order), ("max_order", max_order), ("block_rows", block_rows),
            ("reduce_at", reduce_at))}
    out["orders"] = check_orders(orders, name("orders"))
    if out["order"] is not None and out["max_order"] is not None \
            and out["max_order"] < out["order"]:
        raise ConfigError(f"{name('max_order')} {out['max_order']} is below "
                          f"{name('order')} {out['order']}",
                          fix=f"give {name('max_order')} >= {out['order']}, or leave it out")
    return out


def _order_type(field: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(str(text).strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r} "
                                             f"(fix: e.g. {field} 10)") from None
        try:
            return check_order(value, field)  # type: ignore[return-value]
        except ValueError as exc:  # IdentError
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = field
    return parse


def _orders_type(text: str) -> str:
    try:
        return check_orders(text, "--orders")
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(f"{exc.reason} (fix: {exc.fix})") from None


def _connect_url(text: str) -> str:
    """``--connect``: the gRPC address of a running Rerun viewer."""
    parts = urlsplit(str(text).strip())
    if parts.scheme not in ("rerun", "rerun+http", "rerun+https") or not parts.netloc \
            or parts.path.rstrip("/") != "/proxy":
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a Rerun viewer address (fix: give rerun+http://HOST:PORT/proxy, "
            "e.g. rerun+http://127.0.0.1:9876/proxy, or --connect alone for that one)")
    return str(text).strip()


def _input_name(text: str) -> str:
    """An input file or config name: not empty (``''`` would name the current folder)."""
    if not str(text).strip():
        raise argparse.ArgumentTypeError("is empty (fix: give a file name)")
    return text


#: Input files and configs of every command (``ident ''`` read the current folder).
INPUT = _input_name
#: Model orders (``ident --order``, ``--reduce-at``, ``batch --order``).
ORDER = _order_type("--order")
MAX_ORDER = _order_type("--max-order")
REDUCE_AT = _order_type("--reduce-at")
#: Block rows ``i`` of the subspace step.
BLOCK_ROWS = _order_type("--block-rows")
#: An order sweep in the one syntax.
ORDERS = _orders_type
BLAS_THREADS = whole(1, "give 1 (default, best on a shared machine) or the number of "
                        "cores", name="blas_threads")
HARMONICS = real("1 processes the excited band, 5 up to five times its highest frequency",
                 name="harmonics", minimum=1.0)
EVERY = whole(1, "1 re-identifies after every new steady-state period", name="every")
SAMPLES_PER_PERIOD = whole(1, "give the multisine period in samples, e.g. 8192",
                           name="samples_per_period")
TRANSIENT_PERIODS = whole(0, "give the number of leading periods to drop, 0 for none",
                          name="transient_periods")
STEADY_TOLERANCE = real("give a relative RMS difference such as 0.05", name="tolerance",
                        above=0.0)
DECIMATION = whole(1, "1 logs every sample, 10 every tenth", name="decimation")
WEB_WAIT = real("give the seconds to keep serving, 0 for none", name="seconds", minimum=0.0)
SPEED = real("give recorded seconds per wall second, e.g. 1 for real time, 10 for ten "
             "times faster", name="speed", above=0.0)
FOLLOW_TIMEOUT = real("give the seconds to wait for new data, e.g. 10", name="seconds",
                      above=0.0)
QUEUE_BLOCKS = whole(1, "give a capacity >= 1 (0 would drop every block)", name="blocks")
WORKERS = whole(1, "give N >= 1", name="workers")
RELATIVE_SPREAD = real("give a fraction of |mean| such as 0.1", name="spread", minimum=0.0)
CONTACT_FRACTION = real("give a fraction of the time between 0 and 1, e.g. 0.001",
                        name="fraction", minimum=0.0, maximum=1.0)
SAMPLE_RATE = real("give the sample rate in Hz, e.g. 2048", name="rate", above=0.0)
PERIODS = whole(1, "give the number of periods, e.g. 6", name="periods")
POSITIVE_SCALE = real("give a positive number", name="scale", above=0.0)
CONNECT_URL = _connect_url
