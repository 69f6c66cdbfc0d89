"""The FNSI subspace step: one QR and one SVD give ``Gamma_i`` for every order
(docs/method.md §1.3): block rows, output compression, stacked realisations folded per line,
the input projection, the weighted SVD, and ``A``, ``C`` from the shift invariance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.core.folding import fold_repeated_lines, qr_r_factor
from fnsi_lab.ident.core.weights import LINE_CHUNK, cov_for_svd


@dataclass(frozen=True, eq=False)
class SubspaceDecomposition:
    """Result of the order-independent subspace step (docs/method.md §1.3, §1.7).

    Attributes
    ----------
    singular_values : ndarray, shape (i p,) or (k,)
        Singular values of ``C_Y^{-1/2} L22`` (descending); the order gap shows here. The
        Gram form (``method='gram'``) gives the leading ``k = 2 n_max + 20`` only.
    observability : ndarray, shape (i p, n_cols)
        ``C_Y^{1/2} U S^{1/2}`` for the leading ``n_cols = min(i p, (i-1) p)`` directions;
        ``Gamma_i(n)`` is its first ``n`` columns.
    block_rows : int
        ``i``.
    max_order : int
        Largest order allowed, ``<= (i - 1) p``.
    n_outputs : int
        ``p``.
    n_extended_inputs : int
        ``m_e``.
    weighted : bool
        True if the noise covariance weighted the SVD (and is used for B, D).
    timings_s : dict
        ``{'compress': s, 'fold': s, 'qr': s, 'svd': s}`` (``'projected'`` or ``'gram'``
        instead of ``'qr'`` when that form ran; ``'fold'``: :func:`fold_repeated_lines`).
    shift_weight : ndarray, shape (p, p) or None
        ``W = Sigma_mean^{-1/2}`` applied to every block row of the shift-invariance least
        squares when weighted (None: identity). Without it the weighting did not help: one
        channel 300x noisier than the others gave the same FRF error weighted or not
        (7.6e-3 vs 7.8e-3); with it, 6.1e-5.
    output_basis : ndarray, shape (p, r) or None
        Orthonormal leading output directions ``W`` when the subspace step ran on the
        compressed outputs ``Y W`` (:func:`output_directions`); ``observability`` and
        ``shift_weight`` are then in those ``r`` coordinates and :func:`state_matrices`
        returns ``C = W C_r`` on every channel. None: every channel entered the QR.
    """

    singular_values: np.ndarray
    observability: np.ndarray
    block_rows: int
    max_order: int
    n_outputs: int
    n_extended_inputs: int
    weighted: bool
    timings_s: dict = field(default_factory=dict)
    shift_weight: np.ndarray | None = None
    output_basis: np.ndarray | None = None

    @property
    def block_size(self) -> int:
        """Rows per block row of ``observability``: ``r`` when compressed, else ``p``."""
        return int(self.observability.shape[0] // self.block_rows)




#: Output directions kept beyond ``n_max + m_e`` when compressing (:func:`default_output_rank`).
OUTPUT_RANK_MARGIN = 8
#: Above this QR cost (flops, ``4 F (i q)^2``; about 20 s on one core) the subspace step
#: uses lag sums instead of the QR. Twenty times the 39-channel SmallSat's (i = 20,
#: F = 2008): below it the exact QR always runs, because the Gram form's precision cost
#: models (5 stacked SmallSat realisations: 6 of the 11 Table-1 modes against 10 by QR).
_QR_MAX_FLOPS = 1.2e11
#: Below this QR cost (flops; about 1 s on one core, the 39-channel SmallSat with one
#: realisation costs 5.7e9) the exact QR runs without trying the Gram form first.
_QR_CHEAP_FLOPS = 1e10
#: Between the two, :func:`_projected_residual_gram` is used when the first squared singular
#: value beyond the largest order (the noise floor) is at least this many times its absolute
#: round-off ``eps trace(Y_i Y_i^T)``, i.e. resolved to 1e-6 relative. Measured (10 stacked
#: one-period SmallSat realisations, 39 outputs): 60 dB noise gives 8e6; noise-free data 32
#: (there the exact QR runs).
_GRAM_MIN_FLOOR_RATIO = 1e6
#: Input-lag directions kept by the subspace step's projection: singular value above this
#: share of the largest (equilibrated columns), i.e. energy share above ``eps``
#: (:func:`significant_input_basis`).
INPUT_RANK_TOL = float(np.sqrt(np.finfo(float).eps))


# ---------------------------------------------------------------------------- subspace step
#: Largest share of the data matrix's real columns ``2F`` that its ``i (m_e + p)`` rows may
#: take when ``i`` is chosen for few outputs (the ``max(3 n_max, 120) / p`` term). The noise
#: in the estimated observability range grows with that ratio: on the real Silverbox record
#: (one output, 335 lines, one period per realisation, order 2) the cubic coefficient's
#: spread over ten periods was 0.12-0.22 % up to a ratio of 0.18 and then rose steeply
#: (0.31 % at 0.25, 0.63 % at 0.30, 0.77 % at 0.54 = the former default i = 120;
#: docs/ident.md, "Block rows"). 0.15 keeps below that knee; records with thousands of lines
#: (SmallSat, 2008 lines) are not affected.
NOISE_ROWS_FRACTION = 0.15


def default_block_rows(n_outputs: int, max_order: int, n_lines: int, n_extended_inputs: int) -> int:
    """Block rows ``i`` from ``p``, ``n_max`` and ``F`` (docs/ident.md, "Block rows").

    ``i = max(ceil(n_max / p) + 1, min(ceil(max(3 n_max, 120) / p), c_noise), min(20, c_qr))``:
    few channels need many block rows (docs/method.md §8.2: 3 outputs needed i = 60), but not
    so many that the rows take more than :data:`NOISE_ROWS_FRACTION` of the ``2F`` real
    columns (``c_noise``; short records with few lines); and at least 20 (docs/method.md
    §8.2): with 39 SmallSat outputs, i = 5 made 27-39 of the 59 orders unstable and held 9 of
    the 11 modes at best, i = 20 left 8 unstable and held 10 (docs/robust.md). ``c_qr``: the
    QR size rule ``2F >= i (m_e + p)``. The observability rule ``(i - 1) p >= n_max`` always
    wins.

    Parameters
    ----------
    n_outputs, max_order, n_lines, n_extended_inputs : int
        ``p``, ``n_max``, ``F``, ``m_e``.

    Returns
    -------
    int
    """
    p = max(int(n_outputs), 1)
    need = -(-int(max_order) // p) + 1
    few_outputs = -(-max(3 * int(max_order), 120) // p)
    cap_qr = (2 * int(n_lines)) // (int(n_extended_inputs) + p)
    return int(max(need, min(few_outputs, noise_row_limit(p, n_lines, n_extended_inputs)),
                   min(20, cap_qr), 2))


def noise_row_limit(n_outputs: int, n_lines: int, n_extended_inputs: int) -> int:
    """Most block rows before the noise of a short record dominates (:data:`NOISE_ROWS_FRACTION`).

    Parameters
    ----------
    n_outputs, n_lines, n_extended_inputs : int
        ``p`` (after compression), ``F``, ``m_e``.

    Returns
    -------
    int
        ``floor(NOISE_ROWS_FRACTION * floor(2F / (m_e + p)))``.
    """
    cap_qr = (2 * int(n_lines)) // (int(n_extended_inputs) + max(int(n_outputs), 1))
    return int(NOISE_ROWS_FRACTION * cap_qr)


def block_rows_for(data: FrequencyData, max_order: int) -> int:
    """The default ``i`` that :func:`subspace_decomposition` uses on ``data`` up to ``max_order``.

    Parameters
    ----------
    data : FrequencyData
    max_order : int

    Returns
    -------
    int
        :func:`default_block_rows` of the (compressed, :func:`default_output_rank`) outputs.
    """
    p, m_e = data.n_outputs, data.n_extended_inputs
    rank = default_output_rank(p, max_order, m_e)
    return default_block_rows(rank if rank is not None and rank < p else p, max_order,
                              data.n_lines, m_e)


def default_output_rank(n_outputs: int, max_order: int, n_extended_inputs: int) -> int | None:
    """Output directions kept by the subspace step, or None to use every channel.

    A model of order ``n`` with ``m_e`` extended inputs produces outputs in at most
    ``n + m_e`` real directions (the columns of ``C`` and ``D``), however many sensors there
    are. Keeping ``n_max + m_e + 8`` directions (8 for the noise-level slack) loses nothing
    a model of the sweep could explain, and the cost of the QR and SVD stops growing with
    ``p`` (docs/ident.md, "Many channels").

    Parameters
    ----------
    n_outputs, max_order, n_extended_inputs : int
        ``p``, ``n_max``, ``m_e``.

    Returns
    -------
    int or None
        ``r < p``, or None when compressing would not reduce the problem.
    """
    r = int(max_order) + int(n_extended_inputs) + OUTPUT_RANK_MARGIN
    return r if r < int(n_outputs) else None


def output_directions(Y: np.ndarray, rank: int) -> np.ndarray:
    """Leading ``rank`` real output directions of a spectrum (PCA over the lines).

    Parameters
    ----------
    Y : complex ndarray, shape (F, p)
    rank : int

    Returns
    -------
    ndarray, shape (p, rank)
        Orthonormal columns: the eigenvectors of ``Re(Y^H Y)`` with the largest eigenvalues
        (the right singular vectors of ``[Re Y; Im Y]``). Real, so a real ``C`` stays real.
    """
    Yr = np.concatenate([Y.real, Y.imag], axis=0)
    G = Yr.T @ Yr
    p = G.shape[0]
    k = int(min(rank, p))
    _, V = sla.eigh(G, subset_by_index=(p - k, p - 1), check_finite=False)
    return np.ascontiguousarray(V[:, ::-1])


def _lag_gram(z: np.ndarray, lines: np.ndarray, Wk: np.ndarray, i: int) -> np.ndarray:
    """``G_d = sum_k z_k^d w_k w_k^H`` for the lags ``d = -(i-1) .. i-1``, shape (2i-1, q, q).

    Lines that repeat (stacked realisations share ``z_k``) are summed first, so the lag sums
    cost ``O(F_unique q^2 i)`` whatever the number of realisations.
    """
    import scipy.sparse as sps
    _, first, inv = np.unique(lines, return_index=True, return_inverse=True)
    zu = z[first]
    F_u, q = zu.size, Wk.shape[1]
    order = np.argsort(inv, kind="stable")
    starts = np.searchsorted(inv[order], np.arange(F_u + 1))
    chunk = max(8, 2 * LINE_CHUNK * F_u // max(lines.size, 1))
    lags = np.arange(-(i - 1), i)
    G = np.zeros((lags.size, q * q), complex)
    for k0 in range(0, F_u, chunk):
        k1 = min(k0 + chunk, F_u)
        rows = order[starts[k0]:starts[k1]]
        ws = Wk[rows]
        outer = (ws[:, :, None] * ws.conj()[:, None, :]).reshape(rows.size, q * q)
        if rows.size != k1 - k0:  # repeated lines: sum the realisations of each line
            agg = sps.csr_matrix((np.ones(rows.size), (inv[rows] - k0, np.arange(rows.size))),
                                 shape=(k1 - k0, rows.size))
            outer = agg @ outer
        G += (zu[k0:k1][None, :] ** lags[:, None]) @ outer
    return G.reshape(lags.size, q, q)


#: The projected Gram form (:func:`_projected_residual_gram`) is not tried when more than
#: this share of the lines have realisation components inside the ``eps`` energy budget
#: above (numerically no noise on any channel there): the form needs a noise floor 1e6 times
#: its round-off (:data:`_GRAM_MIN_FLOOR_RATIO`) and refuses such data, so trying it first
#: would only add its cost (0.4-0.8 s on ten noise-free SmallSat realisations) to the QR's.
_FOLD_NOISE_FREE_SHARE = 0.5


def _lag_sum_hankel_gram(z: np.ndarray, grams: np.ndarray, i: int, m_e: int) -> np.ndarray:
    """``sum_k Re[(xi_k xi_k^H) (x) grams[k]]`` in the block-Hankel row order, shape (i q, i q).

    Rows as in :func:`subspace_decomposition`'s ``M``: the ``i m_e`` input rows (block row
    major), then the ``i p`` output rows. ``|z_k| = 1``, so block ``(r, s)`` is the lag sum
    ``Re sum_k z_k^(r-s) grams[k]`` (negative lags: the transpose of the positive one).

    Parameters
    ----------
    z : complex ndarray, shape (F_u,)
    grams : complex ndarray, shape (F_u, q, q)
        Hermitian per-line Grams, channels ``[E; Y]``.
    i, m_e : int
    """
    F_u, q = grams.shape[0], grams.shape[1]
    zl = z[None, :] ** np.arange(i)[:, None]                             # (i, F_u)
    G = (zl @ grams.reshape(F_u, q * q)).reshape(i, q, q).real          # lags 0 .. i-1
    r = np.arange(i)
    lag = r[:, None] - r[None, :]                                        # of block (r, s)
    blocks = np.where((lag >= 0)[:, :, None, None], G[np.abs(lag)],
                      np.swapaxes(G[np.abs(lag)], 2, 3))                  # (i, i, q, q)
    # channel-major within the input rows and within the output rows, as M
    rows = np.concatenate([(r[:, None] * q + np.arange(m_e)[None]).ravel(),
                           (r[:, None] * q + np.arange(m_e, q)[None]).ravel()])
    full = blocks.transpose(0, 2, 1, 3).reshape(i * q, i * q)[np.ix_(rows, rows)]
    return 0.5 * (full + full.T)


def _psd_factor_rows(W: np.ndarray) -> np.ndarray:
    """Rows ``V^T`` with ``V V^T = W`` (symmetric PSD), shape (rank, n): pivoted Cholesky.

    The pivoted Cholesky stops at the LAPACK default tolerance ``n eps max(diag W)``: an error
    of that size on ``W``, whose own round-off is of the same order.
    """
    from scipy.linalg import lapack
    n = W.shape[0]
    if not np.any(W):
        return np.zeros((0, n))
    c, piv, rank, info = lapack.dpstrf(W, lower=0)
    if info < 0:
        raise IdentError(f"pivoted Cholesky failed (LAPACK dpstrf info {info})")
    U = np.triu(c[:rank])                                               # P^T W P = U^T U
    rows = np.zeros((rank, n))
    rows[:, piv - 1] = U
    return rows


def significant_input_basis(Me: np.ndarray, tol: float = INPUT_RANK_TOL) -> np.ndarray:
    """Orthonormal basis of the numerically significant column space of ``Me``, shape (rows, r).

    ``Me`` (real, ``(rows, i m_e)``) holds the block-Hankel extended input, one column per
    input lag. Its columns are equilibrated (unit norm) and kept directions are the left
    singular vectors whose singular value is above ``tol`` times the largest. Why: for a
    band-limited multisine the lagged inputs are nearly collinear (singular values over 16
    decades on a 5-DOF chain with i = 24), so the directions below ``sqrt(eps)`` are set by
    round-off, and a projection on them differs with the BLAS's summation order (1 or 2
    threads moved the information criterion by 1-4 % and flipped the selected order). The
    kept span is accurate to about ``eps / tol`` radians whatever the BLAS does.
    """
    scale = np.linalg.norm(Me, axis=0)
    scale[scale == 0] = 1.0
    U, sv, _ = np.linalg.svd(Me / scale, full_matrices=False)
    if sv.size == 0 or sv[0] == 0:
        return U[:, :0]
    return U[:, sv > tol * sv[0]]


def _truncated_input_residual(MT: np.ndarray, n_in: int) -> np.ndarray:
    """``L22`` (lower triangular, ``(n_y, n_y)``) of ``MT = [Me, My]`` with ``My`` projected
    out of the significant input space only (:func:`significant_input_basis`)."""
    Me, My = MT[:, :n_in], MT[:, n_in:]
    U = significant_input_basis(Me)
    R = My - U @ (U.T @ My)
    R = R - U @ (U.T @ R)          # twice is enough (Kahan-Parlett reorthogonalisation)
    r = qr_r_factor(R)
    out = np.zeros((My.shape[1], My.shape[1]))
    out[:r.shape[0]] = r
    return out.T


def _qr_residual_block(z: np.ndarray, E: np.ndarray, Y: np.ndarray, i: int,
                       extra_rows: np.ndarray | None = None) -> np.ndarray:
    """``L22`` of the QR ``[E_i; Y_i] = L Q^T`` of the block-Hankel data, shape (i p, i p).

    ``M^T = [Re; Im]`` of ``xi_k (x) [E_k; Y_k]`` (``2F`` rows, ``i (m_e + p)`` columns),
    plus ``extra_rows`` (real, already in that column order: a factor of the lag-sum Gram of
    :func:`fold_repeated_lines`' small components). The input columns are not factored
    with the outputs: the outputs are projected out of the input's significant lag space
    (:func:`significant_input_basis`), then factored by a QR (``R`` only), so that the
    round-off of the nearly collinear input lags cannot reach ``L22``.
    """
    m_e, p = E.shape[1], Y.shape[1]
    F, n = z.size, i * (m_e + p)
    n_extra = 0 if extra_rows is None else extra_rows.shape[0]
    MT = np.empty((2 * F + n_extra, n), order="F")
    xi = z[None, :] ** np.arange(i)[:, None]                          # (i, F)
    for r in range(i):  # column blocks: input rows of block row r, then output rows
        for X, c0, w in ((E, r * m_e, m_e), (Y, i * m_e + r * p, p)):
            V = xi[r][:, None] * X
            MT[:F, c0:c0 + w] = V.real
            MT[F:2 * F, c0:c0 + w] = V.imag
    if n_extra:
        MT[2 * F:] = extra_rows
    return _truncated_input_residual(MT, i * m_e)


def _hankel_residual_gram(data_z, lines, E, Y, i: int) -> np.ndarray:
    """``L22 L22^T`` of the QR ``[E_i; Y_i] = L Q^T`` from lag sums, shape (i p, i p).

    ``[E_i; Y_i] [E_i; Y_i]^T = Re(X X^H)`` is block Toeplitz in the block-row lag (block
    ``(r, s)`` is ``Re G_{r-s}``), so the Gram matrix costs ``O(F q^2 i)`` instead of the QR's
    ``O(F q^2 i^2)``; ``L22 L22^T`` is its Schur complement on the output rows.
    """
    m_e, p = E.shape[1], Y.shape[1]
    G = _lag_gram(data_z, lines, np.hstack([E, Y]), i).real
    r = np.arange(i)
    d = r[:, None] - r[None, :] + i - 1          # lag index of block (r, s)

    def blocks(a0, a1, b0, b1):
        B = G[d][:, :, a0:a1, b0:b1]             # (i, i, ., .)
        return B.transpose(0, 2, 1, 3).reshape(i * (a1 - a0), i * (b1 - b0))

    Gee = blocks(0, m_e, 0, m_e)
    Gey = blocks(0, m_e, m_e, m_e + p)
    Gyy = blocks(m_e, m_e + p, m_e, m_e + p)
    Gee = 0.5 * (Gee + Gee.T)
    try:
        L = sla.cholesky(Gee, lower=True, check_finite=False)
        X = sla.solve_triangular(L, Gey, lower=True, check_finite=False)
    except np.linalg.LinAlgError:  # collinear inputs: pseudo-inverse
        w, V = np.linalg.eigh(Gee)
        keep = w > w.max() * 1e-12
        X = (V[:, keep] / np.sqrt(w[keep])).T @ Gey
    S = Gyy - X.T @ X
    return 0.5 * (S + S.T)


def _projected_residual_gram(z, E, Y, lines, i: int, check_order: int) -> np.ndarray | None:
    """``L22 L22^T`` as ``Y_i Y_i^T - C^T C``, ``C = Q_E^T Y_i^T``, or None if not resolved.

    The Gram form's Schur complement divides by the input block ``E_i E_i^T``, whose
    condition number grows without bound when the inputs are band-limited (the SmallSat's
    force: 6e15 with the band-limited lines); here the projection on the inputs uses the
    orthonormal ``Q_E`` of the significant part of ``E_i^T`` (:func:`significant_input_basis`, ``O(F (i m_e)^2)``) and ``C``
    costs ``O(F i^2 m_e p)``, while ``Y_i Y_i^T`` comes from lag sums (``O(F p^2 i)``),
    against the full QR's ``O(F i^2 (m_e + p)^2)``. The one subtraction leaves an absolute
    round-off of about ``eps trace(Y_i Y_i^T)`` on the eigenvalues, so the result is kept
    only when the first eigenvalue beyond ``check_order`` (the noise floor the sweep sees)
    is at least :data:`_GRAM_MIN_FLOOR_RATIO` times that: noisy data, not noise-free
    simulations (there the caller runs the exact QR).
    """
    m_e, p = E.shape[1], Y.shape[1]
    F = z.size
    G = _lag_gram(z, lines, Y, i).real
    r = np.arange(i)
    d = r[:, None] - r[None, :] + i - 1
    Gyy = G[d].transpose(0, 2, 1, 3).reshape(i * p, i * p)
    xi = z[None, :] ** r[:, None]                                    # (i, F)
    Ei = (xi[:, None, :] * E.T[None]).reshape(i * m_e, F)
    Q = significant_input_basis(np.hstack([Ei.real, Ei.imag]).T)     # (2F, r)
    C = np.zeros((Q.shape[1], i * p))
    for a in range(0, F, LINE_CHUNK):                                     # Y_i in line chunks
        b = min(a + LINE_CHUNK, F)
        Yi = (xi[:, None, a:b] * Y[a:b].T[None]).reshape(i * p, b - a)
        C += Q[a:b].T @ Yi.real.T + Q[F + a:F + b].T @ Yi.imag.T
    S = Gyy - C.T @ C
    S = 0.5 * (S + S.T)
    if check_order >= S.shape[0]:
        return None
    floor = np.finfo(float).eps * float(np.trace(Gyy))
    k = S.shape[0] - 1 - int(check_order)              # the (n_max + 1)-th largest eigenvalue
    beyond = sla.eigvalsh(S, subset_by_index=(k, k), check_finite=False)[0]
    return S if beyond >= _GRAM_MIN_FLOOR_RATIO * floor else None


def subspace_decomposition(data: FrequencyData, *, max_order: int, block_rows: int | None = None,
                           weighted: bool = True, output_rank: int | str | None = "auto",
                           method: str = "auto") -> SubspaceDecomposition:
    """One QR and one SVD giving ``Gamma_i`` for every order up to ``max_order``.

    Parameters
    ----------
    data : FrequencyData
    max_order : int
        Largest order that will be asked (``<= (i - 1) p``).
    block_rows : int, optional
        ``i``; default :func:`default_block_rows` (of ``r`` when compressed).
    weighted : bool
        Use the noise covariance (if ``data.noise_cov`` is not None) in the SVD and in B, D.
    output_rank : int, 'auto' or None
        Run the subspace step on the ``r`` leading output directions ``Y W``
        (:func:`output_directions`); ``'auto'``: :func:`default_output_rank`; None: every
        channel. ``C`` is ``W C_r`` on every channel; B, D are estimated on every channel.
    method : {'auto', 'qr', 'gram'}
        How ``L22`` is obtained: ``'qr'`` (QR of the block Hankel matrices; stacked
        realisations first folded per line, exactly to the QR's round-off:
        :func:`fold_repeated_lines`) or ``'gram'``
        (block-Toeplitz lag sums and a Schur complement, :func:`_hankel_residual_gram`:
        ``O(F q^2 i)`` instead of ``O(F q^2 i^2)``, independent of the number of stacked
        realisations per unique line). ``'auto'``: the QR while it is cheap
        (``_QR_CHEAP_FLOPS``); up to ``_QR_MAX_FLOPS`` the projected Gram form
        (:func:`_projected_residual_gram`) when it provably resolves the singular values of
        the sweep (a noise floor far above its round-off, :data:`_GRAM_MIN_FLOOR_RATIO`:
        real, noisy data), else the QR (exact to round-off); beyond, the Gram form (it
        resolves singular values down to about ``sqrt(eps) S[0]`` only). The projected form
        is not tried when most lines' realisations are rank-deficient to round-off
        (noise-free data, which it would refuse; :data:`_FOLD_NOISE_FREE_SHARE`).

    Returns
    -------
    SubspaceDecomposition

    Raises
    ------
    IdentError
        If the size rules ``(i - 1) p >= n_max`` and ``2F >= i (m_e + p)`` cannot be met.

    Notes
    -----
    McKelvey's frequency-domain subspace step on the extended input (Noel & Kerschen 2013;
    docs/ident.md): ``Y_i(k) = xi_k (x) Y(k)``, ``E_i(k) = xi_k (x) E(k)`` with
    ``xi_k = [1, z_k, ..., z_k^{i-1}]``; real and imaginary parts side by side;
    ``[E; Y] = L Q^T`` (QR of the transpose); ``C_Y^{-1/2} L22 = U S V^T``;
    ``Gamma_i = C_Y^{1/2} U S^{1/2}``, ``C_Y = sum_k Re[(xi_k xi_k^H) (x) Sigma_Y(k)]``.
    With ``W`` (``output_rank``) the same on ``Y W`` and ``W^T Sigma_Y W``.
    """
    p_all, m_e = data.n_outputs, data.n_extended_inputs
    max_order = int(max_order)
    if max_order < 1:
        raise IdentError(f"max_order must be >= 1, got {max_order}")
    if method not in ("auto", "qr", "gram"):
        raise IdentError(f"method {method!r} is not one of 'auto', 'qr', 'gram'")
    t0 = time.perf_counter()
    W, Y, i = _compressed_outputs(data, max_order, block_rows, output_rank)
    p = Y.shape[1]
    t_w = time.perf_counter()
    L22, S22, method, t_f = _residual_block(data, Y, i, max_order, method)
    t1 = time.perf_counter()
    cov = cov_for_svd(data, weighted)
    if cov is not None and W is not None:  # W^T Sigma_k W, per line
        cov = (np.einsum("ai,ka,aj->kij", W, cov, W, optimize=True) if cov.ndim == 2
               else W.T @ cov @ W)
    obs, S = _weighted_observability(data, L22, S22, cov, i, p, max_order, method)
    ncols = obs.shape[1]
    t2 = time.perf_counter()
    return SubspaceDecomposition(shift_weight=_shift_weight(cov), singular_values=S,
                                 observability=obs, block_rows=i,
                                 max_order=ncols, n_outputs=p_all, n_extended_inputs=m_e,
                                 weighted=cov is not None, output_basis=W,
                                 timings_s={"compress": t_w - t0, "fold": t_f - t_w,
                                            method: t1 - t_f, "svd": t2 - t1})


def _compressed_outputs(data: FrequencyData, max_order: int, block_rows: int | None,
                        output_rank: int | str | None):
    """The output directions ``W`` (None: every channel), the outputs the subspace step sees
    (``Y W``, shape (F, r)) and the block rows ``i``, checked against the size rules.

    Raises
    ------
    IdentError
        If ``i < 2``, ``(i - 1) p < n_max`` or ``2F < i (m_e + p)``.
    """
    p_all, m_e, F = data.n_outputs, data.n_extended_inputs, data.n_lines
    rank = (default_output_rank(p_all, max_order, m_e) if output_rank == "auto"
            else None if output_rank is None else int(output_rank))
    W = output_directions(data.Y, rank) if rank is not None and rank < p_all else None
    Y = data.Y if W is None else data.Y @ W
    p = Y.shape[1]
    i = int(block_rows) if block_rows is not None else default_block_rows(p, max_order, F, m_e)
    if i < 2:
        raise IdentError(f"block_rows must be >= 2, got {i}")
    if (i - 1) * p < max_order:
        raise IdentError(f"max order {max_order} needs (block_rows - 1) * n_outputs >= "
                         f"{max_order}; block_rows={i}, n_outputs={p} (raise block_rows or "
                         "lower the order)")
    if 2 * F < i * (m_e + p):
        raise IdentError(f"too few lines: 2F = {2 * F} < block_rows * (m_e + p) = "
                         f"{i * (m_e + p)} (widen band_hz, lower block_rows or max order)")
    return W, Y, i


def _residual_block(data: FrequencyData, Y: np.ndarray, i: int, max_order: int, method: str):
    """``L22`` (QR) or its Gram form ``S22 = L22 L22^T``, by the method
    :func:`subspace_decomposition` documents.

    Returns
    -------
    L22 : ndarray, shape (i p, i p), or None
        Lower triangular; None when a Gram form ran.
    S22 : ndarray, shape (i p, i p), or None
        None when the QR ran.
    method : str
        The method that ran: ``'qr'``, ``'gram'`` or ``'projected'``.
    t_fold : float
        ``time.perf_counter()`` when the realisations were folded.
    """
    m_e, p = data.n_extended_inputs, Y.shape[1]
    # stacked realisations: per line, the large SVD components as QR rows and the rest as
    # lag sums (exact to the QR's round-off, fold_repeated_lines)
    fold = (fold_repeated_lines(data.z, data.lines, data.E, Y) if method != "gram" else None)
    z_q, E_q, Y_q = (data.z, data.E, Y) if fold is None else (fold.z, fold.E, fold.Y)
    t_f = time.perf_counter()
    S22 = None
    if method == "auto":  # the QR is exact to round-off; the Gram form to sqrt(eps) of S[0]
        flops = 4.0 * z_q.size * (i * (m_e + p)) ** 2
        method = "qr"
        if flops > _QR_MAX_FLOPS:
            method = "gram"
        elif (flops > _QR_CHEAP_FLOPS  # a Gram form where it provably resolves the sweep
              and (fold is None or fold.deficient_share <= _FOLD_NOISE_FREE_SHARE)):
            S22 = _projected_residual_gram(data.z, data.E, Y, data.lines, i, max_order)
            method = "qr" if S22 is None else "projected"
    if method == "qr":
        extra = None
        if fold is not None and fold.small_gram is not None:
            extra = _psd_factor_rows(_lag_sum_hankel_gram(fold.z_unique, fold.small_gram,
                                                          i, m_e))
        L22 = _qr_residual_block(z_q, E_q, Y_q, i, extra)  # (ip, ip); lower triangular
        S22 = None
    else:
        L22 = None
        if S22 is None:  # method 'gram'
            S22 = _hankel_residual_gram(data.z, data.lines, data.E, Y, i)  # L22 L22^T
    return L22, S22, method, t_f


def _weighted_observability(data: FrequencyData, L22, S22, cov, i: int, p: int, max_order: int,
                            method: str):
    """``Gamma_i = C_Y^{1/2} U S^{1/2}`` from ``C_Y^{-1/2} L22 = U S V^T`` (or the leading
    eigenvectors of the weighted Gram form), ``C_Y = sum_k Re[(xi_k xi_k^H) (x) Sigma_Y(k)]``.

    Returns
    -------
    observability : ndarray, shape (i p, min((i - 1) p, columns of U))
    singular_values : ndarray
    """
    cy_sqrt = None
    if cov is not None:
        lags = np.arange(-(i - 1), i)
        zl = data.z[None, :] ** lags[:, None]
        if cov.ndim == 2:  # diagonal (F, p)
            T = np.einsum("dk,ka,ab->dab", zl, cov, np.eye(p)).real
        else:
            T = np.einsum("dk,kab->dab", zl, cov).real  # (2i-1, p, p)
        CY = np.empty((i * p, i * p))
        for a in range(i):
            for b in range(i):
                CY[a * p:(a + 1) * p, b * p:(b + 1) * p] = T[a - b + i - 1]
        CY = 0.5 * (CY + CY.T)
        w, V = np.linalg.eigh(CY)
        w = np.maximum(w, w.max() * 1e-12)
        cy_isqrt = (V / np.sqrt(w)) @ V.T
        cy_sqrt = (V * np.sqrt(w)) @ V.T
    if L22 is not None:
        U, S, _ = np.linalg.svd(L22 if cy_sqrt is None else cy_isqrt @ L22)
    else:  # only the leading directions an order of the sweep can use (and a margin)
        if S22 is None:   # every method but 'qr' leaves its Gram form
            raise IdentError(f"subspace method {method!r} left no residual Gram matrix")
        K = S22 if cy_sqrt is None else cy_isqrt @ S22 @ cy_isqrt
        k = min((i - 1) * p, 2 * max_order + 20)
        ev, U = sla.eigh(0.5 * (K + K.T), subset_by_index=(K.shape[0] - k, K.shape[0] - 1),
                         check_finite=False)
        ev, U = ev[::-1], U[:, ::-1]
        S = np.sqrt(np.maximum(ev, 0.0))
    if cy_sqrt is not None:
        U = cy_sqrt @ U
    ncols = min((i - 1) * p, U.shape[1])
    return U[:, :ncols] * np.sqrt(S[:ncols]), S


def _shift_weight(cov) -> np.ndarray | None:
    """``Sigma_mean^{-1/2}``: the mean noise covariance as block weight of the shift
    equations (None unweighted)."""
    shift_w = None
    if cov is not None:  # mean noise covariance -> block weight of the shift equations
        sm = np.diag(cov.mean(axis=0)) if cov.ndim == 2 else np.real(cov.mean(axis=0))
        sm = 0.5 * (sm + sm.T)
        ws, vs = np.linalg.eigh(sm)
        ws = np.maximum(ws, ws.max() * 1e-12)
        shift_w = (vs / np.sqrt(ws)) @ vs.T
    return shift_w


def state_matrices(decomp: SubspaceDecomposition, order: int) -> tuple[np.ndarray, np.ndarray]:
    """``A_d`` and ``C_d`` of one order by shift invariance.

    Parameters
    ----------
    decomp : SubspaceDecomposition
    order : int
        ``n <= decomp.max_order``.

    Returns
    -------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
        On every channel (``W C_r`` when the decomposition is compressed).

    Notes
    -----
    ``C = Gamma[0:p]``, ``A = Gamma[0:(i-1)p]^+ Gamma[p:ip]`` (least squares), each block row
    whitened by ``decomp.shift_weight`` when the decomposition is weighted.
    """
    a_d, c_r = state_matrices_block(decomp, order)
    W = decomp.output_basis
    return a_d, (c_r if W is None else W @ c_r)


def state_matrices_block(decomp: SubspaceDecomposition, order: int):
    """:func:`state_matrices` in the decomposition's own block coordinates (``C_r``).

    Every order's ``Gamma(n)`` is the first ``n`` columns of one matrix, so one QR of the
    (whitened) upper block rows ``Gamma_up = Q R`` and ``M = Q^T Gamma_down`` serve the whole
    sweep: ``A(n) = R[:n, :n]^{-1} M[:n, :n]`` is the least-squares shift solution of order
    ``n`` (the leading columns of a QR are the QR of the leading columns). Orders whose
    ``R[:n, :n]`` is numerically singular fall back to ``lstsq``.
    """
    n = int(order)
    p = decomp.block_size
    G = decomp.observability
    c_d = G[:p, :n].copy()
    shared = decomp.__dict__.get("_shift_qr")
    if shared is None or shared[0].shape[1] < n:  # the columns up to 2 n (at least 64)
        k = min(G.shape[1], max(2 * n, 64))
        G = G[:, :k]
        if decomp.shift_weight is not None:  # every block row whitened by Sigma_mean^{-1/2}
            i = decomp.block_rows
            G = (decomp.shift_weight @ G.reshape(i, p, k)).reshape(i * p, k)
        Q, R = np.linalg.qr(G[:-p])
        shared = decomp.__dict__["_shift_qr"] = (R, Q.T @ G[p:], G)
    R, M, Gw = shared
    d = np.abs(np.diag(R[:n, :n]))
    if n and d.min() > 1e-12 * d.max():
        a_d = sla.solve_triangular(R[:n, :n], M[:n, :n], check_finite=False)
    else:
        a_d = np.linalg.lstsq(Gw[:-p, :n], Gw[p:, :n], rcond=None)[0]
    return a_d, c_d
