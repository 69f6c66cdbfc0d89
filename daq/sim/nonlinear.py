"""Localized nonlinear elements and their basis functions.

Convention (``docs/fnsi.md`` §1.1, shared with ``ident``): the equation of motion is

    M q'' + C q' + K q + sum_a c_a h_a(delta_a, delta_a') L_a = T p(t),

with ``delta_a = L_a^T q`` and ``delta_a' = L_a^T q'`` the *relative* displacement and
velocity of the element, ``L_a`` its signed weight vector over the DOFs (+1 at DOF j and -1
at DOF k for an element between j and k; +1 alone for an element to ground) and ``c_a`` the
physical coefficient. The element force on the structure is ``c_a h_a L_a`` on the left-hand
side (a positive ``c_a h_a`` pushes DOF j in the negative direction, like a spring).

One element may carry several basis functions (a trilinear stop has two). Each basis
function has its own coefficient, named by a key of :attr:`NonlinearElement.coefficients`.

Basis functions (``x = delta`` for displacement-type elements, ``v = delta'``)
-----------------------------------------------------------------------------
``polynomial``  (``coefficients = {"k": c}``, ``exponent = p``, ``signed``)
    ``signed = False``: ``h(x) = x**p`` (``p`` must be a whole number);
    ``signed = True``:  ``h(x) = |x|**(p - 1) * x`` (any real ``p > 0``; odd restoring
    force, e.g. ``p = 2`` gives ``|x| x``). With ``argument = "velocity"`` the same law is
    applied to ``v`` instead of ``x``.
``trilinear``   (``coefficients = {"neg": k_neg, "pos": k_pos}``,
    ``clearances = (g_neg, g_pos)``, both >= 0)
    ``h_neg(x) = x + g_neg  if x < -g_neg else 0``,
    ``h_pos(x) = x - g_pos  if x >  g_pos else 0``;
    restoring force ``k_neg h_neg(x) + k_pos h_pos(x)`` (contact stiffness added to the
    linear part once a stop is closed; the linear part itself lives in ``K``).
``bilinear``    one stop: ``coefficients = {"pos": k}`` with ``clearances = (g,)`` uses
    ``h_pos(x) = x - g if x > g else 0``; ``coefficients = {"neg": k}`` uses
    ``h_neg(x) = x + g if x < -g else 0``.
``quadratic_damping``  (``coefficients = {"c": c}``)
    ``h(v) = |v| v``.
``coulomb``  (``coefficients = {"f": F_c}``, ``regularization = v0`` > 0)
    ``h(v) = tanh(v / v0)`` (dry friction of level F_c, smoothed below ``|v| ~ v0``).

Units: ``x`` and ``v`` are in the model's length unit (and length/s); coefficients are
force / length for stops, force / length**p for polynomials, force / (length/s)**2 for
quadratic damping, force for Coulomb.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

import numpy as np

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError

ElementKind = Literal["polynomial", "trilinear", "bilinear", "quadratic_damping", "coulomb"]
ELEMENT_KINDS: tuple[str, ...] = ("polynomial", "trilinear", "bilinear", "quadratic_damping",
                                  "coulomb")

# Integer codes of the basis functions in the compiled kernel (see integrate._eval_forces).
BASIS_POLY = 0        # x**p, or |x|**(p-1) x when signed
BASIS_NEG = 1         # x + g if x < -g
BASIS_POS = 2         # x - g if x > g
BASIS_QUADDAMP = 3    # |v| v
BASIS_COULOMB = 4     # tanh(v / v0)


@dataclass(frozen=True)
class NonlinearElement:
    """One localized nonlinear element (see the module docstring for the basis functions).

    Attributes
    ----------
    name : str
        Unique name, e.g. ``NC2-Z``.
    kind : {'polynomial', 'trilinear', 'bilinear', 'quadratic_damping', 'coulomb'}
    weights : ndarray, shape (n_dof,)
        Signed location vector L_a (``delta = weights @ q``).
    coefficients : mapping str -> float
        ``{"k"}`` polynomial, ``{"neg", "pos"}`` trilinear, ``{"neg"}`` or ``{"pos"}``
        bilinear, ``{"c"}`` quadratic damping, ``{"f"}`` Coulomb.
    clearances : tuple of float
        ``(g_neg, g_pos)`` trilinear, ``(g,)`` bilinear, ``()`` otherwise (length unit).
    exponent : float
        Polynomial exponent p.
    signed : bool
        Polynomial form ``|x|**(p-1) x`` instead of ``x**p``.
    argument : {'displacement', 'velocity'}
        What the polynomial acts on (stops act on displacement, dampers on velocity).
    regularization : float
        Coulomb smoothing velocity v0 (length/s).
    """

    name: str
    kind: ElementKind
    weights: np.ndarray
    coefficients: Mapping[str, float]
    clearances: tuple[float, ...] = ()
    exponent: float = 3.0
    signed: bool = False
    argument: Literal["displacement", "velocity"] = "displacement"
    regularization: float = 1e-3

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=float).reshape(-1)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "coefficients", {k: float(v) for k, v in self.coefficients.items()})
        object.__setattr__(self, "clearances", tuple(float(g) for g in self.clearances))
        where = f"nonlinearities.{self.name}"
        if self.kind not in ELEMENT_KINDS:
            raise ConfigError(f"unknown nonlinear element kind {self.kind!r}", field=where,
                              fix=f"use one of {plain.names(ELEMENT_KINDS)}")
        if not np.any(w):
            raise ConfigError("weights are all zero", field=where,
                              fix="give +1/-1 weights on the DOFs the element connects")
        expected = {"polynomial": [{"k"}], "trilinear": [{"neg", "pos"}],
                    "bilinear": [{"neg"}, {"pos"}], "quadratic_damping": [{"c"}],
                    "coulomb": [{"f"}]}[self.kind]
        if set(self.coefficients) not in expected:
            raise ConfigError(f"{self.kind} element needs coefficients "
                              f"{' or '.join(plain.names(sorted(e)) for e in expected)}, got "
                              f"{plain.names(sorted(self.coefficients))}", field=where)
        n_gaps = {"trilinear": 2, "bilinear": 1}.get(self.kind, 0)
        if len(self.clearances) != n_gaps:
            raise ConfigError(f"{self.kind} element needs {n_gaps} clearance(s), got "
                              f"{len(self.clearances)}", field=where)
        if any(g < 0 for g in self.clearances):
            raise ConfigError("clearances must be >= 0", field=where)
        if self.kind == "polynomial":
            if not self.exponent > 0:
                raise ConfigError("exponent must be > 0", field=where)
            if not self.signed and float(self.exponent) != round(self.exponent):
                raise ConfigError(f"exponent {self.exponent} is not whole", field=where,
                                  fix="use signed: true for |x|**(p-1) x with a real p")
        if self.kind == "coulomb" and not self.regularization > 0:
            raise ConfigError("regularization must be > 0", field=where)
        if self.argument not in ("displacement", "velocity"):
            raise ConfigError(f"argument {self.argument!r} not allowed", field=where,
                              fix="use 'displacement' or 'velocity'")

    # ------------------------------------------------------------------ basis
    @property
    def uses_velocity(self) -> bool:
        """True if the element depends on the relative velocity."""
        return self.kind in ("quadratic_damping", "coulomb") or (
            self.kind == "polynomial" and self.argument == "velocity")

    @property
    def basis_names(self) -> list[str]:
        """Coefficient keys in basis order (``["neg", "pos"]`` for a trilinear stop)."""
        return {"trilinear": ["neg", "pos"]}.get(self.kind, list(self.coefficients))

    def basis(self, delta: np.ndarray, delta_dot: np.ndarray | None = None) -> np.ndarray:
        """Evaluate the basis functions (reference implementation, plain numpy).

        Parameters
        ----------
        delta : ndarray, shape (n,)
            Relative displacement ``L^T q`` (length unit).
        delta_dot : ndarray, shape (n,), optional
            Relative velocity ``L^T q'`` (needed by velocity elements).

        Returns
        -------
        ndarray, shape (n, n_basis)
            Columns in :attr:`basis_names` order.
        """
        x = np.asarray(delta, dtype=float)
        if self.uses_velocity:
            if delta_dot is None:
                raise ConfigError(f"element {self.name} needs the relative velocity")
            x = np.asarray(delta_dot, dtype=float)
        cols = []
        for key in self.basis_names:
            code, gap = self._codes()[self.basis_names.index(key)]
            cols.append(_basis_numpy(code, x, gap, self.exponent, self.signed,
                                     self.regularization))
        return np.stack(cols, axis=-1)

    def force(self, delta: np.ndarray, delta_dot: np.ndarray | None = None) -> np.ndarray:
        """Scalar element force ``sum_j c_j h_j`` along L, shape (n,)."""
        c = np.array([self.coefficients[k] for k in self.basis_names])
        return self.basis(delta, delta_dot) @ c

    def _codes(self) -> list[tuple[int, float]]:
        """(basis code, clearance) per basis function, for the kernel."""
        if self.kind == "polynomial":
            return [(BASIS_POLY, 0.0)]
        if self.kind == "trilinear":
            return [(BASIS_NEG, self.clearances[0]), (BASIS_POS, self.clearances[1])]
        if self.kind == "bilinear":
            return [(BASIS_NEG if "neg" in self.coefficients else BASIS_POS, self.clearances[0])]
        if self.kind == "quadratic_damping":
            return [(BASIS_QUADDAMP, 0.0)]
        return [(BASIS_COULOMB, 0.0)]

    def stop_names(self) -> list[str]:
        """Names of the stops (``NC2-Z.neg``...) for contact statistics; [] if none."""
        if self.kind in ("trilinear", "bilinear"):
            return [f"{self.name}.{k}" for k in self.basis_names]
        return []

    def to_truth(self, dof_names: list[str] | tuple[str, ...]) -> dict[str, Any]:
        """JSON-able description with weights by DOF name."""
        out: dict[str, Any] = {
            "name": self.name, "kind": self.kind,
            "dofs": {dof_names[i]: float(w) for i, w in enumerate(self.weights) if w != 0},
            "clearances": list(self.clearances),
            "coefficients": dict(self.coefficients),
        }
        if self.kind == "polynomial":
            out.update(exponent=self.exponent, signed=self.signed, argument=self.argument)
        if self.kind == "coulomb":
            out["regularization"] = self.regularization
        return out


def _basis_numpy(code: int, x: np.ndarray, gap: float, p: float, signed: bool,
                 v0: float) -> np.ndarray:
    if code == BASIS_POLY:
        return np.abs(x) ** (p - 1.0) * x if signed else x ** int(round(p))
    if code == BASIS_NEG:
        return np.where(x < -gap, x + gap, 0.0)
    if code == BASIS_POS:
        return np.where(x > gap, x - gap, 0.0)
    if code == BASIS_QUADDAMP:
        return np.abs(x) * x
    return np.tanh(x / v0)


@dataclass(frozen=True)
class ElementTables:
    """Flat arrays describing every basis function, for the compiled kernel.

    Attributes
    ----------
    element : int ndarray, shape (n_basis,)
        Element index of each basis function.
    code : int ndarray, shape (n_basis,)
        ``BASIS_*`` code.
    coef, gap, exponent, v0 : float ndarray, shape (n_basis,)
    signed : int ndarray, shape (n_basis,)
    velocity : int ndarray, shape (n_basis,)
        1 if the basis acts on the relative velocity.
    names : list of str
        ``element.key`` per basis function.
    """

    element: np.ndarray
    code: np.ndarray
    coef: np.ndarray
    gap: np.ndarray
    exponent: np.ndarray
    signed: np.ndarray
    velocity: np.ndarray
    v0: np.ndarray
    names: list[str] = field(default_factory=list)


def element_tables(elements: tuple[NonlinearElement, ...]) -> ElementTables:
    """Flatten elements into :class:`ElementTables`."""
    rows: list[tuple] = []
    names = []
    for a, el in enumerate(elements):
        for key, (code, gap) in zip(el.basis_names, el._codes()):
            rows.append((a, code, el.coefficients[key], gap, el.exponent, int(el.signed),
                         int(el.uses_velocity), el.regularization))
            names.append(f"{el.name}.{key}")
    if not rows:
        rows = []
    cols = list(zip(*rows)) if rows else [()] * 8
    return ElementTables(
        element=np.array(cols[0], dtype=np.int64), code=np.array(cols[1], dtype=np.int64),
        coef=np.array(cols[2], dtype=float), gap=np.array(cols[3], dtype=float),
        exponent=np.array(cols[4], dtype=float), signed=np.array(cols[5], dtype=np.int64),
        velocity=np.array(cols[6], dtype=np.int64), v0=np.array(cols[7], dtype=float),
        names=names)
