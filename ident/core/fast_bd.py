"""Fast unweighted B, D estimation for the order sweep of the robust pipeline.

The sweep needs the model error V(n) of every order; :func:`fast_estimate_bd` gives the
same least-squares answer as :func:`fnsi_lab.ident.core.fnsi.estimate_bd` (unweighted) at the cost
of one normal-matrix product per order (docs/robust.md, "Performance").
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from fnsi_lab.ident.core.folding import qr_r_factor
from fnsi_lab.ident.errors import IdentError

__all__ = ["fast_estimate_bd", "model_output", "model_error",
           "line_sums", "line_fold"]

#: Eigenvector condition number above which the sweep falls back to the core's estimate_bd.
_FAST_COND_LIMIT = 1e8


def fast_estimate_bd(a_d, c_d, data, *, d_zero: bool = False, refine: int = 2):
    """Unweighted ``B``, ``D`` least squares in modal coordinates, BLAS-only (docs/method.md §1.4).

    Same problem and result as :func:`ident.core.fnsi.estimate_bd` with ``weighted=False``
    (the oracle in the tests), organised so that one order costs one
    ``(F, m_e n)^H (F, m_e n)`` product.

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
    data : FrequencyData
    d_zero : bool
    refine : int
        Steps of iterative refinement (residual in the original form; against the normal
        equations when realisations are stacked, :func:`line_sums`).

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
    Stacked realisations share ``w_k``: ``U^H U``, ``U^H E``, ``E^H E`` and the right-hand
    side come from the per-line sums of :func:`line_sums`, so ten realisations cost one.
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
    G = ch.conj().T @ ch                                         # (n, n)
    sums = line_sums(data)
    if sums is None:  # every line once: the products over the lines themselves
        E, z = data.E, data.z
        F = z.size
        w = 1.0 / (z[:, None] - mu[None, :])                    # (F, n)
        U = (E[:, :, None] * w[:, None, :]).reshape(F, me * n)  # (F, (j,a))
        UU = (U.conj().T @ U).reshape(me, n, me, n)
        UE = (U.conj().T @ E).reshape(me, n, me)                 # [(j,a), l]
        EE = E.conj().T @ E
    else:  # stacked realisations: the same products from the sums per unique line
        zu, _, S, T, _ = sums
        w = 1.0 / (zu[:, None] - mu[None, :])                   # (F_u, n)
        Sw = (S.reshape(zu.size, me * me, 1) * w.conj()[:, None, :]).reshape(zu.size, -1)
        UU = (Sw.T @ w).reshape(me, me, n, n).transpose(0, 2, 1, 3)  # one GEMM, (j,a,l,b)
        UE = np.einsum("ujl,ua->jal", S, w.conj(), optimize=True)
        EE = S.sum(axis=0)
    Nbb = UU * G[None, :, None, :]
    # to real B coordinates: block (j,l) -> Pinv^H Nbb_jl Pinv
    Nbb = np.einsum("ia,jalb,bk->jilk", pinv.conj().T, Nbb, pinv, optimize=True)
    nb = me * n
    if d_zero:
        Nr = Nbb.reshape(nb, nb).real
    else:
        Nbd = UE[:, :, :, None] * ch.conj().T[None, :, None, :]  # (j, a, l, i)
        Nbd = np.einsum("ia,jalm->jilm", pinv.conj().T, Nbd, optimize=True)
        Ndd = np.einsum("jl,im->jilm", EE, np.eye(p))
        nd = me * p
        Nc = np.zeros((nb + nd, nb + nd), complex)
        Nc[:nb, :nb] = Nbb.reshape(nb, nb)
        Nc[:nb, nb:] = Nbd.reshape(nb, nd)
        Nc[nb:, :nb] = Nbd.reshape(nb, nd).conj().T
        Nc[nb:, nb:] = Ndd.reshape(nd, nd)
        Nr = Nc.real
    Nr = 0.5 * (Nr + Nr.T)

    def to_real(rb, rd):
        rb = (rb @ pinv.conj()).reshape(-1)                      # to real coordinates
        return rb.real if d_zero else np.concatenate([rb.real, rd.reshape(-1).real])

    def rhs(R):
        Z = R @ ch.conj()                                        # (F, n)
        rb = (data.E.conj().T @ (w.conj() * Z))                  # (me, n) modal
        return to_real(rb, None if d_zero else data.E.conj().T @ R)

    def predict(theta):
        B = theta[:nb].reshape(me, n).T
        out = ((data.E @ B.T @ pinv.T) * w) @ ch.T
        if not d_zero:
            D = theta[nb:].reshape(me, p).T
            out = out + data.E @ D.T
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
    if sums is None:
        theta = solve(rhs(data.Y))
        for _ in range(refine):
            theta = theta + solve(rhs(data.Y - predict(theta)))
    else:  # refinement against the normal equations (the lines are summed away)
        TC = (T.reshape(-1, p) @ ch.conj()).reshape(zu.size, me, n)     # one GEMM
        rb = (TC * w.conj()[:, None, :]).sum(axis=0)                      # (me, n)
        b0 = to_real(rb, T.sum(axis=0))
        theta = solve(b0)
        for _ in range(refine):
            theta = theta + solve(b0 - Nr @ theta)
    b = theta[:nb].reshape(me, n).T * data.input_scale[None, :]
    dd = (np.zeros((p, me)) if d_zero else theta[nb:].reshape(me, p).T) * data.input_scale[None, :]
    return b, dd


