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
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from itertools import combinations
from typing import Any, Callable, Mapping, NamedTuple, Sequence

import numpy as np

from fnsi_lab.ident.robust.auto_result import AutoResult
from fnsi_lab.ident.core.basis import ESTIMABLE, Nonlinearity
from fnsi_lab.ident.core.coefficients import (CoefficientSpectra, coefficient_spread,
                                         nonlinear_coefficients, spread_function,
                                         summarize_coefficients)
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.errors import IdentError, IdentWarning
from fnsi_lab.ident.core.fnsi import (StateSpaceModel, SubspaceDecomposition, model_at_order,
                                 subspace_decomposition)
from fnsi_lab.ident.core.io import IdentInput
from fnsi_lab.ident.refine.modal import ModalModel
from fnsi_lab.ident.core.model_json import processing_json, state_space_json
from fnsi_lab.ident.robust.nested import NestedTest
from fnsi_lab.ident.refine.output_error import (MAX_MISFIT, OutputErrorFit, omitted_mode_evidence,
                                        refine_output_error, refinement_case)
from fnsi_lab.ident.refine.parameter_search import DEFAULT_SEARCH_ORDER
from fnsi_lab.ident.core.periodic import FrequencyData, data_report, prepare_frequency_data, with_basis
from fnsi_lab.ident.robust.reduction import reduce_model
from fnsi_lab.ident.core.regressors import regressor_conditioning
from fnsi_lab.ident.request import (DEFAULT_ORDERS, IdentRequest, basis_from_truth,
                                    default_config, resolve_request)
from fnsi_lab.ident.core.result import Coefficient, Mode
from fnsi_lab.ident.robust.verdict import coefficient_verdict, not_supported
from fnsi_lab.ident.core.units import add_coefficient_units, result_units
from fnsi_lab.ident.robust.pole_fate import result_fates
from fnsi_lab.ident.session import (IdentSession, apply_recording_truth, prepare_session)

__all__ = ["IdentSession", "Identification", "Mode", "Coefficient", "prepare_session",
           "identify_input",
           "default_config", "basis_from_truth", "apply_recording_truth", "DEFAULT_ORDERS",
           "identify_request"]


def _structural_start(session: IdentSession, ident: "_Fit") -> StateSpaceModel:
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


def _split_candidates(ident: "_Fit") -> list[int]:
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


