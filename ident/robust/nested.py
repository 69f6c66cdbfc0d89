"""Nested models: is the nonlinear model significantly better than the linear one?

The nonlinear model (forces and basis columns as inputs) contains the linear model (the same
structure with every coefficient zero), so the question whether the data support the basis
functions is a test between nested models on the same data (docs/ident.md, "Nonlinear
against linear"):

- the **residual** of each model is the noise-weighted squared misfit of its periodic
  steady-state output on every processed line, ``V = sum_k sum_o |Y_ko - Yhat_ko|^2 w_ko``,
  ``w = 1 / sigma^2`` from the noise variances (smoothed over +-8 lines), or ``1 / mean|Y_o|^2``
  per output without a noise estimate;
- the **parameter count** of a state-space model of order ``n`` with ``m_e`` inputs and ``p``
  outputs is ``n (m_e + p)`` (its modal form: ``n`` poles and ``n (m_e + p)`` residue
  entries less one scale per mode) plus ``m_e p`` when ``D`` is estimated;
- the **F-test** ``F = ((V_lin - V_nl) / (k_nl - k_lin)) / (V_nl / (N_obs - k_nl))`` with
  ``N_obs = 2 F p`` real residuals, against Fisher's distribution with
  ``(k_nl - k_lin, N_obs - k_nl)`` degrees of freedom.

Why the F-test rather than a likelihood ratio against the noise estimate: the likelihood
ratio ``V_lin - V_nl ~ chi^2(k_nl - k_lin)`` holds when the weights are the true inverse
noise variances and the better model explains the data to the noise. Real structures leave a
model error beyond the noise (the real Silverbox: 2.7x its noise), and a record whose periods
drift has a spread that is not noise; the F-test takes the nonlinear model's own residual per
degree of freedom as the error variance, so an unmodelled error larger than the noise does
not make every small improvement significant. When the nonlinear model has no more
parameters than the linear one (a lower order), it is supported only if its residual is
lower, and no p-value is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.core.periodic import FrequencyData, smooth_lines

if TYPE_CHECKING:   # the identification imports this module
    from fnsi_lab.ident.identification import Identification

__all__ = ["SIGNIFICANCE", "MODE_MATCH", "NestedTest", "weighted_residual", "parameter_count",
           "nested_test", "match_modes"]

#: Significance level of the F-test (the probability of calling a linear structure's
#: nonlinear terms supported).
SIGNIFICANCE = 0.01
#: Two modes are the same mode when their natural frequencies differ by less than this
#: fraction (a joint at a high level moved the aircraft-like GVT's torsion 2.5 %).
MODE_MATCH = 0.05


def residual_weights(data: FrequencyData) -> tuple[np.ndarray, str]:
    """``(F, p)`` weights of the nested test's residual (inverse noise variances, smoothed
    over 8 lines; without a noise estimate each output's inverse power) and what they are."""
    if data.noise_var is not None:
        var = smooth_lines(np.asarray(data.noise_var, float), 8)
        floor = 1e-12 * float(np.mean(var)) if np.any(var > 0) else 1.0
        return 1.0 / np.maximum(var, floor), f"noise ({data.noise_source})"
    power = np.mean(np.abs(data.Y) ** 2, axis=0)
    return np.broadcast_to(1.0 / np.where(power > 0, power, 1.0), data.Y.shape), \
        "each output's power (no noise estimate)"


def weighted_residual(model: StateSpaceModel, data: FrequencyData,
                      weights: np.ndarray | None = None) -> float:
    """``sum w |Y - Yhat|^2`` over the processed lines (``data`` must match ``model``'s inputs)."""
    w = residual_weights(data)[0] if weights is None else weights
    r = data.Y - model.steady_state_output(data)
    return float(np.sum(w * np.abs(r) ** 2))


