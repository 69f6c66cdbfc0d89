"""The one robust pipeline: order sweep -> IC -> stabilisation -> MDI -> reduction (spec §3-8).

:func:`identify_auto` turns frequency-domain data into a model without a human reading the
stabilisation diagram:

1. one QR and one SVD (:func:`ident.fnsi.subspace_decomposition`), then every order of the
   sweep (:func:`ident.fnsi.model_at_order`; spec §1.7);
2. information criterion ``I(n) = V(n)(1 + n/F)`` over the band chosen by
   :func:`ident.order_selection.ic_line_mask` (spec §3, §8.3); unstable orders excluded;
3. stabilisation classes of every in-band pole against the previous order (spec §4);
4. modal dominancy index of every mode of the model at the reduction order (the IC order by
   default, or ``reduce_at``), restricted to the band of interest (spec §5, §8.5);
5. automatic threshold at the largest gap of ``log10 MDI`` among the candidate modes
   (stable, in band, not at Nyquist), split modes grouped, ``top_n`` / manual overrides
   (spec §7); modes above the threshold but not stabilised in frequency are vetoed;
6. reduction to the physical modes by ordered real Schur form and B, D re-estimation
   (spec §6); poles and nonlinear coefficients of the reduced model;
7. a confidence statement combining the separation ratio with the agreement between the
   MDI classification and stabilisation (spec §7.4, §8.5).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg as sla

from fnsi_lab.progress import Progress
from fnsi_lab.ident import mdi as mdi_mod
from fnsi_lab.ident import order_selection as osel
from fnsi_lab.ident import stabilisation as stab
from fnsi_lab.ident.errors import IdentError

#: Policies for the poles outside the band of interest (:attr:`AutoOptions.out_of_band`).
OUT_OF_BAND: tuple[str, ...] = ("keep", "stabilised", "drop")

__all__ = ["AutoOptions", "AutoResult", "identify_auto", "modal_form", "confidence_statement"]


@dataclass(frozen=True)
class AutoOptions:
    """Options of the robust pipeline (all keyword, validated by :meth:`validate`).

    Attributes
    ----------
    ic_band : {'auto', 'processed', 'excited'} or (float, float)
        Lines of the model error V (spec §8.3); see :func:`ident.order_selection.ic_line_mask`.
    criterion : {'mdl', 'seed', 'aic'}
        ``I(n)`` (:func:`ident.order_selection.information_criterion`). ``mdl`` (default):
        Rissanen's minimum description length with the state-space parameter count,
        ``V exp(n_theta ln(N_r) / N_r)``. ``seed``: the paper's ``V (1 + n/F)`` (Eq. 8),
        whose penalty is 3 % at n = 60 and F = 2000 lines, so on a noise or model-error
        plateau its minimum falls anywhere (SmallSat at 40 dB: order 60 against 28 with
        ``mdl``, docs/robust.md); its values are reported either way. ``aic``: AIC-style.
    band_of_interest_hz : (float, float) or None
        Band of the MDI and of the stabilisation diagram; default the excited band.
    mdi_norm : {'h2', 'seed', 'h2_single', 'hinf', 'hinf_band'}
        Norm that classifies (all are reported).
    input_scaling : {'default', 'force', 'raw'}
        Column weights of the modal input rows (spec §5.2).
    output_scaling : {'rms', 'noise', 'none'}
        Row weights of the modal output shapes (:func:`ident.mdi.output_weights`): ``rms``
        counts every channel by its relative response, so a mode that dominates a few
        low-amplitude channels (an instrument plate next to a wheel that moves 10x more)
        is not drowned by the large channels. Not in the seed; ``none`` is the seed's
        absolute sum.
    require_stabilised : bool
        Veto: a mode above the MDI threshold that is not stabilised in frequency against the
        previous order (class ``new``) is dropped and reported (spec §8.5). The gap search
        itself runs over every stable in-band mode.
    min_physical : int
        Search the largest gap below the ``min_physical`` largest candidates.
    top_n : int or None
        Keep exactly the ``top_n`` largest candidates (weak genuine modes; spec §7.5).
    manual_threshold : float or None
        Keep candidates with MDI above this value.
    group_split_modes : bool
        Group near-duplicate poles with cancelling residues (spec §7.5).
    freq_tol, damping_tol, mac_tol : float
        Stabilisation tolerances (spec §4).
    out_of_band : {'keep', 'stabilised', 'drop'}
        Poles outside the band of interest, which the MDI does not judge. ``keep``
        (default): every stable pole outside the band stays in the reduced model (real
        poles too): genuine modes above the excitation band carry the response the basis
        functions drive there, and a pole fitting residual content there does not disturb
        ``c_a`` in the band. ``stabilised``: only the pairs stabilised (at least in
        frequency) against the neighbouring orders and standing out of the residual in
        their bandwidth (``detection_sigma``). ``drop`` (one reading of the seed): only the
        physical in-band modes. Unstable and Nyquist poles are always removed. On the
        SmallSat (39 channels) ``drop`` raised the coefficient std 3-20x and ``stabilised``
        up to 8x against ``keep`` (docs/robust.md). JSON ``poles`` flag as physical the
        out-of-band pairs that pass the ``stabilised`` test, whatever the policy.
    sweep_bd : {'fast', 'weighted'}
        B, D of the sweep's models when the data carry a noise covariance: ``fast`` uses the
        unweighted modal-form least squares for every order (they only feed V(n); poles and
        mode shapes come from A, C of the weighted SVD) and re-estimates the selected and MDI
        models with the weighted routine (spec §1.4); ``weighted`` uses it for every order
        (about 1-3 s per order with 39 outputs).
    stab_lookback : int
        Previous orders each pole is compared with (best class kept); 2 because the sweep
        visits odd orders, which hold a real pole and are poor references for pairs.
    d_zero : bool
        ``D = 0`` in every least squares (displacement/velocity outputs).
    weighted : bool
        Use the noise covariance in the SVD and B, D least squares when available.
    block_rows : int or None
        ``i``; default from the core.
    ambiguous_ratio, clear_ratio : float
        Separation ratios below ``ambiguous_ratio`` are reported as ambiguous, above
        ``clear_ratio`` as clear (spec §7.4: "below about 2, call it ambiguous").
    fallback : {'stabilisation', 'none'}
        Combine the MDI split with stabilisation (spec §7.5, §8.5): an eligible mode below
        the gap is kept if it is fully stable (frequency, damping and MACX against the
        neighbouring orders); when the largest-gap ratio is below ``clear_ratio``, any mode
        stabilised in frequency with ``MDI >= fallback_rel_floor * max MDI`` is kept too. Reason: when no spurious
        pole lies in band the largest gap falls between genuine modes, and dropping a genuine
        mode degrades the reduced model (measured on the lumped model: +8.9 % coefficient
        error) whereas keeping a weak spurious one only forgoes an improvement.
    order_selection : {'consistent', 'ic'}
        ``ic``: the selected order is ``argmin I`` (seed Eq. 8). ``consistent`` (default,
        used when the coefficients can be computed: basis functions and a measured driving
        point): ``argmin I`` over the orders whose coefficient spread ``rho(n)``
        (:func:`ident.coefficients.coefficient_spread`) is within ``spread_factor`` of the
        smallest; see :func:`ident.order_selection.select_order_consistent`.
    detection_sigma : float
        A mode is physical only if its energy in its bandwidth exceeds this many standard
        deviations of the residual's energy there (:func:`ident.mdi.modal_detection`);
        0 disables the test. 5 rather than 3 because residuals are not white when they are
        model error rather than noise: a fully stable spurious pole of a noise-free 3-DOF
        chain reached 3.8, genuine weak modes 29-700 (docs/robust.md).
    spread_factor : float
        Gate of ``consistent`` selection. 3: on the SmallSat the orders whose coefficients
        were within 0.1-0.3 % had ``rho`` within 3x of the best (docs/robust.md).
    fallback_rel_floor : float
        Relative MDI floor of the not-clear-gap fallback (spec §7.5 suggests 1e-3). Fully
        stable modes need no floor: weakly excited genuine modes carry MDI 1e-6 to 1e-3 of the
        largest (spec §8.5; SmallSat modes 9-11 with 39 channels).
    """

    ic_band: Any = "auto"
    criterion: str = "mdl"
    band_of_interest_hz: tuple | None = None
    mdi_norm: str = "h2"
    input_scaling: str = "default"
    output_scaling: str = "rms"
    require_stabilised: bool = True
    min_physical: int = 1
    top_n: int | None = None
    manual_threshold: float | None = None
    group_split_modes: bool = True
    freq_tol: float = 0.01
    damping_tol: float = 0.05
    mac_tol: float = 0.98
    stab_lookback: int = 2
    sweep_bd: str = "fast"
    out_of_band: str = "keep"
    d_zero: bool = False
    weighted: bool = True
    block_rows: int | None = None
    ambiguous_ratio: float = 2.0
    clear_ratio: float = 10.0
    fallback: str = "stabilisation"
    fallback_rel_floor: float = 1e-3
    order_selection: str = "consistent"
    spread_factor: float = 3.0
    detection_sigma: float = 5.0

    def validate(self) -> "AutoOptions":
        """Raise :class:`IdentError` naming the bad option and the allowed values."""
        if self.criterion not in osel.CRITERIA:
            raise IdentError(f"criterion={self.criterion!r} is not one of {osel.CRITERIA}")
        if self.mdi_norm not in mdi_mod.MDI_NORMS:
            raise IdentError(f"mdi_norm={self.mdi_norm!r} is not one of {mdi_mod.MDI_NORMS}")
        if self.output_scaling not in ("rms", "noise", "none"):
            raise IdentError(f"output_scaling={self.output_scaling!r} is not one of "
                             "('rms', 'noise', 'none')")
        if self.input_scaling not in mdi_mod.INPUT_SCALINGS:
            raise IdentError(f"input_scaling={self.input_scaling!r} is not one of "
                             f"{mdi_mod.INPUT_SCALINGS}")
        if isinstance(self.ic_band, str) and self.ic_band not in osel.IC_BANDS:
            raise IdentError(f"ic_band={self.ic_band!r} is not one of {osel.IC_BANDS} or (f1, f2)")
        if self.top_n is not None and self.manual_threshold is not None:
            raise IdentError("give top_n or manual_threshold, not both")
        if self.sweep_bd not in ("fast", "weighted"):
            raise IdentError(f"sweep_bd={self.sweep_bd!r} is not one of ('fast', 'weighted')")
        if self.out_of_band not in OUT_OF_BAND:
            raise IdentError(f"out_of_band={self.out_of_band!r} is not one of {OUT_OF_BAND}")
        if self.fallback not in ("stabilisation", "none"):
            raise IdentError(f"fallback={self.fallback!r} is not one of ('stabilisation', 'none')")
        if self.order_selection not in ("consistent", "ic"):
            raise IdentError(f"order_selection={self.order_selection!r} is not one of "
                             "('consistent', 'ic')")
        if not self.detection_sigma >= 0:
            raise IdentError(f"detection_sigma must be >= 0, got {self.detection_sigma}")
        if not self.spread_factor >= 1:
            raise IdentError(f"spread_factor must be >= 1, got {self.spread_factor}")
        if self.min_physical < 1:
            raise IdentError(f"min_physical must be >= 1, got {self.min_physical}")
        return self

    @classmethod
    def from_dict(cls, d: dict | None) -> "AutoOptions":
        """From a plain mapping (YAML ``auto:`` section); unknown keys are rejected."""
        d = dict(d or {})
        names = set(cls.__dataclass_fields__)
        bad = sorted(set(d) - names)
        if bad:
            raise IdentError(f"unknown auto option(s) {bad}; allowed: {sorted(names)}")
        for k in ("band_of_interest_hz",):
            if d.get(k) is not None:
                d[k] = tuple(float(x) for x in d[k])
        if isinstance(d.get("ic_band"), (list, tuple)):
            d["ic_band"] = tuple(float(x) for x in d["ic_band"])
        return cls(**d).validate()


# --------------------------------------------------------------------------------------
def modal_form(model):
    """Modal form of an identified model for its own time base.

    Parameters
    ----------
    model : ident.fnsi.StateSpaceModel

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
    from fnsi_lab.ident import fnsi
    mu, phi, _ = fnsi._dt_modal(model)
    lam = np.asarray(model.poles.eigenvalues)
    return (mu, lam, model.c_c @ phi, np.linalg.solve(phi, model.b_c.astype(complex)),
            model.c_d @ phi, np.linalg.solve(phi, model.b_d.astype(complex)))


