"""The output-error refinement of FNSI's answer as the configuration asks for it
(:func:`refine`, docs/ident.md): the decision, where it starts (the answer's physical modes,
or without the weaker mode of a close pair that may be one mode split in two) and what it
watches to stop.
"""

from __future__ import annotations

import time
from dataclasses import replace
from itertools import combinations
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab.ident.coefficient_summaries import driving_points
from fnsi_lab.ident.core.basis import ESTIMABLE
from fnsi_lab.ident.core.coefficients import nonlinear_coefficients, summarize_coefficients
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.core.periodic import with_basis
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.fit import Fit
from fnsi_lab.ident.refine.modal import ModalModel
from fnsi_lab.ident.refine.output_error import (MAX_MISFIT, OutputErrorFit, omitted_mode_evidence,
                                                refine_output_error, refinement_case)
from fnsi_lab.ident.robust.reduction import reduce_model
from fnsi_lab.ident.session import IdentSession
from fnsi_lab.progress import Progress

__all__ = ["refine", "SPLIT_HALF_BANDWIDTHS"]


def _structural_start(session: IdentSession, ident: Fit) -> StateSpaceModel:
    """Where an output-error refinement starts: the answer, or for the robust pipeline its
    physical modes alone.

    The robust answer may keep real or out-of-band poles that fit a little of the residual.
    In the output error they are nearly unidentifiable parameters, and Levenberg-Marquardt
    crawled along them (3-DOF chain, 1 % noise: 30 steps, misfit 1.50 -> 1.39, gaps -1 / -2 %
    where the three structural modes alone converge in 5-6 steps to 1.11-1.13 and 0.7 %).
    So the start keeps the physical modes of the model at the MDI order, with ``B``, ``D``
    re-estimated (:func:`ident.robust.reduction.reduce_model`).
    """
    auto = ident.auto
    if auto is None or not np.any(auto.physical):
        return ident.model
    full = auto.full_model
    keep = np.zeros(full.order, bool)
    for i in np.flatnonzero(auto.physical):
        keep[list(auto.modal_dominancy.members[i])] = True
    if keep.all():
        return full
    return reduce_model(full, session.data, keep, d_zero=session.d_zero,
                        weighted=session.weighted)


#: Two physical modes closer than this many half-power bandwidths (``zeta f`` of the
#: two, summed) may be one mode split in two by a model error the refinement removes (the
#: 5-DOF chain's split: 2.0; at 4 the 3-DOF chain's 22.5 and 30.8 Hz modes, damped 3 and
#: 5 % in a robust answer, were a candidate; the score test would keep them, at the cost
#: of a second fit).
SPLIT_HALF_BANDWIDTHS = 3.0
#: Levenberg-Marquardt steps at most: the chains and SmallSat converge in 5-9
#: (docs/ident.md, "The output-error refinement").
MAX_STEPS = 30


def _split_candidates(ident: Fit) -> list[int]:
    """The weaker (lower MDI) mode of every close pair of the robust answer's physical
    modes, indices into its MDI table."""
    auto = ident.auto
    if auto is None:
        return []
    md = auto.modal_dominancy
    modes = [int(i) for i in np.flatnonzero(auto.physical) if md.is_pair[i]]
    weaker = set()
    for a, b in combinations(modes, 2):
        half_bandwidths_hz = (md.damping_ratio[a] * md.frequency_hz[a]
                              + md.damping_ratio[b] * md.frequency_hz[b])
        separation_hz = abs(md.frequency_hz[a] - md.frequency_hz[b])
        if separation_hz < SPLIT_HALF_BANDWIDTHS * half_bandwidths_hz:
            weaker.add(a if md.mdi[a] < md.mdi[b] else b)
    return sorted(weaker)


