"""Validate an identified model on another record: THE entry point of ``fnsi-lab validate``.

:func:`validate_model` reads an ``ident --json`` result (the model, its basis and how it
processed its record: ``state_space``, ``nonlinearities``, ``processing``; see
:mod:`fnsi_lab.ident.core.model_json`) and a record in any format ``ident`` reads (``.mcap``,
``.npz``, ``.mat``; TDMS/UFF/CSV after ``fnsi-lab import``), simulates the nonlinear model
and its underlying linear model with the record's measured forces
(:mod:`fnsi_lab.ident.refine.validation`), and returns per output the RMS of the measured output
and of both simulation errors. docs/validate.md explains the method and the figures.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentDataError, IdentError

__all__ = ["validate_model", "ValidationResult", "figure_validation"]

_UNITS = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}


@dataclass
class ValidationResult:
    """The outcome of :func:`validate_model`.

    Attributes
    ----------
    outputs : list of dict
        Per output ``name``, ``unit``, ``output_rms``, ``error_rms``, ``error_db``,
        ``linear_error_rms``, ``linear_error_db`` (RMS over the compared lines, dB =
        ``20 log10(error / output)``: negative below the output; ``error_*`` None when the
        nonlinear model could not be simulated), and ``linear_fit_error_rms``,
        ``linear_fit_error_db`` when the result holds the linear fit of the same data
        (``nonlinear_vs_linear.linear_state_space``).
    method : {'harmonic balance', 'time integration'}
    simulation : ident.refine.validation.SimulatedOutputs
        The spectra (for figures).
    info : dict
        ``result``, ``record``, ``band_hz``, ``n_periods``, ``transient_periods``,
        ``nonlinearities``, ``order``, ``balance`` (converged, iterations, residual...),
        ``warnings``.
    """

    outputs: list
    method: str
    simulation: Any
    info: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        """The nonlinear model was simulated (always True without a basis)."""
        return bool(self.simulation.info.get("converged", True))

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict (``fnsi-lab validate --json``; docs/validate.md)."""
        from fnsi_lab.outputs import json_safe

        sim = self.simulation
        return json_safe({**{k: v for k, v in self.info.items()}, "method": self.method,
                          "converged": self.converged, "outputs": self.outputs,
                          "simulation": dict(sim.info)})


def load_result(result: Any) -> tuple[dict, str]:
    """The result as a dict and a name for messages.

    Raises
    ------
    IdentDataError
        A missing, unreadable or binary file, invalid JSON, or another command's JSON
        (one line naming the file and the command that wrote it).
    """
    return _load_result(result)


