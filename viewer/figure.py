"""Line and scatter plots drawn as Rerun 2D primitives, readable whatever the timeline.

Rerun plots time-series views against the one timeline selected in the time panel, so a
plot of FRF magnitude against frequency, or pole frequency against model order, is empty
while the panel shows the acquisition time (see ``docs/live.md``). These plots are therefore
drawn in a ``Spatial2DView``: frame, grid, tick labels, axis titles, legend and data are
static 2D lines and points, shown whatever the time cursor.

The numerical part is pure (:class:`Axis`, :func:`nice_ticks`, :class:`Panel` map data to
canvas coordinates); :class:`Figure` turns a panel's content into archetypes and logs
them. Canvas coordinates: x to the right, y *down* (Rerun's 2D convention), one canvas
unit per pixel at 100 % zoom; each panel is :data:`PANEL_W` x :data:`PANEL_H` units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import rerun as rr

#: Plot area of one panel in canvas units (the view scales it to fit).
PANEL_W, PANEL_H = 1000.0, 420.0
#: Room around the plot area for tick labels, axis titles and the title.
MARGIN_LEFT, MARGIN_BOTTOM, MARGIN_TOP = 120.0, 110.0, 50.0
#: Width of the legend column right of the plot area.
LEGEND_W = 240.0
MARGIN_RIGHT = LEGEND_W + 20.0

_FRAME = (70, 70, 70)
_GRID = (225, 225, 225)
_TEXT = (55, 55, 55)  # label boxes: dark grey, the viewer writes white text on them


# ---------------------------------------------------------------------------- pure part
def nice_ticks(lo: float, hi: float, target: int = 6) -> np.ndarray:
    """Round tick values covering ``[lo, hi]`` (steps 1, 2, 2.5 or 5 times a power of 10).

    Returns
    -------
    ndarray, shape (n_ticks,)
        Ticks inside ``[lo, hi]`` (about ``target`` of them).
    """
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if np.isfinite(lo) else np.zeros(0)
    raw = (hi - lo) / max(target, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * power >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    ticks = np.arange(first, hi + step * 1e-9, step)
    return np.round(ticks / step) * step  # no 0.30000000000000004


def format_tick(value: float, step: float) -> str:
    """Short label of a tick: as many decimals as the step needs, no trailing noise."""
    if value == 0:
        return "0"
    if abs(value) >= 1e5 or abs(value) < 1e-3:
        return f"{value:.3g}"
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    return f"{value:.{decimals}f}"


@dataclass(frozen=True)
class Axis:
    """One plot axis.

    Attributes
    ----------
    label : str
        Axis title with its unit (``"frequency (Hz)"``).
    lo, hi : float
        Visible data range (log axes: positive values).
    log : bool
        Logarithmic axis (decade ticks ``1e-3, 1e-2...``).
    """

    label: str
    lo: float
    hi: float
    log: bool = False

    @classmethod
    def fit(cls, label: str, *values: Any, log: bool = False, pad: float = 0.04,
            include: Sequence[float] = ()) -> "Axis":
        """Axis covering every finite value of ``values`` (plus ``include``), padded."""
        parts = [np.asarray(v, dtype=float).ravel() for v in values if v is not None]
        v = np.concatenate(parts + [np.asarray(include, dtype=float)]) if parts or include \
            else np.zeros(0)
        v = v[np.isfinite(v) & (v > 0)] if log else v[np.isfinite(v)]
        if v.size == 0:
            return cls(label, 1.0, 10.0, log) if log else cls(label, 0.0, 1.0, log)
        lo, hi = float(v.min()), float(v.max())
        if log:
            a, b = math.log10(lo), math.log10(hi)
            if b - a < 1.0:
                a, b = a - 0.5, b + 0.5
            span = b - a
            return cls(label, 10 ** (a - pad * span), 10 ** (b + pad * span), True)
        if hi == lo:
            lo, hi = lo - max(abs(lo), 1.0) * 0.5, hi + max(abs(hi), 1.0) * 0.5
        span = hi - lo
        return cls(label, lo - pad * span, hi + pad * span, False)

    def unit(self, values: Any) -> np.ndarray:
        """Data -> position along the axis in [0, 1] (NaN for values a log axis cannot show)."""
        v = np.asarray(values, dtype=float)
        if self.log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
            lo, hi = math.log10(self.lo), math.log10(self.hi)
        else:
            lo, hi = self.lo, self.hi
        return (v - lo) / (hi - lo)

    def ticks(self, target: int = 6) -> tuple[np.ndarray, list[str]]:
        """Tick values inside the range (about ``target`` of them) and their labels."""
        if self.log:
            a, b = math.ceil(math.log10(self.lo) - 1e-9), math.floor(math.log10(self.hi) + 1e-9)
            every = max(1, math.ceil((b - a + 1) / 8))
            exps = np.arange(a, b + 1, every)
            return 10.0 ** exps, [f"1e{int(e)}" if e not in (0, 1, 2) else f"{10 ** int(e)}"
                                  for e in exps]
        t = nice_ticks(self.lo, self.hi, target)
        step = float(t[1] - t[0]) if t.size > 1 else 1.0
        return t, [format_tick(float(x), step) for x in t]


@dataclass
class Series:
    """One legend entry: a line or a set of markers, in data units."""

    key: str  # entity name under the panel
    name: str  # legend text
    x: np.ndarray
    y: np.ndarray
    color: tuple[int, int, int]
    kind: str = "line"  # "line", "dashed" (a line drawn in dashes) or "points"
    width: float = 1.0  # line width or marker radius, ui points
    legend: bool = True
    #: Points only: a text written at each point (its value, e.g. ``"28.3 Hz"``) and one
    #: colour per point (else ``color``).
    labels: list[str] = field(default_factory=list)
    point_colors: list[tuple[int, int, int]] = field(default_factory=list)
    #: Physical values stored with the series (``rr.AnyValues``, one per point or line
    #: vertex) so that the dataframe API returns the data, not only canvas coordinates.
    values: dict[str, Any] = field(default_factory=dict)


@dataclass
class Panel:
    """One plot: two axes, a title, series; ``top`` places it in a stacked figure."""

    key: str  # entity name under the figure ("" = the figure's origin itself)
    title: str
    x: Axis
    y: Axis
    series: list[Series] = field(default_factory=list)
    top: float = 0.0
    height: float = PANEL_H
    vlines: list[tuple[float, str, tuple[int, int, int]]] = field(default_factory=list)

    def to_canvas(self, x: Any, y: Any) -> np.ndarray:
        """Data -> canvas coordinates, shape (n, 2); y grows downwards."""
        px = self.x.unit(x) * PANEL_W
        py = self.top + (1.0 - self.y.unit(y)) * self.height
        return np.stack([np.ravel(px), np.ravel(py)], axis=-1)


def row_height(panel_h: float = PANEL_H) -> float:
    """Canvas height of one stacked row: plot area plus its title and tick-label room."""
    return panel_h + MARGIN_TOP + MARGIN_BOTTOM


def canvas_range(rows: int = 1, panel_h: float = PANEL_H) -> tuple[list[float], list[float]]:
    """``(x_range, y_range)`` of a figure of ``rows`` rows (its ``VisualBounds2D``).

    A fixed canvas per view: the blueprint frames it before any data arrive.
    """
    return ([-MARGIN_LEFT, PANEL_W + MARGIN_RIGHT],
            [-MARGIN_TOP, rows * row_height(panel_h) - MARGIN_TOP + 20.0])


def stack(panels: Sequence[Panel], rows: int | None = None,
          panel_h: float = PANEL_H) -> list[Panel]:
    """Share the canvas of ``rows`` rows (default one per panel) among ``panels``, top down."""
    n = max(len(panels), 1)
    total = (rows or n) * row_height(panel_h)
    share = total / n
    for k, p in enumerate(panels):
        p.top = k * share
        p.height = max(share - MARGIN_TOP - MARGIN_BOTTOM, 60.0)
    return list(panels)


def _segments(xy: np.ndarray) -> list[np.ndarray]:
    """Split a polyline at non-finite points (gaps) and clip to the plot area."""
    ok = np.all(np.isfinite(xy), axis=1)
    out, start = [], None
    for i, good in enumerate(np.append(ok, False)):
        if good and start is None:
            start = i
        elif not good and start is not None:
            if i - start >= 1:
                out.append(xy[start:i])
            start = None
    return out


def dashes(polyline: np.ndarray, on: float = 14.0, off: float = 9.0) -> list[np.ndarray]:
    """Cut a finite polyline, shape (n, 2), into dashes ``on`` long with gaps ``off`` long
    (canvas units, measured along the line).

    Returns
    -------
    list of ndarray, each shape (m, 2)
        The dashes, each following the line (corners kept).
    """
    xy = np.asarray(polyline, dtype=float)
    if len(xy) < 2:
        return [xy] if len(xy) else []
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    out = []
    for start in np.arange(0.0, s[-1], on + off):
        end = min(start + on, s[-1])
        inner = (s > start) & (s < end)
        at = np.concatenate([[start], s[inner], [end]])
        out.append(np.c_[np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])])
    return out


# ---------------------------------------------------------------------------- Rerun part
class Figure:
    """Log :class:`Panel` s under one entity (one ``Spatial2DView`` origin).

    Everything is static: a plot shows the newest data whatever the time cursor, and a
    re-log (next identification update) replaces it.
    """

    def __init__(self, rec: rr.RecordingStream, origin: str) -> None:
        self.rec = rec
        self.origin = origin.rstrip("/")

    def log(self, panels: Sequence[Panel]) -> None:
        """Replace the figure's content by ``panels``."""
        for panel in panels:
            base = f"{self.origin}/{panel.key}" if panel.key else self.origin
            self._frame(base, panel)
            for s in panel.series:
                self._series(f"{base}/{s.key}", panel, s)
            self._legend(base, panel)

    def _frame(self, base: str, p: Panel) -> None:
        top, w, h = p.top, PANEL_W, p.height
        xt, xl = p.x.ticks(8)  # the plot is wider than tall: more ticks along x
        yt, yl = p.y.ticks()
        xu, yu = p.x.unit(xt) * w, top + (1 - p.y.unit(yt)) * h
        grid = [np.array([[x, top], [x, top + h]]) for x in xu] + \
               [np.array([[0, y], [w, y]]) for y in yu]
        rec = self.rec
        rec.log(f"{base}/axes/grid", rr.LineStrips2D(grid, colors=[_GRID],
                                                      radii=rr.Radius.ui_points(0.5),
                                                      draw_order=-10.0), static=True)
        box = np.array([[0, top], [w, top], [w, top + h], [0, top + h], [0, top]])
        rec.log(f"{base}/axes/frame", rr.LineStrips2D([box], colors=[_FRAME],
                                                       radii=rr.Radius.ui_points(0.8),
                                                       draw_order=-5.0), static=True)
        # the title names the y quantity: text cannot be rotated, and a y label above the
        # axis would collide with the title
        labels = list(xl) + list(yl) + [p.x.label, p.title]
        pos = np.concatenate([
            np.c_[xu, np.full(len(xu), top + h + 14)],
            np.c_[np.full(len(yu), -55.0), yu - 10],
            [[w / 2, top + h + 64], [w / 2, top - 44]]])  # axis title clear of the ticks
        rec.log(f"{base}/axes/labels", rr.Points2D(pos, labels=labels, colors=[_TEXT],
                                                    radii=rr.Radius.ui_points(0.01),
                                                    show_labels=True), static=True)
        for k, (x, text, color) in enumerate(p.vlines):
            u = float(p.x.unit([x])[0]) * w
            if np.isfinite(u) and 0 <= u <= w:
                rec.log(f"{base}/axes/marker_{k}",
                        rr.LineStrips2D([[[u, top], [u, top + h]]], colors=[color],
                                        radii=rr.Radius.ui_points(1.0), labels=[text],
                                        show_labels=True, draw_order=-1.0), static=True)

    def _series(self, entity: str, p: Panel, s: Series) -> None:
        xy = p.to_canvas(s.x, s.y)
        inside = (xy[:, 0] >= -1) & (xy[:, 0] <= PANEL_W + 1) & \
                 (xy[:, 1] >= p.top - 1) & (xy[:, 1] <= p.top + p.height + 1)
        if s.kind == "points":
            keep = inside & np.all(np.isfinite(xy), axis=1)
            colors = [c for c, k in zip(s.point_colors, keep) if k] if s.point_colors \
                else [s.color]
            labels = [t for t, k in zip(s.labels, keep) if k] if s.labels else None
            self.rec.log(entity, rr.Points2D(xy[keep], colors=colors, labels=labels,
                                             show_labels=bool(labels),
                                             radii=rr.Radius.ui_points(s.width)), static=True)
        else:
            xy = np.where(inside[:, None], xy, np.nan)
            strips = _segments(xy)
            if s.kind == "dashed":
                strips = [d for strip in strips for d in dashes(strip)]
            self.rec.log(entity, rr.LineStrips2D(strips, colors=[s.color],
                                                 radii=rr.Radius.ui_points(s.width)), static=True)
        if s.values:  # every value, also those outside the visible range
            self.rec.log(entity, rr.AnyValues(**{k: np.asarray(v) for k, v in s.values.items()}),
                         static=True)

    def _legend(self, base: str, p: Panel) -> None:
        """Series names in boxes of the series' colours, in a column right of the plot."""
        entries = [s for s in p.series if s.legend]
        if not entries:
            return
        pos = np.array([[PANEL_W + LEGEND_W / 2 + 10, p.top + 4 + 48.0 * i]
                        for i in range(len(entries))])
        self.rec.log(f"{base}/legend", rr.Points2D(pos, labels=[s.name for s in entries],
                                                   colors=[s.color for s in entries],
                                                   radii=rr.Radius.ui_points(0.01),
                                                   show_labels=True), static=True)
