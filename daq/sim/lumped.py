"""Built-in small lumped models (SI units: m, N, kg, s) for tests and ``lumped.yaml``.

A chain of masses ``m_i`` with springs ``k_i`` between ``i-1`` and ``i`` (``i = 0``:
ground), a free last mass, Rayleigh damping plus one dashpot between DOFs 1
and 2 (non-proportional), force at the last DOF, every DOF measured (``X1``...).

Nonlinear variants
------------------
``cubic``     relative cubic spring ``k3 (q_1 - q_2)^3`` between DOFs 1 and 2 (1-based
              names X2 and X3 for a 3-DOF chain: two non-grounded DOFs);
``trilinear`` relative two-sided stop between the same DOFs (clearances, contact stiffness);
``duffing``   grounded cubic spring ``k3 q_0^3`` on the first DOF;
``none``      linear.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from fnsi_lab.daq.sim.model import StructuralModel
from fnsi_lab.daq.sim.nonlinear import NonlinearElement
from fnsi_lab.errors import ConfigError

LumpedVariant = Literal["cubic", "trilinear", "duffing", "none"]

#: Defaults: 3 masses of 1 kg, springs 2e4, 1e4, 1e4 N/m (modes near 10, 27, 38 Hz).
DEFAULT_MASSES = (1.0, 1.0, 1.0)
DEFAULT_SPRINGS = (2.0e4, 1.0e4, 1.0e4)


def lumped_model(variant: LumpedVariant = "cubic", *, masses=DEFAULT_MASSES,
                 springs=DEFAULT_SPRINGS, mass_damping: float = 3.0,
                 stiffness_damping: float = 2e-4,
                 dashpot: float = 5.0, dashpot_dofs: tuple[int, int] = (0, 1),
                 k3: float = 1.0e9,
                 clearances: tuple[float, float] = (4e-4, 5e-4),
                 contact: tuple[float, float] = (2.0e4, 1.5e4),
                 force_dof: int | None = None) -> StructuralModel:
    """A grounded chain with one localized nonlinearity.

    Parameters
    ----------
    variant : {'cubic', 'trilinear', 'duffing', 'none'}
    masses : sequence of float, length n_dof >= 2
        kg.
    springs : sequence of float, length n_dof
        N/m; ``springs[0]`` ties DOF 0 to the ground, ``springs[i]`` DOFs i-1 and i.
    mass_damping, stiffness_damping : float
        alpha (1/s) and beta (s) of ``C = alpha M + beta K`` (+ the dashpot).
    dashpot : float
        Extra dashpot between ``dashpot_dofs`` (N s/m); makes damping non-proportional.
    dashpot_dofs : (int, int)
        The two DOFs of the dashpot (default 0 and 1).
    k3 : float
        Cubic coefficient (N/m^3) of the ``cubic`` and ``duffing`` variants.
    clearances : (float, float)
        (g_neg, g_pos) of the ``trilinear`` stop, m.
    contact : (float, float)
        (k_neg, k_pos) contact stiffnesses, N/m.
    force_dof : int, optional
        DOF of the force (default the last).

    Returns
    -------
    StructuralModel
        DOFs ``X1..Xn``; the relative elements act between ``X2`` and ``X3`` (DOFs 1, 2)
        with weights +1, -1.
    """
    m = np.asarray(masses, dtype=float)
    k = np.asarray(springs, dtype=float)
    n = m.size
    if n < 2 or k.size != n:
        raise ConfigError(f"need >= 2 masses and as many springs, got {m.size} and {k.size}",
                          field="source.options.lumped")
    if variant not in ("cubic", "trilinear", "duffing", "none"):
        raise ConfigError(f"unknown lumped variant {variant!r}", field="source.options.variant",
                          fix="use one of ['cubic', 'trilinear', 'duffing', 'none']")
    kk = np.zeros((n, n))
    kk[0, 0] += k[0]
    for i in range(1, n):
        kk[i - 1, i - 1] += k[i]
        kk[i, i] += k[i]
        kk[i - 1, i] -= k[i]
        kk[i, i - 1] -= k[i]
    cc = mass_damping * np.diag(m) + stiffness_damping * kk
    i, j = (int(d) for d in dashpot_dofs)
    cc[i, i] += dashpot
    cc[j, j] += dashpot
    cc[i, j] -= dashpot
    cc[j, i] -= dashpot
    names = tuple(f"X{i + 1}" for i in range(n))
    fdof = n - 1 if force_dof is None else int(force_dof)
    t = np.zeros((n, 1))
    t[fdof, 0] = 1.0
    a, b = (1, 2) if n >= 3 else (0, 1)
    rel = np.zeros(n)
    rel[a], rel[b] = 1.0, -1.0
    elements: tuple[NonlinearElement, ...] = ()
    if variant == "cubic":
        elements = (NonlinearElement(f"{names[a]}-{names[b]}-cubic", "polynomial", rel,
                                     {"k": k3}, exponent=3),)
    elif variant == "trilinear":
        elements = (NonlinearElement(f"{names[a]}-{names[b]}-stop", "trilinear", rel,
                                     {"neg": contact[0], "pos": contact[1]},
                                     clearances=tuple(clearances)),)
    elif variant == "duffing":
        g = np.zeros(n)
        g[0] = 1.0
        elements = (NonlinearElement(f"{names[0]}-duffing", "polynomial", g, {"k": k3},
                                     exponent=3),)
    return StructuralModel(
        mass=np.diag(m), damping=cc, stiffness=kk, dof_names=names, force_matrix=t,
        input_names=(f"F-{names[fdof]}",), measured={nm: i for i, nm in enumerate(names)},
        nonlinearities=elements, units={"length": "m", "force": "N", "time": "s", "mass": "kg"},
        name=f"lumped{n}-{variant}", node_direction={nm: (nm, "X") for nm in names},
        description=f"{n}-DOF grounded chain, {variant} nonlinearity")
