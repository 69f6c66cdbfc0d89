"""Stacked realisations folded per line for the subspace step (docs/ident.md, "Many channels,
many realisations").

Every line of stacked realisations repeats ``R`` times; the subspace step
(:mod:`ident.core.subspace`) only sees each line's ``D_k D_k^H``. :func:`merge_repeated_lines`
folds the realisations into ``q = m_e + p`` QR rows per line, :func:`fold_repeated_lines` keeps
the large SVD components as QR rows and moves the rest to lag sums (:class:`FoldedLines`);
:func:`qr_r_factor` is the ``R`` factor both this fold and the subspace step's QR use.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

__all__ = ["FOLD_GRAM_ENERGY", "FoldedLines", "fold_repeated_lines", "merge_repeated_lines",
           "qr_r_factor"]


def qr_r_factor(a: np.ndarray) -> np.ndarray:
    """``R`` of the QR decomposition of ``a`` (stacked over leading axes): numpy's stubs
    type every mode of ``qr`` as the ``(Q, R)`` result; ``mode='r'`` returns ``R`` alone."""
    return cast(np.ndarray, np.linalg.qr(a, mode="r"))


#: Stacked realisations, folded per line (:func:`fold_repeated_lines`): a line's realisation
#: components (its SVD) are moved from the QR rows to lag sums, smallest first, while on every
#: channel (row of ``[E; Y]``) their summed energy stays within this fraction of the channel's
#: energy over all lines and realisations. Why ``eps``: a Gram sum of parts of energy ``e``
#: is exact to about ``eps e`` (entrywise, a few ``eps`` times the sum of the absolute
#: terms), which moves a singular value of the block-Hankel matrix ``M`` by at most
#: ``sqrt(eps e)`` (Weyl on ``M M^T``); with ``e <= eps ||M_c||^2`` that is ``eps ||M_c||``,
#: what the Householder QR's own backward error (``O(eps)`` of each row's norm) moves it by
#: anyway. A larger fraction would resolve less than the QR does (the Gram form's
#: ``sqrt(eps)``); a smaller one only costs QR rows. No component is dropped.
FOLD_GRAM_ENERGY = float(np.finfo(float).eps)
@dataclass(frozen=True, eq=False)
class FoldedLines:
    """Stacked realisations folded per line for the subspace step (:func:`fold_repeated_lines`).

    ``M M^T`` of the block-Hankel data is that of the QR rows ``(z, E, Y)`` plus the lag sums
    of ``small_gram`` (``sum_k Re[(xi_k xi_k^H) (x) small_gram[k]]``), exactly up to the
    per-line SVD's round-off.

    Attributes
    ----------
    z : complex ndarray, shape (F_q,)
        Line of each folded row (``z_k`` repeats once per large component of line ``k``).
    E : complex ndarray, shape (F_q, m_e)
    Y : complex ndarray, shape (F_q, p)
        Large components ``s_kj v_kj`` of each line's ``D_k = [E_k; Y_k]`` (q x R), split
        into their input and output rows.
    z_unique : complex ndarray, shape (F_u,)
    small_gram : complex ndarray, shape (F_u, q, q), or None
        Per line, the Gram ``sum_j s_kj^2 v_kj v_kj^H`` of the components kept out of the QR
        (their energy is within :data:`FOLD_GRAM_ENERGY` of every channel's); None when
        every component is large (noisy data).
    deficient_share : float
        Share of the lines with such small components (numerically noise-free lines).
    n_realisations : int
        ``R``, the number of times every line repeats.
    """

    z: np.ndarray
    E: np.ndarray
    Y: np.ndarray
    z_unique: np.ndarray
    small_gram: np.ndarray | None
    deficient_share: float
    n_realisations: int


def _line_components(z: np.ndarray, lines: np.ndarray, E: np.ndarray, Y: np.ndarray):
    """Per unique line, the SVD components of the realisations, or None if lines do not repeat.

    Returns
    -------
    None, or (z_unique, s, comp)
        ``z_unique`` (F_u,); ``s`` (F_u, r) singular values of ``D_k`` (descending),
        ``r = min(R, q)``; ``comp`` (F_u, r, q) the components ``s_kj v_kj`` (columns of a
        ``G_k`` with ``G_k G_k^H = D_k D_k^H``), ``[E; Y]`` channel order.
    """
    _, first, inv, counts = np.unique(lines, return_index=True, return_inverse=True,
                                      return_counts=True)
    R = int(counts[0]) if counts.size else 0
    if R < 2 or counts.min() != counts.max():
        return None
    q = E.shape[1] + Y.shape[1]
    order = np.argsort(inv, kind="stable")
    A = np.hstack([E, Y])[order].conj().reshape(first.size, R, q)   # D_k^H per line
    # D_k = V_k S_k U_k^H with A = U S V^H: the components are s_j conj(Vh[j]); U is not needed
    _, s, Vh = np.linalg.svd(A, full_matrices=False)                # (F_u, r), (F_u, r, q)
    return z[first], s, s[:, :, None] * Vh.conj()


def merge_repeated_lines(z: np.ndarray, lines: np.ndarray, E: np.ndarray, Y: np.ndarray):
    """The same subspace-step data with each line's realisations folded into ``q`` columns.

    Stacked realisations repeat every line ``R`` times. The subspace step only sees
    ``sum_k Re[(xi_k xi_k^H) (x) D_k D_k^H]``, ``D_k`` (q x R) the line's ``[E_k; Y_k]``
    columns, so any ``G_k`` with ``G_k G_k^H = D_k D_k^H`` gives the same ``L22`` (up to an
    orthogonal factor on the right). ``G_k = R_k^H`` from the QR ``D_k^H = Q_k R_k`` is
    exact to round-off and has ``q = m_e + p`` columns instead of ``R``: the QR of the block
    Hankel matrices then costs ``F q`` columns instead of ``F R`` when ``R > q``.
    :func:`fold_repeated_lines` uses it when no line is rank-deficient.

    Parameters
    ----------
    z : ndarray, shape (F,)
    lines : ndarray of int, shape (F,)
        DFT line of each row; a line repeats once per realisation.
    E : ndarray, shape (F, m_e)
    Y : ndarray, shape (F, p)

    Returns
    -------
    z, E, Y : ndarrays, shapes (F', ), (F', m_e), (F', p)
        ``F' = F_unique q`` rows when every line repeats ``R > q`` times, else the inputs.
    """
    m_e = E.shape[1]
    q = m_e + Y.shape[1]
    _, first, inv, counts = np.unique(lines, return_index=True, return_inverse=True,
                                      return_counts=True)
    R = int(counts[0])
    if counts.min() != counts.max() or R <= q:
        return z, E, Y
    order = np.argsort(inv, kind="stable")
    A = np.hstack([E, Y])[order].conj().reshape(first.size, R, q)     # D_k^H per line
    Rk = qr_r_factor(A)                                                      # (F_u, q, q)
    X = Rk.conj().reshape(first.size * q, q)                           # rows: columns of R_k^H
    return np.repeat(z[first], q), X[:, :m_e], X[:, m_e:]


def fold_repeated_lines(z: np.ndarray, lines: np.ndarray, E: np.ndarray,
                        Y: np.ndarray) -> FoldedLines | None:
    """Stacked realisations folded per line: QR rows for large components, lag sums for the rest.

    docs/ident.md, "Many channels, many realisations".

    ``D_k = [E_k; Y_k]`` (q x R) holds line ``k``'s realisations; the subspace step sees only
    ``sum_k Re[(xi_k xi_k^H) (x) D_k D_k^H]`` (:func:`merge_repeated_lines`), and
    ``D_k D_k^H = sum_j s_kj^2 v_kj v_kj^H`` (SVD). Noise-free realisations of a system with
    ``m_e`` extended inputs are numerically of rank ``m_e`` per line: the other components
    are round-off or tiny model mismatch, yet they are all the data beyond the model and
    may not be dropped. Components whose energy, summed over the lines and smallest first,
    stays within ``FOLD_GRAM_ENERGY = eps`` of every channel's energy enter as lag sums (a
    Gram form, exact to ``eps`` of their own energy: the QR's round-off level, see
    :data:`FOLD_GRAM_ENERGY`); the rest are QR rows. Ten noise-free one-period SmallSat
    realisations (39 outputs, ``m_e = 3``): 3.2 rows per line instead of 10. Noisy data have
    no small component: their rows stay the realisations themselves (``R <= q``) or the QR
    fold of :func:`merge_repeated_lines` (``R > q``), bit for bit as before the split.

    Parameters
    ----------
    z : complex ndarray, shape (F,)
        On the unit circle (every time base's line map).
    lines : int ndarray, shape (F,)
        DFT line of each row; a line repeats once per realisation.
    E : complex ndarray, shape (F, m_e)
    Y : complex ndarray, shape (F, p)

    Returns
    -------
    FoldedLines or None
        None when no line repeats, lines repeat unevenly, ``z`` leaves the unit circle (the
        lag sums assume ``|z_k| = 1``), or nothing would shrink (no small component and
        ``R <= q``). With no small component and ``R > q``, the rows are those of
        :func:`merge_repeated_lines` (the QR fold, as before the split existed).
    """
    parts = _line_components(z, lines, E, Y)
    if parts is None or not np.allclose(np.abs(parts[0]), 1.0, rtol=0, atol=1e-12):
        return None
    zu, s, comp = parts
    m_e, q = E.shape[1], comp.shape[2]
    energy = np.abs(comp) ** 2                                         # (F_u, r, q)
    budget = FOLD_GRAM_ENERGY * energy.sum(axis=(0, 1))                # per channel
    by_size = np.argsort(s, axis=None, kind="stable")                   # smallest first
    within = np.all(np.cumsum(energy.reshape(-1, q)[by_size], axis=0) <= budget, axis=1)
    small = np.zeros(s.size, bool)
    small[by_size[:int(np.argmin(within)) if not within.all() else s.size]] = True
    small = small.reshape(s.shape)
    R = int(lines.size // zu.size)
    if not small.any():  # noisy: every component is a QR row, as the plain fold gives them
        if R <= q:
            return None
        z_rows, E_rows, Y_rows = merge_repeated_lines(z, lines, E, Y)
        return FoldedLines(z=z_rows, E=E_rows, Y=Y_rows, z_unique=zu, small_gram=None,
                           deficient_share=0.0, n_realisations=R)
    X = comp[~small]                                                    # (F_q, q) QR rows
    cs = comp * small[:, :, None]
    return FoldedLines(z=np.broadcast_to(zu[:, None], s.shape)[~small], E=X[:, :m_e],
                       Y=X[:, m_e:], z_unique=zu,
                       small_gram=np.einsum("kjc,kjd->kcd", cs, cs.conj(), optimize=True),
                       deficient_share=float(np.mean(small.any(axis=1))), n_realisations=R)