# --------------------------------------------------------------------------------------
# Fast unweighted B, D for the order sweep (helper kept here, separate from the core)
# --------------------------------------------------------------------------------------
#: Eigenvector condition number above which the sweep falls back to the core's estimate_bd.
_FAST_COND_LIMIT = 1e8


def fast_estimate_bd(a_d, c_d, data, *, d_zero: bool = False, refine: int = 2):
    """Unweighted ``B``, ``D`` least squares in modal coordinates, BLAS-only (spec §1.4).

    Same problem and result as :func:`ident.fnsi.estimate_bd` with ``weighted=False``
    (the oracle in the tests), organised so that one order costs one
    ``(F, m_e n)^H (F, m_e n)`` product.

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
    data : FrequencyData
    d_zero : bool
    refine : int
        Steps of iterative refinement (residual in the original form).

    Returns
    -------
    (b_d, d_d) : ndarrays, shapes (n, m_e), (p, m_e), physical basis units;
        or None when ``A_d``'s eigenvectors are too ill-conditioned (caller falls back).

    Notes
    -----
    ``Y_k = C_hat diag(w_k) B_hat E_k + D E_k``, ``w_k = 1/(z_k - mu)``, ``B_hat = Phi^-1 B``.
    With ``U[k, (j, a)] = E_kj w_ka`` and ``G = C_hat^H C_hat``:
    ``N_BB = (U^H U) .* G`` (blockwise), ``N_BD[(j,a),(l,i)] = conj(C_hat[i,a]) (U^H E)[(j,a),l]``,
    ``N_DD = (E^H E) (x) I_p``; the real unknowns follow from ``vec B_hat = (I (x) Phi^-1) vec B``
    and real parts (the lines are the positive-frequency half of a real problem).
    """
    a_d = np.asarray(a_d, float)
    c_d = np.asarray(c_d, float)
    n = a_d.shape[0]
    p, me = c_d.shape[0], data.E.shape[1]
    mu, phi = np.linalg.eig(a_d)
    if not np.isfinite(np.linalg.cond(phi)) or np.linalg.cond(phi) > _FAST_COND_LIMIT:
        return None
    pinv = np.linalg.inv(phi)
    ch = c_d @ phi
    E, Y, z = data.E, data.Y, data.z
    F = z.size
    w = 1.0 / (z[:, None] - mu[None, :])                        # (F, n)
    U = (E[:, :, None] * w[:, None, :]).reshape(F, me * n)      # (F, (j,a))
    G = ch.conj().T @ ch                                         # (n, n)
    Nbb = (U.conj().T @ U).reshape(me, n, me, n) * G[None, :, None, :]
    # to real B coordinates: block (j,l) -> Pinv^H Nbb_jl Pinv
    Nbb = np.einsum("ia,jalb,bk->jilk", pinv.conj().T, Nbb, pinv, optimize=True)
    nb = me * n
    if d_zero:
        Nr = Nbb.reshape(nb, nb).real
    else:
        UE = (U.conj().T @ E).reshape(me, n, me)                 # [(j,a), l]
        Nbd = UE[:, :, :, None] * ch.conj().T[None, :, None, :]  # (j, a, l, i)
        Nbd = np.einsum("ia,jalm->jilm", pinv.conj().T, Nbd, optimize=True)
        Ndd = np.einsum("jl,im->jilm", E.conj().T @ E, np.eye(p))
        nd = me * p
        Nc = np.zeros((nb + nd, nb + nd), complex)
        Nc[:nb, :nb] = Nbb.reshape(nb, nb)
        Nc[:nb, nb:] = Nbd.reshape(nb, nd)
        Nc[nb:, :nb] = Nbd.reshape(nb, nd).conj().T
        Nc[nb:, nb:] = Ndd.reshape(nd, nd)
        Nr = Nc.real
    Nr = 0.5 * (Nr + Nr.T)

    def rhs(R):
        Z = R @ ch.conj()                                        # (F, n)
        rb = (E.conj().T @ (w.conj() * Z))                       # (me, n) modal
        rb = (rb @ pinv.conj()).reshape(-1)                      # to real coordinates
        if d_zero:
            return rb.real
        rd = (E.conj().T @ R).reshape(-1)                        # (me, p)
        return np.concatenate([rb.real, rd.real])

    def predict(theta):
        B = theta[:nb].reshape(me, n).T
        out = ((E @ B.T @ pinv.T) * w) @ ch.T
        if not d_zero:
            D = theta[nb:].reshape(me, p).T
            out = out + E @ D.T
        return out

    d = np.sqrt(np.abs(np.diag(Nr)))
    d[d == 0] = 1.0
    Ns = Nr / np.outer(d, d)
    try:
        cho = sla.cho_factor(Ns, check_finite=False)
        solve = lambda r: sla.cho_solve(cho, r / d, check_finite=False) / d  # noqa: E731
    except np.linalg.LinAlgError:
        lu = sla.lu_factor(Ns, check_finite=False)
        solve = lambda r: sla.lu_solve(lu, r / d, check_finite=False) / d  # noqa: E731
    theta = solve(rhs(Y))
    for _ in range(refine):
        theta = theta + solve(rhs(Y - predict(theta)))
    b = theta[:nb].reshape(me, n).T * data.input_scale[None, :]
    dd = (np.zeros((p, me)) if d_zero else theta[nb:].reshape(me, p).T) * data.input_scale[None, :]
    return b, dd


