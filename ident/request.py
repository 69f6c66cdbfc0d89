"""One identification request, resolved once: the settings every caller passes whole.

The API (:func:`fnsi_lab.identify`), ``fnsi-lab ident``, the live service and replay
(:func:`fnsi_lab.replay.identifiers.config_identifier`), the report and batch campaigns all build
an :class:`IdentRequest` with :func:`resolve_request` and hand it to
:func:`ident.pipeline.identify_request`, so one recording gives one answer whichever door it
came through: the same default order sweep (:data:`DEFAULT_ORDERS`), the same default
configuration without a config file, the same validation of the orders.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.io import IdentInput
from fnsi_lab.ident.robust.options import parse_orders

__all__ = ["DEFAULT_ORDERS", "IdentRequest", "resolve_request", "check_order",
           "default_config", "basis_from_truth"]

#: Order sweep of the robust pipeline when neither the caller nor the config gives one
#: (the seed's 2..60). Live sessions use it too: the 39-channel SmallSat's sweep takes about
#: 2.7 s of its 8.19 s period on 2 cores.
DEFAULT_ORDERS: tuple[int, ...] = tuple(range(2, 61))


def check_order(value: Any, name: str = "order") -> int:
    """A model order as a positive int, or :class:`IdentError` naming the field and the fix.

    Booleans, non-integral floats and strings are refused (``6.7`` is not an order).
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if (not isinstance(value, bool) and isinstance(value, numbers.Real)
                and float(value).is_integer()):
            value = int(float(value))
        else:
            raise IdentError(f"{name} must be a positive integer, got {plain.value(value)} "
                             f"(fix: e.g. {name}=10)")
    if int(value) < 1:
        raise IdentError(f"{name} must be a positive integer, got {plain.value(value)} (fix: e.g. {name}=10)")
    return int(value)


@dataclass(frozen=True)
class IdentRequest:
    """An identification's resolved settings (built by :func:`resolve_request` only).

    Attributes
    ----------
    config : IdentConfig
        Band, channels, basis functions, options (the caller's, or the default one).
    order : int or None
        Fixed model order; None: the robust pipeline over ``orders``.
    orders : tuple of int
        Order sweep of the robust pipeline (sorted, unique).
    reduce_at : int or None
        Order of the MDI and the reduction (None: the selected order).
    max_order : int or None
        Largest order of a fixed-order decomposition (None: the order, or the config's).
    block_rows : int or None
        Block rows ``i`` of the subspace step (None: from the data sizes).
    """

    config: IdentConfig
    order: int | None
    orders: tuple[int, ...]
    reduce_at: int | None = None
    max_order: int | None = None
    block_rows: int | None = None

    @property
    def auto(self) -> bool:
        """True for the robust pipeline (no fixed order)."""
        return self.order is None


def resolve_request(inp: Any, config: IdentConfig | None = None, *, order: Any = None,
                    orders: str | int | range | list | tuple | None = None,
                    reduce_at: Any = None,
                    max_order: Any = None, block_rows: Any = None, harmonics: float = 1.0,
                    driving_point: str | None = None) -> IdentRequest:
    """Resolve an identification's settings in one place.

    Parameters
    ----------
    inp : IdentInput
        The data (needed for the default configuration).
    config : IdentConfig, optional
        None: :func:`default_config` (the excited band; a simulated
        recording's truth as the basis, its band reaching ``harmonics`` times the highest
        excited frequency; ``driving_point`` as the input's driving point).
    order, orders, reduce_at, max_order, block_rows
        As :func:`fnsi_lab.identify`; ``orders`` defaults to the config's ``auto.orders``,
        else :data:`DEFAULT_ORDERS`; ``block_rows`` to the config's.

    Raises
    ------
    IdentError
        An order that is not a positive integer, ``max_order`` below ``order``, a bad sweep.
    """
    cfg = config if config is not None else default_config(
        inp, harmonics=harmonics, driving_point=driving_point)
    fixed = check_order(order) if order is not None else None
    if orders is not None:
        sweep = tuple(parse_orders(orders))
    elif cfg.orders:
        sweep = tuple(sorted({int(n) for n in cfg.orders}))
    else:
        sweep = DEFAULT_ORDERS
    top = check_order(max_order, "max_order") if max_order is not None else None
    if fixed is not None and top is not None and top < fixed:
        raise IdentError(f"max_order {top} is below order {fixed} (fix: max_order >= order, "
                         "or leave max_order out)")
    rows = block_rows if block_rows is not None else cfg.block_rows
    if fixed is None and reduce_at is not None and check_order(reduce_at, "reduce_at") > max(
            sweep):
        raise IdentError(f"reduce_at {reduce_at} is beyond the order sweep (up to "
                         f"{max(sweep)}): the MDI and the reduction need a model of the sweep "
                         "(fix: a reduce_at within it, or a wider sweep)")
    return IdentRequest(config=cfg, order=fixed, orders=sweep,
                        reduce_at=check_order(reduce_at, "reduce_at") if reduce_at is not None
                        else None,
                        max_order=top,
                        block_rows=check_order(rows, "block_rows") if rows is not None else None)


