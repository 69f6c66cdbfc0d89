"""The one robust pipeline: order sweep -> IC -> stabilisation -> MDI -> reduction (docs/method.md §3-8).

:func:`identify_auto` turns frequency-domain data into a model without a human reading the
stabilisation diagram:

1. one QR and one SVD (:func:`ident.core.fnsi.subspace_decomposition`), then every order of the
   sweep (:func:`ident.core.fnsi.model_at_order`; docs/method.md §1.7);
2. information criterion ``I(n) = V(n)(1 + n/F)`` over the band chosen by
   :func:`ident.robust.order_selection.ic_line_mask` (docs/method.md §3, §8.3); unstable orders excluded;
3. stabilisation classes of every in-band pole against the previous order (docs/method.md §4);
4. modal dominancy index of every mode of the model at the reduction order (the IC order by
   default, or ``reduce_at``), restricted to the band of interest (docs/method.md §5, §8.5);
5. automatic threshold at the largest gap of ``log10 MDI`` among the candidate modes
   (stable, in band, not at Nyquist), split modes grouped, ``top_n`` / manual overrides
   (docs/method.md §7); modes above the threshold but not stabilised in frequency are vetoed;
6. reduction to the physical modes by ordered real Schur form and B, D re-estimation
   (docs/method.md §6); poles and nonlinear coefficients of the reduced model;
7. a confidence statement combining the separation ratio with the agreement between the
   MDI classification and stabilisation (docs/method.md §7.4, §8.5).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.progress import Progress
from fnsi_lab.ident.robust import mdi as mdi_mod
from fnsi_lab.ident.robust import order_selection as osel
from fnsi_lab.ident.robust import stabilisation as stab
from fnsi_lab.ident.robust.auto_result import AutoResult, confidence_statement
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.excitation import MAINS_HZ
from fnsi_lab.ident.core.fast_bd import fast_estimate_bd, model_error, model_output
from fnsi_lab.ident.core.models import model_at_order_fast
from fnsi_lab.ident.core.state_space import dt_modal
from fnsi_lab.ident.robust.options import OUT_OF_BAND, AutoOptions, parse_orders

__all__ = ["AutoOptions", "AutoResult", "identify_auto", "modal_form", "confidence_statement",
           "fast_estimate_bd", "parse_orders", "OUT_OF_BAND"]


# --------------------------------------------------------------------------------------
def modal_form(model):
    """Modal form of an identified model for its own time base.

    Parameters
    ----------
    model : ident.core.fnsi.StateSpaceModel

    Returns
    -------
    mu : complex ndarray, shape (n,)
        Eigenvalues of ``A_d`` (the order of ``model.poles``).
    lam : complex ndarray, shape (n,)
        CT poles (rad/s), ``model.poles.eigenvalues``.
    c_hat, b_hat : complex ndarray, shapes (p, n), (n, m_e)
        ``C_c Phi`` and ``Phi^-1 B_c``: the CT modal outputs and inputs (``A_c`` shares the
        eigenvectors ``Phi`` of ``A_d`` for every time base).
    c_hat_d, b_hat_d : complex ndarray, shapes (p, n), (n, m_e)
        ``C_d Phi`` and ``Phi^-1 B_d``.
    """
    mu, phi, _ = dt_modal(model)
    lam = np.asarray(model.poles.eigenvalues)
    return (mu, lam, model.c_c @ phi, np.linalg.solve(phi, model.b_c.astype(complex)),
            model.c_d @ phi, np.linalg.solve(phi, model.b_d.astype(complex)))


def _restrict_diagram(diagram, band):
    """The stabilisation diagram restricted to the poles inside ``band`` (Hz)."""
    out = []
    for o in diagram.orders:
        sel = np.flatnonzero((o.frequency_hz >= band[0]) & (o.frequency_hz <= band[1]))
        out.append(stab.StabilisationOrder(
            order=o.order, frequency_hz=o.frequency_hz[sel], damping_ratio=o.damping_ratio[sel],
            classes=tuple(o.classes[i] for i in sel), unstable=o.unstable[sel], mac=o.mac[sel],
            index=o.index[sel]))
    return replace(diagram, orders=tuple(out), band_hz=tuple(band))


def _progress(progress, total):
    if progress is None or progress is False:
        return Progress(total, "orders", enabled=False)
    if progress is True:
        return Progress(total, "FNSI orders")
    return progress


def _band_of_interest(data, options):
    if options.band_of_interest_hz is not None:
        return tuple(float(x) for x in options.band_of_interest_hz)
    exc = np.asarray(data.excited, bool)
    if exc.any():
        f = data.frequencies_hz[exc]
        return (float(f.min()), float(f.max()))
    return (float(data.frequencies_hz.min()), float(data.frequencies_hz.max()))


def identify_auto(data, options: AutoOptions | dict | None = None, *,
                  orders: Sequence[int] = range(2, 61), reduce_at: int | None = None,
                  progress=None, coefficients: Callable | None = None,
                  spread: Callable | None = None) -> AutoResult:
    """Identify a model and its physical modes without reading a stabilisation diagram.

    Parameters
    ----------
    data : ident.core.fnsi.FrequencyData
    options : AutoOptions or dict, optional
    orders : sequence of int
        Order sweep (default 2..60, as in the seed).
    reduce_at : int, optional
        Apply MDI and reduction at this order (e.g. a high order that holds every mode);
        default the order chosen by the information criterion.
    progress : bool or fnsi_lab.progress.Progress, optional
        Progress bar over the orders (None/False: silent).
    coefficients : callable, optional
        ``coefficients(model) -> dict`` (JSON-able summary of the nonlinear coefficients,
        e.g. built on :func:`ident.core.coefficients.nonlinear_coefficients`); called for the
        selected, full and reduced models.
    spread : callable, optional
        ``spread(model) -> rho`` (:func:`ident.core.coefficients.spread_function`): the coefficient
        consistency used by ``order_selection='consistent'``; without it the order is
        ``argmin I``.

    Returns
    -------
    AutoResult

    Raises
    ------
    IdentError
        Bad options, no stable order, or sizes the subspace step cannot meet.

    Notes
    -----
    docs/method.md §3 (IC with the exact frequency-domain shortcut), §4 (stabilisation), §5 (MDI),
    §6 (reduction), §7 (threshold), §8.3 and §8.5 (band choices, confidence).
    """
    from fnsi_lab.ident.core import fnsi

    options, orders, sweep = _checked_request(options, orders, reduce_at)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    decomp = fnsi.subspace_decomposition(data, max_order=max(sweep), block_rows=options.block_rows,
                                         weighted=options.weighted)
    timings["subspace"] = time.perf_counter() - t0

    ic_mask, ic_band = osel.ic_line_mask(data.frequencies_hz, data.excited, data.n_outputs,
                                         options.ic_band)
    boi = _band_of_interest(data, options)
    t1 = time.perf_counter()
    models, v, stable = _sweep_models(decomp, data, sweep, orders, ic_mask, options,
                                      _progress(progress, len(sweep)))
    timings["sweep"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    ic, n_sel, rho, consistent, how = _select_order(data, orders, models, v, stable, ic_mask,
                                                    ic_band, options, spread)
    modes = _sweep_modes(models, sweep)
    diagram = stab.classify_stabilisation(sweep, *modes, band_hz=(0.0, np.inf),
                                          freq_tol=options.freq_tol,
                                          damping_tol=options.damping_tol,
                                          mac_tol=options.mac_tol,
                                          lookback=options.stab_lookback)
    diagram_boi = _restrict_diagram(diagram, boi)
    timings["ic_stabilisation"] = time.perf_counter() - t2

    # MDI at the reduction order
    t3 = time.perf_counter()
    n_mdi = int(reduce_at) if reduce_at is not None else n_sel
    if decomp.weighted and options.sweep_bd == "fast":
        # the weighted B, D least squares (docs/method.md §1.4) for the models that are reported
        for n in {n_sel, n_mdi}:
            models[n] = fnsi.model_at_order(decomp, data, n, d_zero=options.d_zero)
    full, answer_rows = _answer_model(decomp, data, models[n_mdi], n_mdi, options)
    # stabilisation classes are looked up by frequency in the sweep's model at n_mdi: exactly
    # for that model, within the stabilisation tolerance for a re-estimated one
    match_tol = 1e-6 if answer_rows is None else options.freq_tol
    modal = modal_form(full)
    md, weights, oweights = _modal_dominancy(data, full, modal, boi, options)
    cls = _classes_at_order(diagram, sweep, modes, n_mdi, md.frequency_hz, match_tol, options)
    cls_arr = np.array(cls, object)
    sel = _mdi_selection(md, modal[1], modal[2], modal[3], weights, oweights, cls_arr, options)
    gates = _detection_gates(full, data, md, modal, sel, options)
    physical = gates["physical"]
    timings["mdi"] = time.perf_counter() - t3
    disagree, final_ratio = _disagreements(data, md, cls_arr, sel, gates, options)

    # reduction
    t4 = time.perf_counter()
    reduced, plausible_oob = _reduce(full, data, md, modal[0], physical, cls_arr, gates["detection"],
                                     options)
    final, answer, rho_full, rho_reduced = _choose_answer(full, reduced, spread, options)
    timings["reduction"] = time.perf_counter() - t4

    conf = _confidence(answer, boi, physical, disagree, sel["threshold"], final_ratio, n_sel,
                       orders, options)
    coefs = _coefficients(coefficients, models[n_sel], full, reduced, timings)
    timings["total"] = time.perf_counter() - t0

    thr = sel["threshold"]
    return AutoResult(information_criterion=ic, selected_order=n_sel, stabilisation=diagram_boi,
                      mdi_order=n_mdi, modal_dominancy=md, candidates=sel["candidates"],
                      physical=physical, threshold=thr, separation_ratio=thr.separation_ratio,
                      confidence=conf, model=models[n_sel], full_model=full, reduced=reduced,
                      coefficients=coefs, options=options,
                      groups=tuple(tuple(g) for g in sel["groups"]),
                      stab_class_at_mdi_order=tuple(cls), timings_s=timings, models=models,
                      ic_order=ic.selected_order, coefficient_spread=rho,
                      consistent=consistent, order_selection=how,
                      detection=gates["detection"], final=final,
                      final_spread={"full": rho_full, "reduced": rho_reduced},
                      plausible_out_of_band=plausible_oob, answer_block_rows=answer_rows)


def _modal_dominancy(data, full, modal, boi, options):
    """The MDI of every mode of ``full`` (docs/method.md §5) and the input and output weights
    it was computed with."""
    _, lam, ch, bh, _, _ = modal
    weights = mdi_mod.input_weights(data.E_physical, data.n_inputs, options.input_scaling)
    oweights = mdi_mod.output_weights(data.Y, options.output_scaling, data.noise_cov)
    md = mdi_mod.modal_dominancy(lam, ch, bh, boi, norm=options.mdi_norm, weights=weights,
                                 nyquist_hz=full.sample_rate_hz / 2, out_weights=oweights)
    return md, weights, oweights


def _checked_request(options: AutoOptions | dict | None, orders: Sequence[int],
                     reduce_at: int | None) -> tuple[AutoOptions, list[int], list[int]]:
    """Validated options, the sorted orders of the criterion and the sweep (orders plus
    ``reduce_at - 2 .. reduce_at + 2``)."""
    if options is None:
        options = AutoOptions()
    elif isinstance(options, dict):
        options = AutoOptions.from_dict(options)
    options = options.validate()
    orders = sorted({int(n) for n in orders})
    if not orders or orders[0] < 1:
        raise IdentError(f"orders must be positive integers, got {plain.value(orders)}")
    sweep = sorted(set(orders) | ({int(reduce_at) + k for k in range(-2, 3)} - {0, -1}
                                   if reduce_at is not None else set()))
    return options, orders, sweep


def _sweep_models(decomp, data, sweep: list[int], orders: list[int], ic_mask: np.ndarray,
                  options: AutoOptions, bar: Progress
                  ) -> tuple[dict[int, Any], dict[int, float], dict[int, bool]]:
    """The model of every order of the sweep, its stability and (for the criterion's orders)
    its error ``V(n)`` on the criterion's lines."""
    models: dict[int, Any] = {}
    v: dict[int, float] = {}
    stable: dict[int, bool] = {}
    for n in sweep:
        model = model_at_order_fast(decomp, data, n, d_zero=options.d_zero,
                                     weighted_bd=options.sweep_bd == "weighted")
        models[n] = model
        stable[n] = bool(model.stable)
        if n in orders:
            v[n] = model_error(model, data, ic_mask)
        bar.update(1, note=f"n={n}")
    return models, v, stable


def _select_order(data, orders, models, v, stable, ic_mask, ic_band, options, spread):
    """The information criterion and the selected order (``argmin I``, or the consistency
    gate when ``spread`` is given and ``order_selection='consistent'``).

    Returns
    -------
    ic, n_sel, rho (coefficient spread per order), consistent (bool per order), how
    """
    ic = osel.InformationCriterion.from_errors(
        orders, [v[n] for n in orders], [stable[n] for n in orders], int(ic_mask.sum()),
        band=ic_band, criterion=options.criterion, n_outputs=data.n_outputs,
        n_extended_inputs=data.n_extended_inputs, d_zero=options.d_zero)
    n_sel = ic.selected_order
    rho = np.full(len(orders), np.nan)
    consistent = np.zeros(len(orders), bool)
    how = "ic"
    if spread is not None and options.order_selection == "consistent":
        for k, n in enumerate(orders):
            if ic.stable[k]:
                rho[k] = spread(models[n])
        if np.any(np.isfinite(rho)):
            n_sel, consistent = osel.select_order_consistent(
                orders, ic.value, ic.stable, rho, options.spread_factor,
                model_error=ic.model_error)
            how = "consistent"
    return ic, n_sel, rho, consistent, how


def _sweep_modes(models, sweep):
    """Frequencies (Hz), damping ratios and mode shapes of each order's modes (one per pair,
    not at Nyquist), lists in the sweep's order."""
    fl, zl, sl = [], [], []
    for n in sweep:
        p = models[n].poles
        idx = np.flatnonzero(p.is_mode)
        fl.append(p.natural_frequency_hz[idx])
        zl.append(p.damping_ratio[idx])
        sl.append(p.mode_shapes[:, idx])
    return fl, zl, sl


_CLASS_RANK = {"none": -1, "new": 0, "frequency": 1, "damping": 2, "mode": 3, "stable": 4}


def _classes_at_order(diagram, sweep, modes, n_mdi, frequency_hz, match_tol, options):
    """Stabilisation class of each MDI mode, matched by frequency to the order ``n_mdi``.

    The class at ``n_mdi`` against the previous orders and, for poles that are 'new' there,
    against the next orders too (docs/method.md §4: "previous (or next) order"): a mode that
    first appears at ``n_mdi`` and persists above it is not vetoed.
    """
    fl, zl, sl = modes
    st_o = diagram.by_order(n_mdi)
    nxt = [n for n in sweep if n > n_mdi][:options.stab_lookback]
    st_f = None
    if nxt:
        seq = sorted(nxt, reverse=True) + [n_mdi]
        rev = stab.classify_stabilisation(seq, [fl[sweep.index(n)] for n in seq],
                                          [zl[sweep.index(n)] for n in seq],
                                          [sl[sweep.index(n)] for n in seq],
                                          freq_tol=options.freq_tol,
                                          damping_tol=options.damping_tol,
                                          mac_tol=options.mac_tol, lookback=len(nxt))
        st_f = rev.by_order(n_mdi)

    def class_of(st, f):
        if st is None or not st.frequency_hz.size:
            return "none"
        k = int(np.argmin(np.abs(st.frequency_hz - f)))
        return st.classes[k] if abs(st.frequency_hz[k] - f) <= match_tol * max(f, 1e-12) else "none"

    cls = []
    for f in frequency_hz:
        cb, cf = class_of(st_o, f), class_of(st_f, f)
        cls.append(cb if _CLASS_RANK[cb] >= _CLASS_RANK[cf] or cb == "none" else cf)
    return cls


def _mdi_selection(md, lam, ch, bh, weights, oweights, cls_arr, options) -> dict:
    """Physical modes by the MDI threshold, the stabilisation rescue and veto (docs/method.md §7).

    Returns
    -------
    dict
        ``candidates``, ``values`` (the norm's MDI), ``groups``, ``threshold``, ``physical``,
        ``rescued``, ``vetoed`` (bool per mode) and ``fallback`` (no clear gap).
    """
    # eligible for the gap search: stable, in the band of interest, not at Nyquist (docs/method.md §7.1);
    # stabilisation acts afterwards as a veto (docs/method.md §8.5), so spurious poles still populate
    # the lower side of the gap and genuine modes are not split among themselves
    cand = md.in_band & md.stable
    veto = (cls_arr == "new") if options.require_stabilised else np.zeros(cand.size, bool)
    values = md.values[options.mdi_norm]
    groups: list[list[int]] = [[i] for i in range(values.size)]
    unit_values = values.copy()
    if options.group_split_modes:
        groups, unit_values = mdi_mod.group_split_modes(md, lam, ch, bh, weights=weights,
                                                        out_weights=oweights)
        if options.mdi_norm != "h2":     # groups' joint value is an H2 value; keep the norm's
            unit_values = np.array([values[g[0]] if len(g) == 1 else unit_values[i]
                                    for i, g in enumerate(groups)])
    unit_cand = np.array([all(cand[g]) for g in groups], bool)
    thr = mdi_mod.largest_gap_threshold(unit_values, candidates=unit_cand,
                                        min_physical=options.min_physical, top_n=options.top_n,
                                        manual_threshold=options.manual_threshold)
    physical = np.zeros(values.size, bool)
    for g, ph in zip(groups, thr.physical):
        physical[g] = ph
    # not a clear gap: the MDI alone cannot separate (e.g. no spurious pole in band, so the
    # gap falls between genuine modes); fall back on stabilisation + a relative floor
    # Asymmetric costs: dropping a genuine mode degrades the reduced model, keeping a weak
    # spurious one only misses an improvement. So a fully stable mode (frequency, damping
    # and MACX) whose MDI is not negligible is kept even below the gap ("rescued"), and when
    # the gap is not clear any mode stabilised in frequency is (docs/method.md §7.5, §8.5).
    fallback = (options.fallback == "stabilisation" and thr.method == "largest_gap"
                and not (thr.separation_ratio >= options.clear_ratio))
    rescued = np.zeros(values.size, bool)
    if options.fallback == "stabilisation" and thr.method == "largest_gap" and cand.any():
        rescued = cand & ~physical & (cls_arr == "stable")
        if fallback:
            floor = options.fallback_rel_floor * float(np.max(values[cand]))
            rescued |= (cand & ~physical & (cls_arr != "new") & (cls_arr != "none")
                        & (values >= floor))
        physical |= rescued
    vetoed = physical & veto
    physical &= ~veto
    return {"candidates": cand, "values": values, "groups": groups, "threshold": thr,
            "physical": physical, "rescued": rescued, "vetoed": vetoed, "fallback": fallback}


def _detection_gates(full, data, md, modal, sel, options) -> dict:
    """The MDI selection after the detectability and mains-hum gates (docs/method.md §8.5).

    Returns
    -------
    dict
        ``physical``, ``detection`` (per mode, in noise sigmas), ``undetectable``,
        ``unresolved`` and ``hum`` (bool per mode).
    """
    mu, _, _, _, ch_d, bh_d = modal
    physical, rescued = sel["physical"].copy(), sel["rescued"]
    # detectability: in its own bandwidth a mode must stand out of the model's residual
    # (docs/method.md §8.5); nested models of one SVD keep noise-fitting poles "stable" across
    # orders, so stability alone does not make a mode
    y_model = model_output(full, data)
    detection = mdi_mod.modal_detection(mu, ch_d, bh_d, data.E_physical, data.z,
                                        data.Y, y_model, data.frequencies_hz, md.members,
                                        md.frequency_hz, md.damping_ratio,
                                        noise_var=getattr(data, "noise_var", None))
    undetectable = physical & ~(detection >= options.detection_sigma)
    # a mode kept by stabilisation alone (below the MDI threshold) must stand clearly out of
    # the residual, beyond the marginal zone: the lab Duffing's spurious 65 Hz pole (0.06 %
    # damping, half a line wide) read 3.0 with two BLAS threads and 5.3 with one, the
    # round-off of the order-8 model alone; genuine weak modes read 29-700 (docs/robust.md)
    undetectable |= physical & rescued & ~(detection >= 2 * options.detection_sigma)
    physical &= ~undetectable
    # resolution: a mode whose half-power half-width zeta f_n is below a fraction of the
    # line spacing falls between the lines, and its damping is poorly determined by them.
    # Genuine lightly damped modes do that too (a 3-DOF test chain: 0.25 lines, identified
    # within 0.5 %), so it only lowers the confidence; at a mains harmonic such a pole fits
    # hum (a sinusoid the force does not drive) and is dropped
    line_hz = data.sample_rate_hz / data.samples_per_period
    unresolved = (physical & (np.abs(md.damping_ratio) * md.frequency_hz
                              < options.min_half_power_lines * line_hz))
    at_mains = np.zeros(unresolved.size, bool)
    for f_m in MAINS_HZ:
        h = np.round(md.frequency_hz / f_m)
        at_mains |= (h >= 1) & (np.abs(md.frequency_hz - h * f_m) <= 3 * line_hz)
    hum = unresolved & at_mains
    physical &= ~hum
    duplicate = _duplicate_modes(md, modal[2], physical, sel["values"])
    physical &= ~duplicate
    return {"physical": physical, "detection": detection, "undetectable": undetectable,
            "unresolved": unresolved, "hum": hum, "duplicate": duplicate}


#: Two kept modes closer than this in frequency (relative) ... (the split-mode grouping's
#: 0.2 %, docs/method.md §7)
_DUPLICATE_FREQUENCY = 0.002
#: ... with damping ratios within this fraction of the larger ...
_DUPLICATE_DAMPING = 0.5
#: ... and output shapes with at least this MAC(X) are one mode fitted twice.
_DUPLICATE_MAC = 0.9


def _duplicate_modes(md, c_hat: np.ndarray, physical: np.ndarray,
                     values: np.ndarray) -> np.ndarray:
    """The weaker pole of every kept pair that fits one mode twice, shape (q,) bool.

    Two kept modes within 0.2 % in frequency, of similar damping and the same output shape
    (MAC >= 0.9) cannot be told apart by the data: their half-power bands overlap many times
    over. The subspace fit split one mode's residue between them (an independent Iwan-joint
    chain at 3 N: 6.678 and 6.683 Hz, MDI 0.70 and 81, one mode at 6.682 Hz in the truth).
    The one of smaller MDI is left out; the reduction refits the other. ``c_hat``: the
    modal outputs :attr:`ModalDominancy.members` index. Pairs whose residues
    cancel are grouped before the threshold instead (:func:`ident.robust.mdi.group_split_modes`).
    """
    duplicate = np.zeros(physical.size, bool)
    kept = [i for i in np.argsort(md.frequency_hz) if physical[i] and md.is_pair[i]]
    for a, b in zip(kept[:-1], kept[1:]):
        fa, fb = md.frequency_hz[a], md.frequency_hz[b]
        za, zb = abs(md.damping_ratio[a]), abs(md.damping_ratio[b])
        if (abs(fb - fa) > _DUPLICATE_FREQUENCY * fa
                or abs(za - zb) > _DUPLICATE_DAMPING * max(za, zb)):
            continue
        # the stabilisation diagram's shape measure (either pole of a pair: MACX does not
        # see the conjugation)
        if stab.macx(c_hat[:, md.members[a][0]], c_hat[:, md.members[b][0]]) >= _DUPLICATE_MAC:
            duplicate[a if values[a] < values[b] else b] = True
    return duplicate


def _disagreements(data, md, cls_arr, sel, gates, options):
    """Where the MDI, stabilisation and detection disagree (the confidence's evidence), and
    the separation ratio of the final selection among the candidates."""
    physical, undetectable = gates["physical"], gates["undetectable"]
    unresolved, hum, detection = gates["unresolved"], gates["hum"], gates["detection"]
    rescued, vetoed, cand, values = sel["rescued"], sel["vetoed"], sel["candidates"], sel["values"]
    inb = md.in_band
    disagree = {
        "kept_not_stabilised": sorted(md.frequency_hz[physical & (cls_arr == "new")].tolist()),
        "vetoed_not_stabilised": sorted(md.frequency_hz[vetoed].tolist()),
        "rescued_by_stabilisation": sorted(md.frequency_hz[rescued & physical].tolist()),
        "dropped_fully_stable": sorted(md.frequency_hz[~physical & inb & md.stable & ~undetectable
                                                       & ~gates["duplicate"]
                                                       & (cls_arr == "stable")].tolist()),
        "excluded_out_of_band": int(np.sum(~inb)),
        "excluded_unstable": int(np.sum(inb & ~md.stable)),
        "below_residual": sorted(md.frequency_hz[undetectable].tolist()),
    }
    disagree["fallback"] = bool(sel["fallback"])
    kept_v, drop_v = values[physical & cand], values[~physical & cand]
    final_ratio = (float(kept_v.min() / drop_v.max()) if kept_v.size and drop_v.size
                   and drop_v.max() > 0 else float("inf") if kept_v.size else float("nan"))
    disagree["unresolved"] = sorted(md.frequency_hz[unresolved & ~hum].tolist())
    disagree["mains_hum"] = sorted(md.frequency_hz[hum].tolist())
    disagree["duplicate_modes"] = sorted(md.frequency_hz[gates["duplicate"]].tolist())
    disagree["marginal_detection"] = sorted(md.frequency_hz[
        physical & (detection < 2 * options.detection_sigma)].tolist())
    disagree["noise_source"] = getattr(data, "noise_source", "none")
    return disagree, final_ratio


def _reduce(full, data, md, mu, physical, cls_arr, detection, options):
    """The reduced model (None when every or no pole is kept) and the plausible out-of-band
    modes.

    Poles kept in the reduced model: the physical in-band modes and the stable poles outside
    the band per ``out_of_band``; unstable and Nyquist poles are always removed
    (docs/method.md §7.1).
    """
    from fnsi_lab.ident.robust.reduction import reduce_model

    reduced = None
    nyq = np.abs(md.eigenvalues.imag) >= 0.999 * np.pi * full.sample_rate_hz
    plausible_oob = (~md.in_band & md.stable & ~nyq & (cls_arr != "new") & (cls_arr != "none")
                     & (detection >= options.detection_sigma))
    keep_modes = physical.copy()
    if options.out_of_band == "keep":
        # real (non-oscillating) poles are no structural mode; they stay when they pass the
        # out-of-band plausibility test, or when real_poles is 'keep'
        real = np.abs(md.eigenvalues.imag) <= 1e-9 * np.abs(md.eigenvalues)
        keep_modes |= (~md.in_band & md.stable & ~nyq
                       & (~real | plausible_oob | (options.real_poles == "keep")))
    elif options.out_of_band == "stabilised":
        keep_modes |= plausible_oob
    if keep_modes.any() and not keep_modes.all():
        keep_mask = np.zeros(mu.size, bool)   # md.members index the poles of ``full``
        for i in np.flatnonzero(keep_modes):
            keep_mask[list(md.members[i])] = True
        reduced = reduce_model(full, data, keep_mask, d_zero=options.d_zero,
                               weighted=options.weighted)
    return reduced, plausible_oob


def _choose_answer(full, reduced, spread, options):
    """The answer: the reduced model, unless the reduction made the coefficients less
    consistent than the model it came from (then removing those poles cost information).

    Returns
    -------
    final ('full' or 'reduced'), answer model, rho_full, rho_reduced
    """
    final, answer = "full", full
    rho_full = rho_reduced = float("nan")
    if reduced is not None:
        final, answer = "reduced", reduced
        if spread is not None:
            rho_full, rho_reduced = spread(full), spread(reduced)
            # "less consistent" with the tolerance of the order gate: the spread of orders
            # that agree (spread_factor); a strict comparison answered full models holding
            # spurious in-band poles for a 1 % smaller spread (Silverbox, docs/robust.md)
            if np.isfinite(rho_full) and not rho_reduced <= options.spread_factor * rho_full:
                final, answer = "full", full
    return final, answer, rho_full, rho_reduced


def _confidence(answer, boi, physical, disagree, thr, final_ratio, n_sel, orders, options):
    """The confidence statement, judged on the answer: a model that keeps poles in the band
    of interest that are not physical modes, or modes barely above the residual, is not
    "clear"; a selected order at the end of the sweep adds a warning."""
    ans = answer.poles
    n_inband_answer = int(np.sum(ans.is_mode & (ans.natural_frequency_hz >= boi[0])
                                 & (ans.natural_frequency_hz <= boi[1])))
    disagree["extra_in_answer"] = max(n_inband_answer - int(physical.sum()), 0)
    conf = confidence_statement(thr.separation_ratio, int(physical.sum()), disagree,
                                ambiguous_ratio=options.ambiguous_ratio,
                                clear_ratio=options.clear_ratio)
    conf["final_separation_ratio"] = final_ratio if np.isfinite(final_ratio) else None

    if n_sel == max(orders) and len(orders) > 1:  # no minimum inside the sweep
        conf.setdefault("warnings", []).append(
            f"the selected order {n_sel} is the last of the sweep {min(orders)}..{max(orders)}: "
            "the criterion may keep decreasing beyond it; extend the sweep (e.g. --orders "
            f"{min(orders)}:{2 * max(orders)}) or check the band and the noise")
    return conf


def _coefficients(coefficients, selected, full, reduced, timings) -> dict:
    """``coefficients(model)`` of the selected, full and reduced models (empty without it)."""
    coefs: dict = {}
    if coefficients is not None:
        t5 = time.perf_counter()
        coefs["selected"] = coefficients(selected)
        coefs["full"] = coefficients(full)
        if reduced is not None:
            coefs["reduced"] = coefficients(reduced)
        timings["coefficients"] = time.perf_counter() - t5
    return coefs


def _answer_model(decomp, data, sweep_model, order: int, options: AutoOptions):
    """The model at the chosen order, estimated as a fixed-order run at that order would be.

    The sweep's block rows serve its largest order (``(i - 1) p >= n_max``): with one output
    a sweep to 60 needs ``i >= 61``, and on a short real record (Silverbox, 335 lines) the
    order-2 model of that decomposition scattered 1.0 % over ten periods against 0.2 % with
    the rows of an order-2 run (docs/ident.md, "Block rows"). When the sweep had to go past
    :func:`ident.core.fnsi.noise_row_limit` and the default rows of the chosen order are fewer,
    the model is re-estimated with them. Otherwise the sweep's model is kept: below that
    limit the rows do not change the scatter (lab Duffing, 2684 lines: 0.23-0.33 % for
    i = 5-120), and a re-estimate would lose the consistency of the nested sweep models
    the stabilisation classes come from. A user's ``block_rows``, or an unstable
    re-estimate, also keeps the sweep's model.

    Returns
    -------
    model : StateSpaceModel
    block_rows : int or None
        The rows of the re-estimate, None when the sweep's model is kept.
    """
    from fnsi_lab.ident.core import fnsi
    if options.block_rows is not None:
        return sweep_model, None
    p_sweep = decomp.n_outputs if decomp.output_basis is None else decomp.output_basis.shape[1]
    limit = fnsi.noise_row_limit(p_sweep, data.n_lines, data.n_extended_inputs)
    rows = fnsi.block_rows_for(data, order)
    if decomp.block_rows <= limit or rows >= decomp.block_rows:
        return sweep_model, None
    dec = fnsi.subspace_decomposition(data, max_order=order, block_rows=rows,
                                      weighted=options.weighted)
    model = fnsi.model_at_order(dec, data, order, d_zero=options.d_zero)
    if sweep_model.stable and not model.stable:
        return sweep_model, None
    return model, rows
