"""The answer against the linear fit of the same data (:func:`compare_with_linear`): the
linear fit (same orders, weighting, ``D`` choice, basis removed) and the nested test
(:mod:`ident.robust.nested`), judged on other periods than the basis columns were read on
when the record has them.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.progress import Progress
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.core.io import IdentInput
from fnsi_lab.ident.core.periodic import FrequencyData, prepare_frequency_data, with_basis
from fnsi_lab.ident.core.result import Mode
from fnsi_lab.ident.errors import IdentError, IdentWarning
from fnsi_lab.ident.fit import fit_session
from fnsi_lab.ident.identification import Identification
from fnsi_lab.ident.robust.nested import NestedTest
from fnsi_lab.ident.session import IdentSession

__all__ = ["compare_with_linear", "split_periods", "simulated_against_linear",
           "validation_input", "worse_outputs", "refit_on_its_record", "NEGLIGIBLE_SHARE"]


def compare_with_linear(session: IdentSession, model: StateSpaceModel, modes: Sequence[Mode],
                        verdicts: Sequence[str], *, order: int | None, sweep: Sequence[int],
                        reduce_at: int | None, max_order: int | None,
                        block_rows: int | None,
                        validation: IdentInput | Sequence[IdentInput] | None = None,
                        linear: Identification | None = None,
                        progress: Any = None,
                        refit: Callable[[StateSpaceModel], StateSpaceModel] | None = None
                        ) -> NestedTest | None:
    """The linear fit of the same data (same orders, weighting, ``D`` choice, basis removed)
    and the nested test of the answer (``model``, its physical ``modes`` and coefficient
    ``verdicts``) against it (:mod:`ident.robust.nested`); None when the linear fit fails (its
    reason goes to the warnings). When the F-test supports the nonlinear terms, both models
    are simulated on the record, or on ``validation`` when given
    (:func:`simulated_against_linear`). ``linear``: that linear fit, already made (a second
    model tested against it). ``progress``: say on stderr which record is being simulated
    (a hysteretic model's balance can take minutes). ``refit``: with ``validation`` records,
    when the F-test supports the nonlinear terms, ``refit(model)``
    (:func:`refit_on_its_record`) is the answer if it predicts those records better than
    ``model`` (:func:`_refit_if_it_predicts_better`); the F-test reads FNSI's own
    regression. The test's ``answer_model`` holds the refit model when it is the answer."""
    from fnsi_lab.ident.robust.nested import nested_test

    if linear is None:
        cfg = replace(session.config, nonlinearities=())
        linear_session = replace(session, config=cfg, data=with_basis(session.data, ()),
                                 timings_s={}, warnings=[], evidence={}, cache={},
                                 parameter_search=None)
        try:
            linear_fit = fit_session(linear_session, order=order, sweep=sweep,
                                     reduce_at=reduce_at, max_order=max_order,
                                     block_rows=None if block_rows is None else block_rows)
        except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            session.warnings.append(f"no linear fit to compare the nonlinear terms with ({exc})")
            return None
        linear = Identification(linear_session, *linear_fit)
    halves = split_periods(session)
    if halves is not None:   # the basis read on other periods than the outputs it explains
        data_nl, data_lin, how = (*halves, "basis columns from the odd periods, outputs and "
                                  "forces from the even ones")
    else:
        data_nl, data_lin, how = session.data, linear.data, "every period"
    test = nested_test(model, data_nl, linear.model, data_lin,
                       d_zero=session.d_zero,
                       modes_nl=[m.frequency_hz for m in modes],
                       modes_lin=[m.frequency_hz for m in linear.modes],
                       verdicts=verdicts, linear=linear, evaluation=how)
    if test.supported:   # and does it predict its own record better? (docs/ident.md)
        check = simulated_against_linear(session, model, linear.model, validation=validation,
                                         progress=progress)
        answer = model
        if refit is not None and validation is not None:
            answer, check = _refit_if_it_predicts_better(session, model, linear.model, check,
                                                         refit, validation, progress)
        elif refit is not None:
            session.evidence["output_refit"] = {
                "applied": False,
                "reason": "not tried: no validation record (--validation) to show that a "
                          "refit on the model's own motion predicts other records better"}
        test = test.require_simulation(check)
        if answer is not model:
            test = replace(test, answer_model=answer)
    return test


def _refit_if_it_predicts_better(session: IdentSession, model: StateSpaceModel,
                                 linear_model: StateSpaceModel, check: dict,
                                 refit: Callable[[StateSpaceModel], StateSpaceModel],
                                 validation: IdentInput | Sequence[IdentInput],
                                 progress: Any) -> tuple[StateSpaceModel, dict]:
    """The answer's model and its simulation check: ``refit(model)`` when it passes the
    check and predicts the validation records better than ``model`` (their outputs' error
    energies over the outputs' energies, summed), else ``model`` and ``check``.

    Only records the model was not fitted to can say so: the refit lowers the error on the
    identified record by construction and can hide a poor model from the check there (the
    aircraft-like GVT's reduced Jenkins model at 84 N, rejected by that check, passed it
    once refit and predicted the 98 N record 1.2-2.2 dB worse than the linear fit;
    docs/ident.md)."""
    candidate = refit(model)
    evidence = session.evidence.setdefault("output_refit", {})
    if candidate is model:
        return model, check
    refit_check = simulated_against_linear(session, candidate, linear_model,
                                           validation=validation, progress=progress)
    mine, theirs = _validation_error(refit_check), _validation_error(check)
    evidence.update(validation_error_fnsi=theirs, validation_error_refit=mine)
    if _fails(refit_check) or not mine < theirs:
        evidence.update(applied=False, reason=(
            "not kept: the refit model predicts the validation records "
            + ("worse than the linear fit" if _fails(refit_check)
               else f"no better than FNSI's ({10 * np.log10(mine / theirs):+.1f} dB in "
                    "summed error energy)")))
        return model, check
    evidence["reason"] = (f"{evidence.get('reason', '')}; on the validation records "
                          f"{10 * np.log10(mine / theirs):+.1f} dB against FNSI's model "
                          "(summed error energy)").lstrip("; ")
    return candidate, refit_check


def _validation_error(check: Mapping[str, Any]) -> float:
    """The summed relative error energy of a simulation check over its records' outputs."""
    rows = [o for r in (check.get("records") or [check]) for o in r.get("outputs") or []]
    return float(sum(10.0 ** (o["error_db"] / 10.0) for o in rows
                     if o.get("error_db") is not None)) or float("inf")


def _fails(check: Mapping[str, Any]) -> bool:
    """The simulation check found no steady state or an output predicted worse."""
    return not check.get("converged", True) or bool(check.get("worse"))


def simulated_against_linear(session: IdentSession, model: StateSpaceModel,
                             linear_model: StateSpaceModel,
                             validation: IdentInput | Sequence[IdentInput] | None = None,
                             progress: Any = None) -> dict:
    """The nonlinear model and the linear fit simulated on the record (or records) the
    check reads: each record identified together (several records at once: each on its
    own, not pooled) and the ``validation`` records; with neither, the record itself
    (:func:`_simulated_on_one`).

    A model that predicts one record better and another worse is no answer for both: the
    check fails on the first record where an output is predicted worse or no steady state
    is found (an independent joint identified on 10 + 20 + 35 N passed pooled and was
    1-4 dB worse than the linear fit on its own 10 and 20 N records; checked on the level
    above alone, a 35 N friction model was 2-10 dB worse on the levels below:
    bench/RESULTS_independent.md).

    Returns
    -------
    dict
        That record's check (:func:`_simulated_on_one`; the first that fails, else the
        first), with ``records``: every record's ``{record, own, converged, reason, worse,
        worse_negligible, outputs}`` when there are several.
    """
    others = ([] if validation is None else [validation] if isinstance(validation, IdentInput)
              else list(validation))
    parts = _parts(session.input) if len(session.input.parts) >= 2 else []
    others = [v for v in others
              if not (parts and v.path and _is_identified(session.input, str(v.path)))]
    records: list[tuple[IdentInput | None, IdentInput | None]] = (
        [(part, None) for part in parts] + [(None, v) for v in others] or [(None, None)])
    bar = Progress(len(records), "simulation check", enabled=bool(progress))
    checks = []

    def name(k: int) -> str:
        part, other = records[k]
        shown = other if other is not None else part if part is not None else session.input
        return Path(str(shown.path or "the record")).name

    bar.update(0, note=f"{name(0)}: the nonlinear model's steady state ...")
    for k, (part, other) in enumerate(records):
        checks.append(_simulated_on_one(session, model, linear_model, part=part,
                                        validation=other))
        bar.update(1, note=f"{name(k)} done" + (f", {name(k + 1)} ..." if k + 1 < len(records)
                                                 else ""))
    if not others and not parts:
        return checks[0]
    # records identified together are each checked, and the validation records as well
    failed = [c for c in checks if not c["converged"] or c["worse"]]
    deciding = failed[0] if failed else checks[0]
    keys = ("record", "own", "converged", "reason", "worse", "worse_negligible", "outputs")
    return {**deciding, "records": [{k: c.get(k) for k in keys} for c in checks]}


def _parts(stacked: IdentInput) -> list[IdentInput]:
    """The records that :func:`ident.core.io.stack_records` put together, each again an
    input of its own (its realisations)."""
    out, start = [], 0
    for path, count in stacked.parts:
        out.append(replace(stacked, u=stacked.u[start:start + count],
                           y=stacked.y[start:start + count], path=path, parts=()))
        start += count
    return out


def _is_identified(identified: IdentInput, path: str) -> bool:
    """Whether the file ``path`` is one of the records identified (``identified.path``, or
    each of the records stacked into it); arrays given without a file never are."""
    names = [p for p, _ in identified.parts] or [str(identified.path)]
    try:
        return Path(path).is_file() and any(
            Path(p).is_file() and Path(p).resolve() == Path(path).resolve() for p in names)
    except OSError:
        return False


def _simulated_on_one(session: IdentSession, model: StateSpaceModel,
                      linear_model: StateSpaceModel, validation: IdentInput | None = None,
                      part: IdentInput | None = None) -> dict:
    """The nonlinear model and the linear fit simulated on one record: the session's own (or
    ``part``, one of the records identified together, or ``validation``, another record),
    as ``fnsi-lab validate`` simulates another record:
    harmonic balance over every line, the nonlinear forces reading the model's own motion
    (:mod:`ident.refine.validation`).

    On its own record the linear fit is the best linear approximation at that very level,
    hard to beat; a record at another level asks what a lab wants to know, whether the
    nonlinear model carries to levels it was not fitted at (aircraft-like GVT, Jenkins
    element at 55 N: worse than the linear fit on its own record, 1.2-2.6 dB better on the
    69 N record; bench/RESULTS.md).

    Returns
    -------
    dict
        ``method``, ``record`` (the other record's path; None for the record itself),
        ``converged``, ``reason`` (when not), ``outputs`` (per output ``name``,
        ``output_rms``, ``error_rms``, ``error_db``, ``linear_fit_error_rms``,
        ``linear_fit_error_db``: :func:`ident.refine.validation.output_errors`) and
        ``worse``: the outputs whose simulation error exceeds the linear fit's.
    """
    from fnsi_lab.ident.refine.validation import balance_outputs, output_errors

    cfg, inp, data = session.config, session.input, session.data
    name = None
    if part is not None:   # one of the records identified together: its own record
        inp, name = part, str(part.path)
    elif validation is not None:
        inp = validation_input(validation, data.output_names, data.input_names,
                               session.input.sample_rate_hz, data.output_quantity,
                               units=session.input.channel_units,
                               transient_periods=cfg.transient_periods)
        name = str(validation.path or "the validation record")
    own = part is not None or name is None or _is_identified(session.input, name)
    try:
        # on another record a stop may never close: zero force, still a prediction
        record = _prediction_record(session, inp,
                                    allow_zero_basis=validation is not None or part is not None)
        # validate's own balance (continuation included: without it the GVT's 84 N friction
        # + stop model found no steady state, with it it predicts 4-6 dB better)
        sim = balance_outputs(model, cfg.nonlinearities, record, data.band_hz)
        fit = balance_outputs(linear_model, (), record, data.band_hz).linear
    except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return {"method": "harmonic balance", "record": name,
                "own": own, "converged": False,
                "reason": str(exc), "outputs": [], "worse": []}
    rows = [{k: r[k] for k in ("name", "output_rms", "error_rms", "error_db",
                               "linear_fit_error_rms", "linear_fit_error_db")}
            for r in output_errors(sim, list(data.output_names), fit)]
    converged = bool(sim.info.get("converged", True))
    units = {(session.input.channel_units or {}).get(n) for n in data.output_names}
    worse, negligible = (worse_outputs(rows, common_unit=len(units) <= 1) if converged
                         else ([], []))
    return {"method": sim.method, "record": name, "own": own,
            "converged": converged,
            "several_records": len(session.input.parts) >= 2,
            "reason": None if converged else sim.info.get("reason"),
            "iterations": sim.info.get("iterations"), "outputs": rows,
            "worse": worse if converged else [],
            "worse_negligible": negligible if converged else []}


def _prediction_record(session: IdentSession, inp: IdentInput, *,
                       allow_zero_basis: bool) -> FrequencyData:
    """``inp`` prepared as ``fnsi-lab validate`` prepares a record for the session's model
    (:func:`ident.refine.validation.prediction_data`: its time base, every line the motion
    needs)."""
    from fnsi_lab.ident.core.model_json import processing_json
    from fnsi_lab.ident.refine.validation import prediction_data

    cfg, data = session.config, session.data
    transient = (cfg.transient_periods if cfg.transient_periods is not None
                 else inp.transient_periods)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentWarning)   # the answer has said them
        return prediction_data(
            inp, cfg.nonlinearities, data.band_hz, data.output_quantity,
            processing_json(cfg, transient, data.samples_per_period),
            transient_periods=transient, time_base=data.time_base,   # the model's
            bilinear_period_s=data.bilinear_period_s, allow_zero_basis=allow_zero_basis)


