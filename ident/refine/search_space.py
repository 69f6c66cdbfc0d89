"""The search spaces of the basis parameters left to the data (clearances, offsets,
exponents) resolved on the recorded motion, and the basis at given values of them
(:mod:`ident.refine.parameter_search`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import IdentError, NotIdentifiableError

__all__ = ["Unknown", "search_spaces", "has_unknown_parameters", "resolve_basis",
           "initial_value", "with_value", "format_values", "AUTO_EXPONENTS",
           "AUTO_SIGNED_EXPONENT_INTERVAL", "AUTO_CLEARANCE_FRACTION", "AUTO_SLIP_FRACTION"]

#: ``exponent: auto`` of an unsigned polynomial: the whole exponents tried.
AUTO_EXPONENTS: tuple[float, ...] = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0)
#: ``exponent: auto`` of a signed polynomial ``|x|^(e-1) x``: the search interval (``e = 1``
#: is a linear spring, indistinguishable from the underlying linear stiffness).
AUTO_SIGNED_EXPONENT_INTERVAL: tuple[float, float] = (1.5, 7.0)
#: ``clearances: auto``: fraction of the largest recorded excursion towards that side
#: searched (a gap of 0 is a linear spring; a gap at the largest excursion never touches).
AUTO_CLEARANCE_FRACTION: tuple[float, float] = (0.02, 0.98)
#: ``slip: auto`` of a Jenkins element: fraction of the recorded relative motion's half
#: peak-to-peak ``A`` searched (a slip of ``A`` or more never slips: a linear spring; at a
#: small fraction the joint slips nearly all the time: a Coulomb law, ``F_s sign(delta')``).
AUTO_SLIP_FRACTION: tuple[float, float] = (0.01, 0.95)


def has_unknown_parameters(basis: Sequence[Nonlinearity]) -> bool:
    """True if an element of ``basis`` has a parameter left to the data."""
    return any(nl.unknown for nl in basis)


@dataclass(frozen=True)
class Unknown:
    """One free basis parameter with its resolved search space.

    Attributes
    ----------
    element : int
        Index of the element in the basis.
    name : str
        Element name.
    parameter : {'g_neg', 'g_pos', 'clearance', 'offset', 'exponent', 'slip'}
    interval : (float, float) or None
        Continuous search interval (clearances, slips and offsets in the outputs' length unit).
    candidates : tuple of float or None
        Discrete values.
    reach : float or None
        Largest recorded excursion of the element's argument towards the stop (clearances).
    scale : float or None
        Offsets: the length that steps and standard deviations are relative to (the smaller
        clearance; an offset can be 0). None: the parameter's own value.
    """

    element: int
    name: str
    parameter: str
    interval: tuple[float, float] | None = None
    candidates: tuple[float, ...] | None = None
    reach: float | None = None
    scale: float | None = None

    @property
    def label(self) -> str:
        """``NAME.parameter``."""
        return f"{self.name}.{self.parameter}"

    @property
    def continuous(self) -> bool:
        return self.candidates is None

    @property
    def is_length(self) -> bool:
        """A clearance or an offset (moved by the noise in the measured motion)."""
        return self.parameter in ("g_neg", "g_pos", "clearance", "offset")

    @property
    def log_spaced(self) -> bool:
        """Scanned on a log scale: a positive interval of a parameter known relative to itself."""
        return self.parameter != "offset" and self.interval is not None and self.interval[0] > 0

    @property
    def bounds(self) -> tuple[float, float]:
        """The search interval of a continuous parameter."""
        if self.interval is None:
            raise IdentError(f"{self.label}: a discrete parameter has no search interval")
        return self.interval

    @property
    def choices(self) -> tuple[float, ...]:
        """The candidates of a discrete parameter."""
        if self.candidates is None:
            raise IdentError(f"{self.label}: a continuous parameter has no candidates")
        return self.candidates

    def magnitude(self, value):
        """``|value|``, or the offset's length scale where that is larger (array-friendly)."""
        return np.maximum(np.abs(value), self.scale or 0.0)



def _argument(nl: Nonlinearity, data: FrequencyData) -> np.ndarray:
    """``L^T q + offset`` of an element on the fine grid of every realization, flattened."""
    motion = data.motion
    if motion is None or not all(c in motion.channels for c in nl.channels):
        raise IdentError("these frequency data do not hold the motion of the basis channels "
                         "(prepare them with motion_for=)")
    L = nl.location_vector(motion.channels)
    if nl.kind == "polynomial" and nl.argument == "velocity":
        return (motion.velocity @ L).ravel()
    return (motion.displacement @ L).ravel() + nl.offset


def search_spaces(data: FrequencyData, basis: Sequence[Nonlinearity]) -> list[Unknown]:
    """The free parameters of ``basis`` with their search spaces resolved on the data.

    ``auto`` clearances are searched over ``AUTO_CLEARANCE_FRACTION`` of the largest
    excursion towards that side; an ``auto`` offset of a trilinear stop over the offsets at
    which the recorded motion touches both stops (:func:`_offset_space`); ``auto``
    exponents over ``AUTO_EXPONENTS`` (unsigned) or ``AUTO_SIGNED_EXPONENT_INTERVAL``
    (signed).

    Raises
    ------
    NotIdentifiableError
        The motion never reaches a stop's search interval (the stop is never in contact),
        or no offset puts both stops of a trilinear element in contact.
    """
    out = []
    for i, nl in enumerate(basis):
        for sp in nl.unknown:
            if sp.parameter == "offset":
                out.append(_offset_space(i, nl, sp.interval, _argument(nl, data) - nl.offset))
                continue
            if sp.parameter == "exponent":
                if sp.candidates is not None:
                    out.append(Unknown(i, nl.name, "exponent", candidates=sp.candidates))
                elif sp.interval is not None:
                    out.append(Unknown(i, nl.name, "exponent", interval=sp.interval))
                elif nl.signed:
                    out.append(Unknown(i, nl.name, "exponent",
                                       interval=AUTO_SIGNED_EXPONENT_INTERVAL))
                else:
                    out.append(Unknown(i, nl.name, "exponent", candidates=AUTO_EXPONENTS))
                continue
            if sp.parameter == "slip":
                out.append(_slip_space(i, nl, sp.interval, _argument(nl, data)))
                continue
            d = _argument(nl, data)
            side = {"g_neg": "neg", "g_pos": "pos"}.get(sp.parameter, nl.side)
            reach = float(np.max(d if side == "pos" else -d))
            lo, hi = (sp.interval if sp.interval is not None
                      else tuple(f * max(reach, 0.0) for f in AUTO_CLEARANCE_FRACTION))
            if not reach > lo or not hi > lo:
                raise NotIdentifiableError(
                    f"nonlinearity {nl.name!r}: the data cannot tell {sp.parameter}: the "
                    f"largest excursion towards the {side} stop is {reach:.4g}, "
                    f"{'below' if sp.interval is not None else 'not beyond'} the search "
                    f"interval [{lo:.4g}, {hi:.4g}] (the stop is never in contact; excite "
                    "harder, or give the clearance or drop the element)", element=nl.name)
            out.append(Unknown(i, nl.name, sp.parameter,
                               interval=(float(lo), float(min(hi, reach))), reach=reach))
    return out


def _slip_space(element: int, nl: Nonlinearity, interval: tuple[float, float] | None,
                motion: np.ndarray) -> Unknown:
    """The search space of a Jenkins element's slip displacement.

    ``motion`` is the element's argument on the fine grid. With ``A`` half its largest
    peak-to-peak over a period, a slip of ``A`` or more never slips (the column is the
    motion less a constant: the underlying linear stiffness), so ``auto`` searches
    ``AUTO_SLIP_FRACTION`` of ``A`` on a log scale.
    """
    half_span = 0.5 * float(np.max(motion) - np.min(motion))
    lo, hi = (interval if interval is not None
              else tuple(f * half_span for f in AUTO_SLIP_FRACTION))
    if not half_span > lo or not hi > lo or not lo > 0:
        raise NotIdentifiableError(
            f"nonlinearity {nl.name!r}: the data cannot tell slip: the recorded relative "
            f"motion's half peak-to-peak is {half_span:.4g}, not beyond the search interval "
            f"[{lo:.4g}, {hi:.4g}] (the joint never slips there; excite harder, give the "
            "slip or drop the element)", element=nl.name)
    return Unknown(element, nl.name, "slip", interval=(float(lo), float(min(hi, half_span))))


def _offset_space(element: int, nl: Nonlinearity, interval: tuple[float, float] | None,
                  motion: np.ndarray) -> Unknown:
    """The search space of a trilinear stop's offset (both clearances known).

    ``motion`` is ``L^T q`` without offset. The stops are touched where
    ``motion + offset`` passes ``g_pos`` or ``-g_neg``, so both are touched for offsets in
    ``[g_pos - max(motion), -g_neg - min(motion)]``. ``auto`` searches the part of it where
    the joint at rest touches neither stop, ``(-g_neg, g_pos)``, less 2 % of its width at
    each end. Beyond that one stop is in contact most of the time, its column becomes
    nearly a copy of the motion and the model error falls again (3-DOF chain, noise-free
    accelerations: 4e-6 at 10 clearances against 2e-6 at the true offset, with a hump of
    1e-3 in between); an offset outside needs an explicit interval (a displacement
    sensor's DC offset larger than the clearances).
    """
    g_neg, g_pos = nl.clearances
    lo_both, hi_both = g_pos - float(np.max(motion)), -g_neg - float(np.min(motion))
    lo, hi = max(lo_both, -g_neg), min(hi_both, g_pos)
    span = float(np.max(motion) - np.min(motion))
    if interval is None:
        if not hi > lo:
            raise NotIdentifiableError(
                f"nonlinearity {nl.name!r}: the data cannot tell offset: the recorded relative "
                f"motion spans {span:.4g}, too little for both stops (clearances "
                f"{g_neg:.4g}, {g_pos:.4g}) to be touched from a position between them; give "
                "the offset, a search interval [low, high] for it, or excite harder", element=nl.name)
        width = hi - lo
        interval = (lo + AUTO_CLEARANCE_FRACTION[0] * width, lo + AUTO_CLEARANCE_FRACTION[1] * width)
    positive = [g for g in (g_neg, g_pos) if g > 0]
    scale = min(positive) if positive else 0.5 * span
    return Unknown(element, nl.name, "offset", interval=(float(interval[0]), float(interval[1])),
                   scale=float(scale))


def resolve_basis(basis: Sequence[Nonlinearity], unknowns: Sequence[Unknown],
                  values: Sequence[float] | np.ndarray) -> tuple[Nonlinearity, ...]:
    """``basis`` with the ``unknowns`` set to ``values``."""
    per: dict[int, dict[str, float]] = {}
    for u, v in zip(unknowns, values):
        per.setdefault(u.element, {})[u.parameter] = float(v)
    return tuple(nl.with_parameters(per[i]) if i in per else nl for i, nl in enumerate(basis))


def initial_value(u: Unknown) -> float:
    """Starting value: centre of the interval (geometric if log-spaced), or 3 (a cubic)
    among the candidates."""
    if u.continuous:
        lo, hi = u.bounds
        return float(np.sqrt(lo * hi)) if u.log_spaced else 0.5 * (lo + hi)
    candidates = u.choices
    return 3.0 if 3.0 in candidates else float(candidates[len(candidates) // 2])


def with_value(values: np.ndarray, k: int, v: float) -> np.ndarray:
    """A copy of ``values`` with entry ``k`` set to ``v``."""
    out = values.copy()
    out[k] = v
    return out


def format_values(unknowns: Sequence[Unknown], values: np.ndarray) -> str:
    """``NAME.parameter=value, ...`` for progress notes."""
    return ", ".join(f"{u.label}={v:.5g}" for u, v in zip(unknowns, values))
