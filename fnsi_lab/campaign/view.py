"""The campaign comparison as a Rerun recording (``fnsi-lab campaign --rrd``).

Three figures drawn with :mod:`fnsi_lab.viewer.figure` (static 2D plots, readable
whatever the timeline) and a summary:

- ``/campaign/coefficients``: each nonlinear coefficient against force level: the mean
  over the runs, mean +- spread, every run, and the levels where it is not identifiable;
- ``/campaign/frequencies``: natural frequencies against force level (every run), and
  their shift from the lowest level in percent;
- ``/campaign/frf``: the underlying linear FRF magnitude of every run at one output,
  overlaid (coloured from the lowest level, blue, to the highest, red);
- ``/campaign/summary``: the text of :func:`~fnsi_lab.campaign.compare.format_comparison`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from fnsi_lab.campaign.compare import Comparison, LevelValue
from fnsi_lab.viewer.figure import Axis, Panel, Series, canvas_range, stack

APP_ID = "fnsi-lab-campaign"
COEFFICIENTS = "/campaign/coefficients"
FREQUENCIES = "/campaign/frequencies"
FRF = "/campaign/frf"
SUMMARY = "/campaign/summary"

#: Plot-area height of one stacked panel, canvas units.
PANEL_H = 320.0

_BLUE, _RED, _GREY, _LIGHT = (0, 114, 178), (213, 94, 0), (120, 120, 120), (150, 190, 220)
_PALETTE = ((0, 114, 178), (213, 94, 0), (0, 158, 115), (204, 121, 167), (230, 159, 0),
            (86, 180, 233), (140, 86, 75), (127, 127, 127), (188, 189, 34), (23, 190, 207))


def _key(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def _level_axis(c: Comparison) -> Axis:
    known = [lv for lv in c.levels if lv is not None]
    # a sweep over a decade or more reads better on a log axis
    log = len(known) > 1 and min(known) > 0 and max(known) / min(known) >= 10
    force = c.units.get("force")
    return Axis.fit(f"force level (RMS, {force})" if force else "force level (RMS)", known,
                    log=log, pad=0.08)


def _known(values: Sequence[LevelValue]) -> list[LevelValue]:
    return [v for v in values if v.level is not None]


def coefficient_panels(c: Comparison) -> list[Panel]:
    """One panel per coefficient against force level."""
    x = _level_axis(c)
    panels = []
    for name, values in c.coefficients.items():
        vals = _known(values)
        if not vals:
            continue
        lv = np.array([v.level for v in vals], float)
        mean = np.array([v.mean for v in vals])
        spread = np.array([v.spread if v.spread is not None else np.nan for v in vals])
        run_x = np.concatenate([[v.level] * len(v.runs) for v in vals])
        run_y = np.concatenate([v.runs for v in vals])
        bad = np.array([v.not_identifiable is not None for v in vals])
        ok = ~bad
        unit = (c.units.get("coefficients") or {}).get(name)
        y = Axis.fit(f"{name} ({unit})" if unit else name, mean[ok] if ok.any() else mean,
                     (mean + spread)[ok] if ok.any() else None,
                     (mean - spread)[ok] if ok.any() else None, run_y[np.isin(run_x, lv[ok])])
        series = [Series("mean", "mean over runs", lv, mean, _BLUE, width=1.5),
                  Series("mean_plus_spread", "mean ± spread", lv, mean + spread, _LIGHT),
                  Series("mean_minus_spread", "", lv, mean - spread, _LIGHT, legend=False),
                  Series("runs", "each run", run_x, run_y, _GREY, kind="points", width=3.0,
                         values={"force_rms": run_x, name: run_y})]
        if bad.any():
            series.append(Series("not_identifiable", "not identifiable", lv[bad], mean[bad],
                                 _RED, kind="points", width=6.0))
        panels.append(Panel(_key(name), y.label, x, y, series))
    return stack(panels, rows=max(len(panels), 1), panel_h=PANEL_H)


def frequency_panels(c: Comparison) -> list[Panel]:
    """Natural frequencies against level, and their shift from the lowest level (%)."""
    x = _level_axis(c)
    freq_series, shift_series, all_f, all_s = [], [], [], []
    for k, values in enumerate(c.frequencies):
        vals = _known(values)
        if not vals:
            continue
        color = _PALETTE[k % len(_PALETTE)]
        lv = np.array([v.level for v in vals], float)
        mean = np.array([v.mean for v in vals])
        run_x = np.concatenate([[v.level] * len(v.runs) for v in vals])
        run_y = np.concatenate([v.runs for v in vals])
        shift = 100.0 * (mean - mean[0]) / mean[0]
        label = f"mode {k + 1} ({c.reference_frequencies_hz[k]:.4g} Hz)"
        freq_series += [Series(f"mode_{k + 1}/mean", label, lv, mean, color, width=1.2),
                        Series(f"mode_{k + 1}/runs", "", run_x, run_y, color, kind="points",
                               width=2.5, legend=False,
                               values={"force_rms": run_x, "frequency_hz": run_y})]
        # same colours as above: one legend (ten modes fill a panel's height)
        shift_series.append(Series(f"mode_{k + 1}", label, lv, shift, color, width=1.2,
                                   legend=False))
        all_f.append(run_y)
        all_s.append(shift)
    panels = [Panel("frequency", "natural frequency (Hz)", x,
                    Axis.fit("frequency (Hz)", *all_f), freq_series),
              Panel("shift", "shift from the lowest level (%)", x,
                    Axis.fit("shift (%)", *all_s, include=[0.0]), shift_series)]
    return stack(panels, rows=2, panel_h=PANEL_H)


def frf_panels(c: Comparison) -> list[Panel]:
    """Underlying linear FRF magnitude (dB) of every run at one output, per input."""
    from fnsi_lab.viewer.log import magnitude_db

    known = [lv for lv in c.levels if lv is not None]
    lo, hi = (min(known), max(known)) if known else (0.0, 1.0)
    n_inputs = max((r.frf.shape[1] for r in c.frfs), default=0)
    panels = []
    for k in range(n_inputs):
        series, mags, freqs = [], [], []
        for i, r in enumerate(c.frfs):
            t = 0.0 if r.level is None or hi == lo else (r.level - lo) / (hi - lo)
            color = tuple(int(round(a + (b - a) * t)) for a, b in zip(_BLUE, _RED))
            mag = magnitude_db(r.frf[:, k])
            level = "?" if r.level is None else f"{r.level:g}"
            series.append(Series(f"run_{i}_{_key(Path(r.file).stem)}",
                                 f"{Path(r.file).stem} (level {level})", r.frequency_hz, mag,
                                 color, legend=len(c.frfs) <= 12))
            mags.append(mag)
            freqs.append(r.frequency_hz)
        name = c.inputs[k] if k < len(c.inputs) else f"input {k}"
        db = f"dB re 1 {c.units['frf']}" if c.units.get("frf") else "dB"
        panels.append(Panel(_key(name), f"|H| {c.output} / {name} ({db}), underlying linear",
                            Axis.fit("frequency (Hz)", *freqs, pad=0.0),
                            Axis.fit(db, *mags), series))
    return stack(panels, rows=max(len(panels), 1), panel_h=PANEL_H)


def save_campaign_rrd(c: Comparison, path: str | os.PathLike[str], *, summary: str = "") -> None:
    """Write the comparison to a Rerun recording (atomically: temp file, then rename).

    Parameters
    ----------
    c : Comparison
    path : path-like
        The ``.rrd`` file.
    summary : str
        Markdown shown in the summary view (default: none).
    """
    import rerun as rr
    import rerun.blueprint as rrb

    from fnsi_lab.outputs import atomic_output
    from fnsi_lab.viewer.figure import Figure

    figures = {COEFFICIENTS: coefficient_panels(c),
               FREQUENCIES: frequency_panels(c) if c.frequencies else [],
               FRF: frf_panels(c)}

    def view(origin: str, name: str, rows: int) -> rrb.Spatial2DView:
        x_range, y_range = canvas_range(max(rows, 1), PANEL_H)
        return rrb.Spatial2DView(origin=origin, name=name, background=[255, 255, 255],
                                 visual_bounds=rrb.VisualBounds2D(x_range=x_range,
                                                                  y_range=y_range))

    blueprint = rrb.Blueprint(
        rrb.Tabs(view(COEFFICIENTS, "coefficients vs force level", len(figures[COEFFICIENTS])),
                 view(FREQUENCIES, "natural frequencies vs force level", 2),
                 view(FRF, "underlying linear FRFs, all runs", len(figures[FRF])),
                 rrb.TextDocumentView(origin=SUMMARY, name="summary")),
        rrb.SelectionPanel(state="collapsed"), collapse_panels=False)
    # rerun writes the file itself: it gets atomic_output's temporary name, which is
    # renamed onto ``path`` once the stream is flushed and closed
    with atomic_output(path, "wb") as fh:
        rec = rr.RecordingStream(APP_ID)
        rec.set_sinks(rr.FileSink(fh.name), default_blueprint=blueprint)
        try:
            for origin, panels in figures.items():
                if panels:
                    Figure(rec, origin).log(panels)
            if summary:
                rec.log(SUMMARY, rr.TextDocument(summary, media_type=rr.MediaType.MARKDOWN),
                        static=True)
            rec.flush()
        finally:
            rec.disconnect()