def _load_result(result: Any) -> tuple[dict, str]:
    """The result as a dict and a name for messages."""
    from fnsi_lab.result_kind import not_an_ident_result

    if isinstance(result, Mapping):
        refusal = not_an_ident_result(result, "result")
        if refusal:
            raise IdentDataError(refusal)
        return dict(result), "result"
    if hasattr(result, "to_json") and not isinstance(result, (str, os.PathLike)):
        return result.to_json(), "result"
    path = Path(result)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise IdentDataError(f"{path}: file not found (fix: give the JSON that "
                             "fnsi-lab ident --json wrote)") from None
    except UnicodeDecodeError:
        # a recording or an array file given as RESULT (the arguments swapped, say)
        raise IdentDataError(f"{path}: not a JSON result (a binary file, not text; fix: give "
                             "the JSON that fnsi-lab ident --json wrote first, then the "
                             "record: fnsi-lab validate RESULT.json RECORD)") from None
    except OSError as exc:
        raise IdentDataError(f"{path}: cannot read: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise IdentDataError(f"{path}: not a JSON result ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise IdentDataError(f"{path}: not an fnsi-lab result (expected a JSON object)")
    refusal = not_an_ident_result(data, str(path))
    if refusal:
        raise IdentDataError(refusal)
    return data, str(path)


def _rejection(nested: Mapping[str, Any]) -> str:
    """Why ident kept the linear fit: the result's own ``nonlinear_vs_linear.statement``
    (an F-test, the simulation check, the parameter search or the localisation: docs/ident.md),
    else the decision's field."""
    statement = str(nested.get("statement") or "").strip()
    return (f"nonlinear_vs_linear: {statement}" if statement
            else "nonlinear_vs_linear.decision: linear")


def _declares_period(path: str) -> bool:
    """Whether an array file gives its period (``N``); recordings always do."""
    ext = Path(path).suffix.lower()
    if ext == ".npz":
        with np.load(path, allow_pickle=False) as z:
            return "N" in z.files
    if ext == ".mat":
        import scipy.io

        return any(v[0] == "N" for v in scipy.io.whosmat(path))
    return True


def _units(path: str | None, names: list[str], quantity: str) -> list[str]:
    """The record's unit of each output (recordings: the channel table; else SI)."""
    default = _UNITS.get(quantity, "")
    if path and Path(path).suffix.lower() == ".mcap":
        try:
            from fnsi_lab.api import open_recording

            with open_recording(path) as rec:
                table = {c.name: c.unit for c in rec.channels}
            return [table.get(n) or default for n in names]
        except Exception:  # noqa: BLE001 - units are cosmetic; the data were read already
            pass
    return [default] * len(names)


def validate_model(result: Any, record: Any, *, method: str = "auto",
                   samples_per_period: int | None = None,
                   transient_periods: int | None = None,
                   oversample: int = 8, simulate: str = "answer",
                   result_name: str | None = None) -> ValidationResult:
    """Simulate an identified model on a record and measure its output error.

    Parameters
    ----------
    result : path, dict or Identification
        An ``ident --json`` result (or :func:`fnsi_lab.identify`'s answer).
    record : path or IdentInput
        ``.mcap``, ``.npz`` or ``.mat`` (as ``fnsi-lab ident`` reads them), or arrays.
    method : {'auto', 'balance', 'time'}
        ``auto``: harmonic balance for a periodic record (a recording, a file giving ``N``,
        or several periods/realisations), time integration otherwise.
    samples_per_period : int, optional
        ``N`` of an array file that does not give it.
    transient_periods : int, optional
        Leading periods of the record to drop (default: the record's own count, else the
        result's).
    oversample : int
        Internal steps per sample of the time integration.
    simulate : {'answer', 'nonlinear'}
        ``answer`` (default): the result's answer, i.e. the linear fit when the nested test
        found the nonlinear terms not supported (``nonlinear_vs_linear.decision`` linear);
        ``nonlinear``: the nonlinear model with its basis whatever that decision.
    result_name : str, optional
        The result's name in messages and in ``info['result']`` (default: its path, or
        ``result`` for a dict).

    Returns
    -------
    ValidationResult

    Raises
    ------
    IdentError, IdentDataError
        Unreadable result or record, a result without a model, channels or sample rate
        that do not match, time integration of velocity/acceleration outputs with a basis.
    """
    from fnsi_lab.ident.core.io import IdentInput, select_channels
    from fnsi_lab.ident.core.model_json import basis_from_json, model_from_json
    from fnsi_lab.ident.refine.validation import (balance_outputs, output_errors, prediction_data,
                                                  time_outputs)
    from fnsi_lab.inputs import load_input

    if method not in ("auto", "balance", "time"):
        raise IdentError(f"method {method!r}: use auto, balance or time")
    if transient_periods is not None and int(transient_periods) < 0:
        raise IdentError(f"transient_periods {transient_periods} is negative (fix: the number "
                         "of leading periods to drop, 0 or more)")
    res, res_name = _load_result(result)
    res_name = result_name or res_name
    model = model_from_json(res, res_name)
    basis = basis_from_json(res.get("nonlinearities"), res_name)
    notes: list[str] = []
    nested = res.get("nonlinear_vs_linear") or {}
    fit = (model_from_json({"state_space": nested["linear_state_space"]}, res_name)
           if isinstance(nested.get("linear_state_space"), Mapping) else None)
    if fit is not None and fit.time_base != model.time_base:
        notes.append("the linear fit has another time base than the answer: not validated")
        fit = None
    if simulate not in ("answer", "nonlinear"):
        raise IdentError(f"simulate {simulate!r}: use answer or nonlinear")
    names = [nl.name for nl in basis]
    decided_linear = bool(basis) and nested.get("decision") == "linear"
    linear_answer = False
    if basis and model.b_d.shape[1] == model.n_inputs:   # no basis columns: a linear answer
        notes.append(f"the answer is a linear model (its nonlinear terms {plain.names(names, quote=True)} were not "
                     "kept): the nonlinear model's error is the linear model's")
        linear_answer = True
    elif decided_linear and fit is not None and simulate == "answer":
        # ident kept the linear fit (F-test, simulation check, parameter search...): say why
        notes.append(f"the nonlinear terms {plain.names(names, quote=True)} were not kept ({_rejection(nested)}): the "
                     "answer is the linear fit, whose error every column gives (--model "
                     "nonlinear simulates the nonlinear model anyway)")
        model, linear_answer = fit, True
    elif decided_linear:
        notes.append(f"the nonlinear terms {plain.names(names, quote=True)} were not kept ({_rejection(nested)}); the "
                     "nonlinear model is simulated all the same")
    elif not basis and nested.get("decision") == "linear":
        # every configured element was left out before the fit (a parameter search, the
        # localisation): the answer is a linear model, as the columns and a warning say
        refused = [str(r.get("name")) for r in nested.get("refused") or [] if isinstance(r, Mapping)]
        notes.append(f"the answer is a linear model (the configured nonlinear terms "
                     f"{refused or 'of the result'} were left out: {_rejection(nested)}): the "
                     "nonlinear model's error is the linear model's")
        linear_answer = True
    if linear_answer:
        basis = ()
    if len(model.input_names) != model.n_inputs + sum(len(nl.coefficient_names) for nl in basis):
        raise IdentError(f"{res_name}: the model has {len(model.input_names)} extended inputs "
                         f"but {model.n_inputs} force(s) and the basis "
                         f"({plain.names([nl.name for nl in basis], quote=True)}) need a different number")
    outputs = list(res.get("outputs") or model.output_names)
    inputs = list(res.get("inputs") or [])
    quantity = str(res.get("output_quantity") or "displacement")
    band = tuple(float(b) for b in res.get("band_hz") or ())
    proc = dict(res.get("processing") or {})
    if len(band) != 2:
        raise IdentError(f"{res_name}: no band_hz in the result")
    if isinstance(record, IdentInput):
        inp, rec_name, declared = record, record.path or "record", True
    else:
        rec_name = str(record)
        inp = load_input(rec_name, samples_per_period=samples_per_period)
        declared = samples_per_period is not None or _declares_period(rec_name)
    try:
        inp = select_channels(inp, outputs=outputs, inputs=inputs or None)
    except IdentError as exc:
        text = str(exc)   # it may name the file already: name it once
        where = "" if text.startswith(rec_name) else f"{rec_name}: "
        raise type(exc)(f"{where}{text} (the model was identified on outputs {plain.names(outputs)} "
                        f"and inputs {plain.names(inputs)})") from None
    if abs(inp.sample_rate_hz - model.sample_rate_hz) > 1e-9 * model.sample_rate_hz:
        raise IdentDataError(f"{rec_name}: sampled at {inp.sample_rate_hz:g} Hz but the model at "
                             f"{model.sample_rate_hz:g} Hz (fix: validate on a record of the "
                             "same rate)")
    if inp.output_quantity and inp.output_quantity != quantity:
        raise IdentDataError(f"{rec_name}: the outputs are {inp.output_quantity} but the model's "
                             f"are {quantity}")
    R, P = inp.u.shape[0], inp.u.shape[1]
    periodic = declared or R > 1 or P > 1
    use = ("balance" if periodic else "time") if method == "auto" else method
    transient = (transient_periods if transient_periods is not None
                 else inp.transient_periods if inp.transient_periods is not None
                 else proc.get("transient_periods"))
    if use == "balance":
        from fnsi_lab.ident.errors import IdentWarning

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IdentWarning)
            data = prediction_data(inp, basis, band, quantity, proc,
                                   transient_periods=transient, time_base=model.time_base,
                                   bilinear_period_s=model.bilinear_period_s,
                                   allow_zero_basis=True)
        notes += [str(w.message) for w in caught]
        sim = balance_outputs(model, basis, data, band)
        fit_lines = None if fit is None else balance_outputs(fit, (), data, band).linear
        n_periods = data.n_periods
    else:
        if basis and quantity != "displacement":
            raise IdentError(f"{rec_name}: time integration needs displacement outputs (the "
                             f"basis reads the relative displacement; these are {quantity}); "
                             "validate on a periodic record (harmonic balance) instead")
        u = np.asarray(inp.u).reshape(-1, inp.u.shape[-1])
        y = np.asarray(inp.y).reshape(-1, inp.y.shape[-1])
        sim = time_outputs(model, basis, u, y, list(inp.output_channels), band,
                           oversample=oversample)
        fit_lines = (None if fit is None else
                     time_outputs(fit, (), u, y, list(inp.output_channels), band,
                                  oversample=oversample).linear)
        n_periods = None
    if linear_answer:
        sim.nonlinear = sim.linear.copy()
        sim.info["linear_answer"] = True
    errors = output_errors(sim, list(inp.output_channels), fit_lines)
    for row, unit in zip(errors, _units(None if isinstance(record, IdentInput) else rec_name,
                                        list(inp.output_channels), quantity)):
        row["unit"] = unit
    if not sim.info.get("converged", True):
        notes.append(f"the nonlinear model has no steady state on this record: "
                     f"{sim.info.get('reason')}; it does not carry to this record's force "
                     f"(the linear columns still compare)")
    info = {"result": res_name, "record": rec_name, "band_hz": list(band),
            "output_quantity": quantity, "n_periods": n_periods, "transient_periods": transient,
            "n_realizations": int(R), "order": int(model.order),
            "nonlinearities": [nl.name for nl in basis], "warnings": notes}
    return ValidationResult(outputs=errors, method=sim.method, simulation=sim, info=info)


