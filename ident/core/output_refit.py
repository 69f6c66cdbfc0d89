"""The output matrices ``C`` and ``D`` of an identified model, by least squares for its poles.

FNSI takes ``C`` from the extended observability matrix (the first block row of the
subspace's singular vectors) and then ``B``, ``D`` by least squares for that ``A`` and ``C``
(:mod:`ident.core.bd`). The poles are good; ``C`` carries the subspace's noise and bias:
on a linear beam record (bench/RESULTS.md, "How far FNSI's linear model is from the data")
FNSI's answer left 256 noise variances per line and output, and predicted another
realisation 10-16 dB above what the record allows; ``C`` and ``D`` by least squares for the
same ``A`` and ``B`` left 10.6 and reached that floor. For given ``A`` and ``B`` the output
is linear in ``C`` and ``D``:

    ``Y(k) = C X(k) + D E(k)``,  ``X(k) = (z_k I - A)^{-1} B E(k)``

so each output's row of ``[C, D]`` is one weighted linear least-squares problem over the
lines (real unknowns: real and imaginary parts stacked). The poles, and with them every
mode's frequency and damping, do not move.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.ident.core.frequency_data import FrequencyData
from fnsi_lab.ident.core.state_space import StateSpaceModel, dt_modal, make_model

__all__ = ["refit_output_matrices", "state_response", "state_response_at",
           "output_matrices_for", "with_output_matrices"]


def state_response(model: StateSpaceModel, data: FrequencyData) -> np.ndarray:
    """``X(k) = (z_k I - A)^{-1} B E(k)`` on the data's lines: shape (F, n), complex."""
    return state_response_at(model, np.asarray(data.z), np.asarray(data.E_physical))


def state_response_at(model: StateSpaceModel, z: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``X(k)`` for lines ``z`` (F,) and extended inputs ``E`` (F, m_e): shape (F, n)."""
    a, b = model.a_d, model.b_d
    mu, phi, ok = dt_modal(model)   # the model's cached eigen-decomposition
    if ok:
        modal = np.linalg.solve(phi, b) @ E.T                    # (n, F)
        return (phi @ (modal / (z[None, :] - mu[:, None]))).T
    eye = np.eye(a.shape[0])
    return np.stack([np.linalg.solve(zk * eye - a, b @ ek) for zk, ek in zip(z, E)])


def output_matrices_for(model: StateSpaceModel, z: np.ndarray, E: np.ndarray, Y: np.ndarray,
                        weights: np.ndarray | None = None, *, d_zero: bool,
                        feedthrough: int | None = None, states: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """``C`` and ``D`` by weighted least squares for ``model``'s ``A`` and ``B``.

    Parameters
    ----------
    model : StateSpaceModel
    z : complex ndarray, shape (F,)
        The lines (``exp(j w T)`` in the model's time base).
    E : complex ndarray, shape (F, m_e)
        Extended inputs on the lines, in the model's input units.
    Y : complex ndarray, shape (F, p)
        Outputs on the lines.
    weights : ndarray, shape (F, p), optional
        Per line and output, on the squared residual (None: equal).
    d_zero : bool
        Keep ``D = 0``.
    feedthrough : int, optional
        Only the first ``feedthrough`` columns of ``E`` enter the regression through ``D``
        (the states still see all of ``E``); the caller has taken the others' share out
        of ``Y``. None: every column.
    states : complex ndarray, shape (F, n), optional
        ``X`` when the caller has it (:func:`state_response_at` of ``z``, ``E``).

    Returns
    -------
    c_d, d_d : ndarray, shapes (p, n) and (p, m_d)
        ``m_d`` is ``feedthrough`` or ``m_e``.
    """
    X = (state_response_at(model, np.asarray(z), np.asarray(E)) if states is None
         else states)                                                       # (F, n)
    return _least_squares(X, E if feedthrough is None else E[:, :feedthrough], Y, weights,
                          d_zero)


def _least_squares(X: np.ndarray, E: np.ndarray, Y: np.ndarray, weights: np.ndarray | None,
                   d_zero: bool) -> tuple[np.ndarray, np.ndarray]:
    """``C`` (p, n) and ``D`` (p, m_d) for states ``X`` (F, n), feedthrough inputs ``E``
    (F, m_d) and outputs ``Y`` (F, p), each output's row its own real least squares."""
    R = X if d_zero else np.concatenate([X, E], axis=1)          # (F, n [+ m_d])
    w = np.ones(Y.shape) if weights is None else np.sqrt(np.asarray(weights, float))
    rows = []
    for o in range(Y.shape[1]):
        A = R * w[:, o:o + 1]
        b = Y[:, o] * w[:, o]
        theta, *_ = np.linalg.lstsq(np.vstack([A.real, A.imag]),
                                    np.concatenate([b.real, b.imag]), rcond=None)
        rows.append(theta)
    theta = np.stack(rows)                                       # (p, n [+ m_d])
    n = X.shape[1]
    d_d = np.zeros((Y.shape[1], E.shape[1])) if d_zero else theta[:, n:]
    return theta[:, :n], d_d


def with_output_matrices(model: StateSpaceModel, c_d: np.ndarray,
                         d_d: np.ndarray) -> StateSpaceModel:
    """``model`` with other ``C`` and ``D`` (the same poles, ``B``, time base and names)."""
    return make_model(model.a_d, model.b_d, c_d, d_d, sample_rate_hz=model.sample_rate_hz,
                      n_inputs=model.n_inputs, input_names=model.input_names,
                      output_names=model.output_names, time_base=model.time_base,
                      bilinear_period_s=model.bilinear_period_s, _modal_dt=dt_modal(model))


def refit_output_matrices(model: StateSpaceModel, data: FrequencyData, weights: np.ndarray, *,
                          d_zero: bool) -> StateSpaceModel:
    """``model`` with ``C`` and ``D`` re-estimated by weighted least squares for its ``A``, ``B``.

    Parameters
    ----------
    model : StateSpaceModel
        Identified on ``data`` (same extended inputs).
    data : FrequencyData
    weights : ndarray, shape (F, p)
        Per line and output, on the squared residual (the nested test's: inverse noise
        variances, :func:`ident.robust.nested.residual_weights`).
    d_zero : bool
        Keep ``D = 0``.

    Returns
    -------
    StateSpaceModel
        The same poles, time base and names; ``model`` itself when the refit does not lower
        the weighted residual (a degenerate regression).
    """
    E, Y = np.asarray(data.E_physical), np.asarray(data.Y)
    X = state_response(model, data)                              # once: fit and residuals
    c_d, d_d = _least_squares(X, E, Y, weights, d_zero)
    before = np.sum(weights * np.abs(Y - X @ model.c_d.T - E @ model.d_d.T) ** 2)
    after = np.sum(weights * np.abs(Y - X @ c_d.T - E @ d_d.T) ** 2)
    if not after < before:
        return model
    return with_output_matrices(model, c_d, d_d)
