"""The distortion analysis in Rerun and in an HTML report (``fnsi-lab analyse --rrd/--report``).

Entity tree (:mod:`viewer.paths`), static 2D figures (:mod:`viewer.figure`):

- ``/analysis/levels/<record>``: the classic level plot of each chosen output: output on
  the excited lines, noise (variance of the period average), odd and even detection lines
  (or the non-excited lines of a grid without parity), the realisations' spread, in dB
  against frequency;
- ``/analysis/frf``: the BLA magnitude of every record at each chosen output, overlaid
  (from the lowest level, blue, to the highest, red);
- ``/analysis/trend``: distortion relative to the output, and resonance frequencies,
  against the input level (several records);
- ``/analysis/summary``: the verdicts and resonances as a markdown table.

The report (:func:`render_distortion_report`) draws the same level plots and overlay with
matplotlib, inline SVG in the style of :mod:`viewer.report`. Both take the report object of
:func:`fnsi_lab.analyse` (``records[].outputs[].spectra``, ``frf``, ``levels``) by
attribute; this module does not import ``ident``.
"""

from __future__ import annotations

import datetime as _dt
import html
import os
from typing import Any, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.viewer import paths
from fnsi_lab.viewer.figure import Axis, Panel, Series, canvas_range, stack

APP_ID = "fnsi-lab-analysis"
#: Plot-area height of one stacked panel, canvas units.
PANEL_H = 320.0
#: Level-plot series: spectra key -> (colour, legend, kind).
LEVEL_STYLE: dict[str, tuple[tuple[int, int, int], str, str]] = {
    "output": ((40, 40, 40), "output (excited lines)", "points"),
    "noise": ((140, 140, 140), "noise", "line"),
    "odd": ((213, 94, 0), "odd detection lines", "points"),
    "even": ((0, 114, 178), "even detection lines", "points"),
    "mixed": ((204, 121, 167), "non-excited lines", "points"),
    "realisations": ((230, 159, 0), "realisations' spread", "line"),
}
_HEX = {k: "#%02x%02x%02x" % v[0] for k, v in LEVEL_STYLE.items()}


