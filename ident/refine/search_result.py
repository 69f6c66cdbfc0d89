"""The records of a basis-parameter search (:mod:`ident.refine.parameter_search`): each
estimate with its evidence, the search's outcome and their JSON summaries
(``parameter_search`` of the answer).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.refine.search_space import Unknown

__all__ = ["ParameterEstimate", "ParameterSearchResult"]


@dataclass
class ParameterEstimate:
    """The estimate of one parameter and the evidence for it.

    Attributes
    ----------
    unknown : Unknown
    value : float
    std : float
        Standard deviation (NaN for discrete candidates).
    profile_values : ndarray, shape (n_points,)
        Parameter values of the objective profile (sorted): the coarse scan of the interval
        (the other parameters at their values at that stage) and a local scan around the
        estimate (the other parameters at their estimates).
    profile_objective : ndarray, shape (n_points,)
        Relative model error ``V`` at each (or what ``objective_name`` says).
    margin : float
        ``(V_other - V_best) / s^2`` in chi-square units (``s^2`` the residual variance per
        degree of freedom at the estimate): ``V_other`` is the runner-up candidate (discrete)
        or the better end of the coarse scan (continuous).
    motion_noise_std : float or None
        Clearances: standard deviation of the noise left in the averaged ``L^T q`` per
        sample (from the period-to-period spread); None without a noise estimate.
    noise_corrected : bool
        The objective had the motion noise's expected share removed
        (:class:`ident.refine.motion_noise.MotionNoise`); ``profile_objective`` is then that
        corrected, noise-weighted model error.
    roughness : float
        Continuous parameters: how far the local profile (``profile_offsets`` around the
        estimate) departs from the curvature the standard deviation comes from, as the
        largest factor between the chi-square rise it shows and the rise
        ``(offset / std)^2`` the curvature predicts (1: a smooth quadratic minimum; NaN
        without local points).
    objective_name : str
        What ``profile_objective`` holds (``slip: auto``: the information criterion,
        :mod:`ident.refine.slip_search`).
    """

    unknown: Unknown
    value: float
    std: float
    profile_values: np.ndarray
    profile_objective: np.ndarray
    margin: float = float("nan")
    motion_noise_std: float | None = None
    noise_corrected: bool = False
    roughness: float = float("nan")
    objective_name: str = "relative model error"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record."""
        u = self.unknown
        return {"name": u.name, "parameter": u.parameter, "value": self.value, "std": self.std,
                "interval": None if u.interval is None else list(u.interval),
                "candidates": None if u.candidates is None else list(u.candidates),
                "reach": u.reach, "margin": self.margin, "motion_noise_std": self.motion_noise_std,
                "noise_corrected": self.noise_corrected, "roughness": self.roughness,
                "profile": {"values": self.profile_values, "objective": self.profile_objective,
                            "quantity": self.objective_name}}


@dataclass
class ParameterSearchResult:
    """Outcome of :func:`ident.refine.parameter_search.estimate_basis_parameters`.

    Attributes
    ----------
    basis : tuple of Nonlinearity
        The basis with every parameter filled in.
    estimates : list of ParameterEstimate
    objective : float
        ``V`` at the estimate (final state matrices).
    order : int
        Model order of the search.
    n_evaluations : int
        Objective evaluations (one QR + SVD and one B, D least squares each).
    block_rows : int
        ``i`` of the search's decompositions.
    timings_s : dict
    warnings : list of str
        What the engineer must read about the estimates (noise in the motion).
    noise_misfit : float
        With the noise correction: the noise-weighted squared residual at the estimate over
        the noise-weighted output noise variance (about 1 when the model explains the data
        to the noise; NaN otherwise).
    motion_noise_warnings : list of str
        The ``warnings`` about what the measured motion's noise does to the estimates (an
        output-error refinement that reads no measured motion makes them moot).
    alternatives : list of dict
        ``slip: auto`` of one element: the criterion's other local minima inside the
        interval that beat the model without the element, best first (``value``,
        ``objective``, ``order``, ``slipping_percent``, ``objective_without_element``;
        :func:`ident.refine.slip_search.estimate_slips`). The identification tries the first
        when the estimate leaves the element's coefficient undetermined
        (docs/ident.md, "A second candidate").
    """

    basis: tuple[Nonlinearity, ...]
    estimates: list[ParameterEstimate]
    objective: float
    order: int
    n_evaluations: int
    block_rows: int = 0
    timings_s: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    noise_misfit: float = float("nan")
    motion_noise_warnings: list = field(default_factory=list)
    alternatives: list = field(default_factory=list)

    def taking_alternative(self, note: str) -> "ParameterSearchResult":
        """This search with its first alternative as the estimate (one slip searched), the
        estimate it replaces among the alternatives, and ``note`` among the warnings."""
        (estimate,) = self.estimates
        first, *rest = self.alternatives
        u = estimate.unknown
        value = float(first["value"])
        basis = tuple(nl.with_parameters({u.parameter: value}) if i == u.element else nl
                      for i, nl in enumerate(self.basis))
        replaced = {"value": estimate.value, "objective": self.objective, "order": self.order,
                    "slipping_percent": None,
                    "objective_without_element": first.get("objective_without_element")}
        return replace(self, basis=basis, estimates=[replace(estimate, value=value)],
                       objective=float(first["objective"]), order=int(first["order"]),
                       warnings=[*self.warnings, note], alternatives=[replaced, *rest])

    def for_element(self, name: str) -> list[ParameterEstimate]:
        """Estimates of the element ``name``."""
        return [e for e in self.estimates if e.unknown.name == name]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (profiles included)."""
        return {"order": self.order, "objective": self.objective,
                "n_evaluations": self.n_evaluations, "block_rows": self.block_rows,
                "estimates": [e.to_dict() for e in self.estimates], "timings_s": self.timings_s,
                "warnings": list(self.warnings), "noise_misfit": self.noise_misfit,
                "alternatives": [dict(a) for a in self.alternatives]}
