"""``B`` and ``D`` by linear least squares given ``A`` and ``C`` (docs/method.md §1.4),
weighted by the noise, with the inputs' scaling undone.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.fast_bd import fast_estimate_bd, line_sums
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.core.state_space import apply_model, eigen_decomposition
from fnsi_lab.ident.core import subspace
from fnsi_lab.ident.core.weights import LINE_CHUNK, inverse_covariance


# ---------------------------------------------------------------------------- B, D
def _normal_solver(N: np.ndarray):
    """A solver ``r -> x`` of the symmetric PSD system ``N x = r`` (Jacobi-scaled, factored once).

    Cholesky when positive definite (ill-conditioned over-parameterized high orders included:
    the caller's iterative refinement recovers the residual), else a least-squares
    pseudo-solve.
    """
    d = np.sqrt(np.abs(np.diag(N)))
    d[d == 0] = 1.0
    Ns = N / np.outer(d, d)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sla.LinAlgWarning)
            fac = sla.cho_factor(Ns, check_finite=False)
        return lambda r: sla.cho_solve(fac, r / d, check_finite=False) / d
    except (np.linalg.LinAlgError, ValueError):
        return lambda r: np.linalg.lstsq(Ns, r / d, rcond=None)[0] / d


def estimate_bd(a_d: np.ndarray, c_d: np.ndarray, data: FrequencyData, *, d_zero: bool = False,
                weighted: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Real ``B``, ``D`` minimizing ``sum_k ||W_k (Y_k - [C (z_k I - A)^{-1} B + D] E_k)||^2``.

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
        Any real ``A`` (diagonalizable or not, e.g. a real Schur block).
    c_d : ndarray, shape (p, n)
    data : FrequencyData
    d_zero : bool
        Drop the ``D`` unknowns (``D = 0``).
    weighted : bool
        ``W_k^H W_k = Sigma_Y(k)^{-1}`` when ``data.noise_cov`` is available, else identity.

    Returns
    -------
    b_d : ndarray, shape (n, m_e)
        In physical basis units (``sigma`` scaling undone: column ``a`` times
        ``data.input_scale[a]``).
    d_d : ndarray, shape (p, m_e)

    Notes
    -----
    docs/method.md §1.4. The model output is linear in ``(B, D)``. In modal coordinates
    (``A = Phi diag(mu) Phi^{-1}``, ``C_hat = C Phi``, ``B_hat = Phi^{-1} B``),
    ``Y_k = C_hat diag(w_k) B_hat E_k + D E_k`` with ``w_k = 1/(z_k - mu)``, so the normal
    equations are ``sum_k (conj(E_k) E_k^T) (x) (diag(conj w~_k) M_k diag(w~_k))`` with
    ``M_k = [C_hat, I]^H Q_k [C_hat, I]``; unweighted, ``M`` is constant and the whole sum is
    one ``V^H V`` product (``O(F m_e^2 (n+p)^2)``), never a GB-sized Jacobian. The real
    unknowns follow from ``B_hat = Phi^{-1} B`` and real parts. One step of iterative
    refinement (residual computed in the original form) recovers the accuracy lost by
    squaring the condition number. When ``Phi`` is ill conditioned (defective or nearly
    defective ``A``) the regressor ``C (z_k I - A)^{-1}`` is formed by batched solves instead.
    """
    a_d = np.asarray(a_d, float)
    c_d = np.asarray(c_d, float)
    n = a_d.shape[0]
    p, m_e = data.n_outputs, data.n_extended_inputs
    if a_d.shape != (n, n) or c_d.shape != (p, n):
        raise IdentError(f"estimate_bd: A {a_d.shape} and C {c_d.shape} do not match "
                         f"n={n}, p={p}")
    return estimate_bd_given_modes(a_d, c_d, data, d_zero=d_zero, weighted=weighted, modal=eigen_decomposition(a_d))


def project_outputs(data: FrequencyData, basis: np.ndarray, *, d_zero: bool = False):
    """Split the outputs into the span of ``basis`` and its orthogonal complement.

    With ``C = W C_r`` (``W`` = ``basis``, orthonormal columns) the unweighted B, D least
    squares separates exactly: ``sum_k ||Y_k - C X_k - D E_k||^2 =
    sum_k ||W^T Y_k - C_r X_k - D_r E_k||^2 + sum_k ||Y_perp,k - D_perp E_k||^2`` with
    ``D = W D_r + D_perp`` (``W`` real, the two parts orthogonal in every line). So B and
    ``D_r`` come from the ``r``-channel problem and ``D_perp`` from one small least squares
    that no model changes: the cost of B, D and of the model error stops growing with ``p``.

    Parameters
    ----------
    data : FrequencyData
    basis : ndarray, shape (p, r)
        Orthonormal columns.
    d_zero : bool
        ``D = 0``: then ``D_perp = 0``.

    Returns
    -------
    reduced : FrequencyData
        ``data`` with ``Y W`` (r channels ``w0 ...``), no noise covariance (the split is exact
        for the unweighted problem only).
    d_perp : ndarray, shape (p, m_e)
        Physical basis units (as ``D``).
    perp_residual : ndarray, shape (F,)
        ``||Y_perp,k - D_perp E_k||^2`` per line (output units squared).
    """
    from dataclasses import replace
    W = np.asarray(basis, float)
    Yc = data.Y @ W
    Yp = data.Y - Yc @ W.T
    if d_zero:
        d_perp = np.zeros((W.shape[0], data.n_extended_inputs))
    else:  # real D: real and imaginary parts of every line are equations
        Ep = data.E_physical
        Er = np.concatenate([Ep.real, Ep.imag])
        d_perp = np.linalg.lstsq(Er, np.concatenate([Yp.real, Yp.imag]), rcond=None)[0].T
        Yp = Yp - data.E_physical @ d_perp.T
    reduced = replace(data, Y=Yc, noise_cov=None,
                      output_names=tuple(f"w{k}" for k in range(W.shape[1])))
    return reduced, d_perp, np.sum(np.abs(Yp) ** 2, axis=1)


def _estimate_bd_diag_weighted(a_d, c_d, data, Q, modal, refine: int = 2):
    """Weighted B, D with per-line, per-channel weights ``Q`` (F, p), D eliminated per channel.

    Same least squares as :func:`estimate_bd_given_modes` (its oracle in the tests), but ``D``'s
    ``p m_e`` unknowns enter through a Schur complement: with a diagonal weight every channel's
    ``D_i`` couples only to ``B``, so ``N_DD`` is block diagonal (``p`` blocks of
    ``m_e x m_e``) and the system is ``m_e n`` wide whatever ``p``. The cost is
    ``O(F p n^2)`` (the per-line ``C_hat^H Q_k C_hat``) instead of ``O(F p (n + p)^2)``.
    """
    n = a_d.shape[0]
    p, me = data.n_outputs, data.n_extended_inputs
    mu, phi, _ = modal
    E, Y, F = data.E, data.Y, data.n_lines
    pinv = np.linalg.inv(phi)
    ch = c_d @ phi                                                   # (p, n)
    w = 1.0 / (data.z[:, None] - mu[None, :])                        # (F, n)
    EE = (E.conj()[:, :, None] * E[:, None, :]).reshape(F, me * me)  # (F, (j,l))
    X = (ch.conj()[:, :, None] * ch[:, None, :]).reshape(p, n * n)
    Nbb = np.zeros((me * me, n * n), complex)
    chunk = max(1, min(LINE_CHUNK, 2 ** 26 // (16 * n * n)))
    for k0 in range(0, F, chunk):
        k1 = min(k0 + chunk, F)
        Mk = Q[k0:k1] @ X.real + 1j * (Q[k0:k1] @ X.imag)           # C_hat^H Q_k C_hat
        G = Mk * (w[k0:k1].conj()[:, :, None] * w[k0:k1, None, :]).reshape(k1 - k0, n * n)
        Nbb += EE[k0:k1].T @ G
    Nbb = Nbb.reshape(me, me, n, n).transpose(0, 2, 1, 3)            # (j, a, l, b)
    Nbb = np.einsum("ia,jalb,bk->jilk", pinv.conj().T, Nbb, pinv, optimize=True)
    Nbb = Nbb.reshape(me * n, me * n).real
    # N_BD[(j,a),(l,i)] = sum_k conj(E_kj) E_kl conj(w_ka) q_ki conj(C_hat_ia)
    V = (EE.reshape(F, me, me)[:, :, None, :] * w.conj()[:, None, :, None]).reshape(F, -1)
    Nbd = (V.T @ Q).reshape(me, n, me, p) * ch.conj().T[None, :, None, :]
    Nbd = np.einsum("ia,jalm->jilm", pinv.conj().T, Nbd, optimize=True)
    Nbd = Nbd.transpose(0, 1, 3, 2).reshape(me * n, p * me).real     # columns (i, l)
    Ndd = (Q.T @ EE).reshape(p, me, me).real                         # per-channel blocks
    Ndd = 0.5 * (Ndd + np.swapaxes(Ndd, 1, 2))
    Ndd_inv = np.linalg.inv(Ndd + 1e-300)                            # (p, me, me)

    def dd_solve(r):  # N_DD^{-1} r for r (..., p me)
        return np.einsum("iab,...ib->...ia", Ndd_inv, r.reshape(r.shape[:-1] + (p, me))
                         ).reshape(r.shape)

    Schur = Nbb - Nbd @ dd_solve(Nbd).T
    solve_s = _normal_solver(0.5 * (Schur + Schur.T))

    def rhs(R):
        QR_ = Q * R
        rb = (E.conj().T @ ((QR_ @ ch.conj()) * w.conj()))           # (me, n) modal
        rb = (rb @ pinv.conj()).reshape(-1).real
        rd = (QR_.T @ E.conj()).real.reshape(-1)                     # (i, l)
        return rb, rd

    def solve(rb, rd):
        tb = solve_s(rb - Nbd @ dd_solve(rd))
        return tb, dd_solve(rd - Nbd.T @ tb)

    def predict(tb, td):
        B = tb.reshape(me, n).T
        return ((E @ B.T @ pinv.T) * w) @ ch.T + E @ td.reshape(p, me).T

    tb, td = solve(*rhs(Y))
    for _ in range(refine):  # iterative refinement, residual in the original form
        db, dd = solve(*rhs(Y - predict(tb, td)))
        tb, td = tb + db, td + dd
    b_d = tb.reshape(me, n).T * data.input_scale[None, :]
    d_d = td.reshape(p, me) * data.input_scale[None, :]
    return b_d, d_d


def estimate_bd_given_modes(a_d, c_d, data, *, d_zero, weighted, modal):
    """:func:`estimate_bd` with a precomputed ``(mu, Phi, ok)`` of ``a_d``."""
    n = a_d.shape[0]
    p, m_e = data.n_outputs, data.n_extended_inputs
    Q = inverse_covariance(data, weighted)
    shortcut = _bd_shortcut(a_d, c_d, data, Q, d_zero=d_zero, modal=modal)
    if shortcut is not None:
        return shortcut
    mu, phi, ok = modal
    E, Y = data.E, data.Y
    nq = n + (0 if d_zero else p)
    base, wt, K, T = _regressor_blocks(a_d, c_d, data, modal, d_zero)

    def regress(k0, k1):
        """Per-line regressor R_k (chunk, p, nq)."""
        if ok:
            return base[None] * wt[k0:k1, None, :]
        Rk = K[k0:k1]
        if not d_zero:
            Rk = np.concatenate([Rk, np.broadcast_to(np.eye(p), (k1 - k0, p, p))], axis=2)
        return Rk

    def weigh(Yr):
        """Q_k Yr_k, shape (F, p)."""
        if Q is None:
            return Yr
        return Q * Yr if Q.ndim == 2 else (Q @ Yr[:, :, None])[:, :, 0]

    def rhs_of(Yr):
        """sum_k conj(E_ka) (R_k^H Q_k Yr_k) -> (m_e, nq) complex."""
        QY = weigh(Yr)
        if ok:  # R_k^H v = conj(w~_k) * (base^H v): never form R_k
            return E.conj().T @ ((QY @ base.conj()) * wt.conj())
        out = np.zeros((m_e, nq), complex)
        for k0 in range(0, len(data.z), LINE_CHUNK):
            k1 = min(k0 + LINE_CHUNK, len(data.z))
            P_ = (QY[k0:k1, None, :] @ regress(k0, k1).conj())[:, 0, :]
            out += E[k0:k1].conj().T @ P_
        return out

    Nc = _normal_matrix(E, Q, base, wt, regress, ok=ok, n=n, nq=nq, p=p)
    Nt = T.conj().T @ Nc.transpose(0, 2, 1, 3) @ T  # (a, b, i, l)
    Nr = Nt.transpose(0, 2, 1, 3).real.reshape(m_e * nq, m_e * nq)
    Nr = 0.5 * (Nr + Nr.T)

    def to_real(rc):
        return (rc @ T.conj()).real.reshape(-1)  # (T^H r) per a: r_a T^* -> (m_e, nq)

    def predict(theta):
        th = theta.reshape(m_e, nq)
        Bm = th[:, :n].T  # (n, m_e) real
        Dm = th[:, n:].T if nq > n else np.zeros((p, m_e))
        return apply_model(a_d, Bm, c_d, Dm, data.z, E, modal=(mu, phi, ok))

    solve = _normal_solver(Nr)
    theta = solve(to_real(rhs_of(Y)))
    for _ in range(2):  # iterative refinement (semi-normal equations)
        resid = Y - predict(theta)
        theta = theta + solve(to_real(rhs_of(resid)))
    th = theta.reshape(m_e, nq)
    b_d = th[:, :n].T * data.input_scale[None, :]
    d_d = (th[:, n:].T if nq > n else np.zeros((p, m_e))) * data.input_scale[None, :]
    return b_d, d_d


def _bd_shortcut(a_d, c_d, data, Q, *, d_zero, modal):
    """``(B_d, D_d)`` by a cheaper exact route when one applies, else None.

    Unweighted with many channels: on ``range(C)`` plus the complement's ``D``
    (:func:`project_outputs`); diagonal weights with many channels: the per-channel form
    (:func:`_estimate_bd_diag_weighted`); unweighted stacked realisations: per-line sums
    (:func:`ident.core.fast_bd.fast_estimate_bd`).
    """
    n = a_d.shape[0]
    p = data.n_outputs
    if Q is None and p > n + subspace.OUTPUT_RANK_MARGIN and n > 0:
        # unweighted: exact on range(C) plus the complement's D (project_outputs), so the
        # D unknowns of hundreds of channels never enter the normal equations
        W = np.linalg.qr(c_d)[0]
        reduced, d_perp, _ = project_outputs(data, W, d_zero=d_zero)
        b_d, d_r = estimate_bd_given_modes(a_d, W.T @ c_d, reduced, d_zero=d_zero, weighted=False,
                                modal=modal)
        return b_d, W @ d_r + d_perp
    if (Q is not None and Q.ndim == 2 and modal[2] and not d_zero
            and p > n + subspace.OUTPUT_RANK_MARGIN):
        return _estimate_bd_diag_weighted(a_d, c_d, data, Q, modal)
    if Q is None and modal[2]:
        if line_sums(data) is not None:  # stacked realisations: per-line sums, same answer
            bd = fast_estimate_bd(a_d, c_d, data, d_zero=d_zero)
            if bd is not None:
                return bd
    return None


def _regressor_blocks(a_d, c_d, data, modal, d_zero):
    """The pieces of the per-line regressors and the map ``T`` from real to modal unknowns.

    Returns
    -------
    base, wt : ndarrays or None
        Modal form (``modal[2]``): ``R_k = base diag(wt[k])``, ``base = [C Phi, I]`` (p, nq),
        ``wt[k] = [1 / (z_k - mu), 1]`` (F, nq); None otherwise.
    K : ndarray, shape (F, p, n), or None
        Direct fallback: ``K_k = C (z_k I - A)^{-1}`` in real state coordinates.
    T : ndarray, shape (nq, nq)
    """
    n = a_d.shape[0]
    p = data.n_outputs
    mu, phi, ok = modal
    nq = n + (0 if d_zero else p)
    base = wt = K = None
    if ok:
        # regressor blocks: C_hat diag(w_k) for B_hat, identity for D; T maps real -> modal
        ch = c_d @ phi
        w = 1.0 / (data.z[:, None] - mu[None, :])
        base = np.hstack([ch, np.eye(p)]) if not d_zero else ch
        wt = np.hstack([w, np.ones((w.shape[0], p))]) if not d_zero else w
        T = sla.block_diag(np.linalg.inv(phi), np.eye(nq - n)) if nq > n else np.linalg.inv(phi)
    else:
        # direct fallback: K_k = C (z_k I - A)^{-1}, real state coordinates
        zI = data.z[:, None, None] * np.eye(n)[None]
        K = np.linalg.solve(np.swapaxes(zI - a_d, 1, 2), np.broadcast_to(c_d.T, (len(data.z), n, p)))
        K = np.swapaxes(K, 1, 2)  # (F, p, n)
        T = np.eye(nq)
    return base, wt, K, T


def _normal_matrix(E, Q, base, wt, regress, *, ok, n, nq, p):
    """The normal matrix ``N[a, i, b, j]`` (complex, modal coordinates), shape (m_e, nq, m_e, nq).

    ``regress(k0, k1)`` gives the per-line regressors ``R_k`` (chunk, p, nq) of lines
    ``k0:k1`` (used when no modal form is available).
    """
    F, m_e = E.shape
    if ok and Q is None:
        M0 = base.conj().T @ base  # (nq, nq)
        # the p weights of the D unknowns are all 1: use one column for them, then expand
        nw = n + (nq > n)
        V = (E[:, :, None] * wt[:, None, :nw]).reshape(F, m_e * nw)
        S = (V.conj().T @ V).reshape(m_e, nw, m_e, nw)
        idx = np.concatenate([np.arange(n), np.full(nq - n, n)]).astype(int)
        Nc = S[:, idx][:, :, :, idx] * M0[None, :, None, :]
    else:
        Nc = np.zeros((m_e, nq, m_e, nq), complex)
        if ok and Q is not None and Q.ndim == 2:
            X = (base.conj()[:, :, None] * base[:, None, :]).reshape(p, nq * nq)
            Xr, Xi = np.ascontiguousarray(X.real), np.ascontiguousarray(X.imag)
        chunk = max(1, min(LINE_CHUNK, 2 ** 26 // (16 * nq * nq)))  # (chunk, nq, nq) <= 64 MB
        for k0 in range(0, F, chunk):
            k1 = min(k0 + chunk, F)
            c = k1 - k0
            if ok and Q.ndim == 2:  # diagonal: M_k = sum_r q_kr conj(base_r) base_r^T
                Mk = (Q[k0:k1] @ Xr + 1j * (Q[k0:k1] @ Xi)).reshape(c, nq, nq)
                Gk = wt[k0:k1].conj()[:, :, None] * Mk * wt[k0:k1, None, :]
            elif ok:  # G_k = diag(conj w~) (base^H Q_k base) diag(w~), all as single GEMMs
                QB = (Q[k0:k1].reshape(c * p, p) @ base).reshape(c, p, nq)
                Mk = (base.conj().T @ QB.transpose(1, 0, 2).reshape(p, c * nq))
                Mk = Mk.reshape(nq, c, nq).transpose(1, 0, 2)
                Gk = wt[k0:k1].conj()[:, :, None] * Mk * wt[k0:k1, None, :]
            else:
                Rk = regress(k0, k1)
                QR_ = Rk if Q is None else (Q[k0:k1, :, None] * Rk if Q.ndim == 2
                                            else Q[k0:k1] @ Rk)
                Gk = np.swapaxes(Rk.conj(), 1, 2) @ QR_  # (c, nq, nq)
            EE = E[k0:k1].conj()[:, :, None] * E[k0:k1][:, None, :]  # (c, m_e, m_e)
            Nc += (EE.reshape(c, -1).T @ Gk.reshape(c, -1)).reshape(
                m_e, m_e, nq, nq).transpose(0, 2, 1, 3)
    return Nc