def parameter_count(model: StateSpaceModel, d_zero: bool) -> int:
    """Free parameters of a state-space model: ``n (m_e + p)`` (+ ``m_e p`` with ``D``)."""
    p, m_e = model.d_d.shape
    return int(model.order * (m_e + p) + (0 if d_zero else m_e * p))


def match_modes(linear: Sequence[float], nonlinear: Sequence[float],
                tolerance: float = MODE_MATCH) -> dict:
    """Pair each linear mode with the nearest unused nonlinear one within ``tolerance``.

    Returns
    -------
    dict
        ``kept``: ``[{linear_hz, nonlinear_hz, shift_percent}]``; ``lost``: linear modes
        without a partner (Hz); ``added``: nonlinear modes without one (Hz).
    """
    free = list(range(len(nonlinear)))
    kept, lost = [], []
    for f in sorted(linear):
        if free:
            j = min(free, key=lambda i: abs(nonlinear[i] - f))
            if abs(nonlinear[j] - f) <= tolerance * f:
                free.remove(j)
                kept.append({"linear_hz": float(f), "nonlinear_hz": float(nonlinear[j]),
                             "shift_percent": 100.0 * (nonlinear[j] / f - 1.0)})
                continue
        lost.append(float(f))
    return {"kept": kept, "lost": lost, "added": sorted(float(nonlinear[i]) for i in free)}


