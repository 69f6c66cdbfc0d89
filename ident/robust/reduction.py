"""Model reduction: remove spurious poles and re-estimate B, D (docs/method.md §6; seed Eq. 9-12).

Real-valued implementation (docs/method.md §6, "recommended"):

1. work on the discrete-time model ``(A_d, C_d)`` that the least squares fits;
2. keep a set of eigenvalues ``mu_i`` of ``A_d`` (both members of every conjugate pair);
3. ordered real Schur form ``A_d = Q T Q^T`` with the kept eigenvalues in the leading block;
   ``A_r = T[:r, :r]``, ``C_r = C_d Q[:, :r]`` (restriction of ``A_d`` to the kept invariant
   subspace: kept poles and their output mode shapes are preserved exactly; orthogonal, so
   well conditioned even for close eigenvalues);
4. re-estimate real ``(B_r, D_r)`` by the weighted least squares of docs/method.md §1.4
   (:func:`ident.core.fnsi.estimate_bd`, same lines, weights and D option) -- seed Eq. 11-12;
5. continuous time, extended FRF and nonlinear coefficients are recomputed from the reduced
   model by the caller (:func:`ident.core.fnsi.make_model` does the CT conversion and poles).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from fnsi_lab.ident.errors import IdentError

__all__ = ["complete_pairs", "restrict_to_eigenvalues", "reduce_model"]


def complete_pairs(eigenvalues, keep, *, rel_tol: float = 1e-6) -> np.ndarray:
    """Extend a keep-mask so that both members of every conjugate pair are kept.

    Parameters
    ----------
    eigenvalues : complex ndarray, shape (n,)
    keep : bool ndarray, shape (n,)
    rel_tol : float
        Two eigenvalues are partners when ``|mu_a - conj(mu_b)| <= rel_tol * max(|mu_a|, 1e-300)``.

    Returns
    -------
    bool ndarray, shape (n,)
    """
    mu = np.asarray(eigenvalues, complex).ravel()
    keep = np.asarray(keep, bool).ravel().copy()
    if keep.size != mu.size:
        raise IdentError(f"keep has {keep.size} entries, there are {mu.size} eigenvalues")
    for i in np.flatnonzero(keep):
        if mu[i].imag == 0:
            continue
        d = np.abs(mu - np.conj(mu[i]))
        d[i] = np.inf
        k = int(np.argmin(d))
        if d[k] <= rel_tol * max(abs(mu[i]), 1e-300) + 1e-14:
            keep[k] = True
    return keep


def restrict_to_eigenvalues(a_d, c_d, keep):
    """Restrict ``(A_d, C_d)`` to the invariant subspace of the kept eigenvalues.

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
        Real state matrix.
    c_d : ndarray, shape (p, n)
    keep : bool ndarray, shape (n,)
        Over ``np.linalg.eigvals(a_d)`` order **or** given as the kept eigenvalues themselves
        (complex ndarray); conjugate partners are added.

    Returns
    -------
    a_r : ndarray, shape (r, r)
        Leading block of the ordered real Schur form.
    c_r : ndarray, shape (p, r)
        ``C_d Q[:, :r]``.
    q : ndarray, shape (n, n)
        Orthogonal Schur vectors.

    Notes
    -----
    docs/method.md §6 step 3. The Schur eigenvalues differ from ``eigvals`` by rounding, so each Schur
    eigenvalue is assigned the flag of its nearest ``eigvals`` entry.
    """
    a_d = np.asarray(a_d, float)
    c_d = np.asarray(c_d, float)
    mu = np.linalg.eigvals(a_d)
    keep = np.asarray(keep)
    if keep.dtype != bool:
        kept_vals = keep.astype(complex).ravel()
        mask = np.zeros(mu.size, bool)
        for v in kept_vals:
            mask[int(np.argmin(np.abs(mu - v)))] = True
        keep = mask
    keep = complete_pairs(mu, keep)
    r = int(keep.sum())
    n = a_d.shape[0]
    if r == 0:
        raise IdentError("reduction would keep no pole")
    if r == n:
        return a_d.copy(), c_d.copy(), np.eye(n)

    def sel(x, y=None):
        v = complex(x, 0.0 if y is None else y)
        return bool(keep[int(np.argmin(np.abs(mu - v)))])

    t, q, sdim = sla.schur(a_d, output="real", sort=sel)
    if sdim != r:
        raise IdentError(f"ordered Schur form kept {sdim} eigenvalues instead of {r} "
                         "(eigenvalues too close to separate; reduce the order)")
    return t[:r, :r], c_d @ q[:, :r], q


def reduce_model(model, data, keep, *, d_zero: bool = False, weighted: bool = True):
    """Reduced model with the kept poles of ``model`` and re-estimated ``B``, ``D``.

    Parameters
    ----------
    model : ident.core.fnsi.StateSpaceModel
    data : ident.core.fnsi.FrequencyData
        The data the model was identified on (same lines and weights).
    keep : bool ndarray, shape (n,)
        Over ``model.poles.discrete_eigenvalues`` (conjugate partners are added).
    d_zero : bool
        Constrain ``D = 0`` as for the full model.
    weighted : bool
        Weighted least squares when the noise covariance is available.

    Returns
    -------
    ident.core.fnsi.StateSpaceModel
        Order ``r``; CT matrices and poles recomputed.

    Notes
    -----
    Seed Eq. 11-12 with the real Schur restriction of docs/method.md §6. ``c_a``, the underlying
    linear FRF and the coefficient summary follow from the returned model.
    """
    from fnsi_lab.ident.core import fnsi  # the core: imported late so the pure parts need no core

    keep = np.asarray(keep, bool)
    mu = np.asarray(model.poles.discrete_eigenvalues, complex)
    a_r, c_r, _ = restrict_to_eigenvalues(model.a_d, model.c_d, mu[complete_pairs(mu, keep)])
    b_r, d_r = fnsi.estimate_bd(a_r, c_r, data, d_zero=d_zero, weighted=weighted)
    return fnsi.make_model(a_r, b_r, c_r, d_r, sample_rate_hz=model.sample_rate_hz,
                           n_inputs=model.n_inputs, input_names=model.input_names,
                           output_names=model.output_names, time_base=model.time_base,
                           bilinear_period_s=model.bilinear_period_s)