def figure_validation(v: ValidationResult) -> Any:
    """Measured output spectrum and both simulation errors (dB), one panel per output.

    matplotlib object API (no pyplot state), like :mod:`fnsi_lab.viewer.report`.
    """
    from matplotlib.figure import Figure

    sim = v.simulation
    p = sim.measured.shape[2]
    fig = Figure(figsize=(9.0, 2.6 * p + 0.6), layout="constrained")
    axes = fig.subplots(p, 1, sharex=True, squeeze=False)[:, 0]
    f = sim.frequency_hz

    def db(x):
        return 20 * np.log10(np.maximum(np.sqrt(np.mean(np.abs(x) ** 2, axis=0)), 1e-300))

    for i, ax in enumerate(axes):
        row = v.outputs[i]
        ax.plot(f, db(sim.measured[:, :, i]), color="black", lw=1.0, label="measured")
        ax.plot(f, db(sim.measured[:, :, i] - sim.linear[:, :, i]), color="tab:orange", lw=0.9,
                label=f"linear error ({row['linear_error_db']:+.1f} dB)")
        if sim.nonlinear is not None:
            ax.plot(f, db(sim.measured[:, :, i] - sim.nonlinear[:, :, i]), color="tab:blue",
                    lw=0.9, label=f"nonlinear error ({row['error_db']:+.1f} dB)")
        ax.set_ylabel(f"{row['name']} (dB {row.get('unit', '')})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
    axes[0].set_title(f"validation on {Path(str(v.info.get('record', ''))).name} "
                      f"({v.method})")
    axes[-1].set_xlabel("frequency (Hz)")
    return fig
