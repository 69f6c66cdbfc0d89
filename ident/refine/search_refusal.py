"""When the search refuses rather than guesses (:mod:`ident.refine.parameter_search`): an
estimate at the edge of its interval, on a flat or rough objective, or no better than another
candidate; the refusal that lets the search retry from its second start; and the notes the
engineer must read about the estimates (noise in the motion, a misfit beyond the noise,
clearances from integrated outputs).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import NotIdentifiableError
from fnsi_lab.ident.refine.motion_noise import uncorrected_motion_noise
from fnsi_lab.ident.refine.search_result import ParameterEstimate

__all__ = ["StartRefused", "refuse_if_unclear", "roughness", "search_notes", "MAX_ROUGHNESS",
           "MAX_NOISE_MISFIT"]


class StartRefused(Exception):
    """The search from one start refused its estimate (``refusal``, the error a user sees)
    after the second start was tried (``restarted``) or not;
    :func:`ident.refine.parameter_search.estimate_basis_parameters` decides whether to retry,
    and raises ``refusal`` itself."""

    def __init__(self, refusal: NotIdentifiableError, restarted: bool) -> None:
        super().__init__(str(refusal))
        self.refusal = refusal
        self.restarted = restarted

def roughness(offsets: np.ndarray, rise: np.ndarray, std: float, s2: float) -> float:
    """Largest factor between the chi-square rise ``rise / s2`` seen at ``offsets`` from the
    estimate and the rise ``(offsets / std)^2`` its curvature predicts (NaN if none)."""
    if not offsets.size or not (std > 0 and np.isfinite(std) and s2 > 0):
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = (rise / s2) / (offsets / std) ** 2
        factor = np.where(ratio > 0, np.maximum(ratio, 1.0 / ratio), np.inf)
    return float(np.max(factor))


#: Largest :attr:`ParameterEstimate.roughness` accepted. Smooth minima measured 0.6-2.3 (the
#: 3-DOF chain with 1 % noise, corrected; the SmallSat; offsets; signed exponents; the 5-DOF
#: ODE chain); the 5-DOF chain seen by 2 outputs, whose model error jumped by 10^4-10^19
#: within +-3 % of a lucky low point, gave 130-10^15 (at gaps -60 % / -74 %, under a first
#: version of the search's order choice).
MAX_ROUGHNESS = 10.0
#: Largest noise misfit (:attr:`ident.refine.search_result.ParameterSearchResult.noise_misfit`)
#: without a warning: 1.2-1.5 where the search found the truth (3-DOF chain, 1 % noise; 5-DOF ODE chain at
#: 40 dB); 47 where an unmodelled cubic spring beside the chain's stop pushed the gaps to
#: +170 %, 30 where a 2-output view of the 5-DOF chain settled at -21 % / -70 %. A warning,
#: not a refusal: real structures leave model error beyond the noise too.
MAX_NOISE_MISFIT = 10.0


def refuse_if_unclear(est: ParameterEstimate, nl: Nonlinearity, max_relative_std: float,
                      min_margin: float) -> None:
    """Raise :class:`ident.errors.NotIdentifiableError` when the data cannot tell ``est``
    (the module docstring lists the reasons); the message names the element, the parameter,
    the reason and the fix."""
    u = est.unknown
    what = f"nonlinearity {nl.name!r}: the data cannot tell {u.parameter}"
    fix = ("give it in the configuration, change the search " +
           ("interval" if u.continuous else "candidates") + ", or excite harder")
    if u.continuous:
        lo, hi = u.bounds
        if min(est.value - lo, hi - est.value) <= 0.01 * (hi - lo):
            raise NotIdentifiableError(
                f"{what}: the model error is smallest at the edge of the search interval "
                f"[{lo:.4g}, {hi:.4g}] ({est.value:.4g}), so the value is outside it or the "
                f"element barely acts; {fix}", element=nl.name)
        if not est.std <= max_relative_std * u.magnitude(est.value):
            of = "the smaller clearance" if u.scale else "the value"
            raise NotIdentifiableError(
                f"{what}: the model error is flat around {est.value:.4g} (std {est.std:.3g}, "
                f"more than {100 * max_relative_std:g} % of {of}); {fix}", element=nl.name)
        if not est.margin >= min_margin:
            # an end of the interval fits about as well: no single minimum (5-DOF chain seen
            # by 2 outputs at 40 dB: the model error jumped by 10^4 between scan points)
            raise NotIdentifiableError(
                f"{what}: the ends of the search interval fit about as well as "
                f"{est.value:.4g} (chi-square difference {est.margin:.3g} < {min_margin:g}); "
                f"{fix}", element=nl.name)
        if est.roughness > MAX_ROUGHNESS:
            # the minimum is a lucky low point of a rough objective, not a smooth valley
            raise NotIdentifiableError(
                f"{what}: the model error around {est.value:.4g} is rough (a few percent "
                f"away it changes {est.roughness:.3g}x more or less than its curvature says: "
                f"few outputs for the model order, or an unmodelled effect); {fix}", element=nl.name)
    elif not est.margin >= min_margin:
        raise NotIdentifiableError(
            f"{what}: {est.value:g} fits no better than the next candidate (chi-square "
            f"difference {est.margin:.3g} < {min_margin:g}); {fix}", element=nl.name)

def search_notes(estimates: Sequence[ParameterEstimate], data: FrequencyData, quantity: str,
                 corrected: bool, misfit: float) -> tuple[list[str], list[str]]:
    """What the engineer must read about the estimates: ``(notes, motion_noise_notes)``.

    ``motion_noise_notes`` are the notes about the noise in the measured motion (the
    clearances' bias, or why it was not corrected for); ``notes`` add a noise misfit above
    :data:`MAX_NOISE_MISFIT` and clearances read from integrated outputs (``quantity``, the
    data's output quantity before the search turned them into displacements).
    """
    noise_notes = [
        f"nonlinearity {e.unknown.name!r}: {e.unknown.parameter} = {e.value:.4g} was "
        f"estimated from a relative motion with noise {e.motion_noise_std:.3g} "
        f"({100 * e.motion_noise_std / e.value:.2g} % of it) per sample; "
        + ("its first-order effect was removed; what remains grows with that ratio and "
           "is not in the standard deviation (3-DOF chain, 4-8 noise seeds: within 2-4 % of "
           "the gap at 4-7 %, up to +15 % at 8-10 %, up to +24 % at 12-15 %; docs/ident.md, "
           "'Unknown basis parameters'): average more periods for a tighter gap"
           if e.noise_corrected else
           "noise in the motion biases gaps upwards by about as much (docs/ident.md, "
           "'Unknown basis parameters'): average more periods")
        for e in estimates
        if e.unknown.reach and e.motion_noise_std and e.motion_noise_std > 5e-3 * e.value]
    if any(e.unknown.reach for e in estimates) and not corrected:
        noise_notes.extend(uncorrected_motion_noise(data, quantity))
    notes = list(noise_notes)
    if misfit > MAX_NOISE_MISFIT:
        notes.append(f"the model at the estimated parameters leaves residuals {misfit:.3g}x the "
                     "output noise (noise-weighted; 1.2-1.5 where the search found the truth): "
                     "the basis or the order does not explain these data, and the estimates "
                     "may sit in a wrong minimum (3-DOF chain with an unmodelled cubic spring "
                     "beside its stop: 47x, gaps +170 %); check the basis and the profiles, or "
                     "give the order or the parameters")
    if any(e.unknown.reach for e in estimates):   # clearances
        if quantity != "displacement":
            notes.append(f"clearances estimated from {quantity} outputs count from the mean "
                         "relative position during the test (integrated outputs carry no "
                         "static position; a stop whose contacts are asymmetric shifts that "
                         "mean); the contact stiffnesses do not depend on it (docs/ident.md, "
                         "'Unknown basis parameters')")
    return notes, noise_notes