def _merged_start(session: IdentSession, ident: Fit,
                  weaker: Sequence[int]) -> StateSpaceModel | None:
    """A start that holds the robust answer's physical modes less ``weaker``, each close
    pair as one mode: the highest-order model of the sweep below the MDI order with a pole
    near every kept mode (within their half-power bandwidths) and no second pole near one
    (None if no model of the sweep has that).

    Re-estimating ``B``, ``D`` of the MDI-order model without the weaker pole does not do:
    its partner keeps the pole that shared the mode (twice the damping) and the model
    had no steady state (5-DOF chain, 40 dB); FNSI at the lower order places the one pole
    itself.
    """
    auto = ident.auto
    assert auto is not None, "close pairs exist only in a robust answer"
    md = auto.modal_dominancy
    kept = [int(i) for i in np.flatnonzero(auto.physical) if i not in weaker]
    f_kept = md.frequency_hz[kept]
    hb_kept = md.damping_ratio[kept] * f_kept
    for order in range(auto.full_model.order - 2, 2 * len(kept) - 1, -2):
        model = auto.models.get(order)
        if model is None:
            continue
        f = np.asarray(model.poles.natural_frequency_hz)
        hb = np.asarray(model.poles.damping_ratio) * f
        distance = np.abs(f[:, None] - f_kept[None, :]) / (hb[:, None] + hb_kept[None, :])
        near = distance < 1.0
        close = distance < SPLIT_HALF_BANDWIDTHS
        # poles come in conjugate pairs: each kept mode needs one pair, nothing else close
        if np.all(near.sum(axis=0) == 2) and np.all(close.sum(axis=0) == 2):
            keep = near.any(axis=1)
            return model if keep.all() else reduce_model(
                model, session.data, keep, d_zero=session.d_zero, weighted=session.weighted)
    return None


def _fit_without_split_modes(session: IdentSession, ident: Fit,
                             run: Callable[[StateSpaceModel], OutputErrorFit]
                             ) -> OutputErrorFit | None:
    """The refinement started without the weaker mode of each close pair, kept when no
    left-out mode would explain the refined residual (:func:`omitted_mode_evidence` below
    the mode's parameter count); None otherwise or without a close pair.

    A basis parameter the search got a few percent off leaves FNSI a model error that a
    second pole near a mode absorbs; refined with it, the two poles crawl towards each
    other for dozens of steps (5-DOF chain, 40 dB, gaps `auto`: 30 steps, 9 s) where the
    fit without the weaker one converges in 7. A fit without them that leaves more than
    :data:`ident.refine.output_error.MAX_MISFIT` is not kept either.
    """
    weaker = _split_candidates(ident)
    start = _merged_start(session, ident, weaker) if weaker else None
    if start is None:
        return None
    assert ident.auto is not None, "close pairs exist only in a robust answer"
    full = ident.auto.full_model
    md = ident.auto.modal_dominancy
    try:
        fit = run(start)
        modal = ModalModel.from_matrices(full.a_d, full.b_d, full.c_d, full.d_d)
    except IdentError:
        return None
    if fit.misfit > MAX_MISFIT:
        return None
    n_outputs, n_excitation = modal.d.shape
    threshold = 2 + 2 * n_excitation + 2 * n_outputs
    tested = []
    for i in weaker:
        mu = np.asarray(full.poles.discrete_eigenvalues)[list(md.members[i])]
        mu = mu[np.argmax(mu.imag)]
        r = int(np.argmin(np.abs(modal.poles - mu)))
        evidence = omitted_mode_evidence(fit, modal.poles[r], modal.b_pair[r], session.data.z)
        tested.append({"frequency_hz": float(md.frequency_hz[i]), "evidence": evidence,
                       "threshold": threshold})
        if not evidence < threshold:
            return None
    session.evidence["output_error"]["left_out"] = tested
    return fit


