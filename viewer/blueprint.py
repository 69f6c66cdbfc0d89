"""The one declarative Rerun blueprint of fnsi-lab; view origins come from :mod:`viewer.paths`.

Layout: a "Live" tab (signals with a bounded, cursor-relative window, convergence, status,
summary), an "Order" tab (stabilisation diagram, information criterion) and a "Frequency"
tab (FRF, MDI, nonlinear coefficients). Rerun plots every time-series view against the
timeline selected in the time panel: choose ``acq_time`` for the Live tab, ``model_order``
for the Order tab and ``frequency_mHz`` for the Frequency tab.
"""

from __future__ import annotations

from typing import Sequence

import rerun.blueprint as rrb

from fnsi_lab.viewer import paths

#: Seconds of signal history shown behind the time cursor (a bounded window keeps the
#: viewer responsive at kHz rates).
DEFAULT_WINDOW_S = 20.0


def blueprint(groups: Sequence[str] = ("force", "displacement"), *,
              window_s: float = DEFAULT_WINDOW_S, timeline: str = paths.TIME_ACQ,
              coefficient_names: Sequence[str] = (), active_tab: int = 0) -> rrb.Blueprint:
    """Build the blueprint.

    Parameters
    ----------
    groups : sequence of str
        Channel groups logged under :data:`viewer.paths.SIGNALS` (one view each).
    window_s : float
        Width of the visible signal window behind the cursor, seconds.
    timeline : str
        Timeline selected when the viewer opens.
    coefficient_names : sequence of str
        Nonlinear coefficients (one view each); empty gives one view of all of them.
    active_tab : int
        Tab shown first: 0 Live, 1 Order, 2 Frequency (pair it with ``timeline``).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    window = rrb.VisibleTimeRange(
        paths.TIME_ACQ,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-float(window_s)),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0))
    signal_views = [
        rrb.TimeSeriesView(origin=paths.signal_group(g), name=f"signals: {g}",
                           time_ranges=[window])
        for g in groups
    ] or [rrb.TimeSeriesView(origin=paths.SIGNALS, name="signals", time_ranges=[window])]
    live = rrb.Horizontal(
        rrb.Vertical(*signal_views),
        rrb.Vertical(
            rrb.TimeSeriesView(origin=paths.CONVERGENCE_FREQUENCIES,
                               name="natural frequencies per update (Hz)"),
            rrb.TimeSeriesView(origin=paths.CONVERGENCE_COEFFICIENTS,
                               name="coefficients per update (mean Re)"),
            rrb.TimeSeriesView(origin=paths.STATUS, name="status",
                               contents=[f"{paths.STATUS}/**", f"- {paths.STATUS_LOG}"]),
            rrb.TextLogView(origin=paths.STATUS_LOG, name="log"),
            rrb.TextDocumentView(origin=paths.SUMMARY, name="summary"),
        ),
        column_shares=[3, 2], name="Live")
    # order and frequency are not "time": show their whole range, wherever the cursor is
    whole = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                  end=rrb.TimeRangeBoundary.infinite()))

    def full(timeline: str) -> list[rrb.VisibleTimeRange]:
        return [rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.infinite(),
                                     end=rrb.TimeRangeBoundary.infinite())]

    order = rrb.Horizontal(
        rrb.TimeSeriesView(origin=paths.STABILISATION, name="stabilisation diagram (Hz)",
                           time_ranges=full(paths.TIME_ORDER), axis_x=whole),
        rrb.TimeSeriesView(origin=paths.ORDER, name="information criterion (log10)",
                           time_ranges=full(paths.TIME_ORDER), axis_x=whole),
        column_shares=[3, 2], name="Order")

    def fview(origin: str, name: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(origin=origin, name=name, axis_x=whole,
                                  time_ranges=full(paths.TIME_FREQUENCY))

    coeff_views = [fview(f"{paths.COEFFICIENTS}/{paths.part(n)}", f"coefficient {n}")
                   for n in coefficient_names]
    if not coeff_views:
        coeff_views = [fview(paths.COEFFICIENTS, "coefficients (Re)")]
    frequency = rrb.Horizontal(
        rrb.Vertical(fview(paths.FRF, "driving-point FRF (dB)"),
                     fview(paths.MDI, "MDI per pole (log10)")),
        rrb.Vertical(*coeff_views), name="Frequency")
    return rrb.Blueprint(
        rrb.Tabs(live, order, frequency, active_tab=active_tab),
        rrb.TimePanel(timeline=timeline),
        rrb.SelectionPanel(state="collapsed"),
        collapse_panels=False,
    )
