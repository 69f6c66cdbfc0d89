"""The campaign comparison as one offline HTML page (``fnsi-lab campaign --html``).

Same page style as ``fnsi-lab report`` (:mod:`fnsi_lab.viewer.report`: matplotlib SVG
inlined, no external resource): the campaign table, the warnings, coefficients and natural
frequencies against force level, and the underlying linear FRFs of all runs overlaid.
"""

from __future__ import annotations

import datetime as _dt
import html
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab.campaign.compare import Comparison
from fnsi_lab.viewer.html import CSS, figure_html, fmt_g, html_table, new_figure
from fnsi_lab.viewer.report import COEFF_COLOURS


def _level_scale(ax: Any, c: Comparison) -> None:
    known = [lv for lv in c.levels if lv is not None]
    if len(known) > 1 and min(known) > 0 and max(known) / min(known) >= 10:
        from matplotlib.ticker import ScalarFormatter

        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())  # 20, 50, 100 rather than 10^x
        ax.xaxis.set_minor_formatter(ScalarFormatter())
    ax.set_xlabel("force level (RMS)")
    ax.grid(True, alpha=0.3)


def figure_coefficients(c: Comparison) -> Any | None:
    """Each coefficient against level: mean +- spread, every run, not identifiable in red."""
    names = [n for n, values in c.coefficients.items() if any(v.level is not None for v in values)]
    if not names:
        return None
    fig, axes = new_figure(height=2.6 * len(names), rows=len(names), sharex=True)
    for ax, name, colour in zip(axes, names, COEFF_COLOURS * len(names)):
        values = [v for v in c.coefficients[name] if v.level is not None]
        ok = [v for v in values if v.not_identifiable is None]
        bad = [v for v in values if v.not_identifiable is not None]
        for v in values:
            ax.plot([v.level] * len(v.runs), v.runs, ".", color="#888888", ms=4)
        if ok:
            ax.errorbar([v.level for v in ok], [v.mean for v in ok],
                        yerr=[v.spread or 0.0 for v in ok], fmt="o-", color=colour,
                        capsize=3, label="mean ± spread")
        if bad:
            ax.plot([v.level for v in bad], [v.mean for v in bad], "x", color="#d55e00",
                    ms=9, mew=2, label="not identifiable")
            if ok:  # keep the axis on the identifiable values
                lo = min(v.mean - (v.spread or 0) for v in ok)
                hi = max(v.mean + (v.spread or 0) for v in ok)
                pad = 0.2 * max(hi - lo, 1e-12 * max(abs(hi), 1.0))
                ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(name)
        ax.legend(loc="best", fontsize=8)
        _level_scale(ax, c)
    return fig


def figure_frequencies(c: Comparison) -> Any | None:
    """Shift of each natural frequency from the lowest level, percent."""
    if not c.frequencies:
        return None
    fig, (ax,) = new_figure(height=3.6)
    for k, values in enumerate(c.frequencies):
        values = [v for v in values if v.level is not None]
        if not values:
            continue
        lv = np.array([v.level for v in values])
        f = np.array([v.mean for v in values])
        ax.plot(lv, 100 * (f - f[0]) / f[0], "o-", ms=3,
                label=f"{c.reference_frequencies_hz[k]:.4g} Hz")
    ax.axhline(0.0, color="#444444", lw=0.8)
    ax.set_ylabel("frequency shift from lowest level (%)")
    ax.legend(fontsize=7, ncol=4, loc="best")
    _level_scale(ax, c)
    return fig


def figure_frfs(c: Comparison) -> Any | None:
    """Underlying linear FRF magnitude of every run, blue (lowest level) to red (highest)."""
    if not c.frfs:
        return None
    import matplotlib

    cmap = matplotlib.colormaps["coolwarm"]
    known = [lv for lv in c.levels if lv is not None]
    lo, hi = (min(known), max(known)) if known else (0.0, 1.0)
    fig, (ax,) = new_figure(height=4.0)
    for r in c.frfs:
        t = 0.5 if r.level is None or hi == lo else (r.level - lo) / (hi - lo)
        for k in range(r.frf.shape[1]):
            ax.semilogy(r.frequency_hz, np.abs(r.frf[:, k]), color=cmap(t), lw=0.9)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"|H| at {c.output}")
    ax.grid(True, which="both", alpha=0.3)
    if known:
        sm = matplotlib.cm.ScalarMappable(cmap=cmap, norm=matplotlib.colors.Normalize(lo, hi))
        fig.colorbar(sm, ax=ax, label="force level (RMS)")
    return fig


def run_rows(rows: Sequence[Mapping[str, Any]], coefficient_names: Sequence[str]) -> list[dict]:
    """The campaign table, one dict per input, for the page."""
    out = []
    for r in rows:
        row = {"file": Path(str(r["file"])).name, "status": r.get("status"),
               "level": fmt_g(r.get("force_rms")), "order": r.get("order") or "-",
               "modes": r.get("n_modes") if r.get("n_modes") is not None else "-"}
        for name in coefficient_names:
            mean, std = r.get(name), r.get(f"{name}:std")
            row[name] = "-" if mean is None else f"{mean:.6g} ± {fmt_g(std, 3)}"
        row["error"] = r.get("error") or ""
        out.append(row)
    return out


def render_campaign_report(c: Comparison, rows: Sequence[Mapping[str, Any]], *,
                           title: str = "fnsi-lab campaign") -> str:
    """The whole comparison as one HTML document."""
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    deviations = [{"file": Path(r.file).name, "level": fmt_g(r.level),
                   "deviation from the mean (%)": fmt_g(100 * r.deviation, 3)} for r in c.frfs]
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1><p class='note'>generated {now} by fnsi-lab: "
             f"{len(rows)} runs, {len(c.levels)} force level(s), {len(c.failed)} failed</p>",
             "<h2>Warnings</h2>",
             ("<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in c.warnings) + "</ul>")
             if c.warnings else "<p class='note'>none</p>",
             "<h2>Runs</h2>", html_table(run_rows(rows, list(c.coefficients))),
             "<h2>Nonlinear coefficients against force level</h2>",
             figure_html(figure_coefficients(c),
                          "mean over the runs at each level ± the estimate's spread over "
                          "frequency; grey: every run; red x: not identifiable at that level",
                          "fig-coefficients"),
             "<h2>Natural frequencies against force level</h2>",
             figure_html(figure_frequencies(c),
                          "shift of each underlying linear natural frequency from the lowest "
                          "level (modes matched by nearest frequency)", "fig-frequencies"),
             "<h2>Underlying linear FRFs of all runs</h2>",
             figure_html(figure_frfs(c),
                          "they coincide when the nonlinear model is right: the underlying "
                          "linear system does not depend on the force level", "fig-frfs"),
             html_table(deviations),
             "</body></html>"]
    return "\n".join(parts)