def _model_at_order_fast(decomp, data, order, *, d_zero=False, weighted_bd=True):
    """:func:`ident.fnsi.model_at_order` with :func:`fast_estimate_bd` for B, D.

    ``A`` and ``C`` always come from ``decomp`` (weighted SVD if it was). ``B``, ``D`` use the
    fast unweighted routine unless the decomposition is weighted and ``weighted_bd``.
    """
    from fnsi_lab.ident import fnsi
    if decomp.weighted and weighted_bd:
        return fnsi.model_at_order(decomp, data, order, d_zero=d_zero)
    n = int(order)
    if not 1 <= n <= decomp.max_order:
        raise IdentError(f"order {n} is outside 1..{decomp.max_order} (max order of this "
                         "decomposition)")
    a_d, c_d = fnsi.state_matrices(decomp, n)
    bd = fast_estimate_bd(a_d, c_d, data, d_zero=d_zero)
    if bd is None:
        b_d, d_d = fnsi.estimate_bd(a_d, c_d, data, d_zero=d_zero, weighted=False)
    else:
        b_d, d_d = bd
    return fnsi.make_model(a_d, b_d, c_d, d_d, sample_rate_hz=data.sample_rate_hz,
                           n_inputs=data.n_inputs, input_names=data.extended_input_names,
                           output_names=data.output_names, time_base=data.time_base,
                           bilinear_period_s=data.bilinear_period_s)