def refit_on_its_record(session: IdentSession, model: StateSpaceModel) -> StateSpaceModel:
    """The nonlinear ``model`` with ``C`` and ``D`` refit on its own simulated motion on the
    session's record (:func:`ident.refine.own_motion.refit_on_own_motion`); the decision
    and its numbers go to ``session.evidence['output_refit']``. ``model`` itself when not
    applied: several records identified together (one refit would have to serve each), no
    steady state, no gain, no coefficient of the refit determined, or a numerical failure
    (said in the evidence)."""
    from fnsi_lab.ident.refine.own_motion import refit_on_own_motion

    if len(session.input.parts) >= 2:
        session.evidence["output_refit"] = {
            "applied": False, "reason": "not applied: several records identified together"}
        return model
    t0 = time.perf_counter()
    try:
        record = _prediction_record(session, session.input, allow_zero_basis=False)
        refit = refit_on_own_motion(model, session.config.nonlinearities, record,
                                    session.data.band_hz, d_zero=session.d_zero)
    except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        session.evidence["output_refit"] = {"applied": False, "reason": f"not applied: {exc}"}
        return model
    session.timings_s["output_refit"] = time.perf_counter() - t0
    session.evidence["output_refit"] = refit.to_dict()
    if refit.applied and not _some_coefficient_determined(session, refit.model):
        # the nested test kept the answer for a determined coefficient
        session.evidence["output_refit"].update(
            applied=False, reason="not kept: no coefficient of the refit model is determined")
        return model
    return refit.model


