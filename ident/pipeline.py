"""One identification from arrays to answer: the entry point every caller shares.

:func:`identify_input` takes periodic arrays (:class:`~fnsi_lab.ident.core.io.IdentInput`) and a
configuration (:class:`~fnsi_lab.ident.config.IdentConfig`) and returns an
:class:`Identification`: the model at a fixed order, or the robust automatic pipeline
(information criterion, stabilisation, modal dominancy index, reduction) when no order is
given. The ``fnsi-lab ident`` command, :func:`fnsi_lab.identify`, the live identification
service, batch campaigns and the benchmarks all call it, so a configuration means the same
thing everywhere (docs/architecture.md).

Reading files is not done here (``ident`` works on arrays): :mod:`fnsi_lab.inputs` turns a
recording or an array file into an ``IdentInput``.

The jobs around it have their own modules: :mod:`ident.fit` (FNSI at a fixed order or the
robust pipeline), :mod:`ident.refinement` (the output-error refinement),
:mod:`ident.coefficient_summaries` (coefficients and their verdicts),
:mod:`ident.linear_comparison` (the answer against the linear fit) and
:mod:`ident.identification` (the answer, :class:`Identification`, and its JSON), re-exported
here.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.progress import Progress
from fnsi_lab.ident.coefficient_summaries import (coefficient_summaries,
                                                  session_coefficient_spectra)
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.coefficients import CoefficientSpectra
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.core.io import IdentInput
from fnsi_lab.ident.core.result import Coefficient, Mode
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.fit import Fit, answer_modes, fit_session
from fnsi_lab.ident.identification import Identification
from fnsi_lab.ident.linear_comparison import compare_with_linear, refit_on_its_record
from fnsi_lab.ident.refine.parameter_search import DEFAULT_SEARCH_ORDER, ParameterSearchResult
from fnsi_lab.ident.refinement import refine
from fnsi_lab.ident.robust.mode_support import mode_evidence
from fnsi_lab.ident.robust.options import AutoOptions
from fnsi_lab.ident.robust.nested import NestedTest
from fnsi_lab.ident.request import (DEFAULT_ORDERS, IdentRequest, basis_from_truth,
                                    default_config, resolve_request)
from fnsi_lab.ident.session import (IdentSession, apply_recording_truth, linear_answer_evidence,
                                    prepare_session)

__all__ = ["IdentSession", "Identification", "Mode", "Coefficient", "prepare_session",
           "identify_input",
           "default_config", "basis_from_truth", "apply_recording_truth", "DEFAULT_ORDERS",
           "identify_request"]


def identify_input(inp: IdentInput, cfg: IdentConfig, *, order: int | None = None,
                   orders: Any = None, reduce_at: int | None = None,
                   max_order: int | None = None, block_rows: int | None = None,
                   progress: Any = None) -> Identification:
    """Identify a nonlinear model from periodic arrays: THE entry point.

    Parameters
    ----------
    inp : IdentInput
        Periodic forces and responses, shapes ``(R, P, N, m)`` and ``(R, P, N, p)``.
    cfg : IdentConfig
        Band, channels, basis functions, options (``cfg.auto`` for the robust pipeline).
    order : int, optional
        Fixed model order. None (default): the robust pipeline over ``orders`` (the
        config's ``order`` is the command line's default for ``--order``, not used here).
    orders : str or sequence of int, optional
        Sweep of the robust pipeline (``'2:60'``, ``'4,6,8'``...); default the config's
        ``auto.orders``, else 2..60.
    reduce_at : int, optional
        Apply the MDI and reduction at this order (default: the selected order).
    max_order : int, optional
        Largest order of a fixed-order decomposition (default: the order).
    block_rows : int, optional
        ``i`` (default: the config's, else from the data sizes).
    progress : bool or fnsi_lab.progress.Progress, optional
        Progress bar over the orders of the sweep.

    Returns
    -------
    Identification

    Raises
    ------
    IdentError
        Bad configuration for these data, or no stable model.
    """
    request = resolve_request(inp, cfg, order=order, orders=orders, reduce_at=reduce_at,
                              max_order=max_order, block_rows=block_rows)
    return identify_request(inp, request, progress=progress)


def identify_request(inp: IdentInput, request: IdentRequest, *, progress: Any = None,
                     spent_s: Mapping[str, float] | None = None,
                     validation: IdentInput | Sequence[IdentInput] | None = None,
                     left_out: Sequence[dict] = (),
                     searched_out: tuple[Sequence[dict], Sequence[str]] = ((), ()),
                     search: ParameterSearchResult | None = None,
                     linear: Identification | None = None,
                     second_candidate: bool = False
                     ) -> Identification:
    """Identify with resolved settings (:func:`ident.request.resolve_request`).

    Parameters
    ----------
    inp : IdentInput
        Periodic forces and responses.
    request : IdentRequest
        The configuration, the fixed order or the sweep, and the decomposition's sizes.
    progress : bool or fnsi_lab.progress.Progress, optional
        Progress bar over the orders of the sweep.
    spent_s : mapping, optional
        Seconds spent before, per stage (``{"load": 0.4}``: reading the file), added to the
        result's timings and total.
    validation : IdentInput or sequence of IdentInput, optional
        Other records of the same structure (other levels, another realisation): the
        nested test's simulation check predicts each of them instead of the identified
        record (:func:`ident.linear_comparison.simulated_against_linear`), and runs even
        where every coefficient is identified.
    left_out : sequence of dict
        Elements an earlier pass left out because none of their coefficients is determined
        (:func:`_undetermined_elements`), reported with the answer.
    searched_out : (sequence of dict, sequence of str)
        Elements an earlier pass's parameter search left out (their ``refused`` entries)
        and its warnings, reported with the answer (the pass run again has no search).
    search : ParameterSearchResult, optional
        A search of the configured elements made before, taking another minimum
        (:func:`_second_candidate`): no search is run.
    linear : Identification, optional
        The linear fit of this record, made before (the nested test's).
    second_candidate : bool
        This pass tries a second candidate after the first answered the linear fit
        (:func:`_second_candidate`): the nested test always runs, and no third is tried.

    Returns
    -------
    Identification
        Frozen, built once with everything it holds.
    """
    t0 = time.perf_counter()
    cfg, order, sweep = request.config, request.order, list(request.orders)
    reduce_at, max_order, block_rows = request.reduce_at, request.max_order, request.block_rows
    search_order = (int(order) if order is not None
                    else min(cfg.order or DEFAULT_SEARCH_ORDER, max(sweep)))
    located = None
    if cfg.nonlinearities_auto:   # the element from the data: located, then a spline there
        from fnsi_lab.ident.locate import with_located_element
        cfg, located = with_located_element(
            inp, cfg, order=order, progress=(lambda note: None) if progress else None)
    # without any order given, the criterion picks the search's (at most search_order)
    # a basis parameter the data cannot tell leaves its element out: at worst the linear answer
    session = prepare_session(inp, cfg, search_order=search_order,
                              select_search_order=order is None and cfg.order is None,
                              progress=progress, refused_as_linear=True, search=search)
    if located is not None:
        session.evidence["localisation"] = located.to_json()
        if located.located is None:
            session.evidence["nonlinear_vs_linear"] = linear_answer_evidence(
                "localisation", "nonlinearities: auto located no element whose nonlinear force "
                "explains the distortion beyond the noise (localisation: the candidates and "
                "why): the answer is the linear fit")
    if searched_out[0]:   # the first pass's search: said again, not lost with its session
        evidence = session.evidence.setdefault("nonlinear_vs_linear", {})
        evidence["refused"] = [*searched_out[0], *evidence.get("refused", [])]
    session.warnings[:0] = list(searched_out[1])
    if left_out:
        _report_left_out(session, left_out)
    fit = fit_session(session, order=order, sweep=sweep, reduce_at=reduce_at,
                      max_order=max_order, block_rows=block_rows, progress=progress)
    output_error = refine(session, fit, progress=progress)
    model = output_error.model if output_error is not None else fit.model
    t2 = time.perf_counter()
    spectra = session_coefficient_spectra(session, model)
    session.timings_s["coefficients"] = time.perf_counter() - t2
    summaries = coefficient_summaries(spectra, session)   # the verdicts, read once
    undetermined = _undetermined_elements(session.config.nonlinearities, summaries)
    if undetermined:   # identified again without them (docs/ident.md)
        spent = {**(spent_s or {}), "left_out_pass": time.perf_counter() - t0}
        return identify_request(
            inp, replace(request, config=replace(
                session.config, nonlinearities=tuple(
                    nl for nl in session.config.nonlinearities
                    if nl.name not in {u["name"] for u in undetermined}))),
            progress=progress, spent_s=spent, validation=validation,
            left_out=[*left_out, *undetermined], searched_out=_searched_out(session, left_out,
                                                                           searched_out),
            linear=linear, second_candidate=second_candidate)
    compare = session.config.compare_linear
    nested = None
    if validation is not None and not (session.config.nonlinearities and compare):
        named = [str(v.path) for v in (
            [validation] if isinstance(validation, IdentInput) else validation)]
        session.warnings.append(
            ("the validation records " + plain.names(named[:-1]) + f" and {named[-1]} were"
             if len(named) > 1 else f"the validation record {named[0]} was") + " not used: "
            + ("no nonlinear element to check" if not session.config.nonlinearities
               else "compare_linear: false skips the nested test and its simulation check"))
    if session.config.nonlinearities and compare:
        verdicts = [str(c.get("verdict")) for c in summaries]
        modes = answer_modes(Fit(model, fit.method, fit.auto, fit.decomposition), output_error)
        if (compare == "auto" and validation is None and not second_candidate and verdicts
                and all(v == "identified" for v in verdicts)
                and modes and len(session.input.parts) < 2):
            # every coefficient determined: the test would only confirm it (chain, SmallSat,
            # Silverbox); it costs a second identification (docs/ident.md). Not for an answer
            # without a physical mode: a degenerate order can make any coefficient look
            # determined (GVT at 26 N, another realisation: order 1, no mode, "identified").
            # Nor for several records: each must be predicted no worse (docs/ident.md)
            from fnsi_lab.ident.robust.nested import weighted_residual

            session.evidence["nonlinear_vs_linear"] = {
                **session.evidence.get("nonlinear_vs_linear", {}),   # elements left out
                "decision": "nonlinear", "test": None,
                "residual_nonlinear": weighted_residual(model, session.data),
                "residual_linear": None, "statistic": None, "p_value": None,
                "statement": "every coefficient is identified: the linear fit was not run "
                             "(compare_linear: true runs it)"}
        else:
            t3 = time.perf_counter()
            nested = compare_with_linear(
                session, model, modes, verdicts, order=order,
                sweep=sweep, reduce_at=reduce_at, max_order=max_order, block_rows=block_rows,
                validation=validation, linear=linear, progress=progress,
                refit=lambda start: refit_on_its_record(session, start))
            if nested is not None and not nested.supported and output_error is None:
                before = _before_the_reduction(session, fit, nested, validation,
                                               progress=progress)
                if before is not None:
                    fit, spectra, nested = before
                    summaries = coefficient_summaries(spectra, session)   # the full model's
                    model = fit.model
            if nested is not None and nested.supported and nested.answer_model is not None:
                model, spectra, summaries = _refit_answer(session, nested.answer_model)
            # an added mode without physical evidence leaves the answer's list (issue 29)
            nested = _with_mode_evidence(nested, model, session, summaries)
            session.timings_s["linear_fit"] = time.perf_counter() - t3
    candidate = (None if second_candidate or nested is None or nested.supported
                 else _second_candidate(session, request, summaries, left_out))
    if candidate is not None and nested is not None:
        kwargs, tried = candidate
        t_second = time.perf_counter()
        refused, said = _searched_out(session, left_out, searched_out)
        alone = kwargs.pop("alone", None)
        if alone is not None:   # searched again: no longer among the refused
            refused = [r for r in refused if r.get("name") != alone]
            said = [*(w for w in said if f"nonlinearity {alone!r}" not in w),
                    f"{tried}; it was tried and passed the nested test against the same "
                    "linear fit (docs/ident.md, \"A second candidate\")"]
        if progress:   # why the sweep runs again
            Progress(1, "second candidate").update(1, note=tried.split(":")[0])
        try:
            second = identify_request(
                inp, kwargs.pop("request", request), progress=progress,
                validation=validation, linear=nested.linear, second_candidate=True,
                searched_out=(refused, said),
                spent_s={**(spent_s or {}), "first_candidate": time.perf_counter() - t0},
                **kwargs)
        except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            # the first answer stands: the second candidate is optional
            session.warnings.append(f"{tried}; it was tried and failed ({exc})")
            session.timings_s["second_candidate"] = time.perf_counter() - t_second
        else:
            if second.nested is not None and second.nested.supported:
                return second
            session.timings_s["second_candidate"] = time.perf_counter() - t_second
            session.warnings.append(
                f"{tried}; it was tried and not kept (" + (
                    second.nested.statement if second.nested is not None
                    else "no nested test") + ")")
    session.timings_s["total"] = time.perf_counter() - t0
    for stage, seconds in (spent_s or {}).items():
        session.timings_s[stage] = seconds
        session.timings_s["total"] += seconds
    # built once, with everything it holds (docs/architecture.md, "The result")
    return Identification(session, model, fit.method, auto=fit.auto,
                          decomposition=fit.decomposition, output_error=output_error,
                          coefficient_spectra=spectra, nested=nested)


def _second_candidate(session: IdentSession, request: IdentRequest,
                      summaries: Sequence[dict], left_out: Sequence[dict]
                      ) -> tuple[dict[str, Any], str] | None:
    """A second candidate model when the first answer is the linear fit because the elements
    whose parameters the search found leave every coefficient undetermined: the keyword
    arguments of :func:`identify_request` that try it and what it is, in words; None
    otherwise. The second answer is kept only if it passes the nested test against the same
    linear fit, which is always run for it (two candidates tried: neither is taken on its
    verdicts alone; docs/ident.md, "A second candidate").

    - **The slip's next minimum** (one slip searched): the criterion can have two minima of
      nearly one value, the joint's slip and one where the element barely slips and its
      column nearly copies the measured motion (:func:`ident.refine.slip_search._other_minima`;
      the Bouc-Wen beam at 3 N, another realisation: 498 um taken, the spring `not
      identifiable`; at 32 um it is 13.7e3 N/m `identified`, the law's 14e3;
      bench/RESULTS_beam.md, defect 6).
    - **An element refused beside them, searched on its own** (``session.refused_beside``):
      in a joint search one element can take up what the other explains (the independent
      Iwan joint at 20 N, a Jenkins element and a stop both left to the data: the slip
      refused at the top of its interval, the stop kept at a clearance, its contact
      stiffnesses `not identifiable`; the Jenkins element alone is kept there).
    """
    search = session.parameter_search
    if search is None:
        return None
    searched = {e.unknown.name for e in search.estimates}
    verdicts = [c.get("verdict") for c in summaries
                if any(c.get("name") in nl.coefficient_names
                       for nl in session.config.nonlinearities if nl.name in searched)]
    if not verdicts or any(v != "not identifiable" for v in verdicts):
        return None
    if search.alternatives and len(search.estimates) == 1:
        estimate, nxt = search.estimates[0], search.alternatives[0]
        tried = (f"{estimate.unknown.name} slip: the information criterion's lowest minimum, "
                 f"{estimate.value:.4g} m (criterion {search.objective:.3g}), left the "
                 "element's coefficients undetermined and the answer the linear fit; its next "
                 f"minimum is {nxt['value']:.4g} m (slipping {nxt['slipping_percent']:.2g} % of "
                 f"the period, criterion {nxt['objective']:.3g}, "
                 f"{nxt['objective_without_element']:.3g} without the element)")
        return {"search": search.taking_alternative(
            tried + "; it was tried and passed the nested test against the same linear fit "
            "(docs/ident.md, \"A second candidate\")"), "left_out": left_out}, tried
    if session.refused_beside:
        alone = session.refused_beside[0]
        dropped = [nl for nl in session.config.nonlinearities if nl.name in searched]
        keep = [nl for nl in request.config.nonlinearities
                if nl.name == alone or (nl.name not in searched and not nl.unknown)]
        names = plain.names([nl.name for nl in dropped], quote=True)
        tried = (f"{names} left no coefficient determined and the answer the linear fit; "
                 f"{alone!r}, refused beside {names} by the parameter search, is searched on "
                 "its own instead")
        gone = [{"name": nl.name, "kind": nl.kind, "channels": dict(nl.channels),
                 "parameters": [], "reason": f"nonlinearity {nl.name!r}: no coefficient "
                 f"determined by the data; {alone!r} was searched on its own instead "
                 "(docs/ident.md, \"A second candidate\")"} for nl in dropped]
        return {"request": replace(request, config=replace(
                    request.config, nonlinearities=tuple(keep))),
                "left_out": [*left_out, *gone], "alone": alone}, tried
    return None


def _refit_answer(session: IdentSession, refit: StateSpaceModel
                  ) -> tuple[StateSpaceModel, CoefficientSpectra | None, list[dict]]:
    """The kept answer's model with its output matrices refit on its own motion, and its
    coefficients read from it (:func:`ident.linear_comparison.refit_on_its_record`, which
    keeps a refit only when some coefficient of it is determined)."""
    spectra = session_coefficient_spectra(session, refit)
    return refit, spectra, coefficient_summaries(spectra, session)


def _with_mode_evidence(nested: NestedTest | None, model: StateSpaceModel,
                        session: IdentSession, summaries: Sequence[dict]
                        ) -> NestedTest | None:
    """``nested`` (a kept nonlinear answer's :class:`ident.robust.nested.NestedTest`) with the
    passivity test of its modes (:func:`ident.robust.mode_support.mode_evidence`); unchanged
    when the answer is the linear fit's.

    Parameters
    ----------
    nested : NestedTest or None
    model : StateSpaceModel
        The answer's model.
    session : IdentSession
        Its configuration (driving points, elements) and data (output quantity).
    summaries : sequence of dict
        The answer's coefficients with their verdicts
        (:func:`ident.coefficient_summaries.coefficient_summaries`, computed once: the
        determined coefficients' signs).
    """
    if nested is None or not nested.supported:
        return nested
    frequencies = [float(k["nonlinear_hz"]) for k in nested.modes.get("kept") or []] + [
        float(f) for f in nested.modes.get("added") or []]
    if not frequencies:
        return nested
    values = {str(c["name"]): float(c["value"]) for c in summaries
              if c.get("verdict") != "not identifiable" and c.get("value") is not None
              and np.isscalar(c.get("value"))}
    rows = mode_evidence(model, sorted(frequencies),
                         driving_points=session.config.driving_points,
                         basis=session.config.nonlinearities,
                         output_quantity=session.data.output_quantity,
                         coefficient_values=values,
                         resolution_hz=(session.input.sample_rate_hz
                                        / session.data.samples_per_period),
                         data=session.data, detection_sigma=AutoOptions().detection_sigma)
    return nested.require_mode_evidence(rows)


def _before_the_reduction(session: IdentSession, fit: Fit, nested: NestedTest,
                          validation: IdentInput | Sequence[IdentInput] | None, *,
                          progress: Any = None
                          ) -> tuple[Fit, CoefficientSpectra | None, NestedTest] | None:
    """The model the reduction came from, as the answer, when the data support its nonlinear
    terms against the same linear fit and not the reduced model's (nested test and
    simulation check); None otherwise.

    The reduction only removes poles judged spurious; when it leaves a model that explains
    the record worse than the linear fit, it removed what the nonlinear terms needed
    (aircraft-like GVT, Jenkins element at 40 N, another multisine realisation: reduced
    from order 30 to 18, residual 1.69x the linear fit's; the order-30 model 6.9x below it,
    and 12-13 dB better than the linear fit on a record at 69 N; bench/RESULTS.md).
    """
    auto = fit.auto
    if auto is None or auto.final != "reduced" or auto.reduced is None:
        return None
    full_auto = replace(auto, final="full")
    full = Fit(auto.full_model, fit.method, full_auto, fit.decomposition)
    spectra = session_coefficient_spectra(session, full.model)
    test = compare_with_linear(
        session, full.model, answer_modes(full),
        [c["verdict"] for c in coefficient_summaries(spectra, session)], order=None,
        sweep=(), reduce_at=None, max_order=None, block_rows=None, validation=validation,
        linear=nested.linear, progress=progress,
        refit=lambda start: refit_on_its_record(session, start))
    if test is None or not test.supported:
        if test is not None:   # said, not only done: the answer stays the linear fit
            session.evidence.setdefault("nonlinear_vs_linear", {})["before_reduction"] = {
                "order": full.model.order, "statement": test.statement}
        return None
    why = (f"the reduced model at order {auto.reduced.order} did not pass the nested test "
           "against the linear fit, the model it came from did")
    return (full._replace(auto=replace(full_auto, final_reason=why,
                                       reduced_statement=nested.statement)), spectra, test)


def _undetermined_elements(basis: Sequence[Nonlinearity], summaries: Sequence[dict]
                           ) -> list[dict]:
    """The elements of ``basis`` to leave out: those none of whose coefficients the data
    determine (every verdict ``not identifiable`` in ``summaries``,
    :func:`ident.coefficient_summaries.coefficient_summaries`) while another element's are
    determined, as
    ``{name, kind, channels, parameters, reason}`` (the keys of
    ``nonlinear_vs_linear.refused``); empty otherwise.

    Why: a term whose coefficient the data cannot tell still moves the others and the
    model's simulation (aircraft-like GVT, Jenkins element and stop at 40 N, another
    realisation: the stop's contact stiffnesses -9.5e4 and -1.4e4 N/m, both `not
    identifiable`, and the model then had no steady state on the next level's record).
    Left out, the model is the one the data support, as a basis parameter the data cannot
    tell leaves its element out (docs/ident.md, "When the data cannot tell").
    """
    if len(basis) < 2:
        return []
    rows = {c["name"]: c for c in summaries}
    verdicts = {nl.name: [rows[n].get("verdict") for n in nl.coefficient_names if n in rows]
                for nl in basis}
    none = [nl for nl in basis
            if verdicts[nl.name] and all(v == "not identifiable" for v in verdicts[nl.name])]
    if not none or len(none) == len(basis):
        return []
    return [{"name": nl.name, "kind": nl.kind, "channels": dict(nl.channels),
             "parameters": [],
             "reason": f"nonlinearity {nl.name!r}: no coefficient determined by the data ("
                       + "; ".join(f"{n}: {rows[n].get('verdict_reason')}"
                                   for n in nl.coefficient_names if n in rows) + ")"}
            for nl in none]


def _searched_out(session: IdentSession, left_out: Sequence[dict],
                  before: tuple[Sequence[dict], Sequence[str]]
                  ) -> tuple[list[dict], list[str]]:
    """The elements this pass's parameter search left out (``refused`` entries that are not
    coefficient refusals) and its warning, with those of the passes ``before``: the pass run
    again has no search of its own, and lost them (the GVT at 40 N with a Jenkins element, a
    stop and a cubic spring: the stop, never touched, was left out by the search, the
    cubic spring for its coefficient, and only the cubic spring was reported)."""
    evidence = session.evidence.get("nonlinear_vs_linear") or {}
    searched = [r for r in evidence.get("refused", []) if r not in left_out
                and r not in before[0]]
    said = [evidence["statement"]] if searched and evidence.get("statement") else []
    return [*before[0], *searched], [*before[1], *said]


def _report_left_out(session: IdentSession, left_out: Sequence[dict]) -> None:
    """Say, in the warnings and in ``nonlinear_vs_linear.refused``, which elements an
    earlier pass left out and why."""
    names = ", ".join(repr(e["name"]) for e in left_out)
    kept = ", ".join(repr(nl.name) for nl in session.config.nonlinearities)
    said = (f"{names} left out: none of its coefficients is determined by the data "
            f"(identified again with {kept}; nonlinear_vs_linear.refused says why)")
    session.warnings.append(said)
    evidence = session.evidence.setdefault("nonlinear_vs_linear", {})
    evidence["refused"] = [*evidence.get("refused", []), *left_out]
    # the nested test's statement replaces it; without the test (compare_linear: false)
    # it is the one line the summary and the report print (a KeyError traceback before)
    evidence.setdefault("statement", said)

