"""One self-contained HTML report of an identification, for a test report.

``render_report(result, metadata)`` turns the identification JSON (what
``fnsi-lab ident --json`` writes, :meth:`fnsi_lab.ident.pipeline.Identification.to_json`)
and, optionally, the recording's metadata into one HTML page: stabilisation diagram,
information criterion, MDI per pole, coefficient spectra with their statistics, measured /
model / underlying-linear FRFs, the mode table, the Table-2-like summary and the recording
metadata. Figures are matplotlib SVG inlined in the page: it opens offline, in any browser,
and can be attached or printed as it is.

Extraction (``*_rows``, :func:`driving_point`) is plain dict/array work; the ``figure_*``
functions return matplotlib figures; :func:`render_report` assembles the page.
"""

from __future__ import annotations

import datetime as _dt
import html
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.viewer.html import CSS, figure_html, fmt_g, html_table, kv_table, new_figure, svg

#: Stabilisation classes in legend order -> (colour, marker, legend).
STAB_STYLE: dict[str, tuple[str, str, str]] = {
    "new": ("#3c3c3c", "o", "new pole"),
    "frequency": ("#56b4e9", "X", "stable in frequency"),
    "damping": ("#0072b2", "s", "+ damping"),
    "mode": ("#cc79a7", "D", "+ mode shape (MAC)"),
    "stable": ("#009e73", "^", "fully stable"),
    "unstable": ("#d55e00", "*", "unstable (zeta < 0)"),
}
FRF_STYLE = {"measured": "#282828", "model": "#e69f00", "underlying_linear": "#0072b2"}
#: A pole's fate (ident.robust.pole_fate) -> (colour, marker): kept ones filled, dropped ones open
#: or crossed, each reason its own colour.
FATE_STYLE: dict[str, tuple[str, str]] = {
    "physical": ("#009e73", "o"),
    "rescued": ("#0072b2", "s"),
    "split": ("#9467bd", "D"),
    "spurious": ("#d55e00", "x"),
    "not_detectable": ("#56b4e9", "v"),
    "not_stabilised": ("#8c564b", "^"),
    "mains_hum": ("#f0e442", "*"),
    "no_evidence": ("#e377c2", "h"),
    "unstable": ("#000000", "+"),
    "out_of_band": ("#aaaaaa", "."),
}
COEFF_COLOURS = ("#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9")


# ---------------------------------------------------------------------------- extraction
def complex_array(obj: Any) -> np.ndarray:
    """``{"re": ..., "im": ...}`` (JSON) -> complex ndarray (nulls become NaN)."""
    re = np.asarray(obj["re"], dtype=float)
    im = np.asarray(obj["im"], dtype=float)
    return re + 1j * im


def stabilisation_rows(result: Mapping[str, Any]) -> list[dict]:
    """One row per pole of the stabilisation diagram: ``order``, ``frequency_hz``,
    ``damping_ratio``, ``class`` (``unstable`` for zeta < 0), ``mac``."""
    rows = []
    for entry in result.get("stabilisation") or []:
        for p in entry.get("poles", []):
            rows.append({"order": int(entry["order"]), "frequency_hz": p["frequency_hz"],
                         "damping_ratio": p.get("damping_ratio"),
                         "class": "unstable" if p.get("unstable") else p.get("class"),
                         "mac": p.get("mac")})
    return rows


def mdi_key(result: Mapping[str, Any]) -> str:
    """Column of the MDI table the pipeline used (``mdi_h2``, ``mdi_hinf``...)."""
    norm = str(result.get("mdi_norm") or "h2")
    key = f"mdi_{norm}"
    rows = result.get("mdi") or []
    return key if rows and key in rows[0] else "mdi_h2"


def failure_reason(result: Mapping[str, Any]) -> str | None:
    """Why the result is not an identification, or None when it is one.

    A result whose processed band holds no excited line (``n_excited_lines`` 0: an ident
    config whose ``band_hz`` misses the excitation) has poles fitted to noise and an empty
    FRF: the report says so instead of presenting them as modes.
    """
    if result.get("n_excited_lines") == 0:
        band = result.get("band_hz")
        where = (f" {float(band[0]):g}-{float(band[1]):g} Hz"
                 if isinstance(band, (list, tuple)) and len(band) == 2 else "")
        return (f"no excited line in the processed band{where} (fix: an ident config "
                "band_hz that covers the excited lines)")
    return None


