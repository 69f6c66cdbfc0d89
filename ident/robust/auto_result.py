"""The robust pipeline's result (:class:`AutoResult`) and its confidence statement."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fnsi_lab.ident.robust.options import AutoOptions

__all__ = ["AutoResult", "confidence_statement"]


@dataclass(frozen=True)
class AutoResult:
    """Everything the robust pipeline decided, with the evidence (JSON via :meth:`to_json`).

    Attributes
    ----------
    information_criterion : ident.robust.order_selection.InformationCriterion
    selected_order : int
        The order of the model: ``argmin I`` over the stable orders, restricted to the
        orders with consistent coefficients when ``order_selection='consistent'``.
    ic_order : int
        Plain ``argmin I`` over the stable orders (seed Eq. 8).
    coefficient_spread : ndarray, shape (q,)
        ``rho(n)`` per order of the information criterion (NaN where not computed).
    consistent : bool ndarray, shape (q,)
        Orders that passed the coefficient gate (all False if it was not applied).
    order_selection : str
        ``'consistent'`` or ``'ic'``: how ``selected_order`` was chosen.
    final : {'reduced', 'full'}
        Which model is the answer (:attr:`final_model`): the reduced one, unless the
        reduction raised the coefficient spread of the model it came from, or the nonlinear
        terms were not supported against the linear fit in the reduced model but were in
        the one it came from (then the full model at ``mdi_order``; ``final_reason``).
    final_reason : str or None
        Why the answer is the full model although a reduced one exists, when not the spread.
    reduced_statement : str or None
        The nested test's statement on the reduced model, when it was set aside for that.
    final_spread : dict
        ``{'full': rho, 'reduced': rho}`` behind that choice (NaN when not computed).
    answer_block_rows : int or None
        Block rows of ``full_model`` when it was re-estimated at ``mdi_order`` with the rows
        of that order (fewer than the sweep's); None when it is the sweep's model.
    plausible_out_of_band : bool ndarray, shape (n_modes,)
        MDI modes outside the band of interest that are stable, stabilised across orders
        and detectable: reported as physical in the JSON ``poles``.
    detection : ndarray, shape (n_modes,)
        Detection statistic of each MDI mode (:func:`ident.robust.mdi.modal_detection`): its energy
        over the residual's fluctuation in its bandwidth; below ``detection_sigma`` a mode
        is not physical.
    stabilisation : ident.robust.stabilisation.StabilisationDiagram
    mdi_order : int
        Order at which MDI and reduction were applied (``reduce_at`` or ``selected_order``).
    modal_dominancy : ident.robust.mdi.ModalDominancy
        Every mode of the model at ``mdi_order``.
    candidates : bool ndarray
        Modes eligible for the gap search (stable, in band, not at Nyquist).
    physical : bool ndarray
        Final classification per mode.
    threshold : ident.robust.mdi.Threshold
    separation_ratio : float
    confidence : dict
        ``{'level': 'clear'|'moderate'|'ambiguous', 'statement': str, ...}``.
    model : ident.core.fnsi.StateSpaceModel
        The model at ``selected_order``.
    full_model : ident.core.fnsi.StateSpaceModel
        The model at ``mdi_order`` (before reduction).
    reduced : ident.core.fnsi.StateSpaceModel or None
        The reduced model (None if nothing was removed).
    coefficients : dict
        ``{'selected': ..., 'full': ..., 'reduced': ...}`` summaries from the coefficient
        callback (empty without one).
    options : AutoOptions
    groups : tuple of tuple of int
        Mode groups used by the threshold (split modes share one group).
    stab_class_at_mdi_order : tuple of str
        Stabilisation class of each MDI mode at ``mdi_order`` (``'none'`` if out of band).
    timings_s : dict
        Seconds per stage.
    models : dict int -> StateSpaceModel
        Every model of the sweep (not serialised).
    """

    information_criterion: Any
    selected_order: int
    stabilisation: Any
    mdi_order: int
    modal_dominancy: Any
    candidates: np.ndarray
    physical: np.ndarray
    threshold: Any
    separation_ratio: float
    confidence: dict
    model: Any
    full_model: Any
    reduced: Any
    coefficients: dict
    options: AutoOptions
    groups: tuple = ()
    stab_class_at_mdi_order: tuple = ()
    ic_order: int = 0
    coefficient_spread: np.ndarray = field(default_factory=lambda: np.zeros(0))
    consistent: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    order_selection: str = "ic"
    detection: np.ndarray = field(default_factory=lambda: np.zeros(0))
    final: str = "full"
    final_spread: dict = field(default_factory=dict)
    plausible_out_of_band: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    answer_block_rows: int | None = None
    final_reason: str | None = None
    reduced_statement: str | None = None

    @property
    def final_model(self):
        """The answer: ``reduced`` or ``full_model`` as :attr:`final` says."""
        return self.reduced if self.final == "reduced" else self.full_model
    timings_s: dict = field(default_factory=dict)
    models: dict = field(default_factory=dict, repr=False)

    def mdi_table(self) -> list[dict]:
        """``[{frequency_hz, damping_ratio, mdi_h2, mdi_seed, mdi_hinf, mdi_hinf_band, in_band,
        stable, stabilisation, candidate, physical}]`` sorted by frequency."""
        md = self.modal_dominancy
        rows = []
        for k in np.argsort(md.frequency_hz):
            rows.append({
                "frequency_hz": float(md.frequency_hz[k]),
                "damping_ratio": float(md.damping_ratio[k]),
                "mdi_h2": float(md.values["h2"][k]),
                "mdi_seed": float(md.values["seed"][k]),
                "mdi_hinf": float(md.values["hinf"][k]),
                "mdi_hinf_band": float(md.values["hinf_band"][k]),
                "in_band": bool(md.in_band[k]),
                "stable": bool(md.stable[k]),
                "stabilisation": (self.stab_class_at_mdi_order[k]
                                  if self.stab_class_at_mdi_order else None),
                "candidate": bool(self.candidates[k]),
                "detection": (float(self.detection[k]) if self.detection.size
                              and np.isfinite(self.detection[k]) else None),
                "physical": bool(self.physical[k]),
            })
        return rows

    def to_dict(self) -> dict:
        """JSON-able dictionary of the decisions (models as poles, not matrices)."""
        def fin(x):
            x = float(x)
            return x if np.isfinite(x) else None

        def poles_of(model):
            if model is None:
                return None
            m = model.poles.modes()
            return [{"frequency_hz": float(f), "damping_ratio": float(z), "stable": bool(s)}
                    for f, z, s in zip(m["frequency_hz"], m["damping_ratio"], m["stable"])]

        red = None
        if self.reduced is not None:
            red = {"order": int(self.reduced.order), "poles": poles_of(self.reduced),
                   "coefficients": self.coefficients.get("reduced"),
                   "nonlinear_vs_linear": self.reduced_statement}
        final = self.final_model
        md = self.modal_dominancy
        final_poles = poles_of(final)
        for pl in final_poles:  # classification of the same pole at the MDI order
            k = int(np.argmin(np.abs(md.frequency_hz - pl["frequency_hz"]))) if md.frequency_hz.size else -1
            same = k >= 0 and abs(md.frequency_hz[k] - pl["frequency_hz"]) <= 1e-6 * pl["frequency_hz"]
            oob = (bool(self.plausible_out_of_band[k]) if self.plausible_out_of_band.size
                   else False)
            pl["physical"] = bool(same and (self.physical[k] or oob))
        modes = [{"frequency_hz": r["frequency_hz"], "damping_ratio": r["damping_ratio"],
                  "mdi_h2": r["mdi_h2"], "stabilisation": r["stabilisation"]}
                 for r in self.mdi_table() if r["physical"]]
        return {
            "order": int(final.order),
            "final": self.final,
            "final_reason": self.final_reason,
            "modes": modes,
            "poles": final_poles,
            "coefficients": self.coefficients.get(self.final if self.final == "reduced" else "full"),
            "information_criterion": self.information_criterion.to_list(),
            "ic_band": (self.information_criterion.band
                        if isinstance(self.information_criterion.band, str)
                        else list(self.information_criterion.band)),
            "criterion": self.information_criterion.criterion,
            "selected_order": int(self.selected_order),
            "ic_order": int(self.ic_order),
            "order_selection": self.order_selection,
            "coefficient_spread": [
                {"order": int(n), "spread": fin(r), "consistent": bool(c)}
                for n, r, c in zip(self.information_criterion.orders,
                                   self.coefficient_spread, self.consistent)]
            if self.coefficient_spread.size else [],
            "stabilisation": self.stabilisation.to_list(),
            "mdi_order": int(self.mdi_order),
            "mdi_norm": self.options.mdi_norm,
            "mdi_band_hz": list(self.modal_dominancy.band_hz),
            "mdi": self.mdi_table(),
            "threshold": fin(self.threshold.threshold),
            "threshold_method": self.threshold.method,
            "separation_ratio": fin(self.separation_ratio),
            "confidence": self.confidence,
            "selected_model": {"order": int(self.model.order), "poles": poles_of(self.model),
                               "coefficients": self.coefficients.get("selected")},
            "full_model": {"order": int(self.full_model.order),
                           "block_rows": self.answer_block_rows,
                           "coefficients": self.coefficients.get("full")},
            "reduced": red,
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
        }

    def to_json(self, **kw) -> str:
        """:meth:`to_dict` as strict JSON text (NaN as null; :func:`fnsi_lab.outputs.dumps`)."""
        from fnsi_lab.outputs import dumps

        return dumps(self.to_dict(), **kw)


def confidence_statement(separation_ratio: float, n_physical: int, disagreements: dict, *,
                         ambiguous_ratio: float = 2.0, clear_ratio: float = 10.0) -> dict:
    """How sure the physical/spurious split is (docs/method.md §7.4, §8.5).

    Parameters
    ----------
    separation_ratio : float
        Lowest physical MDI / highest spurious candidate MDI.
    n_physical : int
    disagreements : dict
        ``{'kept_not_stabilised': [f_hz...], 'dropped_fully_stable': [f_hz...],
        'excluded_out_of_band': int, 'excluded_unstable': int}``.

    Returns
    -------
    dict
        ``level`` (``'clear'``, ``'moderate'``, ``'ambiguous'``), ``statement`` (one paragraph
        for a person), and the inputs.

    Notes
    -----
    The level comes from the separation ratio (below ``ambiguous_ratio``: ambiguous; at or
    above ``clear_ratio``: clear) and is lowered by one step if the MDI and the
    stabilisation diagram disagree about any in-band mode.
    """
    r = separation_ratio
    if not np.isfinite(r):
        level = "clear" if n_physical > 0 and r == np.inf else "ambiguous"
    elif r < ambiguous_ratio:
        level = "ambiguous"
    elif r < clear_ratio:
        level = "moderate"
    else:
        level = "clear"
    kept_ns = disagreements.get("kept_not_stabilised", [])
    unresolved = disagreements.get("unresolved", [])
    marginal = disagreements.get("marginal_detection", [])
    extra = int(disagreements.get("extra_in_answer", 0))
    vetoed = disagreements.get("vetoed_not_stabilised", [])
    rescued = disagreements.get("rescued_by_stabilisation", [])
    drop_fs = disagreements.get("dropped_fully_stable", [])
    below = disagreements.get("below_residual", [])
    steps = ["ambiguous", "moderate", "clear"]
    if (kept_ns or drop_fs or vetoed or rescued) and level != "ambiguous":
        level = steps[steps.index(level) - 1]
    # calibration on outcomes (docs/robust.md): an answer that keeps in-band poles that are
    # not physical modes, a kept mode within 2x of the detection limit, or near-undamped
    # poles between the lines (a disturbance the model had to fit) is not "clear"
    if (extra or marginal or unresolved or disagreements.get("mains_hum")) and level == "clear":
        level = "moderate"
    parts = [f"{n_physical} mode(s) classified physical; separation ratio "
             + (f"{r:.3g}" if np.isfinite(r) else str(r))
             + f" (ambiguous below {ambiguous_ratio:g}, clear from {clear_ratio:g})."]
    hum = disagreements.get("mains_hum", [])
    named = [
        ("Kept although not stabilised in frequency", kept_ns),
        ("Above the MDI threshold but dropped because not stabilised in frequency", vetoed),
        ("Dropped because they do not stand out of the model's residual in their bandwidth "
         "(not detectable above noise or model error)", below),
        ("Dropped although fully stable (possibly genuine weak modes; consider top_n or a "
         "manual threshold)", drop_fs),
        (None, None),
        ("Kept below the MDI threshold because stabilised across orders", rescued),
        # the half-power band's half-width zeta f_n against the lines: "near-undamped" read
        # as a defect for genuine 0.5-0.7 % modes (the beam at 4.6 Hz, the GVT at 3.0 Hz)
        ("Kept although its half-power band spans less than one line spacing (zeta f_n < "
         "0.5 fs/N: its damping is poorly determined by these periods; longer periods "
         "resolve it, or it is a disturbance)", unresolved),
        ("Dropped as mains hum (near-undamped at a 50/60 Hz harmonic)", hum),
        ("Left out as one mode fitted twice (within 0.2 % in frequency of a stronger pole, "
         "similar damping, the same shape)", disagreements.get("duplicate_modes", [])),
        ("Kept but within 2x of the detection limit", marginal),
    ]
    for text, freqs in named:
        if text is None:       # the fallback note sits between the drop and rescue lists
            if disagreements.get("fallback"):
                parts.append("The MDI gap is not clear, so every stable in-band mode stabilised "
                             "in frequency with an MDI above 1e-3 of the largest was kept as "
                             "well.")
        elif freqs:
            parts.append(f"{text}: " + ", ".join(f"{f:.2f} Hz" for f in freqs) + ".")
    if extra:
        parts.append(f"The answer keeps {extra} in-band pole pair(s) that are not physical "
                     "modes (removing them made the coefficients less consistent).")
    src = disagreements.get("noise_source")
    if src == "none":
        parts.append("No noise estimate (one period per realisation and no non-excited lines "
                     "in the band): detection is judged against the model's residual only.")
    if level == "ambiguous":
        parts.append("The split is ambiguous: check the stabilisation diagram or lower the order.")
    return {"level": level, "statement": " ".join(parts), "separation_ratio":
            float(r) if np.isfinite(r) else None, "n_physical": int(n_physical),
            "kept_not_stabilised": [float(f) for f in kept_ns],
            "dropped_fully_stable": [float(f) for f in drop_fs],
            "vetoed_not_stabilised": [float(f) for f in vetoed],
            "fallback_stabilisation": bool(disagreements.get("fallback", False)),
            "rescued_by_stabilisation": [float(f) for f in rescued],
            "excluded_out_of_band": int(disagreements.get("excluded_out_of_band", 0)),
            "excluded_unstable": int(disagreements.get("excluded_unstable", 0)),
            "below_residual": [float(f) for f in below],
            "unresolved": [float(f) for f in unresolved],
            "marginal_detection": [float(f) for f in marginal], "extra_in_answer": extra,
            "mains_hum": [float(f) for f in hum],
            "duplicate_modes": [float(f) for f in disagreements.get("duplicate_modes", [])],
            "noise_source": src}
