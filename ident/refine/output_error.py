"""Output-error refinement of an FNSI model: the model's own steady state against the outputs.

FNSI regresses the outputs on basis functions of the *measured* motion. With noisy outputs
that motion carries the noise into the regressors (errors in variables): the coefficients are
biased by a share that grows with the time in contact and a searched clearance wanders by
several times its curvature's standard deviation (docs/ident.md, "The output-error
refinement"). This module refines the identified model by minimising

    ``V(theta) = sum_k sum_o W_ko^2 |Y_ko - Y_hat_ko(theta)|^2``

where ``Y_hat`` is the model's periodic steady state with the basis functions read on the
motion the model itself predicts (:mod:`ident.refine.harmonic_balance`), ``W = 1/sigma`` the noise
weights of the averaged outputs, and ``theta`` the model in modal form
(:class:`ident.refine.modal.ModalModel`: poles, input rows, output rows, ``D``) plus the continuous
basis parameters that were left to the data (clearances, offsets, signed exponents). No noisy
signal then enters a regressor, so the minimum is the maximum-likelihood estimate for white
Gaussian output noise.

Levenberg-Marquardt with an exact elimination of the output rows that no basis function
reads: every such row is linear in its own parameters ``[Re gamma, Im gamma, c, d]``, so the
normal equations are block-arrow shaped and are solved through their Schur complement (the
size of the step's dense system is that of the shared parameters: poles, input rows, the
rows the basis reads and the basis parameters). The sensitivity of the predicted motion to
a parameter comes from the linearised harmonic balance.

The jobs live in their own modules: the modal problem, its Jacobian and normal equations
(:mod:`ident.refine.output_error_problem`), the Levenberg-Marquardt loop
(:mod:`ident.refine.output_error_fit`), the evidence for a mode left out
(:mod:`ident.refine.mode_evidence`) and the record with its JSON summary
(:mod:`ident.refine.output_error_result`); this module decides how the lines under the band
enter and whether ``refine: auto`` refines (:func:`refinement_case`).

Shapes: ``F = R F0`` stacked lines, ``p`` outputs, ``m_e`` extended inputs; complex residuals
``(F, p)``.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.refine.mode_evidence import omitted_mode_evidence
from fnsi_lab.ident.refine.motion_noise import MotionNoise
from fnsi_lab.ident.refine.output_error_fit import (MAX_POLE_SHIFT, BelowBandDisagrees,
                                                   fit_output_error)
from fnsi_lab.ident.refine.output_error_problem import smoothed_noise
from fnsi_lab.ident.refine.output_error_result import OutputErrorFit, RefinedParameter

__all__ = ["OutputErrorFit", "refine_output_error", "RefinedParameter", "refinement_case",
           "omitted_mode_evidence",
           "MIN_MOTION_NOISE_SHARE", "MAX_UNEXPLAINED", "DOMINANT_MOTION_NOISE_SHARE",
           "MAX_MISFIT", "MAX_POLE_SHIFT"]

#: ``refine: auto`` refines when the measured motion's noise, carried through FNSI's model,
#: adds at least this fraction of the output noise to the expected squared residual: then
#: the regressors' noise is a material part of what FNSI fits. 3-DOF chain, 1 % noise:
#: 10 (the known-gap coefficients 0.2-0.9 % off, refined 0.02-0.26 %); 39-channel SmallSat,
#: 1 % noise, 6 periods: 1.7.
MIN_MOTION_NOISE_SHARE = 0.5
#: ... and when FNSI's weighted residual is at most this factor above what the output noise
#: and that share explain: a model that misses dynamics (misfit beyond the noise) is not
#: improved by fitting its own steady state. SmallSat reduced to its physical modes: 6.6
#: against 2.7 explained (refined anyway, the misfit stopped at 2.7 and NC2-Z moved from
#: 0.25 % to 0.45 % off, at 2.5 s per step).
MAX_UNEXPLAINED = 1.5
#: ... unless the motion's noise dominates that residual, at least this many times the
#: output noise: the share is a first-order estimate, and where the motion noise is large
#: against the gaps FNSI's residual exceeds it by more (3-DOF chain, velocity outputs, 1 %
#: noise: 169 against 72 explained; refined, misfit 1.00 and stiffnesses within 0.02 %).
#: The refinement is then tried and kept only if it explains the outputs (``MAX_MISFIT``).
DOMINANT_MOTION_NOISE_SHARE = 5.0
#: A refinement whose misfit stays above this is not kept (``refine: auto``): the model does
#: not explain the outputs to their noise. 3-DOF chain, 1 % noise, 16 periods: 1.00-1.07.
MAX_MISFIT = 1.5
#: Displacements: the motion under the band is predicted by the model unless its prediction
#: there is off the measurement by more than this (mean over the lines, in noise variances;
#: about 1 where the model holds the structure there, the 3-DOF chain 0.8-1.5). Predicted,
#: the chain's gaps (1 % noise, 16 periods) scattered 0.17-0.22 % against a standard
#: deviation of 0.14 %; measured, 0.30 % (their noise enters the basis as motion).
MAX_BELOW_BAND_MISFIT = 4.0


def refine_output_error(data: FrequencyData, basis: Sequence[Nonlinearity],
                        model: StateSpaceModel, *, estimated: Sequence[tuple[int, str]] = (),
                        d_zero: bool = False, weighted: bool = True, max_iterations: int = 30,
                        tolerance: float = 1e-3,
                        watch: Callable[[StateSpaceModel, tuple], Any] | None = None,
                        watch_tolerance: float = 1e-5,
                        give_up_above: float | None = None,
                        on_step: Callable[[int, float], None] | None = None
                        ) -> OutputErrorFit:
    """Refine an identified model (and searched basis parameters) on its own output error.

    Parameters
    ----------
    data : FrequencyData
        The data the model was identified on, with the motion of the basis channels.
    basis : sequence of Nonlinearity
        The basis of ``model`` (every parameter known).
    model : StateSpaceModel
        The start: FNSI's model (its order, time base and names are kept).
    estimated : sequence of (int, str)
        Basis parameters refined with the model: ``(element index, parameter)``, e.g.
        ``[(0, 'g_neg'), (0, 'g_pos')]`` for the clearances the search estimated.
    d_zero : bool
        Keep ``D = 0``.
    weighted : bool
        Weigh each line and output by ``1 / sigma`` (the data's ``noise_var``); False, or
        no noise estimate: by ``1 / RMS`` of each output over the lines.
    max_iterations : int
        Levenberg-Marquardt steps at most.
    tolerance : float
        Stop when a step lowers ``V`` by less than this: with noise weights ``V`` counts
        noise variances, and a decrease of ``dV`` means the parameters moved by about
        ``sqrt(2 dV)`` standard deviations (1e-3: 0.045 std). A model that leaves more than
        the noise (``V`` per line and output, the misfit, above 1) counts ``dV`` in misfits:
        its parameters' standard deviations grow with its square root. Unweighted, a
        fraction of ``V``.
    watch : callable, optional
        ``watch(model, basis)`` gives the quantities of interest (e.g. the nonlinear
        coefficients); the fit also stops when a step changes none of them by more than
        ``watch_tolerance`` of its value. A pole that the data barely determine (a split
        mode kept by the robust pipeline) lets ``V`` fall by a few 1e-6 per step for dozens
        of steps while the answer no longer moves.
    give_up_above : float, optional
        Raise :class:`ident.errors.IdentError` when the misfit (``V`` per line and output)
        is still above this after :data:`ident.refine.output_error_fit.GIVE_UP_AFTER` steps
        and the last step did not halve it: a model that cannot explain the data (a wrong
        static position of integrated outputs: 1e7 noise variances) is not worth 30 steps,
        while a poor start still falling fast is (velocities whose searched gaps were
        +11 / +22 % off: 26 noise variances after 3 steps, 1.00 after 6).
    on_step : callable, optional
        ``on_step(step, misfit)`` after each Levenberg-Marquardt step (``misfit``: ``V`` per
        line and output), for a progress report: a step can take seconds to a minute.

    Returns
    -------
    OutputErrorFit

    Raises
    ------
    IdentError
        No basis, a model without a usable modal form, or a start whose
        steady state does not exist (:class:`ident.refine.harmonic_balance.BalanceError`).
    """
    t0 = time.perf_counter()
    if not basis:
        raise IdentError("the output-error refinement needs basis functions")
    weighted = bool(weighted and data.noise_var is not None)
    if weighted:
        weights = 1.0 / np.sqrt(smoothed_noise(data))
    else:
        rms = np.sqrt(np.mean(np.abs(data.Y) ** 2, axis=0))
        weights = np.broadcast_to(1.0 / np.where(rms > 0, rms, 1.0), data.Y.shape)
    options = dict(estimated=tuple(estimated), weights=weights, weighted=weighted, d_zero=d_zero,
                   max_iterations=max_iterations, tolerance=tolerance, watch=watch,
                   watch_tolerance=watch_tolerance, give_up_above=give_up_above,
                   on_step=on_step)
    if data.output_quantity != "displacement" or data.motion is None \
            or data.motion.line_noise is None:
        return fit_output_error(data, basis, model, t0=t0, **options)
    # displacements: the lines under the band predicted, unless the model's prediction there
    # disagrees with the measurement (modes under the band that the model does not hold)
    try:
        fit = fit_output_error(data, basis, model, t0=t0, predict_below=True, **options)
        if fit.below_band_misfit is None or fit.below_band_misfit <= MAX_BELOW_BAND_MISFIT:
            return fit
        kept = fit.below_band_misfit
    except BelowBandDisagrees as exc:
        kept = exc.misfit
    fit = fit_output_error(data, basis, model, t0=t0, predict_below=False, **options)
    fit.below_band = (f"measured (predicted, they were {kept:.3g} noise variances off the "
                      "measurement)")
    return fit


def refinement_case(data: FrequencyData, basis: Sequence[Nonlinearity],
                    model: StateSpaceModel) -> dict[str, Any]:
    """Whether ``refine: auto`` refines FNSI's ``model`` on these data, and why.

    The refinement removes what the noise of the measured motion does to FNSI's regressors.
    It runs when that noise is a material share of the residual
    (:data:`MIN_MOTION_NOISE_SHARE`) and the model otherwise explains the outputs to their
    noise (:data:`MAX_UNEXPLAINED`), or when it dominates the residual
    (:data:`DOMINANT_MOTION_NOISE_SHARE`).

    Returns
    -------
    dict
        ``run`` (bool), ``reason`` (one line), ``motion_noise_share`` and ``fnsi_misfit``
        (None where they cannot be computed): the expected share of the motion noise in
        FNSI's weighted squared residual per line and output, and that residual itself.
    """
    from fnsi_lab.ident.core.fnsi import steady_state_output, transfer_discrete

    out: dict[str, Any] = {"run": False, "reason": "", "motion_noise_share": None,
                           "fnsi_misfit": None}
    if not basis:
        out["reason"] = "no basis functions"
        return out
    if any(nl.hysteretic for nl in basis):
        # the share below carries the motion noise through each column's tangent, which
        # drops a hysteretic element's memory (ident.core.hysteresis.periodic_play_anchors):
        # no ground for the decision (the aircraft-like GVT: a share 180x FNSI's residual,
        # the refinement 10-30 s per level, never kept)
        out["reason"] = ("a hysteretic element (jenkins): the motion noise's share is not "
                         "modelled for it; refine: output-error forces the refinement")
        return out
    if data.noise_var is None or data.noise_resolved is None or not np.any(data.noise_resolved):
        out["reason"] = "no noise above the record resolution (noise-free data or one period)"
        return out
    if data.motion is None or data.motion.line_noise is None:
        out["reason"] = ("no noise spectrum of the measured motion (needs at least 2 periods); "
                         "refine: output-error forces it")
        return out
    w2 = 1.0 / smoothed_noise(data)
    G = transfer_discrete(model, data.z)[:, :, data.n_inputs:]
    integrated = data.output_quantity != "displacement"
    variance, _ = MotionNoise(data, basis, integrated=integrated).terms(G, basis)
    share = float(np.sum(variance * w2) / data.Y.size)
    misfit = float(np.sum(w2 * np.abs(data.Y - steady_state_output(model, data)) ** 2)
                   / data.Y.size)
    out.update(motion_noise_share=share, fnsi_misfit=misfit)
    if share < MIN_MOTION_NOISE_SHARE:
        out["reason"] = (f"the measured motion's noise adds {share:.2g} of the output noise to "
                         f"the residual (below {MIN_MOTION_NOISE_SHARE:g}): FNSI's regressors "
                         "are clean enough")
    elif misfit > MAX_UNEXPLAINED * (1.0 + share) and share < DOMINANT_MOTION_NOISE_SHARE:
        out["reason"] = (f"FNSI's residual is {misfit:.3g} noise variances where noise and "
                         f"motion noise explain {1 + share:.3g}: the model misses dynamics "
                         "that its own steady state would not fit either")
    else:
        out.update(run=True, reason=f"the measured motion's noise adds {share:.3g} of the "
                                    "output noise to FNSI's residual")
    return out