def driving_point(outputs: Sequence[str], inputs: Sequence[str], output: str | None = None) -> int:
    """Index of the output to show: ``output`` if given, else the one whose name ends the
    force's name (``F-NC2W-Z`` -> ``NC2W-Z``), else the first.

    Raises
    ------
    KeyError
        ``output`` is not one of ``outputs``.
    """
    if output is not None:
        return list(outputs).index(output)
    force = inputs[0] if inputs else ""
    for i, name in enumerate(outputs):
        if force.endswith(name):
            return i
    return 0


def exact_values(result: Mapping[str, Any]) -> dict[str, float]:
    """Known coefficient values (simulations): from the coefficient spectra, else from the
    relative error the pipeline reports against them."""
    spectra = result.get("coefficient_spectra") or {}
    exact = {k: float(v) for k, v in (spectra.get("exact") or {}).items() if v is not None}
    for c in result.get("coefficients") or []:
        err = c.get("error_percent")
        if c["name"] not in exact and err is not None and c.get("mean_real") is not None:
            exact[c["name"]] = c["mean_real"] / (1.0 + err / 100.0)
    return exact


def coefficient_unit(result: Mapping[str, Any], name: str) -> str:
    """Unit of a coefficient (``N/mm``...): the JSON's ``units`` block (``ident.core.units``);
    empty for results written before units were recorded."""
    return str(((result.get("units") or {}).get("coefficients") or {}).get(name) or "")


def frf_unit(result: Mapping[str, Any]) -> str:
    """Unit of the FRFs (output over force, ``mm/N``); empty when the result has none."""
    return str((result.get("units") or {}).get("frf") or "")


def _with_unit(text: str, unit: str) -> str:
    return f"{text} {unit}" if unit else text