@dataclass(frozen=True)
class NestedTest:
    """The comparison of the nonlinear answer with the linear fit on the same data (frozen:
    built once by :func:`nested_test`).

    Attributes
    ----------
    residual_nonlinear, residual_linear : float
        Noise-weighted residuals ``V``.
    parameters_nonlinear, parameters_linear : int
    n_observations : int
        ``2 F p`` real residuals.
    statistic, p_value : float or None
        The F statistic and its upper-tail probability (None when the nonlinear model has no
        more parameters).
    decision : {'nonlinear', 'linear'}
        ``nonlinear`` when its residual is significantly lower (``p_value < significance``)
        and some coefficient is determined (:meth:`require_coefficients`).
    modes : dict
        :func:`match_modes` of the two answers' physical modes.
    order_nonlinear, order_linear : int
    weighting : str
    significance : float
    linear : Identification or None
        The linear fit itself (given by the pipeline).
    evaluation : str
        Which data the residuals were computed on.
    undetermined : bool
        Every coefficient was judged ``not identifiable`` (:meth:`require_coefficients`).
    simulation : dict or None
        Both models simulated on the record, the nonlinear forces reading the model's own
        motion (:meth:`require_simulation`): ``method``, ``converged``, ``reason``,
        ``outputs`` (per output ``name``, ``error_db``, ``linear_fit_error_db``) and
        ``worse`` (the outputs the nonlinear model predicts worse); None when not run.
    simulation_rejected : bool
        The F-test supported the nonlinear terms but that simulation did not: some output
        predicted worse than by the linear fit, or no steady state.
    mode_evidence : tuple of dict
        The passivity test of each physical mode of the nonlinear answer
        (:func:`ident.robust.mode_support.mode_evidence`, :meth:`require_mode_evidence`);
        those that fail it are in ``modes["left_out"]``, not in the answer's modes.
    answer_model : StateSpaceModel or None
        The kept nonlinear answer's model when it is not the one tested: FNSI's with its
        output matrices refit on its own simulated motion
        (:func:`ident.linear_comparison.refit_on_its_record`); None: the tested model.
    """

    residual_nonlinear: float
    residual_linear: float
    parameters_nonlinear: int
    parameters_linear: int
    n_observations: int
    statistic: float | None
    p_value: float | None
    decision: str
    order_nonlinear: int
    order_linear: int
    weighting: str
    significance: float = SIGNIFICANCE
    modes: dict = field(default_factory=dict)
    linear: Identification | None = None
    evaluation: str = "every period"
    undetermined: bool = False
    simulation: dict | None = None
    simulation_rejected: bool = False
    mode_evidence: tuple = ()
    answer_model: StateSpaceModel | None = None

    @property
    def left_out_hz(self) -> list[float]:
        """Natural frequencies (Hz) of the nonlinear model's modes left out of the answer for
        lack of physical evidence (:meth:`require_mode_evidence`)."""
        return [float(r["frequency_hz"]) for r in self.modes.get("left_out") or []]

    def require_mode_evidence(self, evidence: Sequence[dict]) -> NestedTest:
        """The test whose answer lists only the modes with physical evidence: the modes of
        the rows of :func:`ident.robust.mode_support.mode_evidence` that are not
        ``supported`` go to ``modes["left_out"]`` (``frequency_hz``, ``damping_ratio``,
        ``reason``, and ``linear_fit``: whether the linear fit had a mode within
        :data:`MODE_MATCH`), and the others are paired with the linear fit's modes again
        (:func:`match_modes`: ``kept``, ``lost``, ``added``). Returns a new test."""
        rows = [dict(r) for r in evidence]
        out = [r for r in rows if not r.get("supported", True)]
        gone = [float(r["frequency_hz"]) for r in out]
        kept = self.modes.get("kept") or []
        nonlinear = [float(k["nonlinear_hz"]) for k in kept] + [
            float(f) for f in self.modes.get("added") or []]
        linear = [float(k["linear_hz"]) for k in kept] + [
            float(f) for f in self.modes.get("lost") or []]
        paired = {round(float(k["nonlinear_hz"]), 9) for k in kept}
        left = [{"frequency_hz": r["frequency_hz"], "damping_ratio": r.get("damping_ratio"),
                 "linear_fit": round(float(r["frequency_hz"]), 9) in paired,
                 "reason": r.get("reason")} for r in out]
        survivors = [f for f in nonlinear
                     if not any(abs(f - g) <= 1e-9 * max(g, 1e-12) for g in gone)]
        return replace(self, mode_evidence=tuple(rows),
                       modes={**match_modes(linear, survivors), "left_out": left})

    @property
    def supported(self) -> bool:
        """The data support the nonlinear terms."""
        return self.decision == "nonlinear"

    def require_coefficients(self, verdicts: Sequence[str]) -> NestedTest:
        """The test that keeps ``nonlinear`` only if some coefficient is determined by the
        data (a verdict other than ``not identifiable``): a significant residual drop whose
        coefficients mean nothing gives no usable nonlinear model, so the answer stays the
        linear fit's. Returns a new test."""
        undetermined = bool(verdicts) and all(v == "not identifiable" for v in verdicts)
        return replace(self, undetermined=undetermined,
                       decision="linear" if undetermined else self.decision)

    def require_simulation(self, simulation: dict) -> NestedTest:
        """The test that keeps ``nonlinear`` only if the nonlinear model, simulated on its own
        record with the nonlinear forces reading its *own* motion (what ``fnsi-lab
        validate`` does on another record), predicts no output worse than the linear fit
        and has a steady state. The F-test's residual reads the measured motion in the
        basis; a model can explain the record that way and still predict it worse (the
        aircraft-like GVT's Jenkins model at 84 N: the payload 4.8 dB below the output
        where the linear fit is 7.3 dB below). Returns a new test."""
        worse = not simulation.get("converged", True) or bool(simulation.get("worse"))
        rejected = self.supported and worse
        return replace(self, simulation=dict(simulation), simulation_rejected=rejected,
                       decision="linear" if rejected else self.decision)

    @property
    def _simulated_on(self) -> str:
        """Which record the simulation check predicted, in words."""
        sim = self.simulation or {}
        record = sim.get("record")
        if not record:
            return "its own record"
        names = " + ".join(Path(p).name for p in str(record).split(" + "))
        # one of the records identified together, or another record
        return f"its own record {names}" if sim.get("own") else f"the validation record {names}"

    @property
    def statement(self) -> str:
        """One line for the summary and the JSON."""
        ratio = (self.residual_linear / self.residual_nonlinear if self.residual_nonlinear
                 else np.inf)
        what = (f"{ratio:.3g}x lower than the linear fit's" if ratio >= 1
                else f"{1 / ratio:.3g}x the linear fit's")
        test = (f"F-test p = {self.p_value:.2g}" if self.p_value is not None
                else "no more parameters than the linear model")
        if self.supported:
            lost, added = self.modes.get("lost") or [], self.modes.get("added") or []
            extra = ""
            if lost or added:
                extra = ("; it " + " and ".join(
                    part for part in (
                        f"loses the linear fit's {', '.join(f'{f:.4g}' for f in lost)} Hz"
                        if lost else "",
                        f"adds {', '.join(f'{f:.4g}' for f in added)} Hz" if added else "")
                    if part) + ": check them")
            left = self.modes.get("left_out") or []
            if left:
                extra += ("; left out of the answer, the nonlinear model's " + ", ".join(
                    f"{r['frequency_hz']:.4g}" for r in left) + " Hz (isolated modes with a "
                    "negative modal mass at the driving point or at the element: no mode of a "
                    "passive structure; nonlinear_vs_linear.modes.left_out)")
            checked = ""
            if self.simulation and self.simulation.get("record"):
                rows = self.simulation.get("outputs") or []
                more = [Path(str(r["record"])).name for r in
                        (self.simulation.get("records") or [])[1:]]
                checked = (f"; simulated on {self._simulated_on} it predicts every output at "
                           "least as well as the linear fit (" + ", ".join(
                               f"{r['name']} {r['error_db']:+.1f} dB against "
                               f"{r['linear_fit_error_db']:+.1f} dB" for r in rows) + ")"
                           + (f", and on {', '.join(more)} (simulation.records)" if more
                              else ""))
            sim = self.simulation or {}
            records = sim.get("records") or [sim]   # each record's, not the first one's only
            small = [", ".join(r["worse_negligible"]) + (
                f" on {Path(str(r['record'])).name}" if len(records) > 1 and r.get("record")
                else "") for r in records if r.get("worse_negligible")]
            if small:
                checked += (f"; simulated, it predicts {'; '.join(small)} slightly worse than "
                            "the linear fit (each below 1 % of the linear fit's error energy: "
                            "see simulation)")
            return (f"the nonlinear terms are supported: noise-weighted residual {what} "
                    f"({test}){extra}{checked}")
        if self.simulation_rejected:
            sim = self.simulation or {}
            if not sim.get("converged", True):
                why = (f"has no periodic steady state under the record's force "
                       f"({sim.get('reason')})")
            else:
                rows = {r["name"]: r for r in sim.get("outputs") or []}
                why = "predicts " + ", ".join(
                    f"{name} worse than the linear fit ({rows[name]['error_db']:+.1f} dB "
                    f"against {rows[name]['linear_fit_error_db']:+.1f} dB)"
                    for name in sim["worse"])
            sim = self.simulation or {}
            hint = ("" if sim.get("record") or sim.get("several_records") else
                    "; on its own record the linear fit is that level's best linear "
                    "approximation: with other levels, --validation BELOW.mcap --validation "
                    "ABOVE.mcap (the levels around it) or several records at once ask "
                    "whether the model carries (docs/ident.md)")
            return (f"the nonlinear terms lower the noise-weighted residual ({what}, {test}) "
                    f"but the nonlinear model, simulated on {self._simulated_on}, {why}: the "
                    f"modes are the linear fit's (order {self.order_linear}){hint}")
        if self.undetermined and self.p_value is not None and self.p_value < self.significance:
            return (f"the nonlinear terms lower the noise-weighted residual ({what}, {test}) "
                    f"but no coefficient is determined by the data (every verdict: not "
                    f"identifiable): the modes are the linear fit's (order {self.order_linear})")
        return (f"the nonlinear terms are not supported by the data (noise-weighted residual "
                f"{what}, {test}, significance {self.significance:g}): the modes are "
                f"the linear fit's (order {self.order_linear})")

    def to_dict(self) -> dict:
        return {"test": "F-test on the noise-weighted residual",
                "residual_nonlinear": self.residual_nonlinear,
                "residual_linear": self.residual_linear,
                "parameters_nonlinear": self.parameters_nonlinear,
                "parameters_linear": self.parameters_linear,
                "n_observations": self.n_observations, "statistic": self.statistic,
                "p_value": self.p_value, "significance": self.significance,
                "decision": self.decision, "order_nonlinear": self.order_nonlinear,
                "order_linear": self.order_linear, "weighting": self.weighting,
                "evaluation": self.evaluation, "coefficients_undetermined": self.undetermined,
                "modes": self.modes, "statement": self.statement,
                "simulation": self.simulation, "simulation_rejected": self.simulation_rejected,
                "mode_evidence": [dict(r) for r in self.mode_evidence],
                "linear_modes": ([{"frequency_hz": m["frequency_hz"],
                                   "damping_ratio": m["damping_ratio"]}
                                  for m in self.linear.modes] if self.linear is not None else None)}


