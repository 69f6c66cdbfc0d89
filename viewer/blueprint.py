"""The one declarative Rerun blueprint of fnsi-lab; view origins come from :mod:`viewer.paths`.

Layout: a "Live" tab (signals with a bounded, cursor-relative window, the modes of the
latest update, natural frequencies and coefficients per update over the whole recording,
status, summary and log), an "Order" tab (stabilisation diagram, information criterion) and a
"Frequency" tab (FRF magnitude and phase over the MDI per pole, the nonlinear coefficients'
Re and Im).

Rerun has one global timeline (the time panel's) and a time-series view plots against it.
So only the Live tab uses time-series views, on ``acq_time`` (the timeline selected when
the viewer opens); the Order and Frequency tabs are 2D views of static figures
(:mod:`viewer.figure`), which show their content whatever timeline or cursor is selected
(``docs/live.md``).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import rerun.blueprint as rrb

from fnsi_lab.viewer import paths
from fnsi_lab.viewer.figure import canvas_range
from fnsi_lab.viewer.log import FIGURE_LAYOUT

#: Seconds of signal history shown behind the time cursor (a bounded window keeps the
#: viewer responsive at kHz rates).
DEFAULT_WINDOW_S = 20.0


#: Seconds past the time cursor that the per-update views show on ``acq_time``: the newest
#: update's markers sit inside the plot, clear of its right edge. The Live tab reads on
#: ``acq_time`` (the signal views too): a view range holds one offset for every timeline,
#: and on the ``update`` sequence these seconds would be 5e9 steps (docs/live.md).
UPDATE_MARGIN_S = 5.0


#: Channels above which a signal view hides its legend: a column of 39 names covers the
#: curves (the channels are told apart by colour family per direction; names on hover).
MAX_LEGEND_CHANNELS = 8


def blueprint(groups: Sequence[str] = ("force", "displacement"), *,
              window_s: float = DEFAULT_WINDOW_S, active_tab: int = 0,
              group_sizes: Mapping[str, int] | None = None,
              group_units: Mapping[str, str] | None = None) -> rrb.Blueprint:
    """Build the blueprint.

    Parameters
    ----------
    groups : sequence of str
        Channel groups logged under :data:`viewer.paths.SIGNALS` (one view each).
    window_s : float
        Width of the visible signal window behind the cursor, seconds.
    active_tab : int
        Tab shown first: 0 Live, 1 Order, 2 Frequency (every tab reads on ``acq_time``).
    group_sizes : mapping of str to int, optional
        Channels per group: a group of more than :data:`MAX_LEGEND_CHANNELS` hides its
        legend (unknown: shown).
    group_units : mapping of str to str, optional
        Unit of each group's values, shown in its view's name (``signals: displacement
        (mm)``).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    window = rrb.VisibleTimeRange(
        paths.TIME_ACQ,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-float(window_s)),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0))

    def figure(origin: str, name: str) -> rrb.Spatial2DView:
        x_range, y_range = canvas_range(*FIGURE_LAYOUT[origin])
        return rrb.Spatial2DView(origin=origin, name=name, background=[255, 255, 255],
                                 visual_bounds=rrb.VisualBounds2D(x_range=x_range,
                                                                  y_range=y_range))

    sizes, units = dict(group_sizes or {}), dict(group_units or {})
    signal_views = [
        rrb.TimeSeriesView(origin=paths.signal_group(g),
                           name=f"signals: {g}" + (f" ({units[g]})" if units.get(g) else ""),
                           time_ranges=[window],
                           plot_legend=rrb.PlotLegend(
                               visible=sizes.get(g, 0) <= MAX_LEGEND_CHANNELS))
        for g in groups
    ] or [rrb.TimeSeriesView(origin=paths.SIGNALS, name="signals", time_ranges=[window])]
    # on acq_time the per-update views span the whole recording and UPDATE_MARGIN_S past
    # the cursor, so the first update is a column of markers inside a labelled time axis
    # (not one of a single tick, nor cut in half on the view's right edge)
    history = rrb.TimeAxis(view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=UPDATE_MARGIN_S)))
    live = rrb.Horizontal(
        rrb.Vertical(*signal_views),
        rrb.Vertical(
            # the modes of the latest update, labelled: reads with one update
            figure(paths.MODES, "modes of the latest update"),
            # one series per mode: a legend of 9+ modes is clipped in this short view and
            # covers the markers; the names show on hover
            rrb.TimeSeriesView(origin=paths.CONVERGENCE_FREQUENCIES,
                               name="natural frequencies per update (Hz; hover: mode)",
                               plot_legend=rrb.PlotLegend(visible=False), axis_x=history),
            rrb.TimeSeriesView(origin=paths.CONVERGENCE_COEFFICIENTS,
                               name="coefficients per update (mean Re)", axis_x=history),
            rrb.TimeSeriesView(origin=paths.STATUS, name="status (hover: quantity)",
                               contents=[f"{paths.STATUS}/**", f"- {paths.STATUS_LOG}"],
                               plot_legend=rrb.PlotLegend(visible=False), axis_x=history),
            rrb.Tabs(rrb.TextDocumentView(origin=paths.SUMMARY, name="summary"),
                     rrb.TextLogView(origin=paths.STATUS_LOG, name="log")),
            row_shares=[4, 2, 2, 2, 3],
        ),
        column_shares=[3, 2], name="Live")

    order = rrb.Horizontal(
        figure(paths.STABILISATION, "stabilisation diagram"),
        figure(paths.ORDER, "information criterion"),
        column_shares=[3, 2], name="Order")
    # the coefficients (Re over Im of each) take the right column's full height
    frequency = rrb.Horizontal(
        rrb.Vertical(figure(paths.FRF, "driving-point FRF"), figure(paths.MDI, "MDI per pole"),
                     row_shares=[2, 1]),
        figure(paths.COEFFICIENTS, "nonlinear coefficients (Re solid, Im dashed)"),
        column_shares=[1, 1], name="Frequency")
    return rrb.Blueprint(
        rrb.Tabs(live, order, frequency, active_tab=active_tab),
        rrb.TimePanel(timeline=paths.TIME_ACQ),
        rrb.SelectionPanel(state="collapsed"),
        collapse_panels=False,
    )