def line_sums(data):
    """Sums over the stacked realisations of each DFT line, or None if no line repeats.

    Realisations share ``z_k``, so every least-squares product over the lines reduces to
    sums per unique line (cached on ``data``):

    Returns
    -------
    z_unique : complex ndarray, shape (F_u,)
    inverse : int ndarray, shape (F,)
        Unique-line index of every line.
    S : complex ndarray, shape (F_u, m_e, m_e)
        ``sum_r conj(E_rk) E_rk^T`` (scaled inputs ``data.E``).
    T : complex ndarray, shape (F_u, m_e, p)
        ``sum_r conj(E_rk) Y_rk^T``.
    yy : ndarray, shape (F_u,)
        ``sum_r ||Y_rk||^2``.
    """
    import scipy.sparse as sps
    cache = data.__dict__.setdefault("_ident_cache", {})
    if "line_sums" in cache:
        return cache["line_sums"]
    _, first, inv = np.unique(data.lines, return_index=True, return_inverse=True)
    out = None
    if first.size < data.lines.size:
        F, me, p = data.lines.size, data.E.shape[1], data.Y.shape[1]
        agg = sps.csr_matrix((np.ones(F), (inv, np.arange(F))), shape=(first.size, F))
        E, Y = data.E, data.Y
        S = agg @ (E.conj()[:, :, None] * E[:, None, :]).reshape(F, me * me)
        T = agg @ (E.conj()[:, :, None] * Y[:, None, :]).reshape(F, me * p)
        yy = agg @ np.sum(np.abs(Y) ** 2, axis=1)
        out = (data.z[first], inv, S.reshape(-1, me, me), T.reshape(-1, me, p), yy)
    cache["line_sums"] = out
    return out


def line_fold(data):
    """Each line's stacked realisations folded into at most ``m_e`` rows and a constant, or None.

    The output error of a model on line ``k`` is ``||Y_k - G_k E_k||_F^2 =
    ||[-G_k, I] D_k||_F^2`` with ``D_k = [E_k; Y_k]`` (q x R, one column per realisation),
    so it only depends on ``D_k D_k^H = R_k^H R_k``, ``D_k^H = Q_k R_k`` (QR, inputs first).
    Row ``j`` of ``R_k`` is a pseudo-realisation ``(E, Y) = conj(R_k[j, :m_e], R_k[j, m_e:])``;
    the rows ``j >= m_e`` have no input part (``R_k`` is upper triangular), so their output
    energy is the same for every model: ``||Y_k - G_k E_k||^2 = sum_{j < m_e} ||Y~_kj -
    G_k E~_kj||^2 + c_k``, exactly (a unitary change of the realisation axis), with
    ``c_k = ||R_k[m_e:, m_e:]||_F^2``. A model error then costs ``min(R, m_e)`` rows per line
    instead of ``R``, with no cancellation (unlike expanding the square over :func:`line_sums`;
    docs/ident.md, "Many channels, many realisations"). Cached on ``data``.

    Returns
    -------
    None when no line repeats (or lines repeat unevenly), else
    z_unique : complex ndarray, shape (F_u,)
    inverse : int ndarray, shape (F,)
        Unique-line index of every row of ``data``.
    E : complex ndarray, shape (F_u, r, m_e)
        Pseudo-realisation inputs (scaled, as ``data.E``), ``r = min(R, m_e)``.
    Y : complex ndarray, shape (F_u, r, p)
    const : ndarray, shape (F_u,)
        ``c_k``, the output energy no model of the extended input explains.
    """
    cache = data.__dict__.setdefault("_ident_cache", {})
    if "line_fold" in cache:
        return cache["line_fold"]
    _, first, inv, counts = np.unique(data.lines, return_index=True, return_inverse=True,
                                      return_counts=True)
    out = None
    R = int(counts[0]) if counts.size else 0
    if R >= 2 and counts.min() == counts.max():
        me, p = data.E.shape[1], data.Y.shape[1]
        order = np.argsort(inv, kind="stable")
        A = np.hstack([data.E, data.Y])[order].conj().reshape(first.size, R, me + p)
        Rk = qr_r_factor(A)                                  # (F_u, min(R, q), q)
        r = min(R, me)
        X = Rk[:, :r].conj()                                  # (F_u, r, q): pseudo-realisations
        const = np.sum(np.abs(Rk[:, r:, me:]) ** 2, axis=(1, 2))
        out = (data.z[first], inv, X[:, :, :me], X[:, :, me:], const)
    cache["line_fold"] = out
    return out