def _some_coefficient_determined(session: IdentSession, model: StateSpaceModel) -> bool:
    """Some coefficient of ``model`` is not judged ``not identifiable``."""
    from fnsi_lab.ident.coefficient_summaries import (coefficient_summaries,
                                                      session_coefficient_spectra)

    summaries = coefficient_summaries(session_coefficient_spectra(session, model), session)
    return any(c.get("verdict") != "not identifiable" for c in summaries)


#: An output predicted worse than by the linear fit vetoes the nonlinear model unless its
#: extra error energy is below this share of the linear fit's error energy summed over the
#: outputs (same unit): such an output cannot change which model predicts the record better.
#: The 39-channel SmallSat's in-plane channels, 70 dB below the axial ones, were 0.6-1.1 dB
#: worse where the axial ones were 33 dB better; the aircraft-like GVT's payload, the share
#: that rejects its 84 N Jenkins model, is 17 %.
NEGLIGIBLE_SHARE = 0.01


def worse_outputs(rows: Sequence[Mapping], *, common_unit: bool = True
                  ) -> tuple[list[str], list[str]]:
    """The outputs the nonlinear model predicts worse than the linear fit, and among those
    the ones too small to count (:data:`NEGLIGIBLE_SHARE`; only when the outputs share a
    unit, else every worse output counts).

    Parameters
    ----------
    rows : sequence of mapping
        Per output ``name``, ``error_rms``, ``linear_fit_error_rms``.
    common_unit : bool
        The outputs' errors can be added (one unit).

    Returns
    -------
    (list of str, list of str)
        ``worse`` (they veto) and ``negligible`` (worse, below the share).
    """
    rows = [r for r in rows if r.get("error_rms") is not None
            and r.get("linear_fit_error_rms") is not None]
    total = sum(float(r["linear_fit_error_rms"]) ** 2 for r in rows)
    worse, negligible = [], []
    for r in rows:
        extra = float(r["error_rms"]) ** 2 - float(r["linear_fit_error_rms"]) ** 2
        if extra <= 0:
            continue
        if common_unit and total > 0 and extra < NEGLIGIBLE_SHARE * total:
            negligible.append(str(r["name"]))
        else:
            worse.append(str(r["name"]))
    return worse, negligible