def _model_output(model, data, mask=slice(None)):
    """Steady-state output ``G_d(z_k) E_k`` on the lines of ``mask`` (modal form, O(F n (p + m_e)))."""
    mu, phi = np.linalg.eig(model.a_d)
    ch = model.c_d @ phi
    bh = np.linalg.solve(phi, model.b_d.astype(complex))
    Ephys = data.E_physical[mask]
    z = data.z[mask]
    X = (bh @ Ephys.T).T / (z[:, None] - mu[None, :])             # (F, n)
    return X @ ch.T + Ephys @ model.d_d.T


def _fast_error_and_poles(model, data, mask):
    """V(n) over ``mask`` (spec §3 shortcut in modal form)."""
    return osel.relative_model_error(data.Y[mask], _model_output(model, data, mask))


@dataclass(frozen=True)
class AutoResult:
    """Everything the robust pipeline decided, with the evidence (JSON via :meth:`to_json`).

    Attributes
    ----------
    information_criterion : ident.order_selection.InformationCriterion
    selected_order : int
        The order of the model: ``argmin I`` over the stable orders, restricted to the
        orders with consistent coefficients when ``order_selection='consistent'``.
    ic_order : int
        Plain ``argmin I`` over the stable orders (seed Eq. 8).
    coefficient_spread : ndarray, shape (q,)
        ``rho(n)`` per order of the information criterion (NaN where not computed).
    consistent : bool ndarray, shape (q,)
        Orders that passed the coefficient gate (all False if it was not applied).
    order_selection : str
        ``'consistent'`` or ``'ic'``: how ``selected_order`` was chosen.
    final : {'reduced', 'full'}
        Which model is the answer (:attr:`final_model`): the reduced one, unless the
        reduction raised the coefficient spread of the model it came from (then the full
        model at ``mdi_order``).
    final_spread : dict
        ``{'full': rho, 'reduced': rho}`` behind that choice (NaN when not computed).
    plausible_out_of_band : bool ndarray, shape (n_modes,)
        MDI modes outside the band of interest that are stable, stabilised across orders
        and detectable: reported as physical in the JSON ``poles``.
    detection : ndarray, shape (n_modes,)
        Detection statistic of each MDI mode (:func:`ident.mdi.modal_detection`): its energy
        over the residual's fluctuation in its bandwidth; below ``detection_sigma`` a mode
        is not physical.
    stabilisation : ident.stabilisation.StabilisationDiagram
    mdi_order : int
        Order at which MDI and reduction were applied (``reduce_at`` or ``selected_order``).
    modal_dominancy : ident.mdi.ModalDominancy
        Every mode of the model at ``mdi_order``.
    candidates : bool ndarray
        Modes eligible for the gap search (stable, in band, not at Nyquist).
    physical : bool ndarray
        Final classification per mode.
    threshold : ident.mdi.Threshold
    separation_ratio : float
    confidence : dict
        ``{'level': 'clear'|'moderate'|'ambiguous', 'statement': str, ...}``.
    model : ident.fnsi.StateSpaceModel
        The model at ``selected_order``.
    full_model : ident.fnsi.StateSpaceModel
        The model at ``mdi_order`` (before reduction).
    reduced : ident.fnsi.StateSpaceModel or None
        The reduced model (None if nothing was removed).
    coefficients : dict
        ``{'selected': ..., 'full': ..., 'reduced': ...}`` summaries from the coefficient
        callback (empty without one).
    options : AutoOptions
    groups : tuple of tuple of int
        Mode groups used by the threshold (split modes share one group).
    stab_class_at_mdi_order : tuple of str
        Stabilisation class of each MDI mode at ``mdi_order`` (``'none'`` if out of band).
    timings_s : dict
        Seconds per stage.
    models : dict int -> StateSpaceModel
        Every model of the sweep (not serialised).
    """

    information_criterion: Any
    selected_order: int
    stabilisation: Any
    mdi_order: int
    modal_dominancy: Any
    candidates: np.ndarray
    physical: np.ndarray
    threshold: Any
    separation_ratio: float
    confidence: dict
    model: Any
    full_model: Any
    reduced: Any
    coefficients: dict
    options: AutoOptions
    groups: tuple = ()
    stab_class_at_mdi_order: tuple = ()
    ic_order: int = 0
    coefficient_spread: np.ndarray = field(default_factory=lambda: np.zeros(0))
    consistent: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    order_selection: str = "ic"
    detection: np.ndarray = field(default_factory=lambda: np.zeros(0))
    final: str = "full"
    final_spread: dict = field(default_factory=dict)
    plausible_out_of_band: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def final_model(self):
        """The answer: ``reduced`` or ``full_model`` as :attr:`final` says."""
        return self.reduced if self.final == "reduced" else self.full_model
    timings_s: dict = field(default_factory=dict)
    models: dict = field(default_factory=dict, repr=False)

    def mdi_table(self) -> list[dict]:
        """``[{frequency_hz, damping_ratio, mdi_h2, mdi_seed, mdi_hinf, mdi_hinf_band, in_band,
        stable, stabilisation, candidate, physical}]`` sorted by frequency."""
        md = self.modal_dominancy
        rows = []
        for k in np.argsort(md.frequency_hz):
            rows.append({
                "frequency_hz": float(md.frequency_hz[k]),
                "damping_ratio": float(md.damping_ratio[k]),
                "mdi_h2": float(md.values["h2"][k]),
                "mdi_seed": float(md.values["seed"][k]),
                "mdi_hinf": float(md.values["hinf"][k]),
                "mdi_hinf_band": float(md.values["hinf_band"][k]),
                "in_band": bool(md.in_band[k]),
                "stable": bool(md.stable[k]),
                "stabilisation": (self.stab_class_at_mdi_order[k]
                                  if self.stab_class_at_mdi_order else None),
                "candidate": bool(self.candidates[k]),
                "detection": (float(self.detection[k]) if self.detection.size
                              and np.isfinite(self.detection[k]) else None),
                "physical": bool(self.physical[k]),
            })
        return rows

    def to_dict(self) -> dict:
        """JSON-able dictionary of the decisions (models as poles, not matrices)."""
        def fin(x):
            x = float(x)
            return x if np.isfinite(x) else None

        def poles_of(model):
            if model is None:
                return None
            m = model.poles.modes()
            return [{"frequency_hz": float(f), "damping_ratio": float(z), "stable": bool(s)}
                    for f, z, s in zip(m["frequency_hz"], m["damping_ratio"], m["stable"])]

        red = None
        if self.reduced is not None:
            red = {"order": int(self.reduced.order), "poles": poles_of(self.reduced),
                   "coefficients": self.coefficients.get("reduced")}
        final = self.final_model
        md = self.modal_dominancy
        final_poles = poles_of(final)
        for pl in final_poles:  # classification of the same pole at the MDI order
            k = int(np.argmin(np.abs(md.frequency_hz - pl["frequency_hz"]))) if md.frequency_hz.size else -1
            same = k >= 0 and abs(md.frequency_hz[k] - pl["frequency_hz"]) <= 1e-6 * pl["frequency_hz"]
            oob = (bool(self.plausible_out_of_band[k]) if self.plausible_out_of_band.size
                   else False)
            pl["physical"] = bool(same and (self.physical[k] or oob))
        modes = [{"frequency_hz": r["frequency_hz"], "damping_ratio": r["damping_ratio"],
                  "mdi_h2": r["mdi_h2"], "stabilisation": r["stabilisation"]}
                 for r in self.mdi_table() if r["physical"]]
        return {
            "order": int(final.order),
            "final": self.final,
            "modes": modes,
            "poles": final_poles,
            "coefficients": self.coefficients.get(self.final if self.final == "reduced" else "full"),
            "information_criterion": self.information_criterion.to_list(),
            "ic_band": (self.information_criterion.band
                        if isinstance(self.information_criterion.band, str)
                        else list(self.information_criterion.band)),
            "criterion": self.information_criterion.criterion,
            "selected_order": int(self.selected_order),
            "ic_order": int(self.ic_order),
            "order_selection": self.order_selection,
            "coefficient_spread": [
                {"order": int(n), "spread": fin(r), "consistent": bool(c)}
                for n, r, c in zip(self.information_criterion.orders,
                                   self.coefficient_spread, self.consistent)]
            if self.coefficient_spread.size else [],
            "stabilisation": self.stabilisation.to_list(),
            "mdi_order": int(self.mdi_order),
            "mdi_norm": self.options.mdi_norm,
            "mdi_band_hz": list(self.modal_dominancy.band_hz),
            "mdi": self.mdi_table(),
            "threshold": fin(self.threshold.threshold),
            "threshold_method": self.threshold.method,
            "separation_ratio": fin(self.separation_ratio),
            "confidence": self.confidence,
            "selected_model": {"order": int(self.model.order), "poles": poles_of(self.model),
                               "coefficients": self.coefficients.get("selected")},
            "full_model": {"order": int(self.full_model.order),
                           "coefficients": self.coefficients.get("full")},
            "reduced": red,
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
        }

    def to_json(self, **kw) -> str:
        """:meth:`to_dict` as JSON text."""
        return json.dumps(self.to_dict(), **kw)