def refine(session: IdentSession, ident: Fit, progress: Any = None) -> Any:
    """The output-error refinement of FNSI's answer that the configuration asks for
    (docs/ident.md).

    The decision is taken on FNSI's answer ``ident.model``; the refinement starts from
    :func:`_structural_start`. ``refine: auto`` runs it where the
    measured motion's noise is a material part of FNSI's residual and the model otherwise
    explains the data (:func:`refinement_case`), and keeps
    it only if the refined model explains the outputs to their noise
    (:data:`ident.refine.output_error.MAX_MISFIT`); ``output-error`` always runs and keeps it. The
    refined basis parameters and basis columns replace the session's. The decision and its
    numbers go to ``session.evidence['output_error']``. Returns the
    :class:`ident.refine.output_error.OutputErrorFit` kept, or None. ``progress`` (truthy)
    reports each Levenberg-Marquardt step on stderr: a step of a hysteretic joint's
    model takes up to a minute.
    """
    cfg, data = session.config, session.data
    if cfg.refine == "none" or not cfg.nonlinearities:
        return None
    case = refinement_case(data, cfg.nonlinearities, ident.model)
    decision = {"applied": False, **{k: v for k, v in case.items() if k != "run"}}
    session.evidence["output_error"] = decision
    if cfg.refine == "auto" and not case["run"]:
        return None
    search = session.parameter_search
    estimated = [(e.unknown.element, e.unknown.parameter)
                 for e in (search.estimates if search is not None else ())
                 if e.unknown.continuous]
    t0 = time.perf_counter()

    def run(start: StateSpaceModel) -> OutputErrorFit:
        bar = Progress(MAX_STEPS, "output-error refinement (steps)", enabled=bool(progress))
        try:
            return refine_output_error(
                data, cfg.nonlinearities, start, estimated=estimated, d_zero=session.d_zero,
                watch=_answer_values(session), max_iterations=MAX_STEPS,
                give_up_above=100 * MAX_MISFIT if cfg.refine == "auto" else None,
                on_step=lambda step, misfit: bar.update(
                    note=f"misfit {misfit:.3g}"))
        finally:
            bar.finish()
    try:
        fit = _fit_without_split_modes(session, ident, run) or run(
            _structural_start(session, ident))
    except (IdentError, np.linalg.LinAlgError) as exc:
        # a numerical failure of the optional refinement leaves FNSI's answer, said in a
        # warning, never a traceback that loses the identification
        why = str(exc) if isinstance(exc, IdentError) else f"a singular system: {exc}"
        decision["reason"] = f"not applied: {why}"
        session.warnings.append(f"the output-error refinement was not applied ({why}); "
                                "the nonlinear model is FNSI's")
        return None
    session.timings_s["output_error"] = time.perf_counter() - t0
    if cfg.refine == "auto" and fit.misfit > MAX_MISFIT:
        decision["reason"] = (f"not kept: the refined model leaves {fit.misfit:.3g} noise "
                              f"variances (above {MAX_MISFIT:g}); the nonlinear model is FNSI's")
        decision["misfit"] = fit.misfit
        return None
    decision["applied"] = True
    session.config = replace(cfg, nonlinearities=fit.basis)
    session.data = with_basis(data, fit.basis)
    if fit.parameters and search is not None:   # refined values read no measured motion
        moot = set(search.motion_noise_warnings)
        session.warnings = [w for w in session.warnings if w not in moot]
    return fit


def _answer_values(session: IdentSession):
    """``watch(model, basis)``: the declared coefficients and the basis parameters, the
    numbers whose settling ends an output-error refinement (None without a driving point)."""
    dp = driving_points(session)
    if dp is None:
        return None

    def watch(model: StateSpaceModel, basis) -> np.ndarray:
        spectra = nonlinear_coefficients(model, session.data, basis, driving_point=dp)
        values = [s.value for s in summarize_coefficients(spectra)]
        return np.array(values + [nl.parameter(p) for nl in basis
                                  for p in ESTIMABLE.get(nl.kind, ())], float)
    return watch