def summary_rows(result: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The Table-2-like summary: order decisions, then every coefficient estimate."""
    def num(x: Any, fmt: str = ".4g") -> str:
        return "-" if x is None else format(x, fmt)

    rows = [("method", str(result.get("method", "-"))), ("answer order", num(result.get("order"), "d"))]
    if result.get("method") == "auto":
        phys = sum(1 for r in result.get("mdi") or [] if r.get("physical"))
        conf = result.get("confidence")
        rows += [("selected order (IC)", num(result.get("selected_order"), "d")),
                 ("MDI order", num(result.get("mdi_order"), "d")),
                 ("physical modes", str(phys)),
                 ("reduced order", num((result.get("reduced") or {}).get("order"), "d")),
                 ("final model", str(result.get("final", "-"))),
                 ("MDI threshold", num(result.get("threshold"), ".3g")),
                 ("separation ratio", num(result.get("separation_ratio"), ".3g")),
                 ("confidence", str(conf.get("level", conf)) if isinstance(conf, dict)
                  else str(conf or "-"))]
    models = [("answer", result.get("coefficients"))]
    if result.get("method") == "auto":   # the answer's verdicts first (the nested test's)
        models += [("full model", (result.get("full_model") or {}).get("coefficients")),
                   ("reduced model", (result.get("reduced") or {}).get("coefficients"))]
    for label, coeffs in models:
        for c in coeffs or []:
            unit = c.get("unit") or coefficient_unit(result, c["name"])
            text = _with_unit(f"{num(c.get('mean_real'), '.6g')} ± {num(c.get('std_real'), '.3g')}",
                              unit)
            if c.get("error_percent") is not None:
                text += f" (error {c['error_percent']:+.3f} %)"
            text += "; LS " + _with_unit(num(c.get("ls_value"), ".6g"), unit)
            if c.get("ls_error_percent") is not None:
                text += f" ({c['ls_error_percent']:+.3f} %)"
            if c.get("verdict"):
                text += f"; {c['verdict']}"
            rows.append((f"{c['name']}, {label}", text))
    nvl = result.get("nonlinear_vs_linear") or {}
    if nvl.get("statement"):   # is the nonlinear answer the answer? (docs/ident.md)
        rows.append(("nonlinear vs linear", str(nvl["statement"])))
    before = nvl.get("before_reduction")
    if before:                 # the full model was tested too, and failed
        rows.append((f"model before the reduction (order {before.get('order')})",
                     str(before.get("statement"))))
    if result.get("final_reason"):   # the full model is the answer, and why
        rows.append(("answer", f"the full model at order {result.get('order')}: "
                               f"{result['final_reason']}"))
    return rows


def pole_fates(result: Mapping[str, Any]) -> list[str]:
    """The fate of each row of the result's ``mdi`` table (``mdi[].fate``, or derived for
    results written before it was recorded: :func:`ident.robust.pole_fate.result_fates`)."""
    from fnsi_lab.ident.robust.pole_fate import result_fates

    rows = result.get("mdi") or []
    if rows and all("fate" in r for r in rows):
        return [str(r["fate"]) for r in rows]
    return result_fates(result)


def mode_rows(result: Mapping[str, Any]) -> list[dict]:
    """Mode table: the in-band poles of the MDI order with their decisions (robust pipeline),
    else the modes of the answer."""
    from fnsi_lab.ident.robust.pole_fate import fate_label

    key = mdi_key(result)
    fates = pole_fates(result)
    rows = [dict(r, fate=fate) for r, fate in zip(result.get("mdi") or [], fates)
            if r.get("in_band") or r.get("physical")]
    if rows:
        return [{"f (Hz)": f"{r['frequency_hz']:.4g}",
                 "zeta (%)": f"{100 * r['damping_ratio']:.3g}",
                 "MDI (relative)": f"{r[key]:.3g}" if r.get(key) is not None else "-",
                 "stabilisation": str(r.get("stabilisation") or "-"),
                 "fate": fate_label(r["fate"])} for r in rows]
    return [{"f (Hz)": f"{m['frequency_hz']:.4g}", "zeta (%)": f"{100 * m['damping_ratio']:.3g}",
             "stable": "yes" if m.get("stable") else "no"} for m in result.get("modes") or []]


def coefficient_statistics(result: Mapping[str, Any]) -> list[dict]:
    """Per coefficient of the answer: mean, spread, LS value, errors, lines used."""
    exact = exact_values(result)
    out = []
    for c in result.get("coefficients") or []:
        out.append({"coefficient": c["name"],
                    "unit": c.get("unit") or coefficient_unit(result, c["name"]) or "-",
                    "value (declared)": fmt_g(c.get("value")),
                    "mean Re": fmt_g(c.get("mean_real")), "std Re": fmt_g(c.get("std_real"), 3),
                    "log10 |Re/Im|": fmt_g(c.get("log10_re_im"), 3), "LS value": fmt_g(c.get("ls_value")),
                    "exact": fmt_g(exact.get(c["name"])),
                    "error mean (%)": fmt_g(c.get("error_percent"), 3),
                    "error LS (%)": fmt_g(c.get("ls_error_percent"), 3),
                    "lines": str(c.get("n_lines", "-"))})
    return out


# ---------------------------------------------------------------------------- figures
def figure_stabilisation(result: Mapping[str, Any]) -> Any:
    """Pole frequency against model order, one marker per class, the selected order marked."""
    rows = stabilisation_rows(result)
    fig, (ax,) = new_figure(9.0, 5.0)
    classes = list(STAB_STYLE) + sorted({r["class"] for r in rows} - set(STAB_STYLE))
    for cls in classes:
        sel = [r for r in rows if r["class"] == cls]
        if not sel:
            continue
        color, marker, label = STAB_STYLE.get(cls, ("#777777", "o", str(cls)))
        ax.scatter([r["order"] for r in sel], [r["frequency_hz"] for r in sel],
                   s=10 if cls == "new" else 22, c=color, marker=marker,
                   label=f"{label} ({len(sel)})", linewidths=0.5,
                   zorder=4 if cls in ("unstable", "new") else 3)
    _mark_order(ax, result.get("selected_order"))
    ax.set_xlabel("model order")
    ax.set_ylabel("pole frequency (Hz)")
    ax.set_title(f"Stabilisation diagram ({len(rows)} poles)")
    ax.grid(alpha=0.3)
    fig.legend(loc="outside lower center", fontsize=8, ncol=4)  # off the poles
    return fig


def _mark_order(ax: Any, order: Any) -> None:
    if order is not None:
        ax.axvline(order, color="#d55e00", lw=1.0, ls="--", label=f"selected order {order}")


def figure_criterion(result: Mapping[str, Any]) -> Any:
    """Information criterion against model order (log scale), the selected order marked."""
    ic = result.get("information_criterion") or []
    fig, (ax,) = new_figure(9.0, 3.6)
    n = np.array([r["order"] for r in ic], dtype=float)
    v = np.array([np.nan if r.get("value") is None else r["value"] for r in ic], dtype=float)
    ok = np.isfinite(v) & (v > 0)
    ax.semilogy(n[ok], v[ok], "o-", color="#0072b2", ms=3, lw=1.2, label="I(n)")
    missing = n[~ok]
    if missing.size and ok.any():  # gaps in the curve: say why, at the bottom of the axis
        unstable = {int(r["order"]) for r in ic if r.get("stable") is False}
        why = "unstable model" if set(missing.astype(int)) <= unstable else "no value"
        ax.semilogy(missing, np.full(missing.size, v[ok].min()), "|", color="#d55e00",
                    ms=12, mew=1.5, label=f"order not fitted: {why} ({missing.size})")
    sel = result.get("selected_order")
    if sel is not None and np.any(n[ok] == sel):
        ax.semilogy([sel], v[ok][n[ok] == sel][:1], "D", color="#d55e00", ms=8,
                    label=f"selected order {sel}")
    ax.set_xlabel("model order")
    ax.set_ylabel(f"information criterion ({result.get('criterion', 'I(n)')})")
    ax.set_title("Information criterion")
    ax.grid(alpha=0.3, which="both")
    fig.legend(loc="outside right upper", fontsize=8)  # beside the curve, not over it
    return fig


def figure_mdi(result: Mapping[str, Any]) -> Any:
    """MDI of each pole of the MDI order against its frequency, physical and spurious apart."""
    from fnsi_lab.ident.robust.pole_fate import FATE_ORDER, fate_label

    key = mdi_key(result)
    rows = [dict(r, fate=fate) for r, fate in zip(result.get("mdi") or [], pole_fates(result))
            if r.get(key) is not None and r[key] > 0]
    fig, (ax,) = new_figure(9.0, 4.2)
    for fate in FATE_ORDER:
        sel = [r for r in rows if r["fate"] == fate]
        if not sel:
            continue
        color, marker = FATE_STYLE[fate]
        filled = fate in ("physical", "rescued", "split")
        ax.semilogy([r["frequency_hz"] for r in sel], [r[key] for r in sel], marker,
                    color=color, ms=7, ls="none", mfc=color if filled else "none",
                    mew=1.5, label=f"{fate_label(fate)} ({len(sel)})", zorder=3)
    thr = result.get("threshold")
    if thr:
        ax.axhline(thr, color="#777777", lw=1.0, ls="--", label=f"threshold {thr:.3g}")
    # the band whose poles are candidates (outside it: "out of band"), not the wider
    # processed band, which would shade out-of-band poles as if they were in it
    band = result.get("mdi_band_hz") or result.get("band_hz")
    if band:
        ax.axvspan(band[0], band[1], color="#0072b2", alpha=0.06,
                   label=f"MDI band {band[0]:.3g}-{band[1]:.3g} Hz (candidates)")
    ax.set_xlabel("pole frequency (Hz)")
    ax.set_ylabel(f"MDI ({key.removeprefix('mdi_')} norm, relative)")
    ax.set_title(f"Modal dominancy index per pole (order {result.get('mdi_order', '-')})")
    ax.grid(alpha=0.3, which="both")
    fig.legend(loc="outside right upper", fontsize=8)  # beside the poles, not over them
    return fig


def _band_limits(values: np.ndarray, include: Sequence[float] = (),
                 pad: float = 0.3) -> tuple[float, float] | None:
    """y-limits from the values over the excited lines (1st-99th percentile, padded)."""
    v = np.concatenate([np.ravel(values), np.asarray(include, dtype=float)])
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    lo, hi = np.percentile(v, [1, 99])
    span = max(hi - lo, 1e-6 * max(abs(lo), abs(hi)), 1e-12)
    return lo - pad * span, hi + pad * span


def figure_coefficients(result: Mapping[str, Any]) -> Any | None:
    """Re and Im of each coefficient spectrum c_a(f), one row each, over the excited band
    (the lines beyond it are extrapolations that swing off any useful scale), mean ± std
    over the excited lines and the exact value when known; None without coefficients."""
    spectra = result.get("coefficient_spectra")
    if not spectra or not spectra.get("names"):
        return None
    from fnsi_lab.viewer.frf import frequency_order

    order = frequency_order(spectra["frequency_hz"])
    f = np.asarray(spectra["frequency_hz"], dtype=float)[order]
    if not f.size:
        return None
    excited = np.asarray(spectra.get("excited", np.ones(f.size)), dtype=bool)[order]
    if not excited.any():
        excited = np.ones(f.size, bool)
    exact = exact_values(result)
    stats = {c["name"]: c for c in result.get("coefficients") or []}
    names = list(spectra["names"])
    fig, axes = new_figure(9.0, 2.2 * 2 * len(names) + 0.8, rows=2 * len(names), sharex=True)
    f_lo, f_hi = float(f[excited].min()), float(f[excited].max())
    margin = 0.03 * max(f_hi - f_lo, 1e-9)
    for k, name in enumerate(names):
        re_ax, im_ax = axes[2 * k], axes[2 * k + 1]
        color = COEFF_COLOURS[k % len(COEFF_COLOURS)]
        unit = coefficient_unit(result, name)
        c = complex_array(spectra["values"][name])[order]
        re_ax.plot(f, c.real, color=color, lw=1.4, label=f"Re {name}")
        im_ax.plot(f, c.imag, color=color, lw=1.4, label=f"Im {name}")
        im_ax.axhline(0.0, color="#282828", lw=0.8, ls=":", label="0 (a physical "
                      "coefficient is real)")
        st = stats.get(name)
        if st and st.get("mean_real") is not None:
            m, s = st["mean_real"], st.get("std_real") or 0.0
            re_ax.axhspan(m - s, m + s, color=color, alpha=0.15,
                          label=f"mean ± std over excited lines: {m:.6g} ± {s:.3g}"
                          + (f" {unit}" if unit else ""))
        if name in exact:
            re_ax.axhline(exact[name], color="#282828", lw=1.0, ls="--",
                          label=f"exact {exact[name]:.6g}" + (f" {unit}" if unit else ""))
        for ax, part, include in ((re_ax, c.real, [exact.get(name, np.nan)]),
                                  (im_ax, c.imag, [0.0])):
            lim = _band_limits(part[excited], include)  # the excited band sets the scale
            if lim is not None:
                ax.set_ylim(*lim)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                      borderaxespad=0.0)  # beside the plot, not over the curve
        re_ax.set_ylabel(f"Re ({unit})" if unit else "Re")
        im_ax.set_ylabel(f"Im ({unit})" if unit else "Im")
        re_ax.set_title(f"{name}" + (f" ({unit})" if unit else ""), fontsize=9, loc="left")
    axes[0].set_xlim(f_lo - margin, f_hi + margin)
    fig.suptitle("Nonlinear coefficient spectra over the excited lines "
                 f"({f_lo:.4g}-{f_hi:.4g} Hz)", fontsize=11)
    axes[-1].set_xlabel("frequency (Hz)")
    return fig


def spline_curves(result: Mapping[str, Any]) -> list[dict]:
    """The ``kind: spline`` force curves of a result (``coefficients[].curve``)."""
    return [c["curve"] for c in result.get("coefficients") or [] if c.get("curve")]


def figure_restoring_force(result: Mapping[str, Any]) -> Any | None:
    """Each spline element's force curve with its band (+-2 standard errors) and the
    suggested parametric form's curve; None without spline elements."""
    curves = spline_curves(result)
    if not curves:
        return None
    fig, axes = new_figure(9.0, 3.2 * len(curves) + 0.6, rows=len(curves))
    sugg = {(s.get("element"), s.get("argument")): s for s in result.get("suggestions") or []}
    for k, (ax, c) in enumerate(zip(axes, curves)):
        x, f = np.asarray(c["x"], float), np.asarray(c["force"], float)
        sd = np.nan_to_num(np.asarray(c["std"], float))
        color = COEFF_COLOURS[k % len(COEFF_COLOURS)]
        ax.fill_between(x, f - 2 * sd, f + 2 * sd, color=color, alpha=0.25,
                        label="+-2 standard errors")
        ax.plot(x, f, color=color, lw=1.6, label="spline (identified)")
        for t in c.get("knots") or []:
            ax.axvline(t, color="#999999", lw=0.5, alpha=0.5)
        s = sugg.get((c["element"], c["argument"]))
        model = _suggested_curve(s, x) if s else None
        if model is not None:
            ax.plot(x, model, color="#282828", lw=1.0, ls="--", label=f"suggested {s['kind']}")
        ax.set_xlabel(f"relative {c['argument']} of {c['element']}")
        ax.set_ylabel("force beyond the linear spring")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_title("Restoring force without an assumed shape (grey lines: knots)")
    return fig


