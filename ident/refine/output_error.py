"""Output-error refinement of an FNSI model: the model's own steady state against the outputs.

FNSI regresses the outputs on basis functions of the *measured* motion. With noisy outputs
that motion carries the noise into the regressors (errors in variables): the coefficients are
biased by a share that grows with the time in contact and a searched clearance wanders by
several times its curvature's standard deviation (docs/ident.md, "The output-error
refinement"). This module refines the identified model by minimising

    ``V(theta) = sum_k sum_o W_ko^2 |Y_ko - Y_hat_ko(theta)|^2``

where ``Y_hat`` is the model's periodic steady state with the basis functions read on the
motion the model itself predicts (:mod:`ident.refine.harmonic_balance`), ``W = 1/sigma`` the noise
weights of the averaged outputs, and ``theta`` the model in modal form
(:class:`ident.refine.modal.ModalModel`: poles, input rows, output rows, ``D``) plus the continuous
basis parameters that were left to the data (clearances, offsets, signed exponents). No noisy
signal then enters a regressor, so the minimum is the maximum-likelihood estimate for white
Gaussian output noise.

Levenberg-Marquardt with an exact elimination of the output rows that no basis function
reads: every such row is linear in its own parameters ``[Re gamma, Im gamma, c, d]``, so the
normal equations are block-arrow shaped and are solved through their Schur complement (the
size of the step's dense system is that of the shared parameters: poles, input rows, the
rows the basis reads and the basis parameters). The sensitivity of the predicted motion to
a parameter comes from the linearised harmonic balance.

Shapes: ``F = R F0`` stacked lines, ``p`` outputs, ``m_e`` extended inputs; complex residuals
``(F, p)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.fnsi import StateSpaceModel, make_model
from fnsi_lab.ident.refine.harmonic_balance import BalanceError, BalanceState, HarmonicBalance
from fnsi_lab.ident.refine.modal import ModalModel, pole_kernel
from fnsi_lab.ident.core.periodic import FrequencyData, smooth_lines

__all__ = ["OutputErrorFit", "refine_output_error", "RefinedParameter", "refinement_case",
           "omitted_mode_evidence",
           "MIN_MOTION_NOISE_SHARE", "MAX_UNEXPLAINED", "DOMINANT_MOTION_NOISE_SHARE",
           "MAX_MISFIT"]

#: Relative GMRES tolerance of the motion's sensitivities in the Jacobian (a Gauss-Newton
#: step needs no more; the gradient is then exact to about this share).
SENSITIVITY_TOLERANCE = 1e-3
#: ``refine: auto`` refines when the measured motion's noise, carried through FNSI's model,
#: adds at least this fraction of the output noise to the expected squared residual: then
#: the regressors' noise is a material part of what FNSI fits. 3-DOF chain, 1 % noise:
#: 10 (the known-gap coefficients 0.2-0.9 % off, refined 0.02-0.26 %); 39-channel SmallSat,
#: 1 % noise, 6 periods: 1.7.
MIN_MOTION_NOISE_SHARE = 0.5
#: ... and when FNSI's weighted residual is at most this factor above what the output noise
#: and that share explain: a model that misses dynamics (misfit beyond the noise) is not
#: improved by fitting its own steady state. SmallSat reduced to its physical modes: 6.6
#: against 2.7 explained (refined anyway, the misfit stopped at 2.7 and NC2-Z moved from
#: 0.25 % to 0.45 % off, at 2.5 s per step).
MAX_UNEXPLAINED = 1.5
#: ... unless the motion's noise dominates that residual, at least this many times the
#: output noise: the share is a first-order estimate, and where the motion noise is large
#: against the gaps FNSI's residual exceeds it by more (3-DOF chain, velocity outputs, 1 %
#: noise: 169 against 72 explained; refined, misfit 1.00 and stiffnesses within 0.02 %).
#: The refinement is then tried and kept only if it explains the outputs (``MAX_MISFIT``).
DOMINANT_MOTION_NOISE_SHARE = 5.0
#: A refinement whose misfit stays above this is not kept (``refine: auto``): the model does
#: not explain the outputs to their noise. 3-DOF chain, 1 % noise, 16 periods: 1.00-1.07.
MAX_MISFIT = 1.5
#: A mode whose pole wanders further than this many of its own half-power bandwidths from
#: the start (``|mu - mu_0| > 3 (1 - |mu_0|)``, at least two line spacings) is not determined
#: by the output error and is dropped: on the 3-DOF chain with gaps 1.2 / 1.5 mm the robust
#: pipeline kept two spurious poles (10.0 and 22.8 Hz) beside the three modes; refined with
#: them, one went to 3.3 Hz and the other onto the 22.5 Hz mode in 30 unconverged steps,
#: genuine modes moved by 1e-4 bandwidths.
MAX_POLE_SHIFT = 3.0
#: Displacements: the motion under the band is predicted by the model unless its prediction
#: there is off the measurement by more than this (mean over the lines, in noise variances;
#: about 1 where the model holds the structure there, the 3-DOF chain 0.8-1.5). Predicted,
#: the chain's gaps (1 % noise, 16 periods) scattered 0.17-0.22 % against a standard
#: deviation of 0.14 %; measured, 0.30 % (their noise enters the basis as motion).
MAX_BELOW_BAND_MISFIT = 4.0
#: ... and the start model's prediction there already decides when it is this far off (the
#: chain: 6.5-10 at FNSI's start, 0.8-1.5 refined; its band started above its first mode:
#: 7e4, where the whole fit with the prediction cost 20 s before being thrown away).
_BELOW_BAND_START_MAX = 100.0
#: Steps after which ``give_up_above`` is checked.
_GIVE_UP_AFTER = 3
#: Half-width (lines) of the moving average of the noise variances behind the weights (as
#: FNSI's weighting, ident.core.fnsi).
_NOISE_SMOOTHING_LINES = 8
#: Bytes of the per-row-chunk Jacobian block held at once.
_CHUNK_BYTES = 64 * 2 ** 20
#: Relative finite-difference step of a basis parameter's derivative (at fixed motion).
_PARAMETER_STEP = 1e-6


@dataclass(frozen=True)
class RefinedParameter:
    """A basis parameter refined with the model.

    Attributes
    ----------
    element : int
        Index of the element in the basis.
    name : str
        Element name.
    parameter : str
        ``g_neg``, ``g_pos``, ``clearance``, ``offset`` or ``exponent``.
    start : float
        The value the refinement started from (the search's estimate).
    value, std : float
        Refined value and its standard deviation (``s^2 (J^T J)^-1``, the other
        parameters free).
    """

    element: int
    name: str
    parameter: str
    start: float
    value: float
    std: float

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "parameter": self.parameter, "start": self.start,
                "value": self.value, "std": self.std}


@dataclass
class OutputErrorFit:
    """Outcome of :func:`refine_output_error`.

    Attributes
    ----------
    model : StateSpaceModel
        The refined model (same order, time base and names as the start).
    basis : tuple of Nonlinearity
        The basis with the refined parameters.
    parameters : list of RefinedParameter
    misfit_start, misfit : float
        ``V / (F p)`` of the starting model (its own steady state) and of the refined one:
        about 1 when the model explains the outputs to their noise.
    iterations : int
        Levenberg-Marquardt steps taken.
    converged : bool
        The relative decrease of ``V`` fell below the tolerance.
    balance_iterations : int
        Harmonic-balance iterations in all.
    background_lines : int or None
        Lines out of the processed band whose measured motion was kept (None: no noise
        estimate to judge them by, all kept).
    weighted : bool
        Residuals weighted by ``1 / sigma`` (else by each output's RMS over the lines).
    frequency_map : list of (float, float or None)
        ``(start, refined)`` natural frequency (Hz) of every pole of the start model; None
        for a dropped one.
    dropped_hz : list of float
        Start frequencies (Hz) of the modes the fit dropped: they wandered by more than
        :data:`MAX_POLE_SHIFT` bandwidths, i.e. the output error does not determine them.
    below_band : str
        How the motion under the processed band entered: ``predicted`` by the model, or
        ``measured`` (and why).
    below_band_misfit : float or None
        Where predicted: the mean ``|measured - predicted|^2`` over the noise variance there
        (about 1 when the model holds the structure under the band).
    timings_s : dict
    weighted_residual : complex ndarray, shape (n_lines, n_outputs), or None
        The refined model's residual on the data's lines, weighted as in ``V``.
    excitation : complex ndarray, shape (n_lines, n_inputs + n_basis), or None
        The inputs and the refined steady state's basis functions on the data's lines (what
        each mode's input vector multiplies); with ``weighted_residual`` it is what
        :func:`omitted_mode_evidence` reads.
    residual_weights : ndarray, shape (n_lines, n_outputs), or None
        The weights of ``weighted_residual`` (``1 / sigma`` of each line and output).
    """

    model: StateSpaceModel
    basis: tuple[Nonlinearity, ...]
    parameters: list = field(default_factory=list)
    misfit_start: float = float("nan")
    misfit: float = float("nan")
    iterations: int = 0
    converged: bool = False
    balance_iterations: int = 0
    background_lines: int | None = None
    weighted: bool = True
    frequency_map: list = field(default_factory=list)
    dropped_hz: list = field(default_factory=list)
    below_band: str = "measured"
    below_band_misfit: float | None = None
    timings_s: dict = field(default_factory=dict)
    weighted_residual: np.ndarray | None = field(default=None, repr=False)
    excitation: np.ndarray | None = field(default=None, repr=False)
    residual_weights: np.ndarray | None = field(default=None, repr=False)

    def refined_frequency(self, start_hz: float) -> float | None:
        """The refined natural frequency of the start model's pole at ``start_hz`` (None if
        the fit dropped it)."""
        best = min(self.frequency_map, key=lambda fr: abs(fr[0] - start_hz), default=None)
        return start_hz if best is None else best[1]

    def parameter_std(self, element: str, parameter: str) -> float | None:
        """Standard deviation of a refined basis parameter (None if it was not refined)."""
        for p in self.parameters:
            if p.name == element and p.parameter == parameter:
                return p.std
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (the timings go to the result's ``timings_s``)."""
        return {"misfit_start": self.misfit_start, "misfit": self.misfit,
                "weighted": self.weighted,
                "iterations": self.iterations, "converged": self.converged,
                "dropped_modes_hz": list(self.dropped_hz),
                "below_band": self.below_band, "below_band_misfit": self.below_band_misfit,
                "balance_iterations": self.balance_iterations,
                "background_lines": self.background_lines,
                "parameters": [p.to_dict() for p in self.parameters]}


# ---------------------------------------------------------------------------- layout
@dataclass(frozen=True)
class _Layout:
    """Where each parameter sits in the shared vector; free rows carry their own."""

    n_pairs: int
    n_real: int
    m_e: int
    n_own: int
    beta_free: np.ndarray        # (nc, m_e) bool: input-row entries that move
    b_free: np.ndarray           # (nr, m_e) bool
    loop_rows: np.ndarray        # outputs read by a basis function
    free_rows: np.ndarray        # the others
    estimated: tuple             # ((element, parameter), ...)

    @property
    def n_beta(self) -> int:
        return int(self.beta_free.sum())

    @property
    def n_b(self) -> int:
        return int(self.b_free.sum())

    def slices(self) -> dict[str, slice]:
        nc, nr = self.n_pairs, self.n_real
        sizes = [("mu_re", nc), ("mu_im", nc), ("nu", nr), ("beta_re", self.n_beta),
                 ("beta_im", self.n_beta), ("b", self.n_b),
                 ("loop", self.loop_rows.size * self.n_own), ("theta", len(self.estimated))]
        out, i = {}, 0
        for name, n in sizes:
            out[name] = slice(i, i + n)
            i += n
        return out

    @property
    def n_shared(self) -> int:
        return self.slices()["theta"].stop


def _normalised(modal: ModalModel, e_rms: np.ndarray) -> tuple[ModalModel, np.ndarray, np.ndarray]:
    """The same model with each mode's largest (RMS-weighted) input entry scaled to 1.

    That entry is then held fixed: a mode's output column and input row are only defined up
    to a common factor, and fixing one entry removes that null direction of the fit."""
    def fix(rows: np.ndarray):
        if rows.shape[0] == 0:
            return rows, np.zeros(rows.shape, bool), np.ones(0)
        idx = np.argmax(np.abs(rows) * e_rms[None], axis=1)
        scale = rows[np.arange(rows.shape[0]), idx]
        free = np.ones(rows.shape, bool)
        free[np.arange(rows.shape[0]), idx] = False
        return rows / scale[:, None], free, scale

    b_pair, beta_free, sp = fix(modal.b_pair)
    b_real, b_free, sr = fix(modal.b_real)
    out = replace(modal, b_pair=b_pair, b_real=b_real.real,
                  c_pair=modal.c_pair * sp[None], c_real=modal.c_real * sr.real[None])
    return out, beta_free, b_free


# ---------------------------------------------------------------------------- the problem
class _Problem:
    """The output error of one data set as a function of the shared and own parameters."""

    def __init__(self, data: FrequencyData, basis: Sequence[Nonlinearity], modal: ModalModel,
                 estimated: Sequence[tuple[int, str]], weights: np.ndarray, d_free: bool,
                 predict_below: bool | None = None):
        self.data = data
        self.basis = tuple(basis)
        self.predict_below = predict_below
        self.balance = HarmonicBalance(data, self.basis, predict_below=predict_below)
        self.z = data.z
        #: the predicted lines of every realisation, stacked like the data's lines
        self.z_predicted = np.tile(self.balance.z, self.balance.R)
        self.low_predicted = (None if self.balance.low is None
                              else self.balance.low.tiled(self.balance.R))
        self.W = weights
        self.Y = data.Y
        self.m = data.n_inputs
        self.d_free = d_free
        self.R, self.F0 = self.balance.R, self.balance.F0
        reads = np.any(self.balance.L_out != 0, axis=0)
        e_rms = np.sqrt(np.mean(np.abs(data.E_physical) ** 2, axis=0))
        modal, beta_free, b_free = _normalised(modal, e_rms)
        n_own = 2 * modal.n_pairs + modal.n_real + (modal.d.shape[1] if d_free else 0)
        self.layout = _Layout(n_pairs=modal.n_pairs, n_real=modal.n_real, m_e=modal.d.shape[1],
                              n_own=n_own, beta_free=beta_free, b_free=b_free,
                              loop_rows=np.flatnonzero(reads), free_rows=np.flatnonzero(~reads),
                              estimated=tuple(estimated))
        self.start_modal = modal

    # -------------------------------------------------------------- packing
    def pack(self, modal: ModalModel, basis) -> tuple[np.ndarray, np.ndarray]:
        lay = self.layout
        rows = modal.row_parameters(self.d_free)
        theta = [basis[e].parameter(name) for e, name in lay.estimated]
        shared = np.concatenate([modal.poles.real, modal.poles.imag, modal.real_poles,
                                 modal.b_pair.real[lay.beta_free],
                                 modal.b_pair.imag[lay.beta_free], modal.b_real[lay.b_free],
                                 rows[lay.loop_rows].ravel(), np.asarray(theta, float)])
        return shared, rows[lay.free_rows]

    def unpack(self, shared: np.ndarray, own: np.ndarray):
        lay, sl = self.layout, self.layout.slices()
        m0 = self.start_modal
        b_pair = m0.b_pair.copy()
        b_pair[lay.beta_free] = shared[sl["beta_re"]] + 1j * shared[sl["beta_im"]]
        b_real = m0.b_real.copy()
        b_real[lay.b_free] = shared[sl["b"]]
        rows = np.empty((m0.d.shape[0], lay.n_own))
        rows[lay.loop_rows] = shared[sl["loop"]].reshape(-1, lay.n_own)
        rows[lay.free_rows] = own
        modal = replace(m0, poles=shared[sl["mu_re"]] + 1j * shared[sl["mu_im"]],
                        real_poles=shared[sl["nu"]].copy(), b_pair=b_pair, b_real=b_real)
        modal = modal.with_rows(rows, self.d_free)
        basis = list(self.basis)
        values: dict[int, dict[str, float]] = {}
        for (e, name), v in zip(lay.estimated, shared[sl["theta"]]):
            values.setdefault(e, {})[name] = float(v)
        for e, vals in values.items():
            basis[e] = basis[e].with_parameters(vals)   # IdentError for a negative clearance
        return modal, tuple(basis)

    # -------------------------------------------------------------- evaluation
    def evaluate(self, shared, own, start: BalanceState | None = None, guess=None):
        """``(point, cost)``; raises IdentError/BalanceError for an unusable point.
        ``start``, ``guess``: see :meth:`HarmonicBalance.solve`."""
        modal, basis = self.unpack(shared, own)
        if np.any(np.abs(modal.poles) >= 1) or np.any(np.abs(modal.real_poles) >= 1):
            raise BalanceError("unstable poles")
        bal = self.balance
        G = modal.transfer(bal.z, bal.low)                           # predicted lines
        state = bal.solve(G, basis=basis, start=start, guess=guess)
        E_pred = np.concatenate([bal.U, state.H], axis=2).reshape(-1, self.m + bal.s)
        E = np.concatenate([self.data.E[:, :self.m],
                            state.H[:, bal.data_index].reshape(-1, bal.s)], axis=1)
        phi = modal.regressor(self.z, E, self.d_free)
        Y_hat = phi @ modal.row_parameters(self.d_free).T
        res = self.W * (self.Y - Y_hat)
        point = dict(shared=shared, own=own, modal=modal, basis=basis, G=G, state=state,
                     E=E, E_pred=E_pred, phi=phi, res=res)
        return point, float(np.sum(np.abs(res) ** 2))

    def _direct(self, point, rows: np.ndarray, dH_theta: np.ndarray, *,
                predicted: bool = False) -> np.ndarray:
        """``dY_hat / d shared`` at fixed motion for the output ``rows``: (F, len(rows), n_s).

        On the data's lines, or (``predicted``) on the balance's predicted lines of every
        realisation; ``dH_theta`` on the same lines."""
        lay, sl = self.layout, self.layout.slices()
        modal = point["modal"]
        E, z = (point["E_pred"], self.z_predicted) if predicted else (point["E"], self.z)
        low = self.low_predicted if predicted else None
        rp, dp = pole_kernel(z, modal.poles, low)
        rm, dm = pole_kernel(z, modal.poles.conj(), low)
        rr, dr = pole_kernel(z, modal.real_poles, low)
        g = modal.c_pair[rows]                       # (c, nc)
        cr = modal.c_real[rows]
        out = np.zeros((z.size, rows.size, lay.n_shared), complex)
        ap = (E @ modal.b_pair.T) * dp                # d xi+ / d mu
        am = (E @ modal.b_pair.conj().T) * dm
        out[:, :, sl["mu_re"]] = g[None] * ap[:, None] + g.conj()[None] * am[:, None]
        out[:, :, sl["mu_im"]] = 1j * (g[None] * ap[:, None] - g.conj()[None] * am[:, None])
        out[:, :, sl["nu"]] = cr[None] * ((E @ modal.b_real.T) * dr)[:, None]
        if lay.n_beta:
            ep = E[:, None, :] * rp[:, :, None]      # (F, nc, m_e)
            em = E[:, None, :] * rm[:, :, None]
            dre = g[None, :, :, None] * ep[:, None] + g.conj()[None, :, :, None] * em[:, None]
            dim = 1j * (g[None, :, :, None] * ep[:, None]
                        - g.conj()[None, :, :, None] * em[:, None])
            out[:, :, sl["beta_re"]] = dre[:, :, lay.beta_free]
            out[:, :, sl["beta_im"]] = dim[:, :, lay.beta_free]
        if lay.n_b:
            er = E[:, None, :] * rr[:, :, None]
            out[:, :, sl["b"]] = (cr[None, :, :, None] * er[:, None])[:, :, lay.b_free]
        phi = modal.regressor(z, E, self.d_free, low) if predicted else point["phi"]
        loop = sl["loop"]
        for i, o in enumerate(rows):
            j = np.flatnonzero(lay.loop_rows == o)
            if j.size:
                start = loop.start + int(j[0]) * lay.n_own
                out[:, i, start:start + lay.n_own] = phi
        if dH_theta.shape[2]:
            out[:, :, sl["theta"]] = np.einsum("kos,ksj->koj",
                                               self._row_gain(point, rows, predicted),
                                               dH_theta)
        return out

    def _row_gain(self, point, rows: np.ndarray, predicted: bool = False) -> np.ndarray:
        """``G_h`` of the output ``rows`` on every stacked line: (F, len(rows), s)."""
        G = point["G"][:, rows, self.m:]                             # (F0, c, s) predicted
        if not predicted:
            G = G[self.balance.data_index]
        return np.tile(G, (self.R, 1, 1))

    def _parameter_spectra(self, point) -> np.ndarray:
        """``dH / d theta`` at fixed motion on the predicted lines, shape (R F0, s, n_theta)."""
        lay = self.layout
        state, basis = point["state"], point["basis"]
        out = np.zeros((self.R * self.F0, self.balance.s, len(lay.estimated)), complex)
        for j, (e, name) in enumerate(lay.estimated):
            v = basis[e].parameter(name)
            h = _PARAMETER_STEP * max(abs(v), 1e-12)
            hi = list(basis)
            lo = list(basis)
            hi[e] = basis[e].with_parameters({name: v + h})
            lo[e] = basis[e].with_parameters({name: v - h})
            dH = (self.balance.basis_spectra(state.delta, hi)
                  - self.balance.basis_spectra(state.delta, lo)) / (2 * h)
            out[:, :, j] = dH.reshape(-1, dH.shape[2])
        return out

    def normal_equations(self, point):
        """Blocks of ``J^T J`` and ``J^T r`` (``J`` of the real-stacked weighted residual)."""
        lay = self.layout
        bal, state = self.balance, point["state"]
        loop_gain = np.einsum("ep,kpa,k->kea", bal.L_out, point["G"], bal.to_displacement)
        bal.linearise(state, loop_gain[:, :, self.m:], point["basis"])
        dH_pred = self._parameter_spectra(point)
        # the motion's sensitivity: v = Lambda dY_hat (loop rows, motion fixed), predicted lines
        direct_loop = self._direct(point, lay.loop_rows, dH_pred, predicted=True)
        Lam = bal.L_out[:, lay.loop_rows]                                # (n_el, nl)
        v = np.einsum("el,kln,k->ken", Lam, direct_loop, np.tile(bal.to_displacement, self.R))
        v = v.reshape(self.R, self.F0, bal.n_el, -1)
        x = bal.solve_linear(state, v, SENSITIVITY_TOLERANCE)
        point["motion_sensitivity"] = x                  # (R, F0, n_el, n_s)
        # the basis spectra's response through the motion on the data's lines (the direct
        # part of a basis parameter is already in _direct)
        dH = bal.apply_slopes(state, x)[:, bal.data_index].reshape(-1, bal.s, v.shape[3])
        n_theta = dH_pred.shape[2]
        dH_theta = dH_pred.reshape(self.R, self.F0, bal.s, n_theta)[:, bal.data_index].reshape(
            self.R * bal.data_index.size, bal.s, n_theta)
        n_s = lay.n_shared
        A = np.zeros((n_s, n_s))
        g_s = np.zeros(n_s)
        res = point["res"]
        W = self.W
        phi = point["phi"]
        free = lay.free_rows
        # the free rows' own blocks: [Re; Im] of W_o phi, one GEMM per row (BLAS)
        phi_w = [_stack(phi * W[:, o, None]) for o in free]             # (2F, n_own) each
        N = np.array([f.T @ f for f in phi_w]).reshape(free.size, lay.n_own, lay.n_own)
        g_o = np.array([f.T @ _stack(res[:, o]) for f, o in zip(phi_w, free)]
                       ).reshape(free.size, lay.n_own)
        M = np.zeros((free.size, lay.n_own, n_s))
        p = self.Y.shape[1]
        chunk = max(1, int(_CHUNK_BYTES // (16 * res.shape[0] * max(n_s, 1))))
        free_pos = {int(o): i for i, o in enumerate(free)}
        for start in range(0, p, chunk):
            rows = np.arange(start, min(p, start + chunk))
            dY = self._direct(point, rows, dH_theta)
            dY += np.einsum("kos,ksn->kon", self._row_gain(point, rows), dH)
            dYw = dY * W[:, rows, None]
            for i, o in enumerate(rows):
                X = _stack(dYw[:, i])                                     # (2F, n_s)
                A += X.T @ X
                g_s += X.T @ _stack(res[:, o])
                if int(o) in free_pos:
                    j = free_pos[int(o)]
                    M[j] = phi_w[j].T @ X
        # J = -W dY_hat: J^T J and J^T_o J_s keep their sign, J^T r flips it
        return A, -g_s, N, M, -g_o


def _stack(x: np.ndarray) -> np.ndarray:
    """``[Re x; Im x]`` along the first axis (complex lines -> real residual components)."""
    return np.concatenate([x.real, x.imag], axis=0)


# ---------------------------------------------------------------------------- the fit
def _scaled_blocks(A, N, M):
    """The block-arrow normal equations scaled to a unit diagonal (Marquardt scaling):
    ``(ds, dn, As, Ns, Ms)``, ``ds`` (n_s,) and ``dn`` (n_free, n_own) the scales."""
    ds = np.sqrt(np.maximum(np.diag(A), 1e-300))
    dn = np.sqrt(np.maximum(np.einsum("onn->on", N), 1e-300))
    As = A / np.outer(ds, ds)
    Ns = N / (dn[:, :, None] * dn[:, None, :])
    Ms = M / (dn[:, :, None] * ds[None, None, :])
    return ds, dn, As, Ns, Ms


def _damped_step(A, g_s, N, M, g_o, lam: float):
    """Levenberg-Marquardt step of the block-arrow normal equations (Marquardt scaling)."""
    ds, dn, As, Ns, Ms = _scaled_blocks(A, N, M)
    As = As + lam * np.eye(ds.size)
    Ns = Ns + lam * np.eye(N.shape[1])[None]
    gs, go = g_s / ds, g_o / dn
    if N.shape[0]:
        NiM = np.linalg.solve(Ns, Ms)                                    # (n_free, n_own, n_s)
        Nig = np.linalg.solve(Ns, go[:, :, None])[:, :, 0]
        S = As - np.einsum("ons,ont->st", Ms, NiM)
        rhs = -(gs - np.einsum("ons,on->s", Ms, Nig))
    else:
        S, rhs = As, -gs
    step_s = np.linalg.lstsq(S, rhs, rcond=None)[0] if not np.all(np.isfinite(S)) else \
        _solve_sym(S, rhs)
    step_o = (-(Nig + np.einsum("ons,s->on", NiM, step_s)) if N.shape[0]
              else np.zeros((0, N.shape[1])))
    return step_s / ds, step_o / dn


def _solve_sym(S: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a symmetric positive (semi-)definite system; least squares if it is singular."""
    try:
        c = np.linalg.cholesky(S)
        return np.linalg.solve(c.T, np.linalg.solve(c, rhs))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(S, rhs, rcond=None)[0]


def _shared_covariance(A, N, M) -> np.ndarray:
    """``(J^T J)^-1`` restricted to the shared parameters (the Schur complement's inverse)."""
    ds, _, As, Ns, Ms = _scaled_blocks(A, N, M)
    if N.shape[0]:
        As = As - np.einsum("ons,ont->st", Ms, np.linalg.solve(Ns, Ms))
    return np.linalg.pinv(As, rcond=1e-13, hermitian=True) / np.outer(ds, ds)


def refine_output_error(data: FrequencyData, basis: Sequence[Nonlinearity],
                        model: StateSpaceModel, *, estimated: Sequence[tuple[int, str]] = (),
                        d_zero: bool = False, weighted: bool = True, max_iterations: int = 30,
                        tolerance: float = 1e-3,
                        watch: Callable[[StateSpaceModel, tuple], Any] | None = None,
                        watch_tolerance: float = 1e-5,
                        give_up_above: float | None = None) -> OutputErrorFit:
    """Refine an identified model (and searched basis parameters) on its own output error.

    Parameters
    ----------
    data : FrequencyData
        The data the model was identified on, with the motion of the basis channels.
    basis : sequence of Nonlinearity
        The basis of ``model`` (every parameter known).
    model : StateSpaceModel
        The start: FNSI's model (its order, time base and names are kept).
    estimated : sequence of (int, str)
        Basis parameters refined with the model: ``(element index, parameter)``, e.g.
        ``[(0, 'g_neg'), (0, 'g_pos')]`` for the clearances the search estimated.
    d_zero : bool
        Keep ``D = 0``.
    weighted : bool
        Weigh each line and output by ``1 / sigma`` (the data's ``noise_var``); False, or
        no noise estimate: by ``1 / RMS`` of each output over the lines.
    max_iterations : int
        Levenberg-Marquardt steps at most.
    tolerance : float
        Stop when a step lowers ``V`` by less than this: with noise weights ``V`` counts
        noise variances, and a decrease of ``dV`` means the parameters moved by about
        ``sqrt(2 dV)`` standard deviations (1e-3: 0.045 std); unweighted, a fraction of ``V``.
    watch : callable, optional
        ``watch(model, basis)`` gives the quantities of interest (e.g. the nonlinear
        coefficients); the fit also stops when a step changes none of them by more than
        ``watch_tolerance`` of its value. A pole that the data barely determine (a split
        mode kept by the robust pipeline) lets ``V`` fall by a few 1e-6 per step for dozens
        of steps while the answer no longer moves.
    give_up_above : float, optional
        Raise :class:`ident.errors.IdentError` when the misfit (``V`` per line and output)
        is still above this after :data:`_GIVE_UP_AFTER` steps and the last step did not
        halve it: a model that cannot explain the data (a wrong static position of
        integrated outputs: 1e7 noise variances) is not worth 30 steps, while a poor start
        still falling fast is (velocities whose searched gaps were +11 / +22 % off: 26
        noise variances after 3 steps, 1.00 after 6).

    Returns
    -------
    OutputErrorFit

    Raises
    ------
    IdentError
        No basis, a model without a usable modal form, or a start whose
        steady state does not exist (:class:`ident.refine.harmonic_balance.BalanceError`).
    """
    t0 = time.perf_counter()
    if not basis:
        raise IdentError("the output-error refinement needs basis functions")
    weighted = bool(weighted and data.noise_var is not None)
    if weighted:
        weights = 1.0 / np.sqrt(_smoothed_noise(data))
    else:
        rms = np.sqrt(np.mean(np.abs(data.Y) ** 2, axis=0))
        weights = np.broadcast_to(1.0 / np.where(rms > 0, rms, 1.0), data.Y.shape)
    options = dict(estimated=tuple(estimated), weights=weights, weighted=weighted, d_zero=d_zero,
                   max_iterations=max_iterations, tolerance=tolerance, watch=watch,
                   watch_tolerance=watch_tolerance, give_up_above=give_up_above)
    if data.output_quantity != "displacement" or data.motion is None \
            or data.motion.line_noise is None:
        return _fit(data, basis, model, t0=t0, **options)
    # displacements: the lines under the band predicted, unless the model's prediction there
    # disagrees with the measurement (modes under the band that the model does not hold)
    try:
        fit = _fit(data, basis, model, t0=t0, predict_below=True, **options)
        if fit.below_band_misfit is None or fit.below_band_misfit <= MAX_BELOW_BAND_MISFIT:
            return fit
        kept = fit.below_band_misfit
    except _BelowBandDisagrees as exc:
        kept = exc.misfit
    fit = _fit(data, basis, model, t0=t0, predict_below=False, **options)
    fit.below_band = (f"measured (predicted, they were {kept:.3g} noise variances off the "
                      "measurement)")
    return fit


class _BelowBandDisagrees(Exception):
    """The start model's prediction under the band is far off the measurement there."""

    def __init__(self, misfit: float):
        super().__init__(misfit)
        self.misfit = misfit


def _fit(data: FrequencyData, basis: Sequence[Nonlinearity], model: StateSpaceModel, *,
         estimated, weights, weighted, d_zero, max_iterations, tolerance, watch,
         watch_tolerance, give_up_above, t0, predict_below=None) -> OutputErrorFit:
    """:func:`refine_output_error` with the lines under the band predicted or not
    (displacements: raises :class:`_BelowBandDisagrees` when the start's prediction there
    is off by more than ``_BELOW_BAND_START_MAX``)."""

    modal = ModalModel.from_matrices(model.a_d, model.b_d, model.c_d, model.d_d)
    origin = (modal.poles.copy(), modal.real_poles.copy())   # each current mode's start pole
    line_step = float(np.min(np.abs(np.diff(np.unique(data.z))))) if data.z.size > 1 else 0.0
    prob = _Problem(data, basis, modal, estimated, weights, d_free=not d_zero,
                    predict_below=predict_below)
    shared, own = prob.pack(prob.start_modal, tuple(basis))
    point, cost = prob.evaluate(shared, own)
    if predict_below and data.output_quantity == "displacement":
        start_below = prob.balance.below_band_misfit(point["state"])
        if start_below is not None and start_below > _BELOW_BAND_START_MAX:
            raise _BelowBandDisagrees(start_below)
    n_lines_out = prob.Y.size
    cost_start = cost
    balance_its = point["state"].iterations
    lam, converged, it = 1e-3, False, 0
    timings = {"start": time.perf_counter() - t0}
    watched = None
    previous_cost = np.inf
    dropped: list[complex] = []
    normal = None
    for it in range(1, max_iterations + 1):
        normal = A, g_s, N, M, g_o = prob.normal_equations(point)
        accepted = False
        while lam < 1e8:
            step_s, step_o = _damped_step(A, g_s, N, M, g_o, lam)
            # the predicted motion, extrapolated by its sensitivity, starts the balance
            guess = point["state"].delta + point["motion_sensitivity"] @ step_s
            try:
                new, c_new = prob.evaluate(point["shared"] + step_s, point["own"] + step_o,
                                           start=point["state"], guess=guess)
            except IdentError:
                lam *= 10
                continue
            balance_its += new["state"].iterations
            if c_new < cost:
                decrease = (cost - c_new) / (1.0 if weighted else cost)
                point, cost, accepted = new, c_new, True
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        pairs, real = _wandered(point["modal"], origin, line_step)
        if accepted and (pairs.any() or real.any()):
            if pairs.all() and real.all():
                raise IdentError("no mode of the start model is determined by the output "
                                 "error (every pole wandered)")
            dropped.extend(list(origin[0][pairs]) + list(origin[1][real]))
            origin = (origin[0][~pairs], origin[1][~real])
            prob = _Problem(data, point["basis"], point["modal"].without(pairs, real),
                            estimated, weights, d_free=not d_zero, predict_below=predict_below)
            shared, own = prob.pack(prob.start_modal, point["basis"])
            point, cost = prob.evaluate(shared, own, start=point["state"])
            lam, watched, normal = 1e-3, None, None
            continue
        settled = False
        if accepted and watch is not None:
            now = np.asarray(watch(_state_space(point["modal"], model), point["basis"]), float)
            settled = watched is not None and bool(
                np.all(np.abs(now - watched) <= watch_tolerance * np.abs(now)))
            watched = now
        if not accepted or decrease < tolerance or settled:
            converged = True
            break
        if (give_up_above is not None and it >= _GIVE_UP_AFTER
                and cost / n_lines_out > give_up_above and previous_cost < 2 * cost):
            raise IdentError(f"the refined model leaves {cost / n_lines_out:.3g} noise "
                             f"variances after {it} steps, no longer halving: it does not "
                             "explain the data")
        previous_cost = cost
    timings["iterations"] = time.perf_counter() - t0 - timings["start"]
    # the covariance from the last normal equations when the fit stopped on a negligible
    # step (they belong to the point before it), else from fresh ones
    A, g_s, N, M, g_o = normal if converged and normal is not None else \
        prob.normal_equations(point)
    n_par = A.shape[0] + N.shape[0] * prob.layout.n_own
    s2 = cost / max(2 * n_lines_out - n_par, 1)
    cov = _shared_covariance(A, N, M) * s2
    theta = prob.layout.slices()["theta"]
    std = np.sqrt(np.maximum(np.diag(cov)[theta], 0.0))
    refined = []
    for j, (e, name) in enumerate(prob.layout.estimated):
        refined.append(RefinedParameter(
            element=e, name=basis[e].name, parameter=name, start=basis[e].parameter(name),
            value=point["basis"][e].parameter(name), std=float(std[j])))
    out_model = _state_space(point["modal"], model)
    timings["total"] = time.perf_counter() - t0
    return OutputErrorFit(model=out_model, basis=point["basis"], parameters=refined,
                          misfit_start=cost_start / n_lines_out, misfit=cost / n_lines_out,
                          iterations=it, converged=converged, balance_iterations=balance_its,
                          background_lines=prob.balance.background_kept, weighted=weighted,
                          frequency_map=_frequency_map(model, out_model, origin,
                                                       point["modal"]),
                          dropped_hz=sorted(_natural_frequency(np.array(dropped), model)),
                          below_band_misfit=prob.balance.below_band_misfit(point["state"]),
                          below_band=("predicted" if prob.balance.low_lines is not None
                                      else "measured"),
                          timings_s=timings, weighted_residual=point["res"],
                          excitation=point["E"], residual_weights=np.asarray(prob.W))


def omitted_mode_evidence(fit: OutputErrorFit, pole: complex, input_vector: np.ndarray,
                          z: np.ndarray) -> float:
    """How much of a refined fit's residual a mode the fit left out would explain.

    The score test of the omitted mode: its pole and input vector held where they were
    (``pole``, discrete time; ``input_vector``, shape (n_inputs + n_basis,), any scale), its
    output vector fitted to ``fit.weighted_residual`` by least squares, row by row.

    Parameters
    ----------
    fit : OutputErrorFit
        A fit without the mode.
    pole : complex
        The mode's discrete-time pole ``mu`` (``Im > 0``).
    input_vector : complex ndarray, shape (n_inputs + n_basis,)
        ``beta`` of the mode in a model that held it.
    z : complex ndarray, shape (n_lines,)
        The data's lines, ``exp(j 2 pi k / N)`` (``FrequencyData.z``).

    Returns
    -------
    float
        The decrease of ``V`` (noise variances) the mode's output vector alone would bring.
        Pure noise gives about the number of outputs; the mode's own parameters number
        ``2 + 2 (n_inputs + n_basis) + 2 n_outputs``, which is what a mode must beat to
        be worth keeping (the Akaike criterion of a complex Gaussian residual).
    """
    if fit.weighted_residual is None or fit.excitation is None \
            or fit.residual_weights is None:
        raise IdentError("the fit holds no residual to test a mode against")
    n_outputs, m_e = fit.weighted_residual.shape[1], fit.excitation.shape[1]
    mode = ModalModel(poles=np.array([pole], complex), real_poles=np.zeros(0),
                      b_pair=np.asarray(input_vector, complex).reshape(1, m_e),
                      b_real=np.zeros((0, m_e)), c_pair=np.zeros((n_outputs, 1), complex),
                      c_real=np.zeros((n_outputs, 0)), d=np.zeros((n_outputs, m_e)))
    phi = mode.regressor(z, fit.excitation, d_free=False)          # (F, 2): Re, Im gamma
    explained = 0.0
    for o in range(n_outputs):
        a = phi * fit.residual_weights[:, o:o + 1]
        a_real = np.concatenate([a.real, a.imag])
        r = fit.weighted_residual[:, o]
        r_real = np.concatenate([r.real, r.imag])
        coef, *_ = np.linalg.lstsq(a_real, r_real, rcond=None)
        explained += float(r_real @ r_real - np.sum((r_real - a_real @ coef) ** 2))
    return explained


def _state_space(modal: ModalModel, like: StateSpaceModel) -> StateSpaceModel:
    """The modal model as a :class:`StateSpaceModel` with the names and time base of ``like``."""
    a, b, c, d = modal.matrices()
    return make_model(a, b, c, d, sample_rate_hz=like.sample_rate_hz, n_inputs=like.n_inputs,
                      input_names=like.input_names, output_names=like.output_names,
                      time_base=like.time_base, bilinear_period_s=like.bilinear_period_s)


def _smoothed_noise(data: FrequencyData) -> np.ndarray:
    """The outputs' noise variance per line, averaged over +-8 neighbouring lines of each
    realisation, shape (F, p).

    From ``P`` periods a line's variance has ``P - 1`` degrees of freedom, and weights
    ``1 / sigma^2`` of so few are biased: the noise-weighted residual of the *true* steady
    state read 1.46 noise variances with 4 periods and 5.4 with 2 (1.07 with 16); smoothed
    as FNSI's own weighting is, 1.0."""
    var = np.maximum(np.asarray(data.noise_var, float), 1e-300)
    per = var.reshape(data.n_realizations, -1, var.shape[1])
    return np.concatenate([smooth_lines(v, _NOISE_SMOOTHING_LINES) for v in per])


def _wandered(modal: ModalModel, origin: tuple[np.ndarray, np.ndarray],
              line_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the pairs and real poles further than :data:`MAX_POLE_SHIFT` bandwidths (at
    least two line spacings ``line_step`` on the unit circle) from their start poles."""
    def far(now, start):
        limit = np.maximum(MAX_POLE_SHIFT * (1.0 - np.abs(start)), 2.0 * line_step)
        return np.abs(now - start) > limit
    return far(modal.poles, origin[0]), far(modal.real_poles, origin[1])


def _natural_frequency(mu: np.ndarray, like: StateSpaceModel) -> list[float]:
    """Natural frequencies (Hz) of DT poles ``mu`` read with ``like``'s time base."""
    from fnsi_lab.ident.core.fnsi import compute_poles
    if mu.size == 0:
        return []
    a = np.diag(np.asarray(mu, complex))
    poles = compute_poles(a, np.eye(mu.size), like.sample_rate_hz, time_base=like.time_base,
                          bilinear_period_s=like.bilinear_period_s,
                          _modal_dt=(np.asarray(mu, complex), np.eye(mu.size), True))
    return [float(f) for f in poles.natural_frequency_hz]


def _frequency_map(start: StateSpaceModel, refined: StateSpaceModel,
                   origin: tuple[np.ndarray, np.ndarray],
                   modal_refined: ModalModel) -> list[tuple[float, float | None]]:
    """Pairs each pole of ``start`` with the same mode of ``refined`` (natural frequencies;
    None where the fit dropped the mode). ``origin`` holds the start pole of every mode of
    ``modal_refined``."""
    before = np.concatenate(origin)
    after = np.concatenate([modal_refined.poles, modal_refined.real_poles])
    out: list[tuple[float, float | None]] = []
    for mu, f in zip(start.poles.discrete_eigenvalues, start.poles.natural_frequency_hz):
        mu_up = mu if mu.imag >= 0 else np.conj(mu)
        if before.size == 0 or np.min(np.abs(before - mu_up)) > 1e-9 * max(abs(mu_up), 1e-300):
            out.append((float(f), None))
            continue
        j = int(np.argmin(np.abs(before - mu_up)))
        k = int(np.argmin(np.abs(refined.poles.discrete_eigenvalues - after[j])))
        out.append((float(f), float(refined.poles.natural_frequency_hz[k])))
    return out


def refinement_case(data: FrequencyData, basis: Sequence[Nonlinearity],
                    model: StateSpaceModel) -> dict[str, Any]:
    """Whether ``refine: auto`` refines FNSI's ``model`` on these data, and why.

    The refinement removes what the noise of the measured motion does to FNSI's regressors.
    It runs when that noise is a material share of the residual
    (:data:`MIN_MOTION_NOISE_SHARE`) and the model otherwise explains the outputs to their
    noise (:data:`MAX_UNEXPLAINED`), or when it dominates the residual
    (:data:`DOMINANT_MOTION_NOISE_SHARE`).

    Returns
    -------
    dict
        ``run`` (bool), ``reason`` (one line), ``motion_noise_share`` and ``fnsi_misfit``
        (None where they cannot be computed): the expected share of the motion noise in
        FNSI's weighted squared residual per line and output, and that residual itself.
    """
    from fnsi_lab.ident.core.fnsi import steady_state_output, transfer_discrete
    from fnsi_lab.ident.refine.parameter_search import MotionNoise

    out: dict[str, Any] = {"run": False, "reason": "", "motion_noise_share": None,
                           "fnsi_misfit": None}
    if not basis:
        out["reason"] = "no basis functions"
        return out
    if data.noise_var is None or data.noise_resolved is None or not np.any(data.noise_resolved):
        out["reason"] = "no noise above the record resolution (noise-free data or one period)"
        return out
    if data.motion is None or data.motion.line_noise is None:
        out["reason"] = ("no noise spectrum of the measured motion (needs at least 2 periods); "
                         "refine: output-error forces it")
        return out
    w2 = 1.0 / _smoothed_noise(data)
    G = transfer_discrete(model, data.z)[:, :, data.n_inputs:]
    integrated = data.output_quantity != "displacement"
    variance, _ = MotionNoise(data, basis, integrated=integrated).terms(G, basis)
    share = float(np.sum(variance * w2) / data.Y.size)
    misfit = float(np.sum(w2 * np.abs(data.Y - steady_state_output(model, data)) ** 2)
                   / data.Y.size)
    out.update(motion_noise_share=share, fnsi_misfit=misfit)
    if share < MIN_MOTION_NOISE_SHARE:
        out["reason"] = (f"the measured motion's noise adds {share:.2g} of the output noise to "
                         f"the residual (below {MIN_MOTION_NOISE_SHARE:g}): FNSI's regressors "
                         "are clean enough")
    elif misfit > MAX_UNEXPLAINED * (1.0 + share) and share < DOMINANT_MOTION_NOISE_SHARE:
        out["reason"] = (f"FNSI's residual is {misfit:.3g} noise variances where noise and "
                         f"motion noise explain {1 + share:.3g}: the model misses dynamics "
                         "that its own steady state would not fit either")
    else:
        out.update(run=True, reason=f"the measured motion's noise adds {share:.3g} of the "
                                    "output noise to FNSI's residual")
    return out