def basis_from_truth(truth: Mapping[str, Any] | None) -> tuple[Nonlinearity, ...]:
    """Basis functions of a simulated recording's ``truth`` (its nonlinear elements).

    Returns an empty tuple when the truth has none or describes an element this version
    cannot express (the identification then stays linear).
    """
    out = []
    for el in (truth or {}).get("nonlinearities") or []:
        try:
            kind = el["kind"]
            coeffs = dict(el.get("coefficients") or {})
            kw: dict[str, Any] = {"name": el["name"], "kind": kind,
                                  "channels": dict(el.get("channels") or el["dofs"])}
            if kind == "polynomial":
                kw.update(exponent=float(el.get("exponent", 3)), signed=bool(el.get("signed")),
                          argument=el.get("argument", "displacement"))
                values: tuple = (float(next(iter(coeffs.values()))),) if coeffs else ()
            elif kind == "trilinear":
                kw["clearances"] = tuple(float(g) for g in el["clearances"])
                values = (float(coeffs["neg"]), float(coeffs["pos"]))
            elif kind == "bilinear":
                side = "neg" if "neg" in coeffs else "pos"
                kw.update(side=side, clearance=float(el["clearances"][0]))
                values = (float(coeffs[side]),)
            else:
                values = (float(next(iter(coeffs.values()))),) if coeffs else ()
            out.append(Nonlinearity(**kw, truth=values or None))
        except (KeyError, TypeError, ValueError, StopIteration):
            return ()
    return tuple(out)


def _active_basis(basis: Sequence[Nonlinearity], inp: IdentInput,
                  quantity: str) -> tuple[Nonlinearity, ...]:
    """The elements of a truth-derived basis that the recorded motion actually engages.

    A simulated structure may hold stops that the motion never reaches; their basis columns
    are identically zero and cannot be identified, so they are left out (displacement
    outputs and displacement-driven elements only; others are kept).
    """
    if quantity != "displacement" or not basis:
        return tuple(basis)
    from fnsi_lab.ident.core.basis import evaluate_basis

    q = np.asarray(inp.y)[0, -1]  # last period of the first realization, (N, p)
    kept = []
    for nl in basis:
        if nl.needs_velocity:
            kept.append(nl)
            continue
        try:
            h = evaluate_basis([nl], q, None, list(inp.output_channels))
        except (IdentError, KeyError, ValueError):
            kept.append(nl)  # let the identification report it
            continue
        if np.any(h != 0):
            kept.append(nl)
    return tuple(kept)


def _drive_lines(inp: IdentInput) -> np.ndarray:
    """The excited lines found in the drive's spectrum (periods after the transient ones);
    empty when no multisine is found (a random or swept force)."""
    from fnsi_lab.ident.core.excitation import detect_excited_lines
    from fnsi_lab.ident.core.io import steady_drive_power

    if np.ndim(inp.u) != 4 or np.shape(inp.u)[2] < 4:
        return np.zeros(0)
    power = steady_drive_power(inp)
    try:
        return np.asarray(detect_excited_lines(power, inp.sample_rate_hz,
                                               inp.samples_per_period).lines)
    except (ValueError, IdentError):
        return np.zeros(0)


def default_config(inp: IdentInput, *, harmonics: float = 1.0,
                   driving_point: str | None = None) -> IdentConfig:
    """The configuration used when the caller gives none.

    Band: the excited lines (or the whole spectrum without them); with basis functions
    from a simulated recording's truth the band reaches ``harmonics`` times the highest
    excited frequency (capped at 0.45 fs), where the nonlinear distortion lives (the seed
    excites 5-50 Hz and processes 5-250 Hz: 5). Basis: the truth's elements that the motion
    engages (none for measured data: a linear identification).
    """
    from fnsi_lab.ident.config import InputSpec

    fs, n = inp.sample_rate_hz, inp.samples_per_period
    df = fs / n
    quantity = inp.output_quantity or "displacement"
    basis = _active_basis(basis_from_truth(inp.truth), inp, quantity)
    lines = np.asarray(inp.excited_lines) if inp.excited_lines is not None else np.zeros(0)
    if not lines.size:   # an array file that does not say: the drive's multisine lines
        lines = _drive_lines(inp)
    if lines.size:
        hi = float(lines.max()) * df
        if basis and harmonics > 1:
            hi = min(harmonics * hi, 0.45 * fs)
        band = (float(lines.min()) * df, hi)
    else:
        band = (df, fs / 2 - df)
    inputs: tuple = ()
    if driving_point is not None and inp.input_channels:
        inputs = (InputSpec(inp.input_channels[0], driving_point),)
    return IdentConfig(band_hz=band, nonlinearities=basis, inputs=inputs)
