"""Log fnsi-lab data to Rerun: one ``log_*`` function per entity subtree.

Every function takes an explicit :class:`rerun.RecordingStream` (tests log to a file and
read it back) and plain arrays or dicts; none of them imports :mod:`ident`. Time-indexed
data go through ``send_columns`` with exactly one "x" timeline each (see
:mod:`viewer.paths`), so an entity never shows up against the wrong axis and no implicit
``log_time``/``log_tick`` index is attached. Styling (names, colours, markers) is static and
logged once by :func:`log_styles` / :func:`log_signal_styles`.

Rerun has no logarithmic y axis: FRF magnitudes are logged in dB and MDI values as
``log10``. Frequencies are logged on the integer ``frequency_mHz`` timeline.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import rerun as rr

from fnsi_lab.viewer import paths

# RGB colours, one per series kind (colour-blind-friendly Okabe-Ito palette).
_BLUE, _ORANGE, _GREEN = (0, 114, 178), (230, 159, 0), (0, 158, 115)
_RED, _GREY, _PURPLE, _SKY = (213, 94, 0), (140, 140, 140), (204, 121, 167), (86, 180, 233)

#: Colours cycled over the channels of a group (matplotlib's tab10).
SIGNAL_PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))

#: pole class -> (colour, marker, legend) of the stabilisation diagram (spec §4 legend).
POLE_STYLE: dict[str, tuple[tuple[int, int, int], str, str]] = {
    "new": (_GREY, "Circle", "new pole"),
    "frequency": (_SKY, "Cross", "stable in frequency"),
    "damping": (_ORANGE, "Square", "+ damping"),
    "mode": (_PURPLE, "Diamond", "+ mode shape (MACX)"),
    "stable": (_GREEN, "Up", "fully stable"),
    "unstable": (_RED, "Asterisk", "unstable (zeta < 0)"),
}


# ---------------------------------------------------------------------------- helpers
def frequency_index(frequency_hz: Any) -> np.ndarray:
    """Frequencies in Hz -> integer millihertz for the ``frequency_mHz`` timeline."""
    return np.rint(np.asarray(frequency_hz, dtype=float) * 1000.0).astype(np.int64)


def magnitude_db(frf: Any) -> np.ndarray:
    """``20 log10 |H|``, with zeros mapped to -400 dB instead of -inf."""
    mag = np.abs(np.asarray(frf))
    with np.errstate(divide="ignore"):
        return np.where(mag > 0, 20.0 * np.log10(np.where(mag > 0, mag, 1.0)), -400.0)


def _send_freq(rec: rr.RecordingStream, entity: str, frequency_hz: Any, values: Any) -> None:
    f = frequency_index(frequency_hz)
    if len(f) == 0:
        return
    v = np.asarray(values, dtype=float).reshape(len(f), -1)
    rec.send_columns(entity, indexes=[rr.TimeColumn(paths.TIME_FREQUENCY, sequence=f)],
                     columns=rr.Scalars.columns(scalars=v))


def _send_order(rec: rr.RecordingStream, entity: str, order: Any, values: Any) -> None:
    n = np.asarray(order, dtype=np.int64).ravel()
    if len(n) == 0:
        return
    v = np.asarray(values, dtype=float).reshape(len(n), -1)
    rec.send_columns(entity, indexes=[rr.TimeColumn(paths.TIME_ORDER, sequence=n)],
                     columns=rr.Scalars.columns(scalars=v))


# ---------------------------------------------------------------------------- styles
def _fixed_style(base: str, visible: bool = True, suffix: str = "") -> Any:
    """Static style of one fixed identification entity (``visible=False`` hides it).

    ``suffix`` is appended to the legend name: the viewer merges legend entries of equal
    names, so every update's series needs its own.
    """
    vis = None if visible else [False]
    line, point = rr.SeriesLines, rr.SeriesPoints
    table = {
        paths.FRF_MEASURED: lambda: line(colors=[_GREY], names=["measured" + suffix], widths=[1.0],
                                         visible_series=vis),
        paths.FRF_LINEAR: lambda: line(colors=[_BLUE], names=["underlying linear" + suffix],
                                       widths=[1.5], visible_series=vis),
        paths.FRF_MODEL: lambda: line(colors=[_ORANGE], names=["model" + suffix], widths=[1.0],
                                      visible_series=vis),
        paths.ORDER_CRITERION: lambda: line(colors=[_BLUE], names=["log10 information criterion" + suffix],
                                            visible_series=vis),
        paths.ORDER_SELECTED: lambda: point(colors=[_RED], markers=["Diamond"],
                                            names=["selected order" + suffix], marker_sizes=[6.0],
                                            visible_series=vis),
        paths.MDI_KEPT: lambda: point(colors=[_GREEN], markers=["Circle"],
                                      names=["log10 MDI, kept" + suffix], marker_sizes=[4.0],
                                      visible_series=vis),
        paths.MDI_REMOVED: lambda: point(colors=[_RED], markers=["Cross"],
                                         names=["log10 MDI, removed" + suffix], marker_sizes=[4.0],
                                         visible_series=vis),
        paths.MDI_THRESHOLD: lambda: line(colors=[_GREY], names=["log10 threshold" + suffix],
                                          visible_series=vis),
    }
    return table[base]()


def _pole_style(pole_class: str, visible: bool = True, suffix: str = "") -> Any:
    color, marker, name = POLE_STYLE.get(pole_class, (_GREY, "Circle", pole_class))
    return rr.SeriesPoints(colors=[color], markers=[marker], names=[name + suffix],
                           marker_sizes=[3.0],
                           visible_series=None if visible else [False])


def _coefficient_style(name: str, which: str, visible: bool = True, suffix: str = "") -> Any:
    color, label = {"full": (_GREY, f"Re {name}, full model"),
                    "reduced": (_BLUE, f"Re {name}, reduced model"),
                    "exact": (_RED, f"{name}, exact")}[which]
    return rr.SeriesLines(colors=[color], names=[label + suffix],
                          visible_series=None if visible else [False])


def _target(rec: rr.RecordingStream, base: str, style: Any, update: int | None) -> str:
    """Entity for this update's data under ``base``; styles it and hides the previous one.

    ``style(visible, suffix)`` returns the static style archetype. Without ``update`` the
    data go to ``base`` itself (styled once by :func:`log_styles`).
    """
    if update is None:
        return base
    entity = paths.versioned(base, update)
    rec.log(entity, style(True, f" #{update}"), static=True)
    if update > 1:
        rec.log(paths.versioned(base, update - 1), style(False, f" #{update - 1}"),
                static=True)
    return entity


def log_styles(rec: rr.RecordingStream, *, coefficient_names: Sequence[str] = ()) -> None:
    """Static names, colours and markers of every identification entity (log once)."""
    for base in (paths.FRF_MEASURED, paths.FRF_LINEAR, paths.FRF_MODEL, paths.ORDER_CRITERION,
                 paths.ORDER_SELECTED, paths.MDI_KEPT, paths.MDI_REMOVED, paths.MDI_THRESHOLD):
        rec.log(base, _fixed_style(base), static=True)
    for cls in POLE_STYLE:
        rec.log(paths.stabilisation_class(cls), _pole_style(cls), static=True)
    for name in coefficient_names:
        _coefficient_styles(rec, name)


def _coefficient_styles(rec: rr.RecordingStream, name: str) -> None:
    for which in ("full", "reduced", "exact"):
        rec.log(paths.coefficient(name, which), _coefficient_style(name, which), static=True)


def log_signal_styles(rec: rr.RecordingStream, groups: Mapping[str, Sequence[int]],
                      channel_names: Sequence[str]) -> None:
    """Static series names and colours of each channel group (one legend entry per channel)."""
    for group, cols in groups.items():
        rec.log(paths.signal_group(group),
                rr.SeriesLines(names=[channel_names[c] for c in cols],
                               colors=[SIGNAL_PALETTE[i % len(SIGNAL_PALETTE)]
                                       for i in range(len(cols))]), static=True)


# ---------------------------------------------------------------------------- signals
def channel_groups(channel_names: Sequence[str], quantities: Sequence[str]) -> dict[str, list[int]]:
    """Default grouping: one group per physical quantity (``force``, ``displacement``...).

    Returns
    -------
    dict
        group name -> column indices, in channel order.
    """
    groups: dict[str, list[int]] = {}
    for i, q in enumerate(quantities):
        groups.setdefault(str(q), []).append(i)
    return groups


def log_signals(rec: rr.RecordingStream, data: np.ndarray, t0_s: float, sample_rate_hz: float,
                groups: Mapping[str, Sequence[int]], *, decimation: int = 1) -> None:
    """Send a block of samples, one entity per channel group, in one call per group.

    Parameters
    ----------
    data : ndarray, shape (n_samples, n_channels)
        Samples of one block.
    t0_s : float
        Acquisition time of the first row, seconds.
    sample_rate_hz : float
        Sampling rate.
    groups : mapping of str to sequence of int
        Group name -> column indices (see :func:`channel_groups`).
    decimation : int
        Keep every ``decimation``-th row (plain subsampling; the viewer needs no more
        than a few hundred points per second and per channel for a live look).
    """
    data = np.asarray(data)
    step = max(int(decimation), 1)
    rows = data[::step]
    if rows.shape[0] == 0:
        return
    t = t0_s + np.arange(rows.shape[0]) * (step / sample_rate_hz)
    index = [rr.TimeColumn(paths.TIME_ACQ, duration=t)]
    for group, cols in groups.items():
        rec.send_columns(paths.signal_group(group), indexes=index,
                         columns=rr.Scalars.columns(scalars=rows[:, list(cols)].astype(float)))


# ---------------------------------------------------------------------------- identification
def log_frf(rec: rr.RecordingStream, frequency_hz: Any, *, measured: Any = None,
            linear: Any = None, model: Any = None, update: int | None = None) -> None:
    """Driving-point FRF magnitudes in dB against frequency.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_lines,)
    measured, linear, model : complex array_like, shape (n_lines,), optional
        Measured FRF (output spectrum over force spectrum), synthesised underlying linear
        FRF, and the identified model's FRF at the same lines.
    update : int, optional
        Identification update: data go to ``<entity>/update_<k>`` and the previous update's
        curves are hidden (see :func:`viewer.paths.versioned`).
    """
    for entity, frf in ((paths.FRF_MEASURED, measured), (paths.FRF_LINEAR, linear),
                        (paths.FRF_MODEL, model)):
        if frf is not None:
            target = _target(rec, entity, lambda v, x, e=entity: _fixed_style(e, v, x), update)
            _send_freq(rec, target, frequency_hz, magnitude_db(frf))


def log_stabilisation(rec: rr.RecordingStream, order: Any, frequency_hz: Any,
                      pole_class: Sequence[str], *, update: int | None = None) -> None:
    """Stabilisation diagram: pole frequency against model order, one entity per class.

    Parameters
    ----------
    order : array_like of int, shape (n_poles,)
        Model order of each pole.
    frequency_hz : array_like, shape (n_poles,)
        Natural frequency of each pole.
    pole_class : sequence of str, length n_poles
        One of :data:`viewer.paths.POLE_CLASSES` per pole.
    update : int, optional
        See :func:`log_frf`.
    """
    order = np.asarray(order, dtype=np.int64).ravel()
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    cls = np.asarray(pole_class, dtype=str).ravel()
    present = set(cls.tolist())
    for name in list(POLE_STYLE) + sorted(present - set(POLE_STYLE)):
        base = paths.stabilisation_class(name)
        if name not in present:  # hide a class this update no longer has
            if update is not None and update > 1:
                rec.log(paths.versioned(base, update - 1),
                        _pole_style(name, False, f" #{update - 1}"), static=True)
            continue
        sel = cls == name
        idx = np.argsort(order[sel], kind="stable")
        target = _target(rec, base, lambda v, x, n=name: _pole_style(n, v, x), update)
        # one row per pole: several rows may share an order (one series, many points)
        _send_order(rec, target, order[sel][idx], freq[sel][idx])


def log_information_criterion(rec: rr.RecordingStream, orders: Any, criterion: Any,
                              selected_order: int | None, *, update: int | None = None) -> None:
    """log10 of the information criterion against model order, the selected order marked.

    Parameters
    ----------
    orders : array_like of int, shape (n_orders,)
    criterion : array_like, shape (n_orders,)
        Criterion value ``I(n) > 0`` at each order (non-finite or non-positive values, e.g.
        the ``inf`` of unstable orders, are skipped). Logged as ``log10 I(n)``: the
        criterion spans decades.
    selected_order : int or None
        The chosen order (one point on the curve).
    update : int, optional
        See :func:`log_frf`.
    """
    orders = np.asarray(orders, dtype=np.int64).ravel()
    raw = np.asarray(criterion, dtype=float).ravel()
    with np.errstate(divide="ignore", invalid="ignore"):
        crit = np.where(raw > 0, np.log10(np.where(raw > 0, raw, 1.0)), np.nan)
    ok = np.isfinite(crit)
    target = _target(rec, paths.ORDER_CRITERION,
                     lambda v, x: _fixed_style(paths.ORDER_CRITERION, v, x), update)
    _send_order(rec, target, orders[ok], crit[ok])
    target = _target(rec, paths.ORDER_SELECTED,
                     lambda v, x: _fixed_style(paths.ORDER_SELECTED, v, x), update)
    if selected_order is not None:
        hit = np.flatnonzero((orders == int(selected_order)) & ok)
        if hit.size:
            _send_order(rec, target, [int(selected_order)], [crit[hit[0]]])


def log_mdi(rec: rr.RecordingStream, frequency_hz: Any, mdi: Any, kept: Any,
            threshold: float | None, *, update: int | None = None) -> None:
    """MDI per pole (log10) against pole frequency, kept and removed poles apart.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_poles,)
    mdi : array_like, shape (n_poles,)
        Modal distribution index of each pole (> 0).
    kept : array_like of bool, shape (n_poles,)
        True for poles kept by the reduction.
    threshold : float or None
        The MDI threshold; drawn as a horizontal line over the poles' frequency span.
    update : int, optional
        See :func:`log_frf`.
    """
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    val = np.log10(np.maximum(np.asarray(mdi, dtype=float).ravel(), 1e-300))
    kept = np.asarray(kept, dtype=bool).ravel()
    for entity, sel in ((paths.MDI_KEPT, kept), (paths.MDI_REMOVED, ~kept)):
        idx = np.argsort(freq[sel], kind="stable")
        target = _target(rec, entity, lambda v, x, e=entity: _fixed_style(e, v, x), update)
        _send_freq(rec, target, freq[sel][idx], val[sel][idx])
    target = _target(rec, paths.MDI_THRESHOLD,
                     lambda v, x: _fixed_style(paths.MDI_THRESHOLD, v, x), update)
    if threshold is not None and threshold > 0 and freq.size:
        span = [float(freq.min()), float(freq.max())]
        if span[1] == span[0]:
            span[1] = span[0] + 1.0
        _send_freq(rec, target, span, [np.log10(threshold)] * 2)


def log_coefficients(rec: rr.RecordingStream, frequency_hz: Any,
                     full: Mapping[str, Any] | None = None,
                     reduced: Mapping[str, Any] | None = None,
                     exact: Mapping[str, float] | None = None, *,
                     update: int | None = None) -> None:
    """Real part of each nonlinear coefficient c_a(f), before and after reduction.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_lines,)
    full, reduced : mapping of str to complex array_like, shape (n_lines,), optional
        Coefficient name -> c_a at each line, from the full and the reduced model.
    exact : mapping of str to float, optional
        Known values (simulations): drawn as a constant line over the band.
    update : int, optional
        See :func:`log_frf` (the exact value stays in one entity).
    """
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    for which, table in (("full", full), ("reduced", reduced)):
        for name, values in (table or {}).items():
            target = _target(rec, paths.coefficient(name, which),
                             lambda v, x, n=name, w=which: _coefficient_style(n, w, v, x), update)
            _send_freq(rec, target, freq, np.real(np.asarray(values)).ravel())
    if freq.size:
        for name, value in (exact or {}).items():
            _send_freq(rec, paths.coefficient(name, "exact"), [freq.min(), freq.max()],
                       [float(value)] * 2)


def log_convergence(rec: rr.RecordingStream, update: int, acq_time_s: float,
                    values: Mapping[str, Any],
                    coefficients: Mapping[str, float] | None = None) -> None:
    """Estimates after one identification update, on the ``update`` and ``acq_time`` timelines.

    Parameters
    ----------
    update : int
        Update counter (1 for the first identification).
    acq_time_s : float
        Acquisition time of the end of the data used.
    values : mapping of str to float or array_like
        Quantity -> value(s), e.g. ``natural_frequency_hz`` -> one value per kept mode.
        A vector is one row (series ``name[i]``); its length may change between updates.
    coefficients : mapping of str to float, optional
        Coefficient name -> headline estimate (e.g. mean Re c_a over the excited lines),
        one entity each under :data:`viewer.paths.CONVERGENCE_COEFFICIENTS`.
    """
    index = [rr.TimeColumn(paths.TIME_UPDATE, sequence=[int(update)]),
             rr.TimeColumn(paths.TIME_ACQ, duration=[float(acq_time_s)])]
    for name, value in values.items():
        v = np.atleast_1d(np.asarray(value, dtype=float)).reshape(1, -1)
        if v.size == 0:
            continue
        rec.send_columns(paths.convergence(name), indexes=index,
                         columns=rr.Scalars.columns(scalars=v))
    for name, value in (coefficients or {}).items():
        rec.send_columns(paths.convergence_coefficient(name), indexes=index,
                         columns=rr.Scalars.columns(scalars=[float(value)]))


def log_summary(rec: rr.RecordingStream, markdown: str) -> None:
    """The result table (markdown) as a static TextDocument (the latest one wins)."""
    rec.log(paths.SUMMARY, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN),
            static=True)


def summary_markdown(title: str, rows: Sequence[tuple[str, str]],
                     table: Sequence[Mapping[str, Any]] = ()) -> str:
    """A markdown summary: key/value lines, then an optional table (list of row dicts)."""
    lines = [f"## {title}", "", "| quantity | value |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in rows]
    if table:
        cols = list(table[0])
        lines += ["", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        lines += ["| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |" for r in table]
    return "\n".join(lines) + "\n"


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else str(value)


def log_status(rec: rr.RecordingStream, acq_time_s: float, values: Mapping[str, float],
               message: str | None = None, *, level: str = "INFO") -> None:
    """Status scalars (rate, dropped blocks, file size...) and an optional log line."""
    index = [rr.TimeColumn(paths.TIME_ACQ, duration=[float(acq_time_s)])]
    for name, value in values.items():
        rec.send_columns(paths.status(name), indexes=index,
                         columns=rr.Scalars.columns(scalars=[float(value)]))
    if message:
        rec.send_columns(paths.STATUS_LOG, indexes=index,
                         columns=rr.TextLog.columns(text=[message], level=[level]))


def log_identification(rec: rr.RecordingStream, view: Mapping[str, Any], *,
                       update: int | None = None) -> None:
    """Log every subtree present in a plain-dict identification result.

    Parameters
    ----------
    view : mapping
        Optional keys, each a dict of the keyword arguments of one ``log_*`` function:
        ``frf`` (:func:`log_frf`, with ``frequency_hz``), ``stabilisation``,
        ``criterion`` (:func:`log_information_criterion`), ``mdi``, ``coefficients``,
        ``convergence`` (with ``update``, ``acq_time_s``, ``values``), and ``summary``
        (markdown text).
    update : int, optional
        Identification update: order- and frequency-indexed data go to one child entity per
        update and the previous one is hidden (see :func:`viewer.paths.versioned`).
    """
    if "frf" in view:
        log_frf(rec, **view["frf"], update=update)
    if "stabilisation" in view:
        log_stabilisation(rec, **view["stabilisation"], update=update)
    if "criterion" in view:
        log_information_criterion(rec, **view["criterion"], update=update)
    if "mdi" in view:
        log_mdi(rec, **view["mdi"], update=update)
    if "coefficients" in view:
        names = set()
        for key in ("full", "reduced", "exact"):
            names |= set((view["coefficients"].get(key) or {}))
        for name in sorted(names):
            _coefficient_styles(rec, name)
        log_coefficients(rec, **view["coefficients"], update=update)
    if "convergence" in view:
        log_convergence(rec, **view["convergence"])
    if "summary" in view:
        log_summary(rec, view["summary"])