def model_output(model, data, mask=slice(None)):
    """Steady-state output ``G_d(z_k) E_k`` on the lines of ``mask`` (modal form, O(F n (p + m_e)))."""
    return _output(model, model.c_d, model.d_d, data.E_physical[mask], data.z[mask])


def _output(model, c_d, d_d, Ephys, z):
    mu, phi = np.linalg.eig(model.a_d)
    ch = c_d @ phi
    bh = np.linalg.solve(phi, model.b_d.astype(complex))
    X = (bh @ Ephys.T).T / (z[:, None] - mu[None, :])             # (F, n)
    return X @ ch.T + Ephys @ d_d.T


def _residual_energy(model, c_d, d_d, data, mask) -> float:
    """``sum_{k in mask} ||Y_k - G(z_k) E_k||^2`` (output units squared).

    With stacked realisations and a mask that treats every realisation of a line alike,
    the same sum over the folded pseudo-realisations of :func:`line_fold` plus their fixed
    remainder: ``min(R, m_e)`` rows per line instead of ``R``, exact (no expansion).
    """
    fold = line_fold(data)
    mask = np.asarray(mask, bool) if not isinstance(mask, slice) else np.ones(data.n_lines, bool)
    if fold is not None:
        zu, inv, Ef, Yf, const = fold
        mask_u = np.zeros(zu.size, bool)
        mask_u[inv[mask]] = True
        if not np.array_equal(mask_u[inv], mask):
            fold = None
    if fold is None:
        Yh = _output(model, c_d, d_d, data.E_physical[mask], data.z[mask])
        return float(np.sum(np.abs(data.Y[mask] - Yh) ** 2))
    r = Ef.shape[1]
    Ep = (Ef[mask_u] / data.input_scale).reshape(-1, Ef.shape[2])   # physical inputs
    Yh = _output(model, c_d, d_d, Ep, np.repeat(zu[mask_u], r))
    resid = Yf[mask_u].reshape(-1, Yf.shape[2]) - Yh
    return float(np.sum(resid.real ** 2 + resid.imag ** 2) + np.sum(const[mask_u]))


def model_error(model, data, mask):
    """V(n) over ``mask`` (docs/method.md §3 shortcut in modal form).

    A model of :func:`ident.core.models.model_at_order_fast` on a compressed decomposition is evaluated on its
    ``r`` channels plus the fixed out-of-span residual (the two parts are orthogonal), so
    the cost does not grow with the number of channels; stacked realisations are folded
    per unique line (:func:`line_fold`, :func:`_residual_energy`).
    """
    cache = data.__dict__.setdefault("_ident_cache", {})
    hit = cache.get("ic_energy")
    if hit is None or hit[0] is not mask:  # the same mask for every order of a sweep
        hit = cache["ic_energy"] = (mask, float(np.sum(np.abs(data.Y[mask]) ** 2)))
    den = hit[1]
    if den <= 0:
        raise IdentError("the output has no energy on the lines of the information criterion")
    twin = model.__dict__.get("_compressed")
    if twin is None:
        return _residual_energy(model, model.c_d, model.d_d, data, mask) / den
    c_r, d_r, reduced, _, perp = twin
    return float((_residual_energy(model, c_r, d_r, reduced, mask) + np.sum(perp[mask])) / den)