def _suggested_curve(s: Mapping[str, Any], x: np.ndarray) -> np.ndarray | None:
    """The suggested parametric form's force on ``x`` (read-off parameters)."""
    kind, v = s.get("kind"), s.get("values") or []
    if kind == "trilinear":
        gn, gp = s["clearances"]
        return v[0] * np.where(x < -gn, x + gn, 0) + v[1] * np.where(x > gp, x - gp, 0)
    if kind == "bilinear":
        g = s["clearance"]
        return v[0] * (np.where(x > g, x - g, 0) if s.get("side") == "pos"
                       else np.where(x < -g, x + g, 0))
    if kind == "polynomial":
        return v[0] * np.abs(x) ** s["exponent"] * np.sign(x)
    if kind == "coulomb":
        return v[0] * np.tanh(x / max(float(s.get("velocity_scale") or 1e-30), 1e-30))
    return None


def restoring_force_html(result: Mapping[str, Any]) -> list[str]:
    """The report's section on spline elements (empty without them)."""
    if not spline_curves(result):
        return []
    rows = []
    for s in result.get("suggestions") or []:
        pars = ", ".join(f"{k} " + (fmt_g(s[k]) if not isinstance(s[k], list)
                                    else "[" + ", ".join(fmt_g(v) for v in s[k]) + "]")
                         for k in ("clearances", "clearance", "side", "exponent",
                                   "velocity_scale", "slip") if k in s)
        rows.append({"element": s.get("element"), "argument": s.get("argument"),
                     "suggested form": s.get("kind"), "parameters": pars or s.get("reason", ""),
                     "coefficients": ", ".join(fmt_g(v) for v in s.get("values") or []),
                     "misfit": fmt_g(s["misfit"], 3) if "misfit" in s else ""})
    text = (result.get("suggested_config") or {}).get("yaml") or ""
    return ["<h2>Restoring force (kind: spline)</h2>",
            figure_html(figure_restoring_force(result),
                         "the identified force curve, its band and the parametric form it "
                         "suggests (docs/discovery.md)", "fig-restoring-force"),
            html_table(rows),
            "<p>Suggested config (<code>fnsi-lab ident ... --suggest OUT.yaml</code> writes "
            "it):</p>", f"<pre id='suggested-config'>{html.escape(text)}</pre>"]


