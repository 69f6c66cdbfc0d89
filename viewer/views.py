"""Plain-dict views of the live service's updates for the Rerun logging and the terminal
(:func:`auto_view`, summary rows, mode tables): formatting only, no identification.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from fnsi_lab.replay.identifiers import AutoIdentification, driving_point
from fnsi_lab.replay.service import ServiceUpdate


def auto_view(update: ServiceUpdate) -> dict[str, Any]:
    """Plain-dict view of an :class:`AutoIdentification` update for :func:`viewer.log.log_identification`."""
    from fnsi_lab.viewer.log import summary_markdown

    ai: AutoIdentification = update.result
    res, data = ai.result, ai.data
    record = update.record
    dp = driving_point(record.output_channels, record.input_channels)
    exc = np.asarray(data.excited, dtype=bool)
    f = data.frequencies_hz[exc]
    u = data.E_physical[exc, 0]
    view: dict[str, Any] = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        measured = data.Y[exc, dp] / u
        y_model = res.model.steady_state_output(data)[exc, dp] / u
    units = ai.identification.units
    view["frf"] = {"frequency_hz": f, "measured": measured,
                   "linear": res.model.underlying_linear_frf(f)[:, dp, 0], "model": y_model,
                   "output": getattr(record.output_channels[dp], "name",
                                     str(record.output_channels[dp])),
                   "force": getattr(record.input_channels[0], "name",
                                    str(record.input_channels[0])),
                   "unit": units.get("frf")}
    order, freq, cls = [], [], []
    for o in res.stabilisation.orders:
        for fi, c, unst in zip(o.frequency_hz, o.classes, o.unstable):
            order.append(o.order)
            freq.append(fi)
            cls.append("unstable" if unst else str(c))
    view["stabilisation"] = {"order": order, "frequency_hz": freq, "pole_class": cls}
    ic = res.information_criterion
    view["criterion"] = {"orders": ic.orders, "criterion": ic.value,
                         "selected_order": res.selected_order}
    from fnsi_lab.ident.robust.pole_fate import pole_fates

    thr = res.threshold.threshold
    rows = res.mdi_table()  # sorted by frequency, with the decisions
    key = f"mdi_{res.modal_dominancy.norm}"
    view["mdi"] = {"frequency_hz": np.array([r["frequency_hz"] for r in rows]),
                   "mdi": np.array([r.get(key, r["mdi_h2"]) for r in rows]),
                   "kept": np.array([r["physical"] for r in rows], bool),
                   "fate": pole_fates(rows, res.confidence, left_out_hz(ai)),
                   "threshold": float(thr) if np.isfinite(thr) else None}
    if ai.coefficient_curves:
        view["coefficients"] = {"frequency_hz": ai.coefficient_curves["frequency_hz"],
                                "full": ai.coefficient_curves.get("full"),
                                "reduced": ai.coefficient_curves.get("reduced"),
                                "exact": ai.exact_coefficients,
                                "excited": data.excited,
                                "units": units.get("coefficients")}
    search = ai.identification.session.parameter_search   # clearances/exponents from the data
    if search is not None and search.estimates:
        view["parameters"] = {"profiles": [
            {"label": e.unknown.label, "values": e.profile_values,
             "objective": e.profile_objective, "estimate": e.value, "std": e.std}
            for e in search.estimates]}
    curves = ai.identification.spline_curves    # kind: spline: the force curves
    if curves:
        view["restoring_force"] = {"curves": [dict(c.to_dict(), suggestion=c.suggestion)
                                              for c in curves]}
    # the physical modes of the answer: one per-update series each ("mode 3 (28.3 Hz)")
    physical = ai.identification.modes
    modes = {"frequency_hz": np.array([m["frequency_hz"] for m in physical]),
             "damping_ratio": np.array([m["damping_ratio"] for m in physical])}
    with np.errstate(divide="ignore", invalid="ignore"):
        log_sep = np.log10(res.separation_ratio) if res.separation_ratio > 0 else np.nan
    view["convergence"] = {"update": update.update, "acq_time_s": update.acq_time_s,
                           "values": {"natural_frequency_hz": modes["frequency_hz"],
                                      "damping_ratio": modes["damping_ratio"],
                                      "selected_order": [res.selected_order],
                                      "log10_separation_ratio": [log_sep]},
                           "coefficients": coefficient_means(ai),
                           "units": units.get("coefficients")}
    view["summary"] = summary_markdown(
        f"Identification update {update.update} ({update.n_periods} steady periods)",
        summary_rows(update), mode_table(res, left_out_hz(ai)))
    return view


def coefficient_means(ai: AutoIdentification) -> dict[str, float]:
    """Mean Re c_a over the excited lines, of the reduced model when there is one."""
    curves = ai.coefficient_curves.get("reduced") or ai.coefficient_curves.get("full") or {}
    band = np.asarray(ai.data.excited, dtype=bool)
    out = {}
    for name, curve in curves.items():
        c = np.asarray(curve)
        c = c[band] if c.size == band.size else c
        if c.size:
            out[name] = float(np.mean(c.real))
    return out


def summary_rows(update: ServiceUpdate) -> list[tuple[str, str]]:
    """Key/value rows of the result summary (the paper's Table 2 headline values)."""
    ai: AutoIdentification = update.result
    res = ai.result
    rows = [("periods averaged", str(update.n_periods)),
            ("selected order (IC)", str(res.selected_order)),
            ("MDI order", str(res.mdi_order)),
            ("physical modes", str(int(np.sum(res.physical)))),
            ("reduced order", str(res.reduced.order) if res.reduced is not None else "-"),
            ("separation ratio", f"{res.separation_ratio:.3g}"),
            ("confidence", str(res.confidence.get("level", ""))),
            ("identification time", f"{update.ident_s:.2f} s")]
    units = ai.identification.units["coefficients"]
    for which in ("full", "reduced"):
        for name, curve in (ai.coefficient_curves.get(which) or {}).items():
            band = np.asarray(ai.data.excited, dtype=bool)
            c = np.asarray(curve)[band] if np.size(curve) == band.size else np.asarray(curve)
            mean, std = float(np.mean(c.real)), float(np.std(c.real))
            unit = units.get(name, "")
            text = f"{mean:.5g} ± {std:.3g}" + (f" {unit}" if unit else "")
            exact = ai.exact_coefficients.get(name)
            if exact:
                text += f" (error {100 * (mean - exact) / exact:+.3f} %)"
            rows.append((f"{name}, {which} model", text))
    for c in ai.identification.coefficients:   # how far the answer's values can be trusted
        if c.get("verdict"):
            reason = c.get("verdict_reason") if c["verdict"] != "identified" else None
            rows.append((f"{c['name']}, verdict", str(c["verdict"])
                         + (f" ({reason})" if reason else "")))
    statement = ai.identification.linear_comparison_statement
    if statement:   # is the nonlinear answer the answer? (docs/ident.md)
        rows.append(("nonlinear vs linear", statement))
    return rows


def left_out_hz(ai: AutoIdentification) -> list[float]:
    """Frequencies of the split modes the output-error refinement left out (Hz)."""
    evidence = getattr(ai.identification.session, "evidence", {}) or {}
    return [float(m["frequency_hz"]) for m in
            ((evidence.get("output_error") or {}).get("left_out") or [])]


def mode_table(res: Any, left_out_hz: Sequence[float] = ()) -> list[dict[str, Any]]:
    """One row per mode of the MDI order: frequency, damping, MDI, stabilisation and its fate
    (:mod:`ident.robust.pole_fate`: physical, spurious by MDI, not detectable...)."""
    from fnsi_lab.ident.robust.pole_fate import fate_label, pole_fates

    out = []
    rows = res.mdi_table()
    for row, fate in zip(rows, pole_fates(rows, res.confidence, left_out_hz)):
        if not row["in_band"]:
            continue
        out.append({"f (Hz)": round(row["frequency_hz"], 3),
                    "zeta (%)": round(100 * row["damping_ratio"], 3),
                    "MDI": float(f"{row[f'mdi_{res.options.mdi_norm}']:.3g}")
                    if f"mdi_{res.options.mdi_norm}" in row else None,
                    "stabilisation": row["stabilisation"],
                    "fate": fate_label(fate)})
    return out
