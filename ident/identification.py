"""The answer of one identification, :class:`Identification`: frozen, built once by the
entry point (:func:`ident.pipeline.identify_request`) with everything it holds, its derived
records (modes, coefficients, spline curves, FRFs) and its JSON (:meth:`Identification.to_json`,
the documented result layout: docs/ident.md "Result file").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from fnsi_lab.ident.coefficient_summaries import (coefficient_summaries,
                                                  session_coefficient_spectra,
                                                  session_conditioning)
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.core.basis import ESTIMABLE, Nonlinearity
from fnsi_lab.ident.core.coefficients import CoefficientSpectra
from fnsi_lab.ident.core.fnsi import StateSpaceModel, SubspaceDecomposition
from fnsi_lab.ident.core.model_json import processing_json, state_space_json
from fnsi_lab.ident.core.periodic import FrequencyData, data_report
from fnsi_lab.ident.core.result import Coefficient, Mode
from fnsi_lab.ident.core.units import add_coefficient_units, result_units
from fnsi_lab.ident.fit import Fit, answer_modes
from fnsi_lab.ident.refine.output_error import OutputErrorFit
from fnsi_lab.ident.robust.auto_result import AutoResult
from fnsi_lab.ident.robust.nested import NestedTest
from fnsi_lab.ident.robust.pole_fate import result_fates
from fnsi_lab.ident.robust.verdict import not_supported
from fnsi_lab.ident.session import IdentSession

__all__ = ["Identification"]


@dataclass(frozen=True, eq=False)
class Identification:
    """The answer of one identification, with its evidence; frozen, built once by
    :func:`ident.pipeline.identify_request` with everything it holds (docs/api.md, "The
    result").

    Attributes
    ----------
    session : IdentSession
        Configuration, selected input and frequency data.
    model : StateSpaceModel
        The answer: the model at the requested order, or the robust pipeline's final model
        (reduced to the physical modes unless that made the coefficients less consistent).
    method : {'order', 'auto'}
        Fixed order or robust automatic pipeline.
    auto : AutoResult or None
        Everything the robust pipeline decided (``method == 'auto'``).
    decomposition : SubspaceDecomposition or None
        The QR/SVD of a fixed-order identification.
    output_error : OutputErrorFit or None
        The output-error refinement that produced :attr:`model` from FNSI's
        (:mod:`ident.refine.output_error`); None when it did not run.
    coefficient_spectra : CoefficientSpectra or None
        ``c_a(w)`` of :attr:`model` on every processed line.
    nested : ident.robust.nested.NestedTest or None
        The answer against the linear fit of the same data (its ``linear`` attribute holds
        that fit's :class:`Identification`); when the nonlinear terms are not supported,
        :attr:`modes` and the underlying linear FRF are the linear fit's.
    """

    session: IdentSession
    model: StateSpaceModel
    method: str
    auto: AutoResult | None = None
    decomposition: SubspaceDecomposition | None = None
    output_error: OutputErrorFit | None = None
    coefficient_spectra: CoefficientSpectra | None = None
    nested: NestedTest | None = None
    #: derived records computed on first use (modes, coefficients, curves): never patched
    _cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def coefficient_spectra_of(self, model: StateSpaceModel) -> CoefficientSpectra | None:
        """``c_a(w)`` of another model of the same data (e.g. ``auto.full_model``)."""
        return session_coefficient_spectra(self.session, model)

    @property
    def data(self) -> FrequencyData:
        """The frequency data the model was identified from."""
        return self.session.data

    @property
    def config(self) -> IdentConfig:
        """The configuration actually used."""
        return self.session.config

    @property
    def order(self) -> int:
        """Order of the answer model: the linear fit's when the nonlinear terms are not
        supported (its modes are the answer's; the nonlinear fit's order stays in
        ``nested.order_nonlinear``)."""
        if self.linear_answer and self.nested is not None and self.nested.linear is not None:
            return int(self.nested.linear.order)
        return int(self.model.order)

    @property
    def coefficients(self) -> list[Coefficient]:
        """Per coefficient a :class:`~fnsi_lab.ident.core.result.Coefficient`: ``name``,
        ``value`` (the declared answer), ``mean_real``, ``std_real``, ``ls_value``,
        ``error_percent``, ``verdict``, ``unit`` ... (docs/ident.md), read as attributes or
        as keys (``c["value"]``)."""
        if "coefficients" not in self._cache:
            out = coefficient_summaries(self.coefficient_spectra, self.session)
            if self.nested is not None and not self.nested.supported:
                out = [not_supported(c, self.nested.statement) for c in out]
            units = self.units.get("coefficients") or {}
            curves = self._curves_by_coefficient(out)
            self._cache["coefficients"] = [
                Coefficient.from_summary(c, unit=units.get(c["name"]),
                                         curve=curves.get(c["name"])) for c in out]
        return list(self._cache["coefficients"])

    def _curves_by_coefficient(self, summaries: list[dict]) -> dict[str, dict]:
        """``kind: spline``: each element's force curve (as a dict) under its first
        coefficient (displacement) or its first velocity coefficient."""
        basis = self.config.nonlinearities
        curves = self._spline_curves(summaries)
        firsts = {nl.name: nl.coefficient_names[0] for nl in basis}
        vel = {nl.name: next((n for n in nl.coefficient_names if ":v" in n), None)
               for nl in basis}
        out: dict[str, dict] = {}
        for c in curves:
            key = firsts[c.element] if c.argument == "displacement" else vel[c.element]
            if key is not None:
                out[key] = c.to_dict()
        return out

    @property
    def linear_comparison_statement(self) -> str | None:
        """One line: the answer against the linear fit of the same data (the JSON's
        ``nonlinear_vs_linear.statement``: the nested test, a refused parameter search, an
        empty localisation), None without one."""
        if self.nested is not None:
            return self.nested.statement
        statement = (self.session.evidence.get("nonlinear_vs_linear") or {}).get("statement")
        return None if statement is None else str(statement)

    @property
    def linear_answer(self) -> bool:
        """The nonlinear terms are not supported: the modes are the linear fit's."""
        return self.nested is not None and not self.nested.supported

    @property
    def modes(self) -> list[Mode]:
        """Physical modes of the answer, sorted by frequency, as
        :class:`~fnsi_lab.ident.core.result.Mode`: ``frequency_hz``, ``damping_ratio``,
        ``stable``, ``shape`` (complex, one entry per output); the linear fit's when the
        nonlinear terms are not supported (:attr:`nested`)."""
        if self.nested is not None and self.linear_answer and self.nested.linear is not None:
            return self.nested.linear.modes
        if "modes" not in self._cache:
            modes = answer_modes(
                Fit(self.model, self.method, self.auto, self.decomposition), self.output_error)
            gone = self.nested.left_out_hz if self.nested is not None else []
            # an added mode without physical evidence is not the answer's (docs/robust.md)
            self._cache["modes"] = [m for m in modes if not any(
                abs(m.frequency_hz - g) <= 1e-6 * max(g, 1e-12) for g in gone)]
        return list(self._cache["modes"])

    @property
    def units(self) -> dict:
        """Units of the answer from the channel table (:func:`ident.core.units.result_units`):
        ``force``, ``output``, ``length``, ``frf``, ``channels``, ``coefficients``
        {name: unit}, ``assumed`` (no unit table: SI)."""
        s, data = self.session, self.data
        return result_units(s.input.channel_units, data.input_names, data.output_names,
                            data.output_quantity, s.config.nonlinearities)

    @property
    def spline_curves(self) -> list:
        """Force curves of the ``kind: spline`` elements with their bands and suggested
        parametric forms (:func:`ident.core.spline.spline_curves`; empty without spline)."""
        return self._spline_curves([{"name": c.name, "value": c.value, "verdict": c.verdict}
                                    for c in self.coefficients])

    def _spline_curves(self, summaries: list[dict]) -> list:
        """:attr:`spline_curves` at the coefficients' ``value``, each curve's suggestion
        withheld where their ``verdict`` says the data do not determine it (computed once)."""
        basis = self.config.nonlinearities
        if self.coefficient_spectra is None or not any(nl.kind == "spline" for nl in basis):
            return []
        if "spline_curves" not in self._cache:
            from fnsi_lab.ident.core.spline import determined_suggestion, spline_curves
            from fnsi_lab.ident.robust.verdict import NOT_IDENTIFIABLE
            values = {c["name"]: c["value"] for c in summaries}
            curves = spline_curves(basis, self.coefficient_spectra, values, self.data.motion)
            verdicts = {nl.name: [c.get("verdict") for c in summaries
                                  if c["name"] in nl.coefficient_names] for nl in basis}
            length_unit = str(self.units.get("length") or "") if curves else ""
            for c in curves:
                determined = any(v != NOT_IDENTIFIABLE for v in verdicts[c.element])
                c.suggestion = determined_suggestion(
                    c, determined, self._located_jenkins(c.element), length_unit=length_unit)
            self._cache["spline_curves"] = curves
        return list(self._cache["spline_curves"])

    def _located_jenkins(self, element: str) -> dict | None:
        """The localisation's located candidate when a Jenkins element located it on this
        element's channels (``nonlinearities: auto`` with ``locate``'s form ``jenkins``)."""
        loc = self.session.evidence.get("localisation") or {}
        best = (loc.get("candidates") or [None])[0]
        nl = next((n for n in self.config.nonlinearities if n.name == element), None)
        if (loc.get("form") != "jenkins" or not best or best.get("verdict") != "located"
                or nl is None or dict(best.get("channels") or {}) != dict(nl.channels)):
            return None
        return dict(best)

    def suggested_config(self) -> tuple[dict, str] | None:
        """The config with each spline element replaced by its suggested parametric form,
        as a mapping and as YAML text (None without spline elements)."""
        curves = self.spline_curves
        if not curves:
            return None
        from fnsi_lab.ident.core.spline import suggested_config
        raw = None
        if self.config.file and not self.config.file.startswith("<"):
            from fnsi_lab.validate import load_yaml
            try:
                raw, _ = load_yaml(self.config.file)
            except Exception:   # the file moved since: rebuilt from the parsed config
                raw = None
        return suggested_config(raw or _config_mapping(self.config),
                                self.config.nonlinearities, curves)

    def frf(self) -> dict:
        """Measured, model and underlying linear FRFs at the excited lines.

        Returns
        -------
        dict
            ``frequency_hz`` (F,), ``outputs``, ``inputs`` and complex arrays of shape
            ``(F, n_outputs, n_inputs)``: ``underlying_linear`` (the linear part of the
            model), ``model`` (the model's steady-state output over the force, nonlinear
            terms included) and ``measured`` (output over force); the last two only with one
            input, where the ratio is defined.
        """
        data = self.data
        exc = np.asarray(data.excited, bool)
        f = data.frequencies_hz[exc]
        linear = self.nested.linear if self.nested is not None and self.linear_answer else None
        out: dict[str, Any] = {"frequency_hz": f, "outputs": list(data.output_names),
                               "inputs": list(data.input_names),
                               "underlying_linear": (linear.model if linear is not None
                                                     else self.model).underlying_linear_frf(f)}
        if data.n_inputs == 1:
            u = data.E_physical[exc, 0][:, None, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                out["measured"] = data.Y[exc][:, :, None] / u
                out["model"] = self.model.steady_state_output(data)[exc][:, :, None] / u
        return out

    def to_json(self) -> dict:
        """The JSON-able result (what ``fnsi-lab ident --json`` writes).

        Top-level ``order``, ``modes``, ``poles`` and ``coefficients`` are the answer; the
        rest is the evidence (docs/robust.md, docs/ident.md "Result file").
        """
        from fnsi_lab.outputs import json_safe

        s, data, model = self.session, self.data, self.model
        out: dict[str, Any] = {
            "method": self.method, "input": str(s.input.path), "config": s.config.file,
            "outputs": list(data.output_names), "inputs": list(data.input_names),
            "band_hz": list(data.band_hz), "n_lines": data.n_lines,
            "n_excited_lines": int(np.sum(data.excited)), "n_periods": data.n_periods,
            "n_realizations": data.n_realizations, "output_quantity": data.output_quantity,
            "time_base": data.time_base, "weighted": s.weighted, "d_zero": s.d_zero,
            "steady_state_error": data.steady_state_error,
        }
        if self.auto is not None:
            out.update(self.auto.to_dict())
        else:
            out.update(self._fixed_order_dict())
        out["order"] = self.order
        out["modes"] = [m.to_json() for m in self.modes]
        # kind: spline: the curve on the element's first coefficient (Coefficient.curve)
        out["coefficients"] = [c.to_dict() for c in self.coefficients]
        cond = session_conditioning(s) if s.config.nonlinearities else None
        if cond is not None:
            out["regressors"] = cond.to_dict()
        curves = self.spline_curves
        if curves:
            suggested = self.suggested_config() or ({}, "")
            out["suggestions"] = [{"element": c.element, "argument": c.argument,
                                   **c.suggestion} for c in curves]
            out["suggested_config"] = {"config": suggested[0], "yaml": suggested[1]}
        out["nonlinearities"] = [_nonlinearity_json(nl, s.parameter_search, s.input.truth,
                                                    self.output_error)
                                 for nl in s.config.nonlinearities]
        if self.output_error is not None:   # with the decision (session.evidence) below
            out["output_error"] = self.output_error.to_dict()
        if self.nested is not None:   # with the linear fit itself (fnsi-lab validate can use it)
            linear = self.nested.linear
            out["nonlinear_vs_linear"] = dict(
                self.nested.to_dict(), linear_state_space=(
                    state_space_json(linear.model) if linear is not None else None))
        if s.parameter_search is not None:
            out["parameter_search"] = {k: v for k, v in s.parameter_search.to_dict().items()
                                       if k != "estimates"}
        out["coefficient_spectra"] = _spectra_json(self.coefficient_spectra)
        # the model itself, for fnsi-lab validate (ident/core/model_json.py, docs/validate.md)
        out["state_space"] = state_space_json(model)
        out["processing"] = processing_json(
            s.config, s.config.transient_periods if s.config.transient_periods is not None
            else s.input.transient_periods, data.samples_per_period)
        frf = self.frf()
        out["frf"] = {k: ({"re": v.real, "im": v.imag} if isinstance(v, np.ndarray)
                          and np.iscomplexobj(v) else v) for k, v in frf.items()}
        out.update(data_report(data))  # noise (source, level per output), excitation, offsets
        for key, value in s.evidence.items():  # time_base_choice, the refinement's decision
            out[key] = ({**value, **out[key]} if isinstance(value, dict)
                        and isinstance(out.get(key), dict) else value)
        out["warnings"] = list(s.warnings)
        # the robust pipeline's stages, and the whole identification's (its total is the
        # order sweep's alone: 0.27 s where the GVT's linear fit took 5.9 s)
        out["timings_s"] = {**out.get("timings_s", {}), **s.timings_s}
        units = self.units
        out["units"] = units
        doc = add_coefficient_units(json_safe(out), units)
        for row, fate in zip(doc.get("mdi") or [], result_fates(doc)):
            row["fate"] = fate  # one vocabulary for a pole's fate (ident.robust.pole_fate)
        return doc

    def _fixed_order_dict(self) -> dict:
        data, model, dec = self.data, self.model, self.decomposition
        assert dec is not None, "a fixed-order identification holds its decomposition"
        y_hat = model.steady_state_output(data)
        rel = float(np.sum(np.abs(data.Y - y_hat) ** 2) / np.sum(np.abs(data.Y) ** 2))
        p = model.poles.modes()
        return {
            "block_rows": dec.block_rows, "stable": model.stable,
            "n_nyquist_poles": int(model.poles.nyquist.sum()),
            "n_real_poles": int(model.poles.real.sum()),
            "relative_model_error": rel,
            "singular_values": dec.singular_values[:max(2 * model.order, 10)],
            "poles": [{"frequency_hz": f, "damping_ratio": z, "stable": bool(st)}
                      for f, z, st in zip(p["frequency_hz"], p["damping_ratio"], p["stable"])],
        }


def _config_mapping(cfg: IdentConfig) -> dict:
    """The main keys of a parsed config as YAML data (a config given as a mapping or whose
    file is gone): band, quantities, channels, periods and orders; nonlinearities are
    added by :func:`ident.core.spline.suggested_config`."""
    out: dict[str, Any] = {"band_hz": [float(v) for v in cfg.band_hz]}
    for key in ("samples_per_period", "transient_periods", "output_quantity", "order",
                "max_order"):
        value = getattr(cfg, key)
        if value is not None:
            out[key] = value
    if cfg.outputs:
        out["outputs"] = list(cfg.outputs)
    if cfg.inputs:
        out["inputs"] = [{"name": i.name, **({"driving_point": i.driving_point}
                                             if i.driving_point else {})} for i in cfg.inputs]
    return out


def _nonlinearity_json(nl: Nonlinearity, search: Any = None, truth: Mapping | None = None,
                       refined: Any = None) -> dict:
    """The basis element as used: kind, location and its parameters (gaps in the data's units).

    Parameters estimated from the data (``search``) carry their standard deviation (null
    for given values and for a choice among candidate exponents; the output-error
    refinement's, ``refined``, where it refined them), the search's objective profile
    under ``objective`` and, for simulated recordings whose truth holds the element's
    clearances, ``clearance_error_percent`` (the truth is only compared, never used).
    """
    est = {e.unknown.parameter: e for e in search.for_element(nl.name)} if search else {}

    def std(par: str) -> float | None:
        if par not in est:
            return None
        better = refined.parameter_std(nl.name, par) if refined is not None else None
        return est[par].std if better is None else better

    out: dict[str, Any] = {"name": nl.name, "kind": nl.kind, "channels": dict(nl.channels),
                           "coefficients": list(nl.coefficient_names)}
    pars: tuple[str, ...] = ()
    if nl.kind == "trilinear":
        pars = ("g_neg", "g_pos")
        out.update(clearances=list(nl.clearances), clearance_std=[std(p) for p in pars],
                   offset=nl.offset, offset_std=std("offset"))
    elif nl.kind == "bilinear":
        pars = ("clearance",)
        out.update(clearances=[nl.clearance], clearance_std=[std("clearance")], side=nl.side,
                   offset=nl.offset)
    elif nl.kind == "polynomial":
        out.update(exponent=nl.exponent, exponent_std=std("exponent"), signed=nl.signed,
                   argument=nl.argument, offset=nl.offset)
    elif nl.kind == "coulomb":
        out.update(velocity_scale=nl.velocity_scale, offset=nl.offset)
    elif nl.kind == "jenkins":
        out.update(slip=nl.slip, slip_std=std("slip"), offset=nl.offset)
    elif nl.kind == "spline":   # the placed knots: fnsi-lab validate rebuilds the columns
        out.update(knots=list(nl.knots), velocity_knots=list(nl.velocity_knots),
                   offset=nl.offset)
    else:
        out.update(offset=nl.offset)
    out["estimated"] = [p for p in ESTIMABLE.get(nl.kind, ()) if p in est]
    if est:
        out["objective"] = {p: {"values": e.profile_values, "relative_model_error":
                                e.profile_objective, "std": e.std, "margin": e.margin,
                                "interval": e.unknown.interval, "candidates": e.unknown.candidates,
                                "motion_noise_std": e.motion_noise_std,
                                "noise_corrected": e.noise_corrected, "roughness": e.roughness,
                                "quantity": e.objective_name}
                            for p, e in est.items()}
    given = {t.get("name"): t for t in (truth or {}).get("nonlinearities") or []
             if isinstance(t, dict)}.get(nl.name)
    if (given and pars and any(p in est for p in pars)
            and len(given.get("clearances") or ()) == len(pars)):
        out["clearance_error_percent"] = [
            100.0 * (nl.parameter(p) / float(g) - 1.0) if p in est and float(g) else None
            for p, g in zip(pars, given["clearances"])]
    return out


def _spectra_json(spectra: CoefficientSpectra | None) -> dict | None:
    if spectra is None:
        return None
    return {"frequency_hz": spectra.frequencies_hz, "excited": spectra.excited,
            "names": list(spectra.names),
            "values": {n: {"re": spectra.values[:, i].real, "im": spectra.values[:, i].imag}
                       for i, n in enumerate(spectra.names)},
            # known values (simulations), for the report and viewers
            "exact": {n: t for n, t in zip(spectra.names, spectra.truth or ()) if t is not None}}
