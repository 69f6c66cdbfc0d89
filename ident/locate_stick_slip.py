"""Where does a joint stick and slip? Candidate locations ranked by a Jenkins element there
(``fnsi-lab locate --form jenkins``; docs/discovery.md, "Bolted joints").

The generic restoring force of :mod:`ident.locate` is a function of the present relative
displacement and velocity; a bolted joint's friction has memory, which none of those
columns draws. Here each candidate location gets a Jenkins element (a spring in series
with a slider, :mod:`ident.core.hysteresis`) whose slip is left to the data
(:mod:`ident.refine.slip_search`): the candidate's number is the smallest information
criterion (MDL over the orders) the element reaches, against the linear model's on the same
data. The criterion charges each model for its parameters and for the order it needs, so a
candidate whose criterion falls below the linear model's is worth its column (``score`` is
the fraction by which it falls: ``significant``). The criterion is no likelihood (no p-value
here: ``significance`` is null) and its fits read the basis column on the same periods as the
outputs it explains, whose noise the column then partly copies: on the GVT's linear level
(12 N, the joint never slips) every candidate lowered it, one 14x. So the best candidate is
``located`` only when the nested test of ``ident`` (:mod:`ident.robust.nested`: the basis
read on the odd periods, the outputs on the even ones, an F-test of the weighted residuals
against the linear model's) finds its Jenkins model significantly better; its ``-log10 p``
is then the candidate's ``significance``. A candidate whose slip search is refused (the
joint there barely slips, or slips all the time) is ``not significant`` with the reason.
That test too located a Jenkins element on the 12 N record (drive - payload, 14x), so
nothing is located either where the distortion analysis (:mod:`ident.analysis`, ``fnsi-lab
analyse``) calls every output linear within the noise: there is no distortion to place.

Measured on the aircraft-like GVT (docs/aircraft.md, bench/RESULTS.md): the wing-payload
pair first at every level from 26 N (its criterion 1.3-7.8x below the linear model's; the
generic columns put it third at 40 N), located at 26, 40, 55, 84 and 98 N (at 69 N the
nested test did not support it); at 12 N nothing located.
"""

from __future__ import annotations

import time
from typing import Callable, Mapping, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity, ParameterSpace
from fnsi_lab.ident.errors import IdentError, NotIdentifiableError
from fnsi_lab.ident.location_result import Localisation, LocationScore, location_name
from fnsi_lab.ident.refine.search_fit import order_by_information_criterion, search_block_rows
from fnsi_lab.ident.refine.slip_search import estimate_slips
from fnsi_lab.ident.robust.nested import NestedTest, nested_test

__all__ = ["rank_stick_slip", "STICK_SLIP_COLUMN"]

#: The one column each candidate gets.
STICK_SLIP_COLUMN = "play(L^T q, slip): Jenkins element, slip from the data"