def validation_input(record: IdentInput, output_names: Sequence[str] | None,
                     input_names: Sequence[str] | None, sample_rate_hz: float,
                     output_quantity: str | None = None, *,
                     units: Mapping[str, str] | None = None,
                     transient_periods: int | None = None) -> IdentInput:
    """The validation record's channels in the identified record's order (None: all of
    them); a record without them, at another rate, measuring another quantity, in other
    declared units, or with no period left after the transient ones is refused with one
    line naming it."""
    from fnsi_lab.ident.core.io import select_channels
    from fnsi_lab.ident.errors import IdentDataError

    name = str(record.path or "the validation record")
    try:
        out = select_channels(record, outputs=list(output_names or []) or None,
                              inputs=list(input_names or []) or None)
    except IdentError as exc:
        raise IdentDataError(f"{exc} (the validation record needs the identified outputs "
                             f"{plain.names(output_names or [])} and forces "
                             f"{plain.names(input_names or [])})") from None
    if abs(out.sample_rate_hz - sample_rate_hz) > 1e-9 * sample_rate_hz:
        raise IdentDataError(f"{name}: sampled at {out.sample_rate_hz:g} Hz but the identified "
                             f"record at {sample_rate_hz:g} Hz (fix: validate on a record of "
                             "the same rate)")
    if output_quantity and out.output_quantity and out.output_quantity != output_quantity:
        raise IdentDataError(f"{name}: its outputs are {out.output_quantity}, the identified "
                             f"record's {output_quantity} (fix: a record of the same sensors)")
    for ch, unit in (units or {}).items():
        other = (out.channel_units or {}).get(ch)
        if other and unit and other != unit:
            raise IdentDataError(f"{name}: channel {ch} in {other}, the identified record's in "
                                 f"{unit} (fix: a record in the same units)")
    skip = transient_periods if transient_periods is not None else out.transient_periods
    periods = int(np.asarray(out.u).shape[1])
    if periods - int(skip or 0) < 1:
        raise IdentDataError(f"{name}: {periods} period(s) of {out.samples_per_period} samples "
                             f"and {int(skip or 0)} transient: none left to predict (fix: give the file "
                             "its period N, or a record with more periods)")
    return out


