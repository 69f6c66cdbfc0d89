"""Structural models: M, C, K, force locations, measured DOFs, localized nonlinearities.

Pure numpy/scipy. Everything is in the model's own unit system (:attr:`StructuralModel.units`);
the SmallSat uses mm, N and s, hence mass in tonnes (1 t = 1 N s^2/mm).

The linear part is analysed once into complex modes of the first-order form
``x' = A x + B u``, ``x = [q; q']`` (:func:`modal_decomposition`), which the integrator
propagates exactly and which gives the exact linear FRF (:func:`linear_frf`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Mapping

import numpy as np
import scipy.linalg as sla

from fnsi_lab import plain
from fnsi_lab.daq.sim.nonlinear import NonlinearElement
from fnsi_lab.errors import ConfigError

QUANTITY_ORDER = {"displacement": 0, "velocity": 1, "acceleration": 2}


@dataclass(frozen=True)
class Modes:
    """Complex modes of the first-order form (all 2 n_dof eigenvalues, conjugates included).

    Attributes
    ----------
    eigenvalues : complex ndarray, shape (2 n_dof,)
        lambda_m (rad/s), sorted by |Im|, then conjugate pairs adjacent.
    vectors : complex ndarray, shape (2 n_dof, 2 n_dof)
        V, columns are state eigenvectors ``[phi; lambda phi]``.
    inverse : complex ndarray, shape (2 n_dof, 2 n_dof)
        V^-1.
    frequency_hz, damping_ratio : ndarray, shape (n_modes,)
        Of the oscillating modes (one per conjugate pair, Im lambda > 0), ascending
        frequency; ``frequency_hz = |lambda| / 2 pi``, ``damping_ratio = -Re lambda / |lambda|``.
    """

    eigenvalues: np.ndarray
    vectors: np.ndarray
    inverse: np.ndarray
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray


@dataclass(frozen=True, eq=False)
class StructuralModel:
    """A linear structure with localized nonlinear elements (fnsi.md §1.1 convention).

    ``M q'' + C q' + K q + sum_a c_a h_a(L_a^T q, L_a^T q') L_a = T p(t)``

    Attributes
    ----------
    mass, damping, stiffness : ndarray, shape (n_dof, n_dof)
        Symmetric M (positive definite), C, K (the linear part of every connection,
        elastomers included).
    dof_names : tuple of str, length n_dof
    force_matrix : ndarray, shape (n_dof, n_inputs)
        T, maps the input forces p to DOF forces.
    input_names : tuple of str, length n_inputs
        Force channel names (``F-NC2W-Z``).
    measured : mapping channel name -> dof index
        Measured DOFs in channel order.
    nonlinearities : tuple of NonlinearElement
    units : mapping
        ``{"length": "mm", "force": "N", "time": "s", "mass": "t"}``.
    name : str
    node_direction : mapping dof name -> (node, direction), optional
        For channel metadata.
    description : str
        One line for ``describe()``.
    """

    mass: np.ndarray
    damping: np.ndarray
    stiffness: np.ndarray
    dof_names: tuple[str, ...]
    force_matrix: np.ndarray
    input_names: tuple[str, ...]
    measured: Mapping[str, int]
    nonlinearities: tuple[NonlinearElement, ...] = ()
    units: Mapping[str, str] = field(default_factory=lambda: {"length": "m", "force": "N",
                                                              "time": "s", "mass": "kg"})
    name: str = "model"
    node_direction: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        m, c, k = (np.asarray(a, dtype=float) for a in (self.mass, self.damping, self.stiffness))
        n = m.shape[0]
        for nm, a in (("mass", m), ("damping", c), ("stiffness", k)):
            if a.shape != (n, n):
                raise ConfigError(f"{nm} matrix is {plain.shape(a.shape)}, expected {n} x {n}",
                                  field=f"model.{nm}")
            if not np.allclose(a, a.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(a).max())):
                raise ConfigError(f"{nm} matrix is not symmetric", field=f"model.{nm}",
                                  fix="reciprocity needs symmetric M, C, K")
        try:
            np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            raise ConfigError("mass matrix is not positive definite", field="model.mass") from None
        t = np.asarray(self.force_matrix, dtype=float)
        if t.ndim == 1:
            t = t[:, None]
        if t.shape[0] != n:
            raise ConfigError(f"force matrix has {t.shape[0]} rows, expected {n}",
                              field="model.force")
        if len(self.dof_names) != n:
            raise ConfigError(f"{len(self.dof_names)} dof names for {n} DOFs", field="model.dofs")
        if len(self.input_names) != t.shape[1]:
            raise ConfigError(f"{len(self.input_names)} input names for {t.shape[1]} inputs",
                              field="model.force")
        for ch, i in self.measured.items():
            if not 0 <= int(i) < n:
                raise ConfigError(f"measured channel {ch!r} points at DOF {i}, outside 0..{n - 1}",
                                  field="model.measured")
        for el in self.nonlinearities:
            if el.weights.shape != (n,):
                raise ConfigError(f"element {el.name} has {el.weights.size} weights, expected {n}",
                                  field=f"nonlinearities.{el.name}")
        object.__setattr__(self, "mass", (m + m.T) / 2)
        object.__setattr__(self, "damping", (c + c.T) / 2)
        object.__setattr__(self, "stiffness", (k + k.T) / 2)
        object.__setattr__(self, "force_matrix", t)
        object.__setattr__(self, "dof_names", tuple(self.dof_names))
        object.__setattr__(self, "input_names", tuple(self.input_names))
        object.__setattr__(self, "measured", {str(k_): int(v) for k_, v in self.measured.items()})
        object.__setattr__(self, "nonlinearities", tuple(self.nonlinearities))

    # ------------------------------------------------------------------ sizes
    @property
    def n_dof(self) -> int:
        """Number of DOFs."""
        return int(self.mass.shape[0])

    @property
    def n_inputs(self) -> int:
        """Number of input forces."""
        return int(self.force_matrix.shape[1])

    @property
    def measured_names(self) -> list[str]:
        """Measured channel names, in order."""
        return list(self.measured)

    @property
    def measured_dofs(self) -> np.ndarray:
        """DOF index of each measured channel, shape (n_measured,)."""
        return np.array(list(self.measured.values()), dtype=np.int64)

    @property
    def weights(self) -> np.ndarray:
        """L = [L_1 ... L_s], shape (n_dof, n_elements)."""
        if not self.nonlinearities:
            return np.zeros((self.n_dof, 0))
        return np.stack([el.weights for el in self.nonlinearities], axis=1)

    def linear(self) -> "StructuralModel":
        """The same structure without its nonlinear elements."""
        return StructuralModel(self.mass, self.damping, self.stiffness, self.dof_names,
                               self.force_matrix, self.input_names, self.measured, (),
                               self.units, self.name + "-linear", self.node_direction,
                               self.description)

    # ------------------------------------------------------------------ linear analysis
    @cached_property
    def state_matrix(self) -> np.ndarray:
        """A = [[0, I], [-M^-1 K, -M^-1 C]], shape (2 n_dof, 2 n_dof), 1/s units."""
        n = self.n_dof
        minv_k = np.linalg.solve(self.mass, self.stiffness)
        minv_c = np.linalg.solve(self.mass, self.damping)
        return np.block([[np.zeros((n, n)), np.eye(n)], [-minv_k, -minv_c]])

    @cached_property
    def modes(self) -> Modes:
        """Complex modes (computed once per model)."""
        return modal_decomposition(self)

    def frf(self, frequency_hz: np.ndarray, quantity: str = "displacement",
            dofs: np.ndarray | None = None) -> np.ndarray:
        """Exact linear FRF from the input forces (nonlinear elements removed).

        Returns
        -------
        complex ndarray, shape (n_freq, n_out, n_inputs)
            ``(K - w^2 M + j w C)^-1 T`` times ``(j w)^d``, d = 0, 1, 2 for displacement,
            velocity, acceleration; rows are ``dofs`` (default: the measured DOFs).
        """
        return linear_frf(self, frequency_hz, quantity, dofs)

    def summary(self) -> dict[str, Any]:
        """JSON-able summary for ``describe()``."""
        return {"name": self.name, "description": self.description, "n_dof": self.n_dof,
                "dof_names": list(self.dof_names), "inputs": list(self.input_names),
                "measured": dict(self.measured), "units": dict(self.units),
                "nonlinearities": [el.to_truth(self.dof_names) for el in self.nonlinearities]}


def modal_decomposition(model: StructuralModel) -> Modes:
    """Eigen-decomposition of the first-order state matrix.

    Raises
    ------
    ConfigError
        If the linear model is not asymptotically stable (rigid-body or unstable modes):
        the periodic steady state, and thus the multisine experiment, needs a stable model.
    """
    a = model.state_matrix
    lam, v = sla.eig(a)
    if np.any(lam.real >= 0):
        raise ConfigError(f"linear model is not asymptotically stable (max Re lambda = "
                          f"{lam.real.max():.3g} 1/s)", field="model",
                          fix="ground the structure and give every mode some damping")
    order = np.lexsort((lam.imag, np.abs(lam.imag)))
    lam, v = lam[order], v[:, order]
    vinv = np.linalg.inv(v)
    osc = lam.imag > 1e-9 * np.abs(lam)
    wn = np.abs(lam[osc])
    return Modes(eigenvalues=lam, vectors=v, inverse=vinv,
                 frequency_hz=wn / (2 * np.pi), damping_ratio=-lam[osc].real / wn)


#: Lines per batch of :func:`linear_frf`.
_FRF_LINES = 256


def linear_frf(model: StructuralModel, frequency_hz: np.ndarray, quantity: str = "displacement",
               dofs: np.ndarray | None = None, inputs: np.ndarray | None = None) -> np.ndarray:
    """Exact FRF ``(j w)^d (K - w^2 M + j w C)^-1 T``, shape (n_freq, n_out, n_inputs).

    ``inputs`` replaces T (shape (n_dof, n_in)) when given, e.g. by the element weights.
    """
    f = np.atleast_1d(np.asarray(frequency_hz, dtype=float))
    w = 2 * np.pi * f
    t = model.force_matrix if inputs is None else np.asarray(inputs, dtype=float)
    rows = model.measured_dofs if dofs is None else np.asarray(dofs)
    tc = t.astype(complex)
    power = QUANTITY_ORDER[quantity]
    # a few lines at a time: the same numbers as one batched solve (each line is its own
    # LU), without n_lines x n_dof x n_dof complex temporaries (150 MB for the SmallSat's
    # 4097 lines: their page faults cost more than the solves)
    pieces = []
    for i in range(0, f.size, _FRF_LINES):
        wi = w[i:i + _FRF_LINES]
        dyn = (model.stiffness[None] - wi[:, None, None] ** 2 * model.mass[None]
               + 1j * wi[:, None, None] * model.damping[None])
        x = np.linalg.solve(dyn, np.broadcast_to(tc, (wi.size,) + t.shape))
        x = x * ((1j * wi) ** power)[:, None, None]
        pieces.append(x[:, rows, :])
    if not pieces:
        return np.zeros((0, model.n_dof, t.shape[1]), complex)[:, rows, :]
    return np.concatenate(pieces, axis=0)