def figure_frf(result: Mapping[str, Any], output: str | None = None) -> Any | None:
    """Measured, model and underlying-linear FRF (dB, phase) of one output over the force."""
    frf = result.get("frf")
    if not frf or "underlying_linear" not in frf:
        return None
    from fnsi_lab.viewer.frf import frequency_order, magnitude_db, phase_deg

    order = frequency_order(frf["frequency_hz"])
    f = np.asarray(frf["frequency_hz"], dtype=float)[order]
    i = driving_point(frf.get("outputs", []), frf.get("inputs", []), output)
    curves = {}
    for key in ("measured", "model", "underlying_linear"):
        h = complex_array(frf[key]) if key in frf else None
        # (lines, outputs, inputs); an identification without an excited line has none
        if h is not None and h.ndim == 3 and h.shape[0] == f.size and h.shape[1] > i:
            curves[key] = h[order, i, 0]
    if not f.size or "underlying_linear" not in curves:
        return None
    fig, (mag, ph) = new_figure(9.0, 6.0, rows=2, sharex=True)
    # measured: markers on top; model: a thin line under them; underlying linear: dashed
    for key, label, style in (("measured", "measured (markers)",
                               dict(ls="none", marker="o", ms=3.0, mew=0, zorder=3)),
                              ("model", "model (line)", dict(lw=1.0, zorder=2)),
                              ("underlying_linear", "underlying linear (dashed)",
                               dict(lw=1.4, ls="--", zorder=1))):
        if key not in curves:
            continue
        h = curves[key]
        mag.plot(f, magnitude_db(h), color=FRF_STYLE[key], label=label, **style)
        ph.plot(f, phase_deg(h), color=FRF_STYLE[key], label=label, **style)
    name = (frf.get("outputs") or ["?"])[i]
    force = (frf.get("inputs") or ["force"])[0]
    mag.set_title(f"FRF of {name} over {force}")
    unit = frf_unit(result)
    mag.set_ylabel(f"magnitude (dB re 1 {unit})" if unit else "magnitude (dB)")
    ph.set_ylabel("phase (deg)")
    ph.set_yticks([-180, -90, 0, 90, 180])
    ph.set_xlabel("frequency (Hz)")
    for ax in (mag, ph):
        ax.grid(alpha=0.3)
    fig.legend(*mag.get_legend_handles_labels(), loc="outside lower center", ncol=3,
               fontsize=8)  # below the plots, not over the peaks
    return fig