def confidence_statement(separation_ratio: float, n_physical: int, disagreements: dict, *,
                         ambiguous_ratio: float = 2.0, clear_ratio: float = 10.0) -> dict:
    """How sure the physical/spurious split is (spec §7.4, §8.5).

    Parameters
    ----------
    separation_ratio : float
        Lowest physical MDI / highest spurious candidate MDI.
    n_physical : int
    disagreements : dict
        ``{'kept_not_stabilised': [f_hz...], 'dropped_fully_stable': [f_hz...],
        'excluded_out_of_band': int, 'excluded_unstable': int}``.

    Returns
    -------
    dict
        ``level`` (``'clear'``, ``'moderate'``, ``'ambiguous'``), ``statement`` (one paragraph
        for a person), and the inputs.

    Notes
    -----
    The level comes from the separation ratio (below ``ambiguous_ratio``: ambiguous; at or
    above ``clear_ratio``: clear) and is lowered by one step if the MDI and the
    stabilisation diagram disagree about any in-band mode.
    """
    r = separation_ratio
    if not np.isfinite(r):
        level = "clear" if n_physical > 0 and r == np.inf else "ambiguous"
    elif r < ambiguous_ratio:
        level = "ambiguous"
    elif r < clear_ratio:
        level = "moderate"
    else:
        level = "clear"
    kept_ns = disagreements.get("kept_not_stabilised", [])
    vetoed = disagreements.get("vetoed_not_stabilised", [])
    rescued = disagreements.get("rescued_by_stabilisation", [])
    drop_fs = disagreements.get("dropped_fully_stable", [])
    below = disagreements.get("below_residual", [])
    steps = ["ambiguous", "moderate", "clear"]
    if (kept_ns or drop_fs or vetoed or rescued) and level != "ambiguous":
        level = steps[steps.index(level) - 1]
    parts = [f"{n_physical} mode(s) classified physical; separation ratio "
             + (f"{r:.3g}" if np.isfinite(r) else str(r))
             + f" (ambiguous below {ambiguous_ratio:g}, clear from {clear_ratio:g})."]
    if kept_ns:
        parts.append("Kept although not stabilised in frequency: "
                     + ", ".join(f"{f:.2f} Hz" for f in kept_ns) + ".")
    if vetoed:
        parts.append("Above the MDI threshold but dropped because not stabilised in frequency: "
                     + ", ".join(f"{f:.2f} Hz" for f in vetoed) + ".")
    if below:
        parts.append("Dropped because they do not stand out of the model's residual in their "
                     "bandwidth (not detectable above noise or model error): "
                     + ", ".join(f"{f:.2f} Hz" for f in below) + ".")
    if drop_fs:
        parts.append("Dropped although fully stable (possibly genuine weak modes; consider "
                     "top_n or a manual threshold): " + ", ".join(f"{f:.2f} Hz" for f in drop_fs) + ".")
    if disagreements.get("fallback"):
        parts.append("The MDI gap is not clear, so every stable in-band mode stabilised in "
                     "frequency with an MDI above 1e-3 of the largest was kept as well.")
    if rescued:
        parts.append("Kept below the MDI threshold because stabilised across orders: "
                     + ", ".join(f"{f:.2f} Hz" for f in rescued) + ".")
    if level == "ambiguous":
        parts.append("The split is ambiguous: check the stabilisation diagram or lower the order.")
    return {"level": level, "statement": " ".join(parts), "separation_ratio":
            float(r) if np.isfinite(r) else None, "n_physical": int(n_physical),
            "kept_not_stabilised": [float(f) for f in kept_ns],
            "dropped_fully_stable": [float(f) for f in drop_fs],
            "vetoed_not_stabilised": [float(f) for f in vetoed],
            "fallback_stabilisation": bool(disagreements.get("fallback", False)),
            "rescued_by_stabilisation": [float(f) for f in rescued],
            "excluded_out_of_band": int(disagreements.get("excluded_out_of_band", 0)),
            "excluded_unstable": int(disagreements.get("excluded_unstable", 0)),
            "below_residual": [float(f) for f in below]}


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
    data : ident.fnsi.FrequencyData
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
        e.g. built on :func:`ident.coefficients.nonlinear_coefficients`); called for the
        selected, full and reduced models.
    spread : callable, optional
        ``spread(model) -> rho`` (:func:`ident.coefficients.spread_function`): the coefficient
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
    Spec §3 (IC with the exact frequency-domain shortcut), §4 (stabilisation), §5 (MDI),
    §6 (reduction), §7 (threshold), §8.3 and §8.5 (band choices, confidence).
    """
    from fnsi_lab.ident import fnsi
    from fnsi_lab.ident.reduction import reduce_model

    if options is None:
        options = AutoOptions()
    elif isinstance(options, dict):
        options = AutoOptions.from_dict(options)
    options = options.validate()
    orders = sorted({int(n) for n in orders})
    if not orders or orders[0] < 1:
        raise IdentError(f"orders must be positive integers, got {orders!r}")
    sweep = sorted(set(orders) | ({int(reduce_at) + k for k in range(-2, 3)} - {0, -1}
                                   if reduce_at is not None else set()))
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    decomp = fnsi.subspace_decomposition(data, max_order=max(sweep), block_rows=options.block_rows,
                                         weighted=options.weighted)
    timings["subspace"] = time.perf_counter() - t0

    ic_mask, ic_band = osel.ic_line_mask(data.frequencies_hz, data.excited, data.n_outputs,
                                         options.ic_band)
    boi = _band_of_interest(data, options)
    bar = _progress(progress, len(sweep))
    models: dict[int, Any] = {}
    v = {}
    stable = {}
    t1 = time.perf_counter()
    for n in sweep:
        model = _model_at_order_fast(decomp, data, n, d_zero=options.d_zero,
                                     weighted_bd=options.sweep_bd == "weighted")
        models[n] = model
        stable[n] = bool(model.stable)
        if n in orders:
            v[n] = _fast_error_and_poles(model, data, ic_mask)
        bar.update(1, note=f"n={n}")
    timings["sweep"] = time.perf_counter() - t1

    t2 = time.perf_counter()
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
                orders, ic.value, ic.stable, rho, options.spread_factor)
            how = "consistent"

    # stabilisation over the sweep, modes of each order (one per pair, not at Nyquist)
    fl, zl, sl = [], [], []
    for n in sweep:
        p = models[n].poles
        idx = np.flatnonzero(p.is_mode)
        fl.append(p.natural_frequency_hz[idx])
        zl.append(p.damping_ratio[idx])
        sl.append(p.mode_shapes[:, idx])
    diagram = stab.classify_stabilisation(sweep, fl, zl, sl, band_hz=(0.0, np.inf),
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
        # the weighted B, D least squares (spec §1.4) for the models that are reported
        for n in {n_sel, n_mdi}:
            models[n] = fnsi.model_at_order(decomp, data, n, d_zero=options.d_zero)
    full = models[n_mdi]
    mu, lam, ch, bh, ch_d, bh_d = modal_form(full)
    weights = mdi_mod.input_weights(data.E_physical, data.n_inputs, options.input_scaling)
    oweights = mdi_mod.output_weights(data.Y, options.output_scaling, data.noise_cov)
    md = mdi_mod.modal_dominancy(lam, ch, bh, boi, norm=options.mdi_norm, weights=weights,
                                 nyquist_hz=full.sample_rate_hz / 2, out_weights=oweights)
    # stabilisation class of each MDI mode: match by frequency to this order's entries
    # class at n_mdi against the previous orders and, for poles that are 'new' there, against
    # the next orders too (spec §4: "previous (or next) order"): a mode that first appears at
    # n_mdi and persists above it is not vetoed
    rank = {"none": -1, "new": 0, "frequency": 1, "damping": 2, "mode": 3, "stable": 4}
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
        return st.classes[k] if abs(st.frequency_hz[k] - f) <= 1e-6 * max(f, 1e-12) else "none"

    cls = []
    for f in md.frequency_hz:
        cb, cf = class_of(st_o, f), class_of(st_f, f)
        cls.append(cb if rank[cb] >= rank[cf] or cb == "none" else cf)
    cls_arr = np.array(cls, object)
    # eligible for the gap search: stable, in the band of interest, not at Nyquist (spec §7.1);
    # stabilisation acts afterwards as a veto (spec §8.5), so spurious poles still populate
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
    # the gap is not clear any mode stabilised in frequency is (spec §7.5, §8.5).
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
    # detectability: in its own bandwidth a mode must stand out of the model's residual
    # (spec §8.5); nested models of one SVD keep noise-fitting poles "stable" across
    # orders, so stability alone does not make a mode
    y_model = _model_output(full, data)
    detection = mdi_mod.modal_detection(mu, ch_d, bh_d, data.E_physical, data.z,
                                        data.Y, y_model, data.frequencies_hz, md.members,
                                        md.frequency_hz, md.damping_ratio)
    undetectable = physical & ~(detection >= options.detection_sigma)
    physical &= ~undetectable
    timings["mdi"] = time.perf_counter() - t3

    # confidence
    inb = md.in_band
    disagree = {
        "kept_not_stabilised": sorted(md.frequency_hz[physical & (cls_arr == "new")].tolist()),
        "vetoed_not_stabilised": sorted(md.frequency_hz[vetoed].tolist()),
        "rescued_by_stabilisation": sorted(md.frequency_hz[rescued & physical].tolist()),
        "dropped_fully_stable": sorted(md.frequency_hz[~physical & inb & md.stable & ~undetectable
                                                       & (cls_arr == "stable")].tolist()),
        "excluded_out_of_band": int(np.sum(~inb)),
        "excluded_unstable": int(np.sum(inb & ~md.stable)),
        "below_residual": sorted(md.frequency_hz[undetectable].tolist()),
    }
    disagree["fallback"] = bool(fallback)
    kept_v, drop_v = values[physical & cand], values[~physical & cand]
    final_ratio = (float(kept_v.min() / drop_v.max()) if kept_v.size and drop_v.size
                   and drop_v.max() > 0 else float("inf") if kept_v.size else float("nan"))
    conf = confidence_statement(thr.separation_ratio, int(physical.sum()), disagree,
                                ambiguous_ratio=options.ambiguous_ratio,
                                clear_ratio=options.clear_ratio)
    conf["final_separation_ratio"] = final_ratio if np.isfinite(final_ratio) else None

    # reduction
    t4 = time.perf_counter()
    reduced = None
    # poles kept in the reduced model: the physical in-band modes and the stable poles
    # outside the band per out_of_band; unstable and Nyquist poles are always removed
    # (spec §7.1)
    nyq = np.abs(md.eigenvalues.imag) >= 0.999 * np.pi * full.sample_rate_hz
    plausible_oob = (~md.in_band & md.stable & ~nyq & (cls_arr != "new") & (cls_arr != "none")
                     & (detection >= options.detection_sigma))
    keep_modes = physical.copy()
    if options.out_of_band == "keep":
        keep_modes |= ~md.in_band & md.stable & ~nyq
    elif options.out_of_band == "stabilised":
        keep_modes |= plausible_oob
    if keep_modes.any() and not keep_modes.all():
        keep_mask = np.zeros(mu.size, bool)   # md.members index the poles of ``full``
        for i in np.flatnonzero(keep_modes):
            keep_mask[list(md.members[i])] = True
        reduced = reduce_model(full, data, keep_mask, d_zero=options.d_zero,
                               weighted=options.weighted)
    # the answer: the reduced model, unless the reduction made the coefficients less
    # consistent than the model it came from (then removing those poles cost information)
    final = "full"
    rho_full = rho_reduced = float("nan")
    if reduced is not None:
        final = "reduced"
        if spread is not None:
            rho_full, rho_reduced = spread(full), spread(reduced)
            if np.isfinite(rho_full) and not rho_reduced <= rho_full:
                final = "full"
    timings["reduction"] = time.perf_counter() - t4

    coefs: dict = {}
    if coefficients is not None:
        t5 = time.perf_counter()
        coefs["selected"] = coefficients(models[n_sel])
        coefs["full"] = coefficients(full)
        if reduced is not None:
            coefs["reduced"] = coefficients(reduced)
        timings["coefficients"] = time.perf_counter() - t5
    timings["total"] = time.perf_counter() - t0

    return AutoResult(information_criterion=ic, selected_order=n_sel, stabilisation=diagram_boi,
                      mdi_order=n_mdi, modal_dominancy=md, candidates=cand, physical=physical,
                      threshold=thr, separation_ratio=thr.separation_ratio, confidence=conf,
                      model=models[n_sel], full_model=full, reduced=reduced, coefficients=coefs,
                      options=options, groups=tuple(tuple(g) for g in groups),
                      stab_class_at_mdi_order=tuple(cls), timings_s=timings, models=models,
                      ic_order=ic.selected_order, coefficient_spread=rho,
                      consistent=consistent, order_selection=how, detection=detection,
                      final=final, final_spread={"full": rho_full, "reduced": rho_reduced},
                      plausible_out_of_band=plausible_oob)


# --------------------------------------------------------------------------------------
# Command line: hooks called by ident.cli (``fnsi-lab ident INPUT --config C --auto``)
# --------------------------------------------------------------------------------------
def _parse_auto_section(sec, key):
    """``auto:`` section of the ident YAML -> :class:`AutoOptions` (registered in config)."""
    from fnsi_lab.ident.errors import IdentConfigError
    raw = sec.raw(key, None)
    if raw is None:
        return AutoOptions()
    if not isinstance(raw, dict):
        raise IdentConfigError("must be a mapping of robust-pipeline options", file=sec.file,
                               field=key, fix="e.g. auto: {mdi_norm: h2, top_n: 11}")
    try:
        return AutoOptions.from_dict(raw)
    except (IdentError, TypeError) as exc:
        raise IdentConfigError(str(exc), file=sec.file, field=key,
                               fix=f"allowed keys: {', '.join(AutoOptions.__dataclass_fields__)}"
                               ) from None


def _register_config_section():
    try:
        from fnsi_lab.ident import config as _cfg
    except ImportError:  # pragma: no cover - config is part of the core
        return
    _cfg.EXTRA_SECTIONS.setdefault("auto", _parse_auto_section)


_register_config_section()


def parse_orders(text: str) -> range:
    """``'2:60'`` -> ``range(2, 61)`` (inclusive); ``'2:60:2'`` with a step."""
    parts = str(text).split(":")
    try:
        nums = [int(p) for p in parts]
    except ValueError:
        raise IdentError(f"--orders {text!r}: expected FIRST:LAST or FIRST:LAST:STEP") from None
    if len(nums) not in (2, 3) or nums[0] < 1 or nums[1] < nums[0] or (len(nums) == 3 and nums[2] < 1):
        raise IdentError(f"--orders {text!r}: expected 1 <= FIRST <= LAST (and STEP >= 1)")
    return range(nums[0], nums[1] + 1, nums[2] if len(nums) == 3 else 1)


def add_cli_arguments(parser) -> None:
    """``--auto``, ``--orders``, ``--reduce-at`` (hook of :func:`ident.cli.add_ident_arguments`)."""
    g = parser.add_argument_group("robust pipeline (spec §3-8, docs/robust.md)")
    g.add_argument("--auto", action="store_true",
                   help="choose the order (information criterion), classify poles (MDI + "
                        "stabilisation) and remove the spurious ones (model reduction)")
    g.add_argument("--orders", default="2:60", metavar="FIRST:LAST",
                   help="order sweep of --auto (default 2:60)")
    g.add_argument("--reduce-at", type=int, default=None, metavar="N",
                   help="apply the MDI and the reduction at order N (default: the IC order)")


def run_cli(args, session):
    """Robust path of ``fnsi-lab ident`` (hook of :func:`ident.cli.run_ident`).

    Returns None when ``--auto`` is not given (the core's ``--order`` path runs).
    """
    if not getattr(args, "auto", False):
        return None
    from fnsi_lab.ident import cli as core_cli
    from fnsi_lab.ident.coefficients import nonlinear_coefficients, summarize_coefficients

    t0 = time.perf_counter()
    cfg = session.config
    options = cfg.extra.get("auto") or AutoOptions()
    options = replace(options, d_zero=session.d_zero, weighted=session.weighted,
                      block_rows=args.block_rows or cfg.block_rows or options.block_rows)
    orders = parse_orders(args.orders)

    def coef(model):
        if not cfg.nonlinearities:
            return None
        spectra = nonlinear_coefficients(model, session.data, cfg.nonlinearities,
                                         driving_point=cfg.driving_points or None)
        return [s.to_dict() for s in summarize_coefficients(spectra)]

    from fnsi_lab.ident.coefficients import spread_function

    progress = Progress(len(orders), "FNSI orders", enabled=not args.quiet and args.json_out != "-")
    spread = spread_function(session.data, cfg.nonlinearities,
                             driving_point=cfg.driving_points or None)
    res = identify_auto(session.data, options, orders=orders, reduce_at=args.reduce_at,
                        progress=progress, coefficients=coef, spread=spread)
    session.timings_s["auto"] = time.perf_counter() - t0
    out = {"input": str(session.input.path), "config": cfg.file,
           "outputs": list(session.data.output_names), "band_hz": list(session.data.band_hz),
           "n_lines": session.data.n_lines, "warnings": list(session.warnings)}
    out.update(res.to_dict())
    out["timings_s"] = {**{k: float(v) for k, v in session.timings_s.items()}, **out["timings_s"]}
    out = json.loads(json.dumps(out, default=_json_default), parse_constant=lambda c: None)
    if not args.quiet and args.json_out != "-":
        _print_auto_summary(res)
    core_cli.write_json(_nan_to_none(out), args.json_out)
    return 0


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _nan_to_none(o):
    if isinstance(o, float) and not np.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _nan_to_none(v) for k, v in o.items()}
    if isinstance(o, list):
        return [_nan_to_none(v) for v in o]
    return o


def _print_auto_summary(res: AutoResult, out=None) -> None:
    import sys
    out = out or sys.stdout
    ic = res.information_criterion
    print(f"information criterion ({ic.criterion}, band {ic.band}): order {res.selected_order}; "
          f"{int(np.sum(~ic.stable))} of {ic.orders.size} orders unstable", file=out)
    print(f"MDI at order {res.mdi_order} ({res.options.mdi_norm}, band "
          f"{res.modal_dominancy.band_hz[0]:g}-{res.modal_dominancy.band_hz[1]:g} Hz): "
          f"confidence {res.confidence['level']}", file=out)
    print("  " + res.confidence["statement"], file=out)
    for row in res.mdi_table():
        if not row["in_band"]:
            continue
        print(f"  {row['frequency_hz']:9.3f} Hz  {100 * row['damping_ratio']:6.2f} %  "
              f"MDI {row['mdi_h2']:9.3g}  {row['stabilisation'] or '':9s} "
              f"{'physical' if row['physical'] else 'spurious'}", file=out)
    if res.reduced is not None:
        print(f"reduced model: order {res.reduced.order}", file=out)
    answer = "reduced" if res.final == "reduced" else "full"
    print(f"answer: the {'reduced' if answer == 'reduced' else 'full'} model at order "
          f"{res.final_model.order}" + (" (the reduction did not make the coefficients more "
                                        "consistent)" if res.reduced is not None
                                        and answer == "full" else ""), file=out)
    rows = [("selected", "selected")]
    if res.mdi_order != res.selected_order:
        rows.append((f"order {res.mdi_order}", "full"))
    rows.append(("reduced", "reduced"))
    for label, key in rows:
        for c in res.coefficients.get(key) or []:
            err = (f"  error {c['error_percent']:+.3f} %" if c.get("error_percent") is not None
                   else "")
            mark = " <- answer" if key == answer or (answer == "full" and key == "selected"
                                                     and res.mdi_order == res.selected_order) else ""
            print(f"  {label} {c['name']}: mean {c['mean_real']:.6g} (std {c['std_real']:.3g})"
                  f"{err}{mark}", file=out)