def rank_stick_slip(session, candidates: Sequence[Mapping[str, float]], *,
                    max_order: int = 30,
                    progress: Callable[[str], None] | None = None) -> Localisation:
    """Rank candidate locations by the information criterion of a Jenkins element there.

    Parameters
    ----------
    session : IdentSession
        Linear (no basis), its data with the motion of every candidate's channels.
    candidates : sequence of mapping str -> float
        Location vectors.
    max_order : int
        Largest order of the criterion's sweep.
    progress : callable(str), optional
        Called with each candidate's name.

    Returns
    -------
    Localisation
        Candidates best first (``stage`` ``stick-slip``, ``slip`` the estimate in the
        outputs' length unit, ``rss_ratio_to_best`` the criterion over the best one's).
    """
    t0 = time.perf_counter()
    data, weighted, d_zero = session.data, session.weighted, session.d_zero
    max_order = int(min(max_order, 2 * data.n_lines // 4))
    rows = search_block_rows(data.n_outputs, max_order, data.n_lines, data.n_inputs + 1)
    linear_order, linear_ic = order_by_information_criterion(
        data, (), max_order, block_rows=rows, d_zero=d_zero, with_value=True)
    if not np.isfinite(linear_ic):
        raise IdentError("no stable linear model at any order up to "
                         f"{max_order}: nothing to compare the candidates with")
    rows_out: list[tuple[Mapping[str, float], float, tuple | None, int, str]] = []
    for cand in candidates:
        name = location_name(cand)
        if progress is not None:
            progress(name)
        element = Nonlinearity(name=name, kind="jenkins", channels=dict(cand),
                               unknown=(ParameterSpace("slip"),))
        try:
            found = estimate_slips(data, (element,), max_order=max_order, d_zero=d_zero)
            rows_out.append((cand, float(found.objective), found.basis, found.order, ""))
        except NotIdentifiableError as exc:
            rows_out.append((cand, np.inf, None, 0, str(exc)))
    rows_out.sort(key=lambda r: r[1])
    best = rows_out[0][1] if rows_out else np.inf
    out: list[LocationScore] = []
    for rank, (cand, ic, basis, order, reason) in enumerate(rows_out):
        better = np.isfinite(ic) and ic < linear_ic
        verdict = "significant" if better else "not significant"
        significance, fstat = float("nan"), float("nan")
        if better and rank == 0:
            test = _nested(session, basis, order, linear_order, rows)
            significance = (-np.log10(max(test.p_value, 1e-300)) if test.p_value is not None
                            else float("nan"))
            fstat = float("nan") if test.statistic is None else float(test.statistic)
            linear_record = test.supported and _linear_within_the_noise(session)
            if test.supported and not linear_record:
                verdict = "located"
            elif test.supported:
                reason = ("not located: the distortion analysis calls every output linear "
                          "within the noise")
            else:
                reason = f"the nested test on other periods: {test.statement}"
        out.append(LocationScore(
            channels=dict(cand), score=float(1 - ic / linear_ic) if np.isfinite(ic) else 0.0,
            significance=float(significance), f_statistic=fstat,
            rss_ratio_to_best=float(ic / best) if np.isfinite(ic) and best > 0 else float("inf"),
            verdict=verdict, stage="stick-slip",
            slip=None if basis is None else float(basis[0].slip), note=reason))
    return Localisation(candidates=out, order=int(linear_order), n_lines=int(data.n_lines),
                        columns=(STICK_SLIP_COLUMN,), degrees_of_freedom=(1, 0),
                        weighted=weighted, timings_s={"stick_slip": time.perf_counter() - t0},
                        linear_criterion=float(linear_ic))


def _nested(session, basis, order: int, linear_order: int, rows: int) -> NestedTest:
    """``ident``'s nested test of the candidate's Jenkins model (at the criterion's order)
    against the linear model (at its own), judged on other periods than the basis is read
    on when the record has them (:func:`ident.linear_comparison.split_periods`)."""
    from dataclasses import replace

    from fnsi_lab.ident.core.fnsi import model_at_order, subspace_decomposition
    from fnsi_lab.ident.core.periodic import with_basis
    from fnsi_lab.ident.linear_comparison import split_periods

    def model(data, n):
        dec = subspace_decomposition(data, max_order=n, weighted=session.weighted,
                                     block_rows=rows)
        return model_at_order(dec, data, n, d_zero=session.d_zero)

    data_nl = with_basis(session.data, basis)
    model_nl, model_lin = model(data_nl, order), model(session.data, linear_order)
    halves = split_periods(replace(session, config=replace(session.config,
                                                           nonlinearities=tuple(basis))))
    if halves is None:
        return nested_test(model_nl, data_nl, model_lin, session.data, d_zero=session.d_zero)
    return nested_test(model_nl, halves[0], model_lin, halves[1], d_zero=session.d_zero,
                       evaluation="basis columns from the odd periods, outputs and forces "
                                  "from the even ones")


def _linear_within_the_noise(session) -> bool:
    """True when the distortion analysis of the record (``fnsi-lab analyse``) finds no output
    nonlinear (an analysis that cannot run, e.g. one period, does not veto)."""
    from fnsi_lab.ident.analysis import analyse_input

    try:
        record = analyse_input(session.input, session.config, keep_spectra=False)
    except (IdentError, ValueError, np.linalg.LinAlgError):
        return False
    flags = [o.nonlinear for o in record.outputs]
    return bool(flags) and all(f is False for f in flags)
