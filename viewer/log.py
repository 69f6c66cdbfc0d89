"""Log fnsi-lab data to Rerun: one ``log_*`` function per entity subtree.

Every function takes an explicit :class:`rerun.RecordingStream` (tests log to a file and
read it back) and plain arrays or dicts; none of them imports :mod:`ident`.

- Time series (signals, per-update estimates, status) go through ``send_columns`` on the
  ``acq_time`` timeline (per-update values also on ``update``), the timeline the blueprint
  selects; no implicit ``log_time``/``log_tick`` index is attached.
- Data indexed by order or frequency (FRF, stabilisation diagram, information criterion,
  MDI, coefficients) are static 2D figures (:mod:`viewer.figure`): they show whatever the
  time cursor, each update replaces them, and every series carries its physical values
  (``rr.AnyValues``) for export.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import rerun as rr

from fnsi_lab.viewer import paths
from fnsi_lab.viewer.figure import Axis, Figure, Panel, Series, stack
from fnsi_lab.viewer.frf import frequency_order, magnitude_db, phase_deg

# RGB colours, one per series kind (colour-blind-friendly Okabe-Ito palette).
_BLUE, _ORANGE, _GREEN = (0, 114, 178), (230, 159, 0), (0, 158, 115)
_RED, _GREY, _PURPLE, _SKY = (213, 94, 0), (140, 140, 140), (204, 121, 167), (86, 180, 233)
_BLACK, _YELLOW = (40, 40, 40), (240, 228, 66)

#: Channel colours by measurement direction: one hue family per direction (X blues, Y
#: greens, Z reds), a shade per node, so 39 channels read as three groups, not as ten
#: repeating colours (:func:`direction_colours`).
DIRECTION_PALETTES: dict[str, tuple[tuple[int, int, int], ...]] = {
    "X": ((8, 48, 107), (8, 81, 156), (33, 113, 181), (66, 146, 198), (107, 174, 214)),
    "Y": ((0, 68, 27), (0, 109, 44), (35, 139, 69), (65, 171, 93), (116, 196, 118)),
    "Z": ((103, 0, 13), (165, 15, 21), (203, 24, 29), (239, 59, 44), (251, 106, 74)),
}

#: Colours cycled over the channels of a group (matplotlib's tab10).
SIGNAL_PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))

#: pole class -> (colour, legend) of the stabilisation diagram.
#: One hue per class: "new" black (not grey on the grey grid; the label boxes are 55 grey),
#: "+ damping" blue (not an orange beside the vermillion "unstable").
POLE_STYLE: dict[str, tuple[tuple[int, int, int], str]] = {
    "new": ((0, 0, 0), "new pole"),
    "frequency": (_SKY, "stable freq."),
    "damping": (_BLUE, "+ damping"),
    "mode": (_PURPLE, "+ MAC"),
    "stable": (_GREEN, "fully stable"),
    "unstable": (_RED, "unstable"),
}

#: A pole's fate (ident.robust.pole_fate: the words of the terminal, the JSON and the report) ->
#: (colour, legend): every pair far apart in colour (tests/test_pole_fate.py).
FATE_STYLE: dict[str, tuple[tuple[int, int, int], str]] = {
    "physical": (_GREEN, "physical"),
    "rescued": (_BLUE, "physical (stabilisation)"),
    "split": ((148, 103, 189), "split mode, left out"),
    "spurious": (_RED, "spurious by MDI"),
    "not_detectable": (_SKY, "not detectable"),
    "not_stabilised": ((140, 86, 75), "not stabilised"),
    "mains_hum": (_YELLOW, "mains hum"),
    "no_evidence": ((227, 119, 194), "no physical evidence"),
    "unstable": (_BLACK, "unstable"),
    "out_of_band": ((170, 170, 170), "out of band"),
}

#: FRF series -> (colour, legend).
FRF_STYLE: dict[str, tuple[tuple[int, int, int], str]] = {
    "measured": (_BLACK, "measured"),
    "model": (_ORANGE, "model"),
    "linear": (_BLUE, "underlying linear"),
}

#: Canvas of each figure: (rows, plot height) -> ``figure.canvas_range`` for the blueprint.
#: Tall plots for the Order tab's tall views, two rows for the FRF (magnitude over phase),
#: four for the coefficients (Re over Im of each: two coefficients at full height, more
#: share the rows).
FIGURE_LAYOUT: dict[str, tuple[int, float]] = {
    paths.STABILISATION: (1, 620.0), paths.ORDER: (1, 620.0), paths.FRF: (2, 380.0),
    paths.MDI: (1, 300.0), paths.COEFFICIENTS: (4, 300.0), paths.MODES: (1, 420.0)}

#: One colour per estimated coefficient (the full-model curve is a lighter shade).
COEFFICIENT_PALETTE: tuple[tuple[int, int, int], ...] = (_BLUE, _RED, _GREEN, _PURPLE,
                                                         _ORANGE, _SKY)


# ---------------------------------------------------------------------------- helpers
def _lighter(color: tuple[int, int, int], amount: float = 0.55) -> tuple[int, int, int]:
    return tuple(int(round(c + (255 - c) * amount)) for c in color)  # type: ignore[return-value]


def _title(what: str, update: int | None) -> str:
    return what if update is None else f"{what} (update {update})"


def _robust_range(*arrays: Any) -> np.ndarray:
    """2nd-98th percentile span of the finite values (a few wild lines do not set the axis)."""
    v = np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in arrays if a is not None]
                       or [np.zeros(0)])
    v = v[np.isfinite(v)]
    if v.size == 0:
        return v
    lo, hi = np.percentile(v, [2, 98])
    span = hi - lo
    return np.array([lo - 0.1 * span, hi + 0.1 * span])


# ---------------------------------------------------------------------------- signals
def direction_colours(directions: Sequence[str]) -> list[tuple[int, int, int]]:
    """One colour per channel from its direction (``X``, ``-y``, ``Z``...): the direction's
    hue family of :data:`DIRECTION_PALETTES`, shaded in channel order; channels without a
    known direction take :data:`SIGNAL_PALETTE` in turn."""
    seen: dict[str, int] = {}
    out = []
    for k, d in enumerate(directions):
        key = str(d or "").strip().lstrip("+-").upper()[:1]
        palette = DIRECTION_PALETTES.get(key)
        if palette is None:
            out.append(SIGNAL_PALETTE[k % len(SIGNAL_PALETTE)])
            continue
        i = seen.get(key, 0)
        seen[key] = i + 1
        out.append(palette[i % len(palette)])
    return out


def log_signal_styles(rec: rr.RecordingStream, groups: Mapping[str, Sequence[int]],
                      channel_names: Sequence[str],
                      directions: Sequence[str] | None = None,
                      units: Sequence[str] | None = None) -> None:
    """Static series names and colours of each channel group (one legend entry per channel).

    With ``directions`` (one per channel), a group of several channels is coloured by direction
    (:func:`direction_colours`) and named ``name (direction)``; with ``units`` the names
    carry the unit (``NC2W-Z [mm]``).
    """
    for group, cols in groups.items():
        if directions is not None and len(cols) > 1 and any(directions[c] for c in cols):
            colours = direction_colours([directions[c] for c in cols])
        else:
            colours = [SIGNAL_PALETTE[i % len(SIGNAL_PALETTE)] for i in range(len(cols))]
        names = [channel_names[c] + (f" [{units[c]}]" if units is not None and units[c] else "")
                 for c in cols]
        rec.log(paths.signal_group(group), rr.SeriesLines(names=names, colors=colours),
                static=True)


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


# ---------------------------------------------------------------------------- styles
def _series_style(rec: rr.RecordingStream, entity: str, name: str,
                  color: tuple[int, int, int]) -> None:
    # lines AND points: a series of one update (one value) is already visible
    rec.log(entity, rr.SeriesLines(names=[name], colors=[color], widths=[1.5]),
            rr.SeriesPoints(names=[name], colors=[color], markers=["Circle"],
                            marker_sizes=[5.0]), static=True)


# ---------------------------------------------------------------------------- identification
def log_frf(rec: rr.RecordingStream, frequency_hz: Any, *, measured: Any = None,
            linear: Any = None, model: Any = None, output: str | None = None,
            force: str | None = None, unit: str | None = None,
            update: int | None = None) -> None:
    """Driving-point FRF against frequency: magnitude (dB) and phase (deg) panels.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_lines,)
    measured, linear, model : complex array_like, shape (n_lines,), optional
        Measured FRF (output spectrum over force spectrum), synthesised underlying linear
        FRF, and the identified model's FRF at the same lines.
    output, force : str, optional
        Names of the response and force channels (the titles name them).
    unit : str, optional
        FRF unit (``mm/N``): magnitudes in dB re 1 ``unit``.
    update : int, optional
        Identification update (shown in the title).
    """
    f = np.asarray(frequency_hz, dtype=float).ravel()
    order = frequency_order(f)
    f = f[order]
    which = f"FRF {output} / {force}" if output and force else "driving-point FRF"
    db = f"dB re 1 {unit}" if unit else "dB"
    curves = {k: np.asarray(v).ravel()[order] for k, v in
              (("measured", measured), ("model", model), ("linear", linear)) if v is not None}
    mags = {k: magnitude_db(v) for k, v in curves.items()}
    phases = {k: phase_deg(v) for k, v in curves.items()}
    fx = Axis.fit("frequency (Hz)", f, pad=0.0)
    mag_panel = Panel("magnitude", _title(f"{which} magnitude ({db})", update), fx,
                      Axis.fit(f"magnitude ({db})", _robust_range(*mags.values())))
    ph_panel = Panel("phase", f"{which} phase (deg)", fx,
                     Axis("phase (deg)", -190.0, 190.0))
    for key in ("model", "linear", "measured"):  # measured dots on top of the lines
        if key not in curves:
            continue
        h = curves[key]
        color, name = FRF_STYLE[key]
        # measured: markers drawn last (on top), larger than the model line is wide
        kind, width = ("points", 2.2) if key == "measured" else ("line", 1.2)
        values = {"frequency_hz": f, "re": h.real, "im": h.imag}
        mag_panel.series.append(Series(key, name, f, mags[key], color, kind=kind, width=width,
                                       values=values))
        ph_panel.series.append(Series(key, name, f, phases[key], color, kind=kind, width=width))
    Figure(rec, paths.FRF).log(stack([mag_panel, ph_panel], *FIGURE_LAYOUT[paths.FRF]))


def log_stabilisation(rec: rr.RecordingStream, order: Any, frequency_hz: Any,
                      pole_class: Sequence[str], *, damping_ratio: Any = None,
                      selected_order: int | None = None, update: int | None = None) -> None:
    """Stabilisation diagram: pole frequency against model order, one series per class.

    Parameters
    ----------
    order : array_like of int, shape (n_poles,)
        Model order of each pole.
    frequency_hz : array_like, shape (n_poles,)
        Natural frequency of each pole.
    pole_class : sequence of str, length n_poles
        One of :data:`viewer.paths.POLE_CLASSES` per pole.
    damping_ratio : array_like, shape (n_poles,), optional
        Stored with the poles for export.
    selected_order : int, optional
        Drawn as a vertical line.
    update : int, optional
        Identification update (shown in the title).
    """
    order = np.asarray(order, dtype=np.int64).ravel()
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    cls = np.asarray(pole_class, dtype=str).ravel()
    zeta = None if damping_ratio is None else np.asarray(damping_ratio, dtype=float).ravel()
    panel = Panel("", _title("stabilisation diagram: pole frequency (Hz)", update),
                  Axis.fit("model order", order, pad=0.03),
                  Axis.fit("frequency (Hz)", freq, include=[0.0], pad=0.05))
    names = list(POLE_STYLE) + sorted(set(cls.tolist()) - set(POLE_STYLE))
    for name in names:
        sel = cls == name
        color, label = POLE_STYLE.get(name, (_GREY, name))
        values = {"order": order[sel], "frequency_hz": freq[sel]}
        if zeta is not None:
            values["damping_ratio"] = zeta[sel]
        # every class is logged, empty ones too: a class an update no longer has is emptied
        panel.series.append(Series(paths.part(name), f"{label} ({int(sel.sum())})",
                                   order[sel], freq[sel], color, kind="points",
                                   width=2.0 if name == "new" else 2.5,
                                   legend=bool(sel.any()), values=values))
    if selected_order is not None:
        panel.vlines.append((float(selected_order), f"selected order {selected_order}", _RED))
    Figure(rec, paths.STABILISATION).log(stack([panel], *FIGURE_LAYOUT[paths.STABILISATION]))


def log_information_criterion(rec: rr.RecordingStream, orders: Any, criterion: Any,
                              selected_order: int | None, *, update: int | None = None) -> None:
    """Information criterion against model order (log axis), the selected order marked.

    Parameters
    ----------
    orders : array_like of int, shape (n_orders,)
    criterion : array_like, shape (n_orders,)
        Criterion value ``I(n) > 0`` at each order (non-finite or non-positive values, e.g.
        the ``inf`` of unstable orders, are not drawn).
    selected_order : int or None
        The chosen order.
    update : int, optional
        Identification update (shown in the title).
    """
    orders = np.asarray(orders, dtype=np.int64).ravel()
    crit = np.asarray(criterion, dtype=float).ravel()
    ok = np.isfinite(crit) & (crit > 0)
    gaps = int(np.sum(~ok))
    what = (f"I(n); red: {gaps} orders not fitted (unstable)" if gaps
            else "information criterion I(n)")
    panel = Panel("", _title(what, update),
                  Axis.fit("model order", orders, pad=0.03),
                  Axis.fit("criterion I(n)", crit[ok], log=True))
    values = {"order": orders, "criterion": crit}
    panel.series.append(Series("criterion", "I(n)", orders[ok], crit[ok],
                               _BLUE, width=1.5, values=values))
    panel.series.append(Series("criterion_points", "", orders[ok], crit[ok], _BLUE,
                               kind="points", width=2.0, legend=False))
    # orders without a value (unstable models: infinite criterion) leave gaps: say why, with
    # a marker at the bottom of the axis for each
    gap = orders[~ok]
    panel.series.append(Series("not_fitted", f"unstable ({gap.size})",
                               gap.astype(float), np.full(gap.size, panel.y.lo * 1.15),
                               _RED, kind="points", width=2.5, legend=bool(gap.size),
                               values={"order": gap}))
    sel_x, sel_y = np.zeros(0), np.zeros(0)
    if selected_order is not None:
        hit = np.flatnonzero((orders == int(selected_order)) & ok)
        if hit.size:
            sel_x, sel_y = orders[hit[:1]], crit[hit[:1]]
        panel.vlines.append((float(selected_order), f"selected order {selected_order}", _RED))
    panel.series.append(Series("selected", "selected order", sel_x, sel_y, _RED,
                               kind="points", width=5.0,
                               values={"order": sel_x, "criterion": sel_y}))
    Figure(rec, paths.ORDER).log(stack([panel], *FIGURE_LAYOUT[paths.ORDER]))


def log_mdi(rec: rr.RecordingStream, frequency_hz: Any, mdi: Any, kept: Any,
            threshold: float | None, *, fate: Sequence[str] | None = None,
            update: int | None = None) -> None:
    """Modal dominancy index per pole (log axis) against pole frequency.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_poles,)
    mdi : array_like, shape (n_poles,)
        Modal dominancy index of each pole (> 0).
    kept : array_like of bool, shape (n_poles,)
        True for poles kept by the reduction.
    threshold : float or None
        The MDI threshold, drawn as a horizontal line.
    fate : sequence of str, optional
        Each pole's fate (:data:`FATE_STYLE` keys: ``physical``, ``spurious``,
        ``not_detectable``...): one series per fate. Without it, kept/removed.
    update : int, optional
        Identification update (shown in the title).
    """
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    val = np.asarray(mdi, dtype=float).ravel()
    kept = np.asarray(kept, dtype=bool).ravel()
    thr = [threshold] if threshold is not None and threshold > 0 else []
    fx = Axis.fit("pole frequency (Hz)", freq, include=[0.0])
    panel = Panel("", _title("modal dominancy index (MDI) per pole", update), fx,
                  Axis.fit("MDI", val, log=True, include=thr))
    if fate is not None:
        fates = np.asarray(list(fate), dtype=str).ravel()
        # entity names: the kept and the MDI-removed poles keep their documented paths
        # (paths.MDI_KEPT, paths.MDI_REMOVED); the other fates are named after themselves
        entity = {"physical": "kept", "spurious": "removed"}
        classes = [(entity.get(k, k), fates == k, *FATE_STYLE[k]) for k in FATE_STYLE]
    else:
        classes = [("kept", kept, _GREEN, "physical"), ("removed", ~kept, _RED, "spurious")]
    for key, sel, color, label in classes:
        # every class is logged, empty ones too: a fate an update no longer has is emptied
        panel.series.append(Series(key, f"{label} ({int(sel.sum())})", freq[sel], val[sel],
                                   color, kind="points", width=3.5, legend=bool(sel.any()),
                                   values={"frequency_hz": freq[sel], "mdi": val[sel]}))
    tx = np.array([fx.lo, fx.hi]) if thr else np.zeros(0)
    panel.series.append(Series("threshold", f"threshold {threshold:.3g}" if thr else "threshold",
                               tx, np.array(thr * 2), _GREY, width=1.2, legend=bool(thr),
                               values={"threshold": np.array(thr)}))
    Figure(rec, paths.MDI).log(stack([panel], *FIGURE_LAYOUT[paths.MDI]))


def log_coefficients(rec: rr.RecordingStream, frequency_hz: Any,
                     full: Mapping[str, Any] | None = None,
                     reduced: Mapping[str, Any] | None = None,
                     exact: Mapping[str, float] | None = None, *, excited: Any = None,
                     units: Mapping[str, str] | None = None,
                     update: int | None = None) -> None:
    """Re and Im of each estimated nonlinear coefficient c_a(f): a panel of each, Re over Im
    (the HTML report's rows), Im dashed with the zero line a physical coefficient sits on.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_lines,)
    full, reduced : mapping of str to complex array_like, shape (n_lines,), optional
        Coefficient name -> c_a at each line, from the full and the reduced model.
    exact : mapping of str to float, optional
        Known values (simulations): drawn for the estimated coefficients only.
    excited : array_like of bool, shape (n_lines,), optional
        Excited lines: they set the x and y ranges (above the excitation band the
        identified coefficients are extrapolations and may swing far off).
    units : mapping of str to str, optional
        Coefficient name -> unit (``N/mm``), shown in the titles and axis labels.
    update : int, optional
        Identification update (shown in the titles).
    """
    freq = np.asarray(frequency_hz, dtype=float).ravel()
    order = frequency_order(freq)
    freq = freq[order]
    full, reduced, exact = dict(full or {}), dict(reduced or {}), dict(exact or {})
    band = np.ones(freq.size, bool) if excited is None else np.asarray(excited, bool).ravel()
    if band.size != freq.size or not band.any():
        band = np.ones(freq.size, bool)
    band = band[order]
    fx = Axis.fit("frequency (Hz)", freq[band], pad=0.02)
    names = list(dict.fromkeys(list(reduced) + list(full)))
    panels = []
    for k, name in enumerate(names):
        color = COEFFICIENT_PALETTE[k % len(COEFFICIENT_PALETTE)]
        est = {w: np.asarray(t[name]).ravel()[order] for w, t in
               (("full", full), ("reduced", reduced)) if name in t}
        unit = (units or {}).get(name, "")
        panels += _coefficient_panels(name, unit, freq, band, fx, est, exact.get(name),
                                      color, update)
    Figure(rec, paths.COEFFICIENTS).log(stack(panels, *FIGURE_LAYOUT[paths.COEFFICIENTS]))


def _coefficient_panels(name: str, unit: str, freq: np.ndarray, band: np.ndarray, fx: Axis,
                        est: Mapping[str, np.ndarray], known: float | None,
                        color: tuple[int, int, int], update: int | None) -> list[Panel]:
    """The Re panel (solid; the exact value) and the Im panel (dashed; zero) of one
    coefficient; ``est``: 'full'/'reduced' -> complex c_a at ``freq``."""
    suffix = f" ({unit})" if unit else ""
    inc = [float(known)] if known is not None else []
    re_panel = Panel(paths.part(name), _title(f"Re {name}{suffix}", update), fx,
                     Axis.fit(f"Re {name}{suffix}",
                              _robust_range(*[c.real[band] for c in est.values()]),
                              include=inc, pad=0.3))
    im_panel = Panel(f"{paths.part(name)}/im", f"Im {name}{suffix}, dashed", fx,
                     Axis.fit(f"Im {name}{suffix}",
                              _robust_range(*[c.imag[band] for c in est.values()]),
                              include=[0.0], pad=0.3))
    for which, c in est.items():
        shade = _lighter(color) if which == "full" and "reduced" in est else color
        width = 1.2 if which == "full" else 1.6
        re_panel.series.append(Series(which, f"Re, {which} model", freq, c.real, shade,
                                      width=width, values={"frequency_hz": freq, "re": c.real,
                                                           "im": c.imag}))
        im_panel.series.append(Series(which, f"Im, {which} model", freq, c.imag, shade,
                                      kind="dashed", width=width,
                                      values={"frequency_hz": freq, "im": c.imag}))
    span = np.array([freq[band].min(), freq[band].max()]) if freq.size else np.zeros(0)
    if known is not None:
        re_panel.series.append(Series("exact", f"exact {float(known):.4g}{unit and ' ' + unit}",
                                      span, np.full(span.size, float(known)), _BLACK,
                                      width=1.0, values={"exact": np.array([float(known)])}))
    im_panel.series.append(Series("zero", "0: real", span, np.zeros(span.size), _GREY,
                                  width=1.0))
    return [re_panel, im_panel]


def log_modes(rec: rr.RecordingStream, frequency_hz: Any, damping_ratio: Any = None, *,
              update: int | None = None) -> None:
    """The physical modes of one update: damping ratio (%) against natural frequency (Hz),
    each marker labelled with its mode number (``mode 3`` of the per-update series). Reads
    with a single update, where the per-update series are one point each.

    Parameters
    ----------
    frequency_hz : array_like, shape (n_modes,)
        Natural frequencies, ascending (mode k is the k-th, as in the per-update series).
    damping_ratio : array_like, shape (n_modes,), optional
        Damping ratios (fractions of critical); without them the modes sit on 0.
    update : int, optional
        Identification update (shown in the title).
    """
    f = np.asarray(frequency_hz, dtype=float).ravel()
    zeta = np.zeros(f.size) if damping_ratio is None else \
        np.asarray(damping_ratio, dtype=float).ravel()[:f.size]
    zeta = np.pad(zeta, (0, f.size - zeta.size), constant_values=np.nan)
    panel = Panel("", _title(f"{f.size} modes: damping (%) vs frequency (Hz)", update),
                  Axis.fit("natural frequency (Hz)", f, include=[0.0], pad=0.06),
                  Axis.fit("damping ratio (%)", 100 * zeta, include=[0.0], pad=0.2))
    # every mode in one entity (an update with fewer modes replaces all of them), in the
    # colour of its per-update series
    panel.series.append(Series(
        "modes", "mode", f, 100 * zeta, _BLUE, kind="points", width=4.0, legend=False,
        labels=[str(k + 1) for k in range(f.size)],
        point_colors=[SIGNAL_PALETTE[k % len(SIGNAL_PALETTE)] for k in range(f.size)],
        values={"mode": np.arange(1, f.size + 1), "frequency_hz": f, "damping_ratio": zeta}))
    Figure(rec, paths.MODES).log(stack([panel], *FIGURE_LAYOUT[paths.MODES]))


def log_convergence(rec: rr.RecordingStream, update: int, acq_time_s: float,
                    values: Mapping[str, Any],
                    coefficients: Mapping[str, float] | None = None,
                    units: Mapping[str, str] | None = None) -> None:
    """Estimates after one identification update, on the ``update`` and ``acq_time`` timelines.

    Parameters
    ----------
    update : int
        Update counter (1 for the first identification).
    acq_time_s : float
        Acquisition time of the end of the data used.
    values : mapping of str to float or array_like
        Quantity -> value(s). A vector holds one value per mode (ascending frequency):
        each mode gets its own series, named after ``natural_frequency_hz`` when given
        (``mode 3 (28.3 Hz)``); its length may change between updates.
    coefficients : mapping of str to float, optional
        Coefficient name -> headline estimate (e.g. mean Re c_a over the excited lines),
        one entity each under :data:`viewer.paths.CONVERGENCE_COEFFICIENTS`.
    units : mapping of str to str, optional
        Coefficient name -> unit (``N/mm``), in the series names.
    """
    index = [rr.TimeColumn(paths.TIME_UPDATE, sequence=[int(update)]),
             rr.TimeColumn(paths.TIME_ACQ, duration=[float(acq_time_s)])]
    freqs = np.atleast_1d(np.asarray(values.get("natural_frequency_hz", []), dtype=float))

    def send(entity: str, value: float, name: str, color: tuple[int, int, int]) -> None:
        _series_style(rec, entity, name, color)
        rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=[value]))

    for quantity, value in values.items():
        v = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
        if v.size == 1 and quantity not in ("natural_frequency_hz", "damping_ratio"):
            send(paths.convergence(quantity), float(v[0]), quantity.replace("_", " "), _BLUE)
            continue
        for i, x in enumerate(v):
            label = f"mode {i + 1}" + (f" ({freqs[i]:.1f} Hz)" if i < freqs.size else "")
            send(paths.convergence_mode(quantity, i + 1), float(x), label,
                 SIGNAL_PALETTE[i % len(SIGNAL_PALETTE)])
    for k, (name, value) in enumerate((coefficients or {}).items()):
        unit = (units or {}).get(name)
        send(paths.convergence_coefficient(name), float(value),
             f"{name} (mean Re" + (f", {unit})" if unit else ")"),
             COEFFICIENT_PALETTE[k % len(COEFFICIENT_PALETTE)])


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
    """Status scalars (updates, latency, dropped blocks...) and an optional log line.

    Each scalar is drawn with lines and points, so the first value is already visible.
    """
    index = [rr.TimeColumn(paths.TIME_ACQ, duration=[float(acq_time_s)])]
    for k, (name, value) in enumerate(values.items()):
        entity = paths.status(name)
        _series_style(rec, entity, name.replace("_", " "), SIGNAL_PALETTE[k % len(SIGNAL_PALETTE)])
        rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=[float(value)]))
    if message:
        rec.send_columns(paths.STATUS_LOG, indexes=index,
                         columns=rr.TextLog.columns(text=[message], level=[level]))


def log_parameter_objective(rec: rr.RecordingStream, profiles: Sequence[Mapping[str, Any]], *,
                            update: int | None = None) -> None:
    """Model error against each basis parameter estimated from the data, estimate marked.

    Parameters
    ----------
    profiles : sequence of mapping
        One per parameter: ``label`` (e.g. ``'NC2-Z.g_pos'``), ``values`` (parameter values,
        shape (n,)), ``objective`` (relative model error at each, shape (n,), > 0),
        ``estimate`` (float) and optionally ``std``.
    update : int, optional
        Identification update (shown in the titles).
    """
    panels = []
    for k, prof in enumerate(profiles):
        x = np.asarray(prof["values"], dtype=float).ravel()
        y = np.asarray(prof["objective"], dtype=float).ravel()
        order = np.argsort(x)
        x, y = x[order], y[order]
        ok = np.isfinite(y) & (y > 0)
        est = float(prof["estimate"])
        std = prof.get("std")
        unc = f" +- {std:.2g}" if std is not None and np.isfinite(std) else ""
        panel = Panel(f"p{k}", _title(f"{prof['label']} = {est:.5g}{unc}", update),
                      Axis.fit(str(prof["label"]), x[ok], include=[est]),
                      Axis.fit("relative model error", y[ok], log=True))
        panel.series.append(Series("objective", "model error", x[ok], y[ok], _BLUE, width=1.5,
                                   values={"parameter": x, "relative_model_error": y}))
        panel.series.append(Series("points", "", x[ok], y[ok], _BLUE, kind="points", width=2.0,
                                   legend=False))
        panel.vlines.append((est, "estimate", _RED))
        panels.append(panel)
    if panels:
        Figure(rec, paths.PARAMETERS).log(stack(panels, len(panels)))


def log_restoring_force(rec: rr.RecordingStream, curves: Sequence[Mapping[str, Any]], *,
                        update: int | None = None) -> None:
    """Restoring-force curves of ``kind: spline`` elements with their confidence bands.

    Parameters
    ----------
    curves : sequence of mapping
        One per curve (``coefficients[].curve`` of the result JSON): ``element``,
        ``argument`` ({'displacement', 'velocity'}), ``x``, ``force``, ``std`` (shape (n,))
        and optionally ``suggestion`` (its ``kind``).
    update : int, optional
        Identification update (shown in the titles).
    """
    panels = []
    for k, c in enumerate(curves):
        x = np.asarray(c["x"], dtype=float).ravel()
        f = np.asarray(c["force"], dtype=float).ravel()
        sd = np.nan_to_num(np.asarray(c["std"], dtype=float).ravel())
        lo, hi = f - 2 * sd, f + 2 * sd
        sug = (c.get("suggestion") or {}).get("kind")
        title = f"{c['element']}: force against relative {c['argument']}" + (
            f" (suggests {sug})" if sug and sug != "none" else "")
        panel = Panel(f"c{k}", _title(title, update),
                      Axis.fit(f"relative {c['argument']}", x, pad=0.0),
                      Axis.fit("force", lo, hi))
        for name, y, color, width in (("band_low", lo, _lighter(_BLUE), 1.0),
                                      ("band_high", hi, _lighter(_BLUE), 1.0),
                                      ("force", f, _BLUE, 1.8)):
            label = {"force": "force", "band_low": "-2 std", "band_high": "+2 std"}[name]
            panel.series.append(Series(name, label, x, y, color, width=width,
                                       values={"x": x, "force": f, "std": sd}
                                       if name == "force" else {}))
        panels.append(panel)
    if panels:
        Figure(rec, paths.RESTORING_FORCE).log(stack(panels, len(panels)))


def log_identification(rec: rr.RecordingStream, view: Mapping[str, Any], *,
                       update: int | None = None) -> None:
    """Log every subtree present in a plain-dict identification result.

    Parameters
    ----------
    view : mapping
        Optional keys, each a dict of the keyword arguments of one ``log_*`` function:
        ``frf`` (:func:`log_frf`, with ``frequency_hz``), ``stabilisation``,
        ``criterion`` (:func:`log_information_criterion`), ``mdi``, ``coefficients``,
        ``convergence`` (with ``update``, ``acq_time_s``, ``values``; its per-mode
        ``natural_frequency_hz``/``damping_ratio`` also drawn by :func:`log_modes`), ``parameters``
        (:func:`log_parameter_objective`), ``restoring_force`` (:func:`log_restoring_force`),
        and ``summary`` (markdown text). The stabilisation diagram marks the criterion's selected order.
    update : int, optional
        Identification update, shown in the figure titles (each update replaces the
        figures; the per-update estimates stay on the ``update`` timeline).
    """
    if "frf" in view:
        log_frf(rec, **view["frf"], update=update)
    if "stabilisation" in view:
        stab = dict(view["stabilisation"])
        if "criterion" in view:
            stab.setdefault("selected_order", view["criterion"].get("selected_order"))
        log_stabilisation(rec, **stab, update=update)
    if "criterion" in view:
        log_information_criterion(rec, **view["criterion"], update=update)
    if "mdi" in view:
        log_mdi(rec, **view["mdi"], update=update)
    if "coefficients" in view:
        log_coefficients(rec, **view["coefficients"], update=update)
    if "parameters" in view:
        log_parameter_objective(rec, **view["parameters"], update=update)
    if "restoring_force" in view:
        log_restoring_force(rec, **view["restoring_force"], update=update)
    if "convergence" in view:
        log_convergence(rec, **view["convergence"])
        values = view["convergence"].get("values") or {}
        if "natural_frequency_hz" in values:
            log_modes(rec, values["natural_frequency_hz"], values.get("damping_ratio"),
                      update=view["convergence"].get("update", update))
    if "summary" in view:
        log_summary(rec, view["summary"])