def nested_test(model_nl: StateSpaceModel, data_nl: FrequencyData,
                model_lin: StateSpaceModel, data_lin: FrequencyData, *, d_zero: bool,
                modes_nl: Sequence[float] = (), modes_lin: Sequence[float] = (),
                significance: float = SIGNIFICANCE, verdicts: Sequence[str] = (),
                linear: Identification | None = None,
                evaluation: str = "every period") -> NestedTest:
    """Test the nonlinear model against the linear one on the same lines.

    Parameters
    ----------
    model_nl, data_nl : the nonlinear answer and its data (forces and basis columns).
    model_lin, data_lin : the linear fit and its data (forces only; the same lines).
    d_zero : bool
        ``D = 0`` in both fits.
    modes_nl, modes_lin : sequence of float
        The physical modes' natural frequencies (Hz) of the two answers.
    significance : float
    verdicts : sequence of str
        The nonlinear answer's coefficient verdicts (:meth:`NestedTest.require_coefficients`:
        all ``not identifiable`` keeps the linear fit's answer).
    linear : Identification, optional
        The linear fit itself, kept in the test.
    evaluation : str
        Which data the residuals are computed on (words, for the JSON).

    Returns
    -------
    NestedTest
    """
    from scipy.special import fdtrc   # F survival function (scipy.stats: +0.35 s of import)

    w, how = residual_weights(data_nl)
    v_nl = weighted_residual(model_nl, data_nl, w)
    v_lin = weighted_residual(model_lin, data_lin, w)
    k_nl, k_lin = parameter_count(model_nl, d_zero), parameter_count(model_lin, d_zero)
    n_obs = 2 * int(data_nl.Y.size)
    stat = p = None
    if k_nl > k_lin and n_obs > k_nl and v_nl > 0:
        stat = float(((v_lin - v_nl) / (k_nl - k_lin)) / (v_nl / (n_obs - k_nl)))
        p = float(fdtrc(k_nl - k_lin, n_obs - k_nl, max(stat, 0.0)))
        supported = p < significance
    else:
        supported = v_nl < v_lin
    undetermined = bool(verdicts) and all(v == "not identifiable" for v in verdicts)
    return NestedTest(residual_nonlinear=v_nl, residual_linear=v_lin, parameters_nonlinear=k_nl,
                      parameters_linear=k_lin, n_observations=n_obs, statistic=stat, p_value=p,
                      decision="nonlinear" if supported and not undetermined else "linear",
                      order_nonlinear=int(model_nl.order), order_linear=int(model_lin.order),
                      weighting=how, significance=significance,
                      modes=match_modes(list(modes_lin), list(modes_nl)), linear=linear,
                      evaluation=evaluation, undetermined=undetermined)