def split_periods(session: IdentSession) -> tuple[FrequencyData, FrequencyData] | None:
    """The data to judge the two models on without the motion's noise in the basis: the
    basis columns from the odd periods used, the outputs and forces from the even ones
    (``(nonlinear data, linear data)`` on the lines all three share), or None with fewer
    than 2 periods or a processing that fails.

    A basis column computed from the measured motion carries that motion's noise, which is
    correlated with the noise of the outputs it is fitted to: on the same periods it explains
    part of the output noise and makes any basis look significant (a stop with 2 um gaps on
    a 3-DOF chain, 1 % noise: 8 of 8 seeds; the linear chain with a cubic basis: 1 of 8).
    Velocity and acceleration outputs are integrated on the lines the answer integrated
    (:func:`_integrated_as_the_answer`).
    """
    data, cfg, inp = session.data, session.config, session.input
    used = [u - 1 for u in (data.periods or {}).get("used") or []]
    if len(used) < 2 or not cfg.nonlinearities:
        return None

    def prepare(periods: list[int], basis) -> FrequencyData:
        return prepare_frequency_data(
            u=np.asarray(inp.u)[:, periods], y=np.asarray(inp.y)[:, periods],
            sample_rate_hz=inp.sample_rate_hz, samples_per_period=inp.samples_per_period,
            basis=basis, band_hz=cfg.band_hz, transient_periods=0, steady_periods="all",
            output_quantity=data.output_quantity, output_names=inp.output_channels,
            input_names=inp.input_channels, excited_lines=inp.excited_lines,
            highpass_hz=cfg.highpass_hz, steady_state_tolerance=np.inf,
            time_base=data.time_base, bilinear_period_s=data.bilinear_period_s,
            basis_oversample=cfg.basis_oversample,
            integration_min_snr=cfg.integration_min_snr or None)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IdentWarning)
            basis_data = prepare(used[0::2], cfg.nonlinearities)
            outputs = prepare(used[1::2], ())
            if data.output_quantity != "displacement" and basis_data.motion is not None:
                basis_data = _integrated_as_the_answer(basis_data, inp, used, cfg,
                                                       data.output_quantity)
    except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError):
        return None
    common = np.intersect1d(np.intersect1d(basis_data.lines, outputs.lines), data.lines)
    if common.size == 0:
        return None
    keep_a, keep_b = np.isin(basis_data.lines, common), np.isin(outputs.lines, common)
    basis_data, outputs = basis_data.subset(keep_a), outputs.subset(keep_b)
    if not np.array_equal(basis_data.lines, outputs.lines):
        return None
    m = data.n_inputs
    mixed = replace(basis_data, Y=outputs.Y,
                    E=np.concatenate([outputs.E[:, :m], basis_data.E[:, m:]], axis=1),
                    noise_var=outputs.noise_var, noise_cov=outputs.noise_cov,
                    noise_source=outputs.noise_source)
    return mixed, outputs


