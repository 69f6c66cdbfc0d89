"""Basis parameters from the data: clearances and offsets of stops, exponents of polynomials.

A stop's gap or a polynomial's exponent enters FNSI only through the extended input
``E = [P; H(theta)]``; for a given ``theta`` the rest is the usual linear problem. The
objective is the **model error of the FNSI fit** as a function of ``theta``:

``V(theta) = sum_k |Y_k - (C (z_k I - A)^-1 B + D) E_k(theta)|^2 / sum_k |Y_k|^2``

over the processed lines, where ``A``, ``C`` come from one QR + one SVD of the data with
``H(theta)`` (:func:`ident.core.fnsi.subspace_decomposition`, few block rows:
:func:`search_block_rows`) and ``B``, ``D`` from one linear least squares
(:func:`ident.core.fast_bd.fast_estimate_bd`). Holding ``A``, ``C`` fixed while ``theta`` moves
is *not* enough: the identified linear dynamics absorb a wrong gap (3-DOF chain: with
``A``, ``C`` from a gap 2x too large, the minimum over the gap sat at 1.8x the truth), so
every candidate pays its own decomposition; with 6 block rows that is about 40-80 ms for
the 39-channel SmallSat.

Continuous parameters (clearances, a stop's offset, a signed exponent): a coarse scan of
each interval (one parameter at a time, log-spaced; linear for an offset; scanned again from
the stops open when a clearance lands at its lowest point,
:func:`ident.refine.search_start.better_start`), then Newton
steps on a quadratic model of ``V`` from a central finite-difference stencil. ``V`` is close
to quadratic near its minimum while the residual vector is strongly curved, so Gauss-Newton
on the residual crawled (SmallSat: 20 iterations without reaching the minimum) where Newton
on ``V`` converged in 4-5. The
standard deviation is curvature-based: ``cov = 2 V_min / dof * H^-1`` (``H`` the Hessian of
``V``, ``dof`` the residual degrees of freedom), i.e. ``s^2 (J^T J)^-1`` with the residual
variance ``s^2`` estimated from the fit. Discrete parameters (candidate exponents) are
evaluated one by one.

The search refuses (:class:`ident.errors.NotIdentifiableError`) rather than guesses when the
motion never reaches the search interval (a stop never in contact), when the minimum lies
on the interval's edge (the truth is outside, or the element barely acts), when the
objective is flat (relative standard deviation above ``max_relative_std``), when two
candidate exponents fit equally well (``min_margin``), and when the objective around the
estimate does not rise as its curvature says (a lucky low point of a rough objective,
``roughness``). With the noise correction it also compares the residual with the output
noise (``noise_misfit``; a warning above 10). docs/ident.md, "Unknown basis parameters",
explains the objective and its limits.

Noise in the measured motion adds to ``V`` a share that grows with the contact time (gaps
come out too large). With displacement outputs and at least 2 periods the continuous
parameters are refined on the noise-weighted model error less that share
(:class:`ident.refine.motion_noise.MotionNoise`), the weights held fixed at the previous
estimate.

The jobs live in their own modules: the search spaces (:mod:`ident.refine.search_space`), the
fit behind the objective and the order of the search (:mod:`ident.refine.search_fit`), the
objective at the candidate points with its memo, threads and scans
(:mod:`ident.refine.search_objective`), the motion noise (:mod:`ident.refine.motion_noise`),
Newton on the continuous parameters (:mod:`ident.refine.search_newton`), the second start
(:mod:`ident.refine.search_start`), the refusals and notes
(:mod:`ident.refine.search_refusal`) and the records (:mod:`ident.refine.search_result`); this
module runs the search and retries it from its second start.

Shapes: ``FrequencyData`` as in :mod:`ident.core.periodic`; residual vectors stack the real and
imaginary parts of ``Y - Y_hat``, shape ``(2 F p,)``.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Callable, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData, as_displacement_outputs
from fnsi_lab.ident.errors import NotIdentifiableError
from fnsi_lab.ident.refine.motion_noise import (CORRECTED_MIN_STEP, MotionNoise,
                                                corrects_motion_noise, motion_noise_std)
from fnsi_lab.ident.refine.search_fit import fixed_state_residual, search_block_rows
from fnsi_lab.ident.refine.search_newton import newton_minimise, wider_curvature
from fnsi_lab.ident.refine.search_objective import SearchObjective
from fnsi_lab.ident.refine.search_refusal import (StartRefused, refuse_if_unclear, roughness,
                                                  search_notes)
from fnsi_lab.ident.refine.search_result import ParameterEstimate, ParameterSearchResult
from fnsi_lab.ident.refine.slip_search import estimate_slips, only_slips_unknown
from fnsi_lab.ident.refine.search_space import (AUTO_CLEARANCE_FRACTION, AUTO_EXPONENTS,
                                                AUTO_SIGNED_EXPONENT_INTERVAL, Unknown,
                                                format_values, has_unknown_parameters,
                                                initial_value, resolve_basis, search_spaces,
                                                with_value)
from fnsi_lab.ident.refine.search_start import choose_start

__all__ = ["Unknown", "ParameterEstimate", "ParameterSearchResult", "search_spaces",
           "fixed_state_residual", "estimate_basis_parameters", "MotionNoise", "has_unknown_parameters",
           "AUTO_EXPONENTS", "DEFAULT_SEARCH_ORDER", "AUTO_SIGNED_EXPONENT_INTERVAL",
           "AUTO_CLEARANCE_FRACTION", "search_block_rows"]

#: Model order of the search when the caller gives none (the configuration's ``order``
#: otherwise; capped by the largest order of the sweep).
DEFAULT_SEARCH_ORDER = 30


def estimate_basis_parameters(data: FrequencyData, basis: Sequence[Nonlinearity], *, order: int,
                              d_zero: bool = False, block_rows: int | None = None,
                              weighted: bool = True, grid_points: int = 7,
                              max_relative_std: float = 0.1, min_margin: float = 25.0,
                              profile_offsets: Sequence[float] = (-0.03, 0.03),
                              noise_correction: bool = True,
                              select_order: bool = False,
                              workers: int | None = None,
                              progress: Callable[[str], None] | None = None
                              ) -> ParameterSearchResult:
    """Estimate the unknown clearances and exponents of ``basis`` from the data.

    Parameters
    ----------
    data : FrequencyData
        Prepared with the motion of the basis channels (``motion_for=basis``); its ``E``
        columns beyond the forces are ignored.
    basis : sequence of Nonlinearity
        Elements, some with ``unknown`` parameters.
    order : int
        Model order of the fits (the objective is the model error at this order).
    d_zero : bool
        ``D = 0`` in the B, D fits.
    block_rows : int, optional
        ``i`` of the decompositions (default :func:`search_block_rows`).
    weighted : bool
        Noise-weighted decompositions in the noise-corrected stages (when the data carry a
        noise covariance); the plain model error always uses unweighted ones.
    grid_points : int
        Points of the coarse scan of each continuous interval (log-spaced when it starts
        above 0: a gap is better known relative to itself).
    max_relative_std : float
        Refuse a continuous estimate whose standard deviation exceeds this fraction of it.
    min_margin : float
        Refuse a discrete choice whose runner-up, or a continuous value whose interval ends,
        fit within this chi-square distance of it (25: five standard deviations in the
        likelihood-ratio sense).
    profile_offsets : sequence of float
        Relative offsets of the local objective scan around each continuous estimate.
    noise_correction : bool
        When the data carry the noise spectrum of the motion (displacement outputs,
        ``P >= 2``, noise above the record resolution), refine continuous parameters on the
        noise-weighted model error less the share the motion noise adds to it
        (:class:`MotionNoise`; docs/ident.md). False: the plain model error.
    select_order : bool
        ``order`` is only the largest order: the information criterion (MDL over the orders
        2..``order``, with the search's own fits) picks the order of the coarse scan at the
        intervals' centres, and again at the scan's estimate for the rest of the search
        (with the second start, see Notes, it compares two orders).
        For callers without an order (the robust pipeline): above the structure's order the model error turns
        rough at the 1e-6 level (spare states fit parts of the misfit, differently for
        neighbouring candidates), and Newton stalls off the minimum (5-DOF chain of
        bench/robustness.py, noise-free, order 30: gaps -0.7 / +0.7 %; at the criterion's
        order 10: -0.006 / +0.002 %).
    workers : int, optional
        Threads that evaluate independent candidates at once (the points of a scan, of a
        Newton stencil, of a profile); default ``min(4, cores)``. Each candidate is one
        QR/SVD, FFTs and small solves that release the interpreter lock: on 2 cores two
        threads ran 16 candidates 1.5-1.9x faster and a whole noise-corrected search 1.3x
        (its Newton steps are sequential), with identical values.
    progress : callable, optional
        ``progress(note)`` after each stage (e.g. to advance a progress bar).

    Returns
    -------
    ParameterSearchResult

    Raises
    ------
    NotIdentifiableError
        The data cannot tell a parameter (see the module docstring); the message names the
        element, the parameter and the reason.
    IdentError
        Data without the basis motion, order too large for the data.

    Notes
    -----
    A search that would refuse is run once more with the second start (from the stops open,
    :func:`ident.refine.search_start.better_start`) if it had not tried it, and refuses only
    if that fails too (the first refusal is raised; without an order it adds that giving one
    helps): without an order, the criterion's order at the intervals' centres (8 for a 3-DOF
    chain of order 6) once led the scan to a wrong valley that no scan point at a lower end
    revealed.
    """
    if only_slips_unknown(basis):   # Jenkins slips: by the information criterion
        return estimate_slips(data, basis, max_order=order, d_zero=d_zero, progress=progress)
    search = partial(_search, data, basis, order=order, d_zero=d_zero, block_rows=block_rows,
                     weighted=weighted, grid_points=grid_points,
                     max_relative_std=max_relative_std, min_margin=min_margin,
                     profile_offsets=profile_offsets, noise_correction=noise_correction,
                     select_order=select_order, workers=workers, progress=progress)
    restarted: bool | None   # whether the refused search tried the second start (None: unknown)
    try:
        return search()
    except StartRefused as exc:
        refusal, restarted = exc.refusal, exc.restarted
    except NotIdentifiableError as exc:
        refusal, restarted = exc, None
    if restarted is False:   # the second start not tried yet
        try:
            return search(force_restart=True)
        except (StartRefused, NotIdentifiableError):
            pass
    if select_order and restarted is not None:
        # the order came from the criterion, which wanders while the basis is wrong
        raise NotIdentifiableError(f"{refusal}; or give the structure's model order "
                                   "(order: in the configuration, --order)",
                                   element=getattr(refusal, "element", None)) from None
    raise refusal

def _search(data: FrequencyData, basis: Sequence[Nonlinearity], *, order: int, d_zero: bool,
            block_rows: int | None, weighted: bool, grid_points: int, max_relative_std: float,
            min_margin: float, profile_offsets: Sequence[float], noise_correction: bool,
            select_order: bool, workers: int | None,
            progress: Callable[[str], None] | None, force_restart: bool = False
            ) -> ParameterSearchResult:
    """:func:`estimate_basis_parameters` from one start; ``force_restart``: the second start
    is tried whatever the first scan gave. A refusal of the estimate comes as
    :class:`ident.refine.search_refusal.StartRefused` (with whether the second start was
    tried)."""
    t0 = time.perf_counter()
    integrated = data.output_quantity
    if integrated != "displacement":
        # compared in displacement units, where the model error falls smoothly towards the
        # true parameters (as_displacement_outputs); D is estimated, whatever the caller's
        # choice for the integrated outputs
        data, d_zero = as_displacement_outputs(data), False
    basis = tuple(basis)
    order = int(order)
    unknowns = search_spaces(data, basis)
    if not unknowns:
        return ParameterSearchResult(basis, [], float("nan"), order, 0)
    values = np.array([initial_value(u) for u in unknowns], float)
    objective = SearchObjective(data, basis, unknowns, values, order=order, d_zero=d_zero,
                                block_rows=block_rows, weighted=weighted,
                                grid_points=grid_points, workers=workers,
                                note=progress or (lambda s: None))
    # the noise correction needs the noise spectrum of the motion and a resolved noise
    correct = bool(noise_correction and data.motion is not None
                   and data.motion.noise_spectrum is not None and data.noise_var is not None
                   and (data.noise_resolved is None or np.any(data.noise_resolved)))
    if select_order:   # the scan at the criterion's order at the interval centres ...
        objective.set_order(objective.ic_order(values), scanned=False)
    centres, scan_order = values.copy(), objective.order
    values[:], scans = objective.coarse_scan(values)
    objective.note(f"scan: {format_values(unknowns, values)}")
    if select_order:   # ... and the rest at its order at the scan's estimate
        objective.set_order(objective.ic_order(values))
    scans, restarted_at_all = choose_start(objective, scans, select_order=select_order,
                                           centres=centres, scan_order=scan_order,
                                           force_restart=force_restart)
    if correct:   # clearances, offsets: only where the motion noise is worth correcting
        correct = corrects_motion_noise(data, basis, unknowns, values, objective.cont)
    if correct:
        objective.noise_model = MotionNoise(data, basis)
    std = _minimise(objective, scans, correct)
    if (correct and objective.cont) or objective.rescan:  # profiles and margins in the
        saved = values.copy()                             # objective minimised
        for k, u in enumerate(unknowns):
            scans[k] = objective.scan(k, u)
        values[:] = saved
    objective.note(f"estimate: {format_values(unknowns, values)}")
    estimates, v_best, misfit = _estimates(objective, scans, std, correct, profile_offsets,
                                           max_relative_std, min_margin, restarted_at_all)
    notes, noise_notes = search_notes(estimates, data, integrated, correct, misfit)
    return ParameterSearchResult(resolve_basis(basis, unknowns, values), estimates, v_best,
                                 objective.order, objective.n_evaluations, objective.i_search,
                                 {"total": time.perf_counter() - t0}, notes,
                                 noise_misfit=misfit, motion_noise_warnings=noise_notes)


def _minimise(objective: SearchObjective, scans: dict, correct: bool) -> np.ndarray:
    """Newton on the continuous parameters from the chosen start, the discrete ones chosen
    again after them; corrected (``correct``): twice, the noise weights taken at the
    previous estimate. Moves ``objective.values`` and updates the discrete parameters'
    ``scans``; returns the standard deviations (NaN for discrete parameters)."""
    values, unknowns, cont = objective.values, objective.unknowns, objective.cont
    disc = [k for k, u in enumerate(unknowns) if not u.continuous]
    dof = objective.dof_at(objective.order)
    std = np.full(len(unknowns), np.nan)
    # corrected: twice, the weights taken at the previous estimate
    n_stages = 2 if correct and cont else 1
    for stage in range(n_stages):
        if correct and cont:
            objective.set_weights(values)
        for _ in range(2 if disc and cont else 1):
            if cont:
                # the first corrected stage only has to bring the weights near the minimum
                loose = correct and stage == 0
                v_min, hess = newton_minimise(objective.objectives, values, cont, unknowns, dof,
                                              noise_level=lambda v: objective.evaluated(v)[1],
                                              min_rel_step=CORRECTED_MIN_STEP if correct
                                              else 0.0,
                                              tolerance=5e-3 if loose else 5e-4)
                if stage == n_stages - 1:   # the uncertainty comes from the last stage
                    hess = wider_curvature(objective.objectives, values, cont, unknowns, hess)
                # cov = s^2 (J^T J)^-1 with ||r||^2 = V y_energy, J^T J = y_energy H / 2 and
                # s^2 = ||r||^2 / dof at the minimum (the noise level, not the corrected V)
                try:
                    cov = 2.0 * objective.evaluated(values)[1] / dof * np.linalg.inv(hess)
                    std[cont] = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.inf))
                except np.linalg.LinAlgError:
                    std[cont] = np.inf
            for k in disc if cont else ():     # the continuous ones moved: choose again
                vs = objective.objectives([with_value(values, k, g)
                                           for g in unknowns[k].choices])
                values[k] = unknowns[k].choices[int(np.argmin(vs))]
                scans[k] = (np.asarray(unknowns[k].choices), vs)
    return std


def _estimates(objective: SearchObjective, scans: dict, std: np.ndarray, correct: bool,
               profile_offsets: Sequence[float], max_relative_std: float, min_margin: float,
               restarted_at_all: bool) -> tuple[list[ParameterEstimate], float, float]:
    """The estimates with their profiles, margins and roughness, each refused if unclear
    (:class:`ident.refine.search_refusal.StartRefused`); with the objective at the estimate
    and the noise misfit (NaN without the correction)."""
    values, unknowns, data = objective.values, objective.unknowns, objective.data
    v_best, v_noise = objective.evaluated(values)
    misfit = float("nan")
    if objective.weights is not None:   # the weighted residual against the output noise
        W = objective.weights
        misfit = float(np.sum(W * np.abs(objective.fit_at(values)[1].residual) ** 2)
                       / np.sum(W * data.noise_var))
    s2 = v_noise / objective.dof_at(objective.order)   # per degree of freedom
    estimates = []
    for k, u in enumerate(unknowns):
        grid, vs = scans[k]
        if u.continuous:
            lo, hi = u.bounds
            local = values[k] + u.magnitude(values[k]) * np.array(profile_offsets)
            local = local[(local >= lo) & (local <= hi)]
            lv = objective.objectives([with_value(values, k, g) for g in local])
            rough = roughness(local - values[k], lv - v_best, std[k], s2)
            pv = np.concatenate([grid, local, [values[k]]])
            po = np.concatenate([vs, lv, [v_best]])
            edge_v = [vs[0], vs[-1]]
            margin = float((min(edge_v) - v_best) / s2) if s2 > 0 else float("inf")
        else:
            pv, po, rough = grid, vs, float("nan")
            rest = np.sort(po)[1:]
            margin = float((rest[0] - v_best) / s2) if rest.size and s2 > 0 else float("inf")
        srt = np.argsort(pv)
        nl = objective.basis[u.element]
        est = ParameterEstimate(u, float(values[k]),
                                float(std[k]) if u.continuous else float("nan"),
                                np.asarray(pv, float)[srt], np.asarray(po, float)[srt], margin,
                                motion_noise_std(data, nl) if u.is_length else None,
                                noise_corrected=correct and u.continuous, roughness=rough)
        try:
            refuse_if_unclear(est, nl, max_relative_std, min_margin)
        except NotIdentifiableError as refusal:   # estimate_basis_parameters may retry
            raise StartRefused(refusal, restarted_at_all) from None
        estimates.append(est)
    return estimates, v_best, misfit
