"""The fit behind the search's objective (:mod:`ident.refine.parameter_search`): ``B``, ``D``
of a candidate basis with ``A``, ``C`` fixed (variable projection) and the candidate's FRF to
its basis columns, the search's block rows, and the model order the information criterion
picks with the search's own fits.

Shapes: ``FrequencyData`` as in :mod:`ident.core.periodic`; residual vectors stack the real and
imaginary parts of ``Y - Y_hat``, shape ``(2 F p,)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.fast_bd import fast_estimate_bd
from fnsi_lab.ident.core.periodic import FrequencyData, with_basis
from fnsi_lab.ident.errors import IdentError

__all__ = ["CandidateFit", "fixed_state_fit", "fixed_state_residual", "search_block_rows",
           "order_by_information_criterion"]


def fixed_state_residual(a_d: np.ndarray, c_d: np.ndarray, data: FrequencyData, *,
                         d_zero: bool = False) -> np.ndarray:
    """Residual of the B, D least squares with ``A``, ``C`` fixed (variable projection).

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
    data : FrequencyData
        With the extended input of the candidate basis.
    d_zero : bool
        ``D = 0``.

    Returns
    -------
    ndarray, shape (2 F p,)
        Real, then imaginary parts of ``Y - (C (z I - A)^-1 B + D) E`` (output units).
    """
    r = fixed_state_fit(a_d, c_d, data, d_zero=d_zero).residual
    return np.concatenate([r.real.ravel(), r.imag.ravel()])


@dataclass
class CandidateFit:
    """B, D of a candidate with ``A``, ``C`` fixed; ``G_basis`` = FRF to the basis columns."""

    residual: np.ndarray   # (F, p) complex, output units
    G_basis: np.ndarray    # (F, p, s) complex, output units per basis unit


def fixed_state_fit(a_d: np.ndarray, c_d: np.ndarray, data: FrequencyData, *,
                    d_zero: bool = False) -> CandidateFit:
    bd = fast_estimate_bd(a_d, c_d, data, d_zero=d_zero)
    if bd is None:  # ill-conditioned eigenvectors: the core's solver
        bd = fnsi.estimate_bd(a_d, c_d, data, d_zero=d_zero, weighted=False)
    b_d, d_d = bd
    E = data.E_physical
    m = data.n_inputs
    mu, phi = np.linalg.eig(a_d)
    if np.linalg.cond(phi) < 1e8:    # modal form: O(F n m_e)
        bh = np.linalg.solve(phi, b_d.astype(complex))
        inv = 1.0 / (data.z[:, None] - mu[None, :])                    # (F, n)
        X = ((E @ bh.T) * inv) @ phi.T
        cphi = c_d @ phi
        G_basis = np.einsum("pn,kn,ns->kps", cphi, inv, bh[:, m:], optimize=True)
    else:                            # defective A: batched solves of (z I - A)
        zi = data.z[:, None, None] * np.eye(a_d.shape[0]) - a_d
        X = np.linalg.solve(zi, (E @ b_d.T)[:, :, None])[:, :, 0]
        G_basis = c_d @ np.linalg.solve(zi, np.broadcast_to(b_d[:, m:], (len(data.z),)
                                                            + b_d[:, m:].shape))
    G_basis = G_basis + d_d[None, :, m:]
    return CandidateFit(data.Y - X @ c_d.T - E @ d_d.T, G_basis)


def search_block_rows(n_outputs: int, order: int, n_lines: int, n_extended_inputs: int) -> int:
    """Block rows ``i`` of the decompositions of the search: few, because each candidate pays one.

    ``max(ceil(n / p) + 2, 6)``, capped so that ``2 F >= i (m_e + p)``. On the SmallSat (39
    outputs, order 22) ``i = 6`` cost 0.08 s per candidate against 0.4 s at the default
    ``i = 20`` and gave a sharper objective (model error at the true gaps 5e-8 vs 7e-7);
    on the 3-DOF chain (order 6) ``i = 4..10`` all located the gap within 2e-5.
    """
    i = max(-(-int(order) // int(n_outputs)) + 2, 6)
    return int(min(i, max(2 * int(n_lines) // (int(n_extended_inputs) + int(n_outputs)), 2)))


def order_by_information_criterion(data: FrequencyData, basis: Sequence[Nonlinearity],
                                   max_order: int, *, block_rows: int, d_zero: bool,
                                   with_value: bool = False):
    """The even order 2..``max_order`` the information criterion (MDL, the robust
    pipeline's default; docs/ident.md) selects for ``data`` with ``basis``: one QR + SVD
    with the search's block rows, then per order the search's own ``A``, ``C`` and ``B``,
    ``D`` fit (about 0.06 s for the 3-DOF chain with 16 periods). ``with_value``: also the
    criterion's value at that order (``(order, value)``; relative model errors, so values
    for different bases on the same data compare; inf where there is no opinion)."""
    from fnsi_lab.ident.robust import order_selection as osel

    try:
        cand = with_basis(data, basis)
        dec = fnsi.subspace_decomposition(cand, max_order=max_order, block_rows=block_rows)
    except (IdentError, np.linalg.LinAlgError):   # e.g. a basis column zero here: no opinion
        return (int(max_order), float("inf")) if with_value else int(max_order)
    mask, band = osel.ic_line_mask(cand.frequencies_hz, cand.excited, cand.n_outputs, "auto")
    energy = float(np.sum(np.abs(cand.Y[mask]) ** 2))
    # even orders (modes come in pairs): half the fits of every order, the same choice on
    # the chains and the SmallSat
    orders = sorted(set(range(2, int(max_order) + 1, 2)) | {int(max_order)})
    errors, stable = [], []
    for n in orders:
        a_d, c_d = fnsi.state_matrices(dec, n)
        residual = fixed_state_fit(a_d, c_d, cand, d_zero=d_zero).residual
        errors.append(float(np.sum(np.abs(residual[mask]) ** 2)) / energy)
        stable.append(bool(np.all(np.abs(np.linalg.eigvals(a_d)) < 1.0)))
    if not any(stable):
        return (int(max_order), float("inf")) if with_value else int(max_order)
    ic = osel.InformationCriterion.from_errors(
        orders, errors, stable, int(mask.sum()), band=band, criterion="mdl",
        n_outputs=cand.n_outputs, n_extended_inputs=cand.n_extended_inputs, d_zero=d_zero)
    if with_value:
        return int(ic.selected_order), float(ic.value[orders.index(int(ic.selected_order))])
    return int(ic.selected_order)