def _merged_start(session: IdentSession, ident: "_Fit",
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


def _fit_without_split_modes(session: IdentSession, ident: "_Fit",
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


def _refine(session: IdentSession, ident: "_Fit") -> Any:
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
    :class:`ident.refine.output_error.OutputErrorFit` kept, or None.
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
        return refine_output_error(data, cfg.nonlinearities, start, estimated=estimated,
                                   d_zero=session.d_zero, watch=_answer_values(session),
                                   give_up_above=(100 * MAX_MISFIT if cfg.refine == "auto"
                                                  else None))
    try:
        fit = _fit_without_split_modes(session, ident, run) or run(
            _structural_start(session, ident))
    except IdentError as exc:
        decision["reason"] = f"not applied: {exc}"
        session.warnings.append(f"the output-error refinement was not applied ({exc}); "
                                "the answer is FNSI's model")
        return None
    session.timings_s["output_error"] = time.perf_counter() - t0
    if cfg.refine == "auto" and fit.misfit > MAX_MISFIT:
        decision["reason"] = (f"not kept: the refined model leaves {fit.misfit:.3g} noise "
                              f"variances (above {MAX_MISFIT:g}); the answer is FNSI's model")
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
    dp = _driving_points(session)
    if dp is None:
        return None

    def watch(model: StateSpaceModel, basis) -> np.ndarray:
        spectra = nonlinear_coefficients(model, session.data, basis, driving_point=dp)
        values = [s.value for s in summarize_coefficients(spectra)]
        return np.array(values + [nl.parameter(p) for nl in basis
                                  for p in ESTIMABLE.get(nl.kind, ())], float)
    return watch


def _driving_points(session: IdentSession) -> Any:
    """Driving points for the coefficients: the config's, else the only output (None: unknown)."""
    cfg, data = session.config, session.data
    if any(cfg.driving_points.values()):
        return cfg.driving_points
    return data.output_names[0] if data.n_outputs == 1 else None


def _coefficient_spectra(session: IdentSession, model: StateSpaceModel) -> CoefficientSpectra | None:
    """``c_a(w)`` of ``model`` (None without basis functions).

    Raises NotIdentifiableError (one line) when the driving point is unknown."""
    basis = session.config.nonlinearities
    if not basis:
        return None
    return nonlinear_coefficients(model, session.data, basis,
                                  driving_point=_driving_points(session))


def _conditioning(session: IdentSession):
    """The regressors' conditioning of the session's current data (cached per data)."""
    cached = session.cache.get("conditioning")
    if cached is None or cached[0] is not session.data:
        cached = (session.data, regressor_conditioning(session.data))
        session.cache["conditioning"] = cached
    return cached[1]


def _summaries(spectra: CoefficientSpectra | None,
               session: IdentSession | None = None) -> list[dict]:
    """Per coefficient the summary dict with its verdict (:mod:`ident.robust.verdict`)."""
    if spectra is None:
        return []
    summaries = [s.to_dict() for s in summarize_coefficients(spectra)]
    rho = coefficient_spread(spectra)
    cond = _conditioning(session) if session is not None else None
    for a, c in enumerate(summaries):
        vif = None
        if cond is not None and c["name"] in cond.names:
            vif = float(cond.inflation[cond.names.index(c["name"])])
        v = coefficient_verdict(c, float(rho[a]), inflation=vif)
        c.update(v.to_dict())
    return summaries


def answer_modes(fit: _Fit, output_error: OutputErrorFit | None = None) -> list[Mode]:
    """Physical modes of an answer, sorted by frequency: every mode of ``fit.model``, or for
    the robust pipeline those of its physical poles (the MDI table's; after an output-error
    refinement the same modes refined, or dropped)."""
    m = fit.model.poles.modes()
    keep = np.ones(m["frequency_hz"].size, bool)
    if fit.auto is not None:
        physical = [r["frequency_hz"] for r in fit.auto.mdi_table() if r["physical"]]
        if output_error is not None:   # the same modes, refined (or dropped)
            physical = [g for g in (output_error.refined_frequency(f)
                                    for f in physical) if g is not None]
        keep = np.array([any(abs(f - g) <= 1e-6 * max(g, 1e-12) for g in physical)
                         for f in m["frequency_hz"]], bool)
    return [Mode(frequency_hz=float(f), damping_ratio=float(z), stable=bool(s),
                 shape=np.asarray(m["mode_shapes"][:, k]))
            for k, (f, z, s, kp) in enumerate(zip(m["frequency_hz"], m["damping_ratio"],
                                                   m["stable"], keep)) if kp]


@dataclass(frozen=True, eq=False)
class Identification:
    """The answer of one identification, with its evidence; frozen, built once by
    :func:`identify_request` with everything it holds (docs/api.md, "The result").

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
        return _coefficient_spectra(self.session, model)

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
        """Order of the answer model."""
        return int(self.model.order)

    @property
    def coefficients(self) -> list[Coefficient]:
        """Per coefficient a :class:`~fnsi_lab.ident.core.result.Coefficient`: ``name``,
        ``value`` (the declared answer), ``mean_real``, ``std_real``, ``ls_value``,
        ``error_percent``, ``verdict``, ``unit`` ... (docs/ident.md), read as attributes or
        as keys (``c["value"]``)."""
        if "coefficients" not in self._cache:
            out = _summaries(self.coefficient_spectra, self.session)
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
        curves = self._spline_curves({c["name"]: c["value"] for c in summaries})
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
            self._cache["modes"] = answer_modes(
                _Fit(self.model, self.method, self.auto, self.decomposition), self.output_error)
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
        return self._spline_curves({c.name: c.value for c in self.coefficients})

    def _spline_curves(self, values: dict[str, float]) -> list:
        """:attr:`spline_curves` at the coefficient ``values`` (computed once)."""
        basis = self.config.nonlinearities
        if self.coefficient_spectra is None or not any(nl.kind == "spline" for nl in basis):
            return []
        if "spline_curves" not in self._cache:
            from fnsi_lab.ident.core.spline import spline_curves
            self._cache["spline_curves"] = spline_curves(basis, self.coefficient_spectra,
                                                         values, self.data.motion)
        return list(self._cache["spline_curves"])

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
        cond = _conditioning(s) if s.config.nonlinearities else None
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
        out["timings_s"] = {**s.timings_s, **out.get("timings_s", {})}
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
                                "noise_corrected": e.noise_corrected, "roughness": e.roughness}
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


class _Fit(NamedTuple):
    """FNSI's answer before the refinement, the coefficients and the nested test: the first
    fields of an :class:`Identification`."""

    model: StateSpaceModel
    method: str
    auto: AutoResult | None = None
    decomposition: SubspaceDecomposition | None = None


def _fit(session: IdentSession, *, order: int | None, sweep: Sequence[int],
         reduce_at: int | None, max_order: int | None, block_rows: int | None,
         progress: Any = None) -> _Fit:
    """FNSI at the fixed ``order``, or the robust pipeline over ``sweep``, on the session's data
    (no refinement, no coefficients yet)."""
    cfg = session.config
    block_rows = block_rows or cfg.block_rows
    dp = _driving_points(session)
    if order is not None:
        max_order = max(int(order), max_order or cfg.max_order or int(order))
        t1 = time.perf_counter()
        if cfg.time_base == "auto" and session.data.output_quantity == "displacement":
            # band-limited or bilinear line map: the one that fits (ident.core.time_base)
            from fnsi_lab.ident.core.time_base import choose_time_base
            session.data, dec, model, choice = choose_time_base(
                session.data, int(order), max_order=max_order, block_rows=block_rows,
                weighted=session.weighted, d_zero=session.d_zero)
            session.evidence["time_base_choice"] = choice
        else:
            dec = subspace_decomposition(session.data, max_order=max_order,
                                         block_rows=block_rows, weighted=session.weighted)
            model = model_at_order(dec, session.data, int(order), d_zero=session.d_zero)
        session.timings_s["decomposition"] = time.perf_counter() - t1
        session.timings_s["model"] = time.perf_counter() - t1 - session.timings_s["decomposition"]
        return _Fit(model, "order", decomposition=dec)
    else:
        from fnsi_lab.ident.robust.auto import identify_auto

        options = replace(cfg.auto, d_zero=session.d_zero, weighted=session.weighted,
                          block_rows=block_rows or cfg.auto.block_rows)
        basis = cfg.nonlinearities

        def coefficients(model: StateSpaceModel) -> list[dict] | None:
            return _summaries(_coefficient_spectra(session, model), session) or None

        spread = (spread_function(session.data, basis, driving_point=dp)
                  if basis and dp is not None else None)
        t1 = time.perf_counter()
        res = identify_auto(session.data, options, orders=sweep, reduce_at=reduce_at,
                            progress=progress, coefficients=coefficients if basis else None,
                            spread=spread)
        session.timings_s["auto"] = time.perf_counter() - t1
        session.warnings.extend(res.confidence.get("warnings", []))  # e.g. order at sweep end
        return _Fit(res.final_model, "auto", auto=res)


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
                     spent_s: Mapping[str, float] | None = None) -> Identification:
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
            inp, cfg, progress=(lambda note: None) if progress else None)
    # without any order given, the criterion picks the search's (at most search_order)
    session = prepare_session(inp, cfg, search_order=search_order,
                              select_search_order=order is None and cfg.order is None,
                              progress=progress)
    if located is not None:
        session.evidence["localisation"] = located.to_json()
    fit = _fit(session, order=order, sweep=sweep, reduce_at=reduce_at, max_order=max_order,
               block_rows=block_rows, progress=progress)
    output_error = _refine(session, fit)
    model = output_error.model if output_error is not None else fit.model
    t2 = time.perf_counter()
    spectra = _coefficient_spectra(session, model)
    session.timings_s["coefficients"] = time.perf_counter() - t2
    compare = session.config.compare_linear
    nested = None
    if session.config.nonlinearities and compare:
        verdicts = [c.get("verdict") for c in _summaries(spectra, session)]
        if compare == "auto" and verdicts and all(v == "identified" for v in verdicts):
            # every coefficient determined: the test would only confirm it (chain, SmallSat,
            # Silverbox); it costs a second identification (docs/ident.md)
            from fnsi_lab.ident.robust.nested import weighted_residual

            session.evidence["nonlinear_vs_linear"] = {
                "decision": "nonlinear", "test": None,
                "residual_nonlinear": weighted_residual(model, session.data),
                "residual_linear": None, "statistic": None, "p_value": None,
                "statement": "every coefficient is identified: the linear fit was not run "
                             "(compare_linear: true runs it)"}
        else:
            t3 = time.perf_counter()
            answer = _Fit(model, fit.method, fit.auto, fit.decomposition)
            nested = _compare_with_linear(
                session, model, answer_modes(answer, output_error),
                [c["verdict"] for c in _summaries(spectra, session)], order=order,
                sweep=sweep, reduce_at=reduce_at, max_order=max_order, block_rows=block_rows)
            session.timings_s["linear_fit"] = time.perf_counter() - t3
    session.timings_s["total"] = time.perf_counter() - t0
    for stage, seconds in (spent_s or {}).items():
        session.timings_s[stage] = seconds
        session.timings_s["total"] += seconds
    # built once, with everything it holds (docs/architecture.md, "The result")
    return Identification(session, model, fit.method, auto=fit.auto,
                          decomposition=fit.decomposition, output_error=output_error,
                          coefficient_spectra=spectra, nested=nested)


def _compare_with_linear(session: IdentSession, model: StateSpaceModel, modes: Sequence[Mode],
                         verdicts: Sequence[str], *, order: int | None, sweep: Sequence[int],
                         reduce_at: int | None, max_order: int | None,
                         block_rows: int | None) -> NestedTest | None:
    """The linear fit of the same data (same orders, weighting, ``D`` choice, basis removed)
    and the nested test of the answer (``model``, its physical ``modes`` and coefficient
    ``verdicts``) against it (:mod:`ident.robust.nested`); None when the linear fit fails (its
    reason goes to the warnings)."""
    from fnsi_lab.ident.robust.nested import nested_test

    cfg = replace(session.config, nonlinearities=())
    linear_session = replace(session, config=cfg, data=with_basis(session.data, ()),
                             timings_s={}, warnings=[], evidence={}, cache={},
                             parameter_search=None)
    try:
        linear_fit = _fit(linear_session, order=order, sweep=sweep, reduce_at=reduce_at,
                          max_order=max_order,
                          block_rows=None if block_rows is None else block_rows)
    except (IdentError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        session.warnings.append(f"no linear fit to compare the nonlinear terms with ({exc})")
        return None
    linear = Identification(linear_session, *linear_fit)
    halves = _split_periods(session)
    if halves is not None:   # the basis read on other periods than the outputs it explains
        data_nl, data_lin, how = (*halves, "basis columns from the odd periods, outputs and "
                                  "forces from the even ones")
    else:
        data_nl, data_lin, how = session.data, linear.data, "every period"
    return nested_test(model, data_nl, linear.model, data_lin,
                       d_zero=session.d_zero,
                       modes_nl=[m.frequency_hz for m in modes],
                       modes_lin=[m.frequency_hz for m in linear.modes],
                       verdicts=verdicts, linear=linear, evaluation=how)


def _split_periods(session: IdentSession) -> tuple[FrequencyData, FrequencyData] | None:
    """The data to judge the two models on without the motion's noise in the basis: the
    basis columns from the odd periods used, the outputs and forces from the even ones
    (``(nonlinear data, linear data)`` on the lines all three share), or None with fewer
    than 2 periods or a processing that fails.

    A basis column computed from the measured motion carries that motion's noise, which is
    correlated with the noise of the outputs it is fitted to: on the same periods it explains
    part of the output noise and makes any basis look significant (a stop with 2 um gaps on
    a 3-DOF chain, 1 % noise: 8 of 8 seeds; the linear chain with a cubic basis: 1 of 8).
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