def _integrated_as_the_answer(basis_data: FrequencyData, inp, used: list[int], cfg,
                              quantity: str) -> FrequencyData:
    """The odd periods' motion integrated on the lines the answer's motion was: the noise
    gate of accelerations (:func:`ident.core.motion.noise_gain`) read on every period used,
    not on the odd ones alone. On three of five periods a slow baseline drift can look
    periodic, pass the gate and, integrated twice, swamp the motion: the aircraft-like GVT
    at 98 N got a relative motion of 1.03 mm RMS instead of 0.14 mm, its stop column 10x
    too large and the nested test's nonlinear residual 270x the linear fit's."""
    from fnsi_lab.ident.core.motion import integrated_motion

    motion = basis_data.motion
    assert motion is not None
    y = np.asarray(inp.y, float)[:, used]                      # (R, P_used, N, p)
    names = list(inp.output_channels)
    columns = [names.index(c) for c in motion.channels]
    q, qd = integrated_motion(y, y[:, 0::2].mean(axis=1), columns, quantity,
                              inp.sample_rate_hz, float(cfg.highpass_hz or 0.0),
                              cfg.integration_min_snr or None, cfg.basis_oversample, False,
                              motion.velocity is not None)
    return with_basis(replace(basis_data, motion=replace(motion, displacement=q, velocity=qd)),
                      cfg.nonlinearities)
