"""How well the basis columns can be told apart from the forces and from each other.

FNSI fits ``Y = G_p P + sum_a G_a h_a`` with one state filter ``(zI - A)^-1`` shared by every
column of the extended input ``E = [P, h_1, ..., h_s]``; a column that is (nearly) a constant
combination of the others over the processed lines gives ``B`` and ``D`` no way to tell them
apart, and its coefficient is shared with them (two stops on the same joint, a Coulomb
``tanh`` next to a quadratic damper at low velocity, a basis column badly scaled against the
force). :func:`regressor_conditioning` measures it on the processed lines:

- ``condition_number`` of ``E`` with unit-norm columns (1 for orthogonal columns; it grows
  without bound as a column becomes a combination of the others);
- per basis column its variance ``inflation`` ``1 / (1 - R^2)``, ``R^2`` of the complex least
  squares of the column by the other columns.

A column that is a linear function of the *motion* (a stop always in contact: a linear spring
in disguise) is not caught here: the equation of motion makes every nonlinear force a
constant combination of the measured displacements, their derivatives and the forces when
every DOF is measured (on the 39-channel SmallSat that regression explained all but 2e-8 of
a stop's column), so only the coefficient's spectrum can tell (:mod:`ident.robust.verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fnsi_lab.ident.core.frequency_data import FrequencyData

__all__ = ["RegressorConditioning", "regressor_conditioning"]


@dataclass(frozen=True)
class RegressorConditioning:
    """Conditioning of the extended input of one identification.

    Attributes
    ----------
    names : tuple of str
        Basis-column names (length ``s``).
    condition_number : float
        ``s_max / s_min`` of the ``(F, m + s)`` extended input with unit-norm columns.
    inflation : ndarray, shape (s,)
        ``1 / (1 - R^2)`` of each basis column against the other extended-input columns.
    """

    names: tuple[str, ...]
    condition_number: float
    inflation: np.ndarray

    def to_dict(self) -> dict:
        """JSON-able: ``condition_number`` and per basis column its ``inflation``."""
        return {"condition_number": self.condition_number,
                "columns": {n: {"inflation": float(vif)}
                            for n, vif in zip(self.names, self.inflation)}}


def _r_squared(target: np.ndarray, regressors: np.ndarray) -> float:
    """``R^2`` of the complex least-squares fit of ``target (F,)`` by ``regressors (F, k)``."""
    total = float(np.sum(np.abs(target) ** 2))
    if total <= 0 or regressors.shape[1] == 0:
        return 0.0
    scale = np.linalg.norm(regressors, axis=0)
    scale[scale == 0] = 1.0
    coef, *_ = np.linalg.lstsq(regressors / scale, target, rcond=None)
    resid = target - (regressors / scale) @ coef
    return float(np.clip(1.0 - np.sum(np.abs(resid) ** 2) / total, 0.0, 1.0))


def regressor_conditioning(data: FrequencyData) -> RegressorConditioning | None:
    """Conditioning of the basis columns of ``data`` (None without basis functions).

    Parameters
    ----------
    data : FrequencyData
        ``E`` (F, m + s): forces then basis columns; ``Y`` (F, p) the outputs.

    Returns
    -------
    RegressorConditioning or None
    """
    m = int(data.n_inputs)
    E = np.asarray(data.E)
    s = E.shape[1] - m
    if s <= 0:
        return None
    names = tuple(data.extended_input_names[m:])
    norms = np.linalg.norm(E, axis=0)
    En = E / np.where(norms > 0, norms, 1.0)
    sv = np.linalg.svd(En, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    others = [np.delete(E, m + a, axis=1) for a in range(s)]
    # a column that the others explain exactly (the same element twice) has an infinite
    # inflation: its coefficient is not identifiable, which the verdicts then say
    left = np.array([1.0 - _r_squared(E[:, m + a], others[a]) for a in range(s)])
    with np.errstate(divide="ignore"):
        vif = np.where(left > 0, 1.0 / np.maximum(left, np.finfo(float).tiny), np.inf)
    return RegressorConditioning(names=names, condition_number=cond, inflation=vif)