def mdi_caption(result: Mapping[str, Any]) -> str:
    """The MDI figure's caption: what each fate drawn means (only those present)."""
    from fnsi_lab.ident.robust.pole_fate import fate_caption

    fates = [f for r, f in zip(result.get("mdi") or [], pole_fates(result))
             if (r.get(mdi_key(result)) or 0) > 0]
    return ("MDI of each pole at the MDI order, drawn by its fate (the same words as the "
            "mode table and the terminal): " + fate_caption(fates)
            + " The dashed line is the MDI threshold.")


# ---------------------------------------------------------------------------- HTML
def metadata_rows(metadata: Mapping[str, Any] | None,
                  result: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Recording and processing facts for the report header (short values only)."""
    rows: list[tuple[str, str]] = []
    md = dict(metadata or {})
    exp = md.get("experiment") or {}
    for k in ("name", "source_kind", "config_file", "software_version"):
        if exp.get(k) is not None:
            rows.append((f"experiment {k.replace('_', ' ')}", str(exp[k])))
    clock = md.get("clock") or {}
    if clock.get("acquisition_start_utc_ns"):
        t = _dt.datetime.fromtimestamp(clock["acquisition_start_utc_ns"] / 1e9, _dt.timezone.utc)
        rows.append(("acquisition start (UTC)", t.isoformat(timespec="seconds")))
    chans = md.get("channels") or []
    if chans:
        kinds: dict[str, int] = {}
        for c in chans:
            kinds[c.get("quantity", "?")] = kinds.get(c.get("quantity", "?"), 0) + 1
        rows.append(("channels", f"{len(chans)} (" + ", ".join(f"{n} {q}" for q, n in kinds.items())
                     + ")"))
    exc = md.get("excitation") or {}
    force = (result.get("units") or {}).get("force") or next(
        (c.get("unit") for c in chans if c.get("quantity") == "force" and c.get("unit")), "")
    for k, unit in (("kind", ""), ("band_hz", ""), ("rms", force), ("samples_per_period", ""),
                    ("periods", ""), ("transient_periods", ""), ("realizations", ""),
                    ("sample_rate_hz", "")):
        if exc.get(k) is not None:
            text = plain.band_hz(exc[k]) if k == "band_hz" else plain.value(exc[k]).strip("'")
            rows.append((f"excitation {k.replace('_', ' ')}", _with_unit(text, unit)))
    if exc.get("excited_lines") is not None:
        rows.append(("excited lines", str(len(exc["excited_lines"]))))
    truth = md.get("truth") or {}
    if truth:
        rows.append(("truth", f"model {truth.get('model', '?')}, "
                              f"{len(truth.get('modes') or [])} modes known"))
    for k in ("input", "config", "band_hz", "n_lines", "n_excited_lines", "n_periods",
              "n_realizations", "output_quantity", "time_base"):
        if result.get(k) is not None:
            text = plain.band_hz(result[k]) if k == "band_hz" else plain.value(result[k]).strip("'")
            rows.append((f"identification {k.replace('_', ' ')}", text))
    units = result.get("units") or {}
    if units.get("force"):
        rows.append(("units", f"force {units['force']}, outputs {units.get('output') or '-'}, "
                              f"FRF {units.get('frf') or '-'}" + (" (assumed SI: the input had no unit "
                                                       "table)" if units.get("assumed") else "")))
    total = (result.get("timings_s") or {}).get("total")
    if total is not None:
        rows.append(("identification time", f"{total:.2f} s"))
    return rows


def render_report(result: Mapping[str, Any], metadata: Mapping[str, Any] | None = None, *,
                  title: str = "fnsi-lab identification report", output: str | None = None) -> str:
    """The whole report as one HTML document (figures inline SVG, no external resource).

    Parameters
    ----------
    result : mapping
        Identification JSON (``Identification.to_json()`` / ``fnsi-lab ident --json``).
    metadata : mapping, optional
        Recording metadata (``Recording.metadata``: experiment, channels, excitation,
        clock, truth...).
    title : str
        Page title.
    output : str, optional
        Output channel of the FRF figure (default: the driving point).
    """
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1><p class='note'>generated {now} by fnsi-lab</p>"]
    failure = failure_reason(result)
    if failure:
        parts.append(f"<p class='failed' id='failed'><strong>Identification failed:</strong> "
                     f"{html.escape(failure)}. What follows was fitted to lines the "
                     "excitation did not drive: it is shown as it came out, not as an "
                     "identification.</p>")
    parts += ["<h2>Summary</h2>", kv_table(summary_rows(result)),
              "<h2>Modes</h2>", html_table(mode_rows(result))]
    warnings = result.get("warnings") or []
    if warnings:
        parts.append("<ul class='note'>" + "".join(f"<li>{html.escape(str(w))}</li>"
                                                   for w in warnings) + "</ul>")
    auto = result.get("method") == "auto"
    parts += ["<h2>Stabilisation diagram</h2>",
              figure_html(figure_stabilisation(result) if auto else None,
                           "pole frequency against model order; classes against the previous "
                           "order (frequency, damping, mode shape)", "fig-stabilisation"),
              "<h2>Information criterion</h2>",
              figure_html(figure_criterion(result) if auto else None,
                           "information criterion against model order", "fig-criterion"),
              "<h2>Modal dominancy index</h2>",
              figure_html(figure_mdi(result) if auto else None,
                           mdi_caption(result), "fig-mdi"),
              "<h2>Nonlinear coefficients</h2>", html_table(coefficient_statistics(result)),
              figure_html(figure_coefficients(result),
                           "coefficient spectra c_a(f): a physical coefficient is constant "
                           "and real over the excited lines", "fig-coefficients"),
              *restoring_force_html(result),
              "<h2>Frequency response</h2>",
              figure_html(figure_frf(result, output),
                           "measured FRF, model FRF (nonlinear terms included) and the "
                           "underlying linear FRF", "fig-frf"),
              "<h2>Recording and processing</h2>", kv_table(metadata_rows(metadata, result)),
              "</body></html>"]
    return "\n".join(parts)


__all__ = ["render_report", "failure_reason", "stabilisation_rows", "summary_rows", "mode_rows",
           "coefficient_statistics", "metadata_rows", "driving_point", "exact_values",
           "figure_stabilisation", "figure_criterion", "figure_mdi", "figure_coefficients",
           "figure_frf", "figure_restoring_force", "svg"]
