"""Values written into user-facing messages as plain text, never as Python reprs.

Errors, warnings, printed summaries and the JSON's ``statement``/``reason`` strings are read
by lab engineers: a list of channels reads ``wing, payload`` (not ``['wing', 'payload']``), a
band ``2-15 Hz`` (not ``(2.0, 15.0)``), a number ``0.1235`` (not ``np.float64(0.12345678)``).
Imports nothing of the package, so every layer may use it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["names", "band_hz", "number", "quantity", "value", "weights", "shape"]


def number(x: Any, digits: int = 4) -> str:
    """``x`` to ``digits`` significant digits (``1.235``, ``2e+06``, ``15``); ints stay whole.

    Numpy scalars print as plain numbers; anything that is not a number prints as text.
    """
    if x is None:
        return "none"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int) or (hasattr(x, "dtype") and getattr(x.dtype, "kind", "") in "iu"):
        return str(int(x))
    try:
        f = float(x)
    except (TypeError, ValueError):
        return str(x)
    return f"{f:.{digits}g}"


def quantity(x: Any, unit: str, digits: int = 4) -> str:
    """A number and its unit: ``quantity(0.1234567, "m")`` -> ``0.1235 m``."""
    return f"{number(x, digits)} {unit}".rstrip()


def names(items: Any, *, quote: bool = False, empty: str = "none", limit: int | None = None) -> str:
    """Channel, key or file names as ``wing, payload`` (``'wing', 'payload'`` with ``quote``).

    A single string is one name; a mapping gives its keys; ``limit`` shows that many and
    ``... (N in all)``; nothing gives ``empty``.
    """
    if items is None:
        return empty
    if isinstance(items, (str, bytes)):
        items = [items]
    elif isinstance(items, Mapping):
        items = list(items)
    shown = [f"'{_plain(i)}'" if quote else _plain(i) for i in items]
    if not shown:
        return empty
    if limit is not None and len(shown) > limit:
        return ", ".join(shown[:limit]) + f", ... ({len(shown)} in all)"
    return ", ".join(shown)


def band_hz(band: Any, digits: int = 4) -> str:
    """A frequency band ``(f_low, f_high)`` as ``2-15 Hz``; anything else via :func:`value`."""
    try:
        low, high = band
        return f"{number(low, digits)}-{number(high, digits)} Hz"
    except (TypeError, ValueError):
        return value(band)


def shape(dims: Any) -> str:
    """An array shape as ``11264 x 2`` (a 1-D one as ``11264 values``)."""
    dims = tuple(int(d) for d in dims)
    if len(dims) == 1:
        return f"{dims[0]} values"
    return " x ".join(map(str, dims)) or "a single value"


def weights(mapping: Mapping[Any, Any]) -> str:
    """A channel -> weight mapping as ``wing +1, payload -1``."""
    out = []
    for k, v in mapping.items():
        try:
            out.append(f"{k} {float(v):+g}")
        except (TypeError, ValueError):
            out.append(f"{k} {value(v)}")
    return ", ".join(out) or "none"


def value(x: Any, digits: int = 10) -> str:
    """A value a user wrote (a config field, an option) echoed back as plain text.

    Written as YAML would show it, so the user recognises what they typed: a top-level
    string quoted (``'abc'``), numbers via :func:`number` (to ``digits``: enough to show
    ``1024.5`` whole, not a numpy repr), lists ``[2, 15]``, mappings
    ``{wing: 1, payload: -1}`` (strings inside unquoted), None as ``nothing``.
    """
    if x is None:
        return "nothing"
    if isinstance(x, str):
        return f"'{x}'"
    return _flow(x, digits)


def _flow(x: Any, digits: int) -> str:
    if x is None:
        return "null"
    if isinstance(x, str):
        return x
    if _is_number(x):
        return number(x, digits)
    if isinstance(x, Mapping):
        return "{" + ", ".join(f"{_flow(k, digits)}: {_flow(v, digits)}" for k, v in x.items()) + "}"
    if isinstance(x, Iterable) and not isinstance(x, bytes):
        return "[" + ", ".join(_flow(v, digits) for v in x) + "]"
    return str(x)


def _is_number(x: Any) -> bool:
    if isinstance(x, (bool, int, float)):
        return True
    return getattr(x, "shape", None) == () and hasattr(x, "dtype")


def _plain(x: Any) -> str:
    if _is_number(x):
        return number(x)
    return str(x)