def _key(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def _db(x: Any) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore"):
        return 10 * np.log10(np.where(x > 0, x, np.nan))


def _level_colour(i: int, n: int) -> tuple[int, int, int]:
    t = 0.0 if n <= 1 else i / (n - 1)
    return (int(0 + 213 * t), int(114 - 20 * t), int(178 - 178 * t))


def record_label(rec: Any) -> str:
    """``file @ RMS`` of one record."""
    name = os.path.basename(rec.path) if rec.path else "arrays"
    return f"{name} @ {rec.input_rms:.4g} RMS"


def chosen_outputs(report: Any, names: Sequence[str] | None = None, n: int = 3) -> list[str]:
    """The outputs drawn: ``names`` if given, else the ``n`` whose distortion stands
    highest above the noise in the highest-level record (its first outputs when none is
    distorted)."""
    recs = report.records
    if names:
        known = {o.name for r in recs for o in r.outputs}
        missing = [x for x in names if x not in known]
        if missing:
            from fnsi_lab.errors import ConfigError
            raise ConfigError(f"{plain.names(missing, quote=True)} not among the outputs "
                              f"({plain.names(sorted(known))})", field="--output",
                              fix="name analysed outputs")
        return list(names)
    top = max(recs, key=lambda r: r.input_rms)

    def excess(o: Any) -> float:
        d = o.odd_distortion_db if o.odd_distortion_db is not None else o.distortion_db
        return -np.inf if d is None else d - o.noise_db

    ranked = sorted(top.outputs, key=excess, reverse=True)
    return [o.name for o in ranked[:n]]


def _output(rec: Any, name: str) -> Any:
    return next(o for o in rec.outputs if o.name == name)


def _has(rec: Any, name: str) -> bool:
    """Whether the record has the output ``name`` (records of one campaign may differ by a
    sensor, records of two structures by every channel)."""
    return any(o.name == name for o in rec.outputs)


def _drawn(rec: Any, names: Sequence[str]) -> list[str]:
    """The chosen outputs this record has; its first three when it has none of them (a
    record of another structure analysed beside the others)."""
    return [n for n in names if _has(rec, n)] or [o.name for o in rec.outputs[:3]]


def level_series(spectra: dict) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(style key, frequency_hz, level_db) of one output's level plot, drawing order."""
    out = [("noise", spectra["band_hz"], _db(spectra["noise_var"]))]
    for kind in ("odd", "even", "mixed"):
        if f"{kind}_hz" in spectra:
            out.append((kind, spectra[f"{kind}_hz"], _db(spectra[f"{kind}_power"])))
    if "realisations_power" in spectra:
        out.append(("realisations", spectra["excited_hz"], _db(spectra["realisations_power"])))
    out.append(("output", spectra["excited_hz"], _db(spectra["output_power"])))
    return out


# ------------------------------------------------------------------------------- Rerun
def level_panels(rec: Any, outputs: Sequence[str]) -> list[Panel]:
    """One level panel per chosen output of one record."""
    panels = []
    for name in _drawn(rec, outputs):
        o = _output(rec, name)
        series = level_series(o.spectra)
        fx = Axis.fit("frequency (Hz)", *[s[1] for s in series], pad=0.0)
        fy = Axis.fit("level (dB)", *[s[2] for s in series])
        p = Panel(_key(name), f"{name}: levels (dB) - {o.verdict[:70]}", fx, fy)
        for key, f, lv in series:
            colour, legend, kind = LEVEL_STYLE[key]
            p.series.append(Series(key, legend, np.asarray(f, float), lv, colour, kind=kind,
                                   width=1.5 if kind == "points" else 1.2,
                                   values={"frequency_hz": np.asarray(f, float),
                                           "level_db": lv}))
        panels.append(p)
    return stack(panels, len(panels), PANEL_H)


def frf_panels(report: Any, outputs: Sequence[str]) -> list[Panel]:
    """BLA magnitude of every record, overlaid, one panel per chosen output."""
    recs = sorted(report.records, key=lambda r: r.input_rms)
    panels = []
    for name in outputs:
        curves = []
        for r in (r for r in recs if _has(r, name)):
            j = [o.name for o in r.outputs].index(name)
            curves.append((r, r.frequency_hz, 20 * np.log10(np.abs(r.frf[:, j]) + 1e-300)))
        p = Panel(_key(name), f"BLA {name} / {recs[0].input_channel} (dB), by level",
                  Axis.fit("frequency (Hz)", *[c[1] for c in curves], pad=0.0),
                  Axis.fit("magnitude (dB)", *[c[2] for c in curves]))
        for i, (r, f, mag) in enumerate(curves):
            p.series.append(Series(f"level_{i}", record_label(r), f, mag,
                                   _level_colour(i, len(curves)), width=1.2,
                                   values={"frequency_hz": f, "magnitude_db": mag}))
        panels.append(p)
    return stack(panels, len(panels), PANEL_H)


def trend_panels(report: Any, outputs: Sequence[str]) -> list[Panel]:
    """Distortion relative to the output, and resonance frequencies, against level."""
    lv = report.levels
    if not lv:
        return []
    x = np.asarray(lv["input_rms"], float)
    log = x.min() > 0 and x.max() / x.min() >= 10
    fx = Axis.fit("input level (RMS)", x, log=log, pad=0.08)
    rows = [r for r in lv["outputs"] if r["name"] in outputs]
    rel = [np.array([np.nan if v is None else v for v in r["relative_distortion_db"]])
           for r in rows]
    p1 = Panel("distortion", "distortion relative to the output (dB) against level", fx,
               Axis.fit("dB", *rel))
    for i, (r, y) in enumerate(zip(rows, rel)):
        p1.series.append(Series(_key(r["name"]), r["name"], x, y, _level_colour(i, len(rows)),
                                width=1.5, values={"input_rms": x, "relative_db": y}))
    shifts = [np.array([np.nan if v is None else v for v in row["frequency_hz"]])
              for row in lv["resonances"] + lv.get("resonances_appearing", [])]
    p2 = Panel("resonances", "resonance frequencies (Hz) against level", fx,
               Axis.fit("frequency (Hz)", *shifts))
    for i, y in enumerate(shifts):
        p2.series.append(Series(f"resonance_{i}", f"resonance {i + 1}", x, y,
                                _level_colour(i, len(shifts)), width=1.5,
                                values={"input_rms": x, "frequency_hz": y}))
    return stack([p1, p2], 2, PANEL_H)


def summary_markdown(report: Any) -> str:
    """Verdicts, levels and resonances of every record as markdown."""
    lines = ["# Distortion analysis", ""]
    for rec in report.records:
        lines += [f"## {record_label(rec)}", "",
                  f"noise: {rec.noise_source}; {rec.n_realizations} realisation(s) x "
                  f"{rec.n_periods} period(s)", "",
                  "| output | output dB | noise dB | odd dB | even dB | verdict |",
                  "|---|---|---|---|---|---|"]
        for o in rec.outputs:
            f = ["-" if v is None else f"{v:.1f}" for v in
                 (o.output_db, o.noise_db, o.odd_distortion_db, o.even_distortion_db)]
            lines.append(f"| {o.name} | {' | '.join(f)} | {o.verdict} |")
        res = ", ".join(f"{r.frequency_hz:.4g} Hz ({100 * r.damping_ratio:.2f} %)"
                        for r in rec.resonances) or "none found"
        lines += ["", f"resonances: {res}", ""]
    return "\n".join(lines)


def save_rrd(report: Any, path: str | os.PathLike[str], *,
             outputs: Sequence[str] | None = None) -> None:
    """Write the analysis as a Rerun recording with its blueprint.

    Parameters
    ----------
    report : DistortionReport
        From :func:`fnsi_lab.analyse` (per-line spectra kept).
    path : path-like
        The ``.rrd`` file (written through a temporary name).
    outputs : sequence of str, optional
        Outputs drawn (default :func:`chosen_outputs`).
    """
    import rerun as rr
    import rerun.blueprint as rrb

    from fnsi_lab.outputs import atomic_output
    from fnsi_lab.viewer.figure import Figure

    names = chosen_outputs(report, outputs)
    figures = {f"{paths.ANALYSIS_LEVELS}/{_key(record_label(r))}": level_panels(r, names)
               for r in report.records}
    figures[paths.ANALYSIS_FRF] = frf_panels(report, names)
    trend = trend_panels(report, names)
    if trend:
        figures[paths.ANALYSIS_TREND] = trend

    def view(origin: str, name: str, rows: int) -> rrb.Spatial2DView:
        x_range, y_range = canvas_range(max(rows, 1), PANEL_H)
        return rrb.Spatial2DView(origin=origin, name=name, background=[255, 255, 255],
                                 visual_bounds=rrb.VisualBounds2D(x_range=x_range,
                                                                  y_range=y_range))

    level_views = [view(origin, origin.rsplit("/", 1)[-1], len(panels))
                   for origin, panels in figures.items()
                   if origin.startswith(paths.ANALYSIS_LEVELS)]
    tabs = [rrb.Tabs(*level_views, name="levels"),
            view(paths.ANALYSIS_FRF, "BLA by level", len(names))]
    if trend:
        tabs.append(view(paths.ANALYSIS_TREND, "against level", 2))
    tabs.append(rrb.TextDocumentView(origin=paths.ANALYSIS_SUMMARY, name="verdicts"))
    blueprint = rrb.Blueprint(rrb.Tabs(*tabs), rrb.SelectionPanel(state="collapsed"),
                              collapse_panels=False)
    with atomic_output(path, "wb") as fh:
        rec = rr.RecordingStream(APP_ID)
        rec.set_sinks(rr.FileSink(fh.name), default_blueprint=blueprint)
        try:
            for origin, panels in figures.items():
                Figure(rec, origin).log(panels)
            rec.log(paths.ANALYSIS_SUMMARY,
                    rr.TextDocument(summary_markdown(report),
                                    media_type=rr.MediaType.MARKDOWN), static=True)
            rec.flush()
        finally:
            rec.disconnect()


# ------------------------------------------------------------------------------ report
def figure_levels(rec: Any, output: str) -> Any:
    """The classic level plot of one output of one record (matplotlib figure)."""
    from fnsi_lab.viewer.html import new_figure

    o = _output(rec, output)
    fig, (ax,) = new_figure(9.0, 4.0)
    for key, f, lv in level_series(o.spectra):
        colour, legend, kind = LEVEL_STYLE[key]
        style = dict(ls="none", marker=".", ms=3.0) if kind == "points" else dict(lw=1.0)
        ax.plot(f, lv, color=_HEX[key], label=legend, **style)
    ax.set_title(f"{output} - {record_label(rec)}")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("level (dB re 1 output unit)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return fig


def figure_frf_overlay(report: Any, output: str) -> Any:
    """BLA magnitude of every record at one output, by level (matplotlib figure)."""
    from fnsi_lab.viewer.html import new_figure

    recs = sorted((r for r in report.records if _has(r, output)), key=lambda r: r.input_rms)
    fig, (ax,) = new_figure(9.0, 4.0)
    for i, r in enumerate(recs):
        j = [o.name for o in r.outputs].index(output)
        c = _level_colour(i, len(recs))
        ax.plot(r.frequency_hz, 20 * np.log10(np.abs(r.frf[:, j]) + 1e-300), lw=1.0,
                color="#%02x%02x%02x" % c, label=record_label(r))
        for res in r.resonances:
            ax.axvline(res.frequency_hz, color="#%02x%02x%02x" % c, lw=0.5, alpha=0.5)
    ax.set_title(f"BLA {output} / {recs[0].input_channel}, by level (lines: resonances)")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("magnitude (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def distortion_section(report: Any, outputs: Sequence[str] | None = None) -> str:
    """The report section (HTML): verdict tables, level plots, BLA overlay, level trend."""
    from fnsi_lab.viewer.html import figure_html, html_table

    names = chosen_outputs(report, outputs)
    parts = ["<h2 id='distortion'>Nonlinear distortion analysis</h2>",
             "<p class='note'>Per line: the output on the excited lines, the noise (variance "
             "of the period average), the odd and even detection lines (noise plus "
             "distortion) and the realisations' spread. A verdict is 'nonlinear' when a "
             "window of lines stands above the noise beyond the false-alarm level "
             f"{report.records[0].alpha:g} per record.</p>"]
    for rec in report.records:
        rows = [{"output": o.name, "output dB": _f(o.output_db), "noise dB": _f(o.noise_db),
                 "odd dB": _f(o.odd_distortion_db), "even dB": _f(o.even_distortion_db),
                 "verdict": o.verdict} for o in rec.outputs]
        res = [{"frequency (Hz)": f"{r.frequency_hz:.5g}",
                "damping (%)": f"{100 * r.damping_ratio:.3g}", "method": r.method}
               for r in rec.resonances]
        parts += [f"<h3>{html.escape(record_label(rec))}</h3>",
                  f"<p class='note'>noise: {html.escape(rec.noise_source)}; "
                  f"{rec.n_realizations} realisation(s) x {rec.n_periods} period(s)</p>",
                  html_table(rows), html_table(res)]
        for name in _drawn(rec, names):
            parts.append(figure_html(figure_levels(rec, name),
                                      f"levels of {name} against frequency",
                                      f"fig-levels-{_key(record_label(rec))}-{_key(name)}"))
    if len(report.records) > 1:
        parts.append("<h3>By level</h3>")
        for name in names:
            parts.append(figure_html(figure_frf_overlay(report, name),
                                      f"BLA of {name} at every level",
                                      f"fig-bla-{_key(name)}"))
        rows = []
        levels = report.levels or {"resonances": []}   # None: not levels of one structure
        for i, row in enumerate(levels["resonances"] + levels.get("resonances_appearing", [])):
            rows.append({"resonance": i + 1, "frequency (Hz)": _list(row["frequency_hz"], 5),
                         "shift (%)": _list(row["shift_percent"], 3),
                         "damping (%)": _list([None if z is None else 100 * z
                                               for z in row["damping_ratio"]], 3),
                         "shape (MAC)": _list(row.get("mac", []), 2)})
        parts.append(html_table(rows))
        parts.append("<p>Each row is one resonance, one entry per level (- where it was not "
                     "found): followed from level to level where its frequency is the nearest "
                     "and its operating deflection shape agrees with its previous sighting "
                     "(MAC, 1 = the same shape, at least 0.8). Rows that start with - are "
                     "resonances first seen at a higher level; their shift is against that "
                     "level.</p>")
    return "\n".join(parts)


def _f(x: Any) -> str:
    return "-" if x is None else f"{x:.1f}"


def _list(values: Sequence[Any], digits: int) -> str:
    return ", ".join("-" if v is None else f"{v:.{digits}g}" for v in values)


def render_distortion_report(report: Any, outputs: Sequence[str] | None = None, *,
                             title: str = "fnsi-lab distortion analysis") -> str:
    """One offline HTML page holding :func:`distortion_section`."""
    from fnsi_lab.viewer.html import CSS

    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    return "\n".join([
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1><p class='note'>generated {now} by fnsi-lab</p>",
        distortion_section(report, outputs), "</body></html>"])


def write_report(report: Any, path: str | os.PathLike[str], *,
                 outputs: Sequence[str] | None = None) -> None:
    """Write :func:`render_distortion_report` to ``path`` (through a temporary file)."""
    from fnsi_lab.outputs import atomic_output

    text = render_distortion_report(report, outputs)
    with atomic_output(path) as fh:
        fh.write(text)
