"""The output error of one data set as a function of the model's parameters: the modal
problem of :mod:`ident.refine.output_error`, its Jacobian and its block-arrow normal equations.

The parameters are split into the *shared* ones (poles, input rows, the output rows a basis
function reads, the searched basis parameters) and each free output row's *own* ones
(``[Re gamma, Im gamma, c, d]``, linear). The sensitivity of the predicted motion to a shared
parameter comes from the linearised harmonic balance (:mod:`ident.refine.harmonic_balance`).
Also the noise weights' variances (:func:`smoothed_noise`).

Shapes: ``F = R F0`` stacked lines, ``p`` outputs, ``m_e`` extended inputs; complex residuals
``(F, p)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData, smooth_lines
from fnsi_lab.ident.refine.harmonic_balance import BalanceError, BalanceState, HarmonicBalance
from fnsi_lab.ident.refine.modal import ModalModel, pole_kernel

__all__ = ["OutputErrorProblem", "smoothed_noise", "SENSITIVITY_TOLERANCE"]

#: Relative GMRES tolerance of the motion's sensitivities in the Jacobian (a Gauss-Newton
#: step needs no more; the gradient is then exact to about this share).
SENSITIVITY_TOLERANCE = 1e-3
#: Half-width (lines) of the moving average of the noise variances behind the weights (as
#: FNSI's weighting, ident.core.fnsi).
_NOISE_SMOOTHING_LINES = 8
#: Bytes of the per-row-chunk Jacobian block held at once.
_CHUNK_BYTES = 64 * 2 ** 20
#: Relative finite-difference step of a basis parameter's derivative (at fixed motion).
_PARAMETER_STEP = 1e-6


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
class OutputErrorProblem:
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


def smoothed_noise(data: FrequencyData) -> np.ndarray:
    """The outputs' noise variance per line, averaged over +-8 neighbouring lines of each
    realisation, shape (F, p).

    From ``P`` periods a line's variance has ``P - 1`` degrees of freedom, and weights
    ``1 / sigma^2`` of so few are biased: the noise-weighted residual of the *true* steady
    state read 1.46 noise variances with 4 periods and 5.4 with 2 (1.07 with 16); smoothed
    as FNSI's own weighting is, 1.0."""
    var = np.maximum(np.asarray(data.noise_var, float), 1e-300)
    per = var.reshape(data.n_realizations, -1, var.shape[1])
    return np.concatenate([smooth_lines(v, _NOISE_SMOOTHING_LINES) for v in per])
