"""The record of an output-error refinement (:func:`ident.refine.output_error.refine_output_error`):
the refined model and basis, the refined basis parameters with their standard deviations, and
the JSON summary the result writes (``output_error`` of the answer; docs/ident.md, "The
output-error refinement").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.fnsi import StateSpaceModel

__all__ = ["RefinedParameter", "OutputErrorFit"]


@dataclass(frozen=True)
class RefinedParameter:
    """A basis parameter refined with the model.

    Attributes
    ----------
    element : int
        Index of the element in the basis.
    name : str
        Element name.
    parameter : str
        ``g_neg``, ``g_pos``, ``clearance``, ``offset`` or ``exponent``.
    start : float
        The value the refinement started from (the search's estimate).
    value, std : float
        Refined value and its standard deviation (``s^2 (J^T J)^-1``, the other
        parameters free).
    """

    element: int
    name: str
    parameter: str
    start: float
    value: float
    std: float

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "parameter": self.parameter, "start": self.start,
                "value": self.value, "std": self.std}


@dataclass
class OutputErrorFit:
    """Outcome of :func:`refine_output_error`.

    Attributes
    ----------
    model : StateSpaceModel
        The refined model (same order, time base and names as the start).
    basis : tuple of Nonlinearity
        The basis with the refined parameters.
    parameters : list of RefinedParameter
    misfit_start, misfit : float
        ``V / (F p)`` of the starting model (its own steady state) and of the refined one:
        about 1 when the model explains the outputs to their noise.
    iterations : int
        Levenberg-Marquardt steps taken.
    converged : bool
        The relative decrease of ``V`` fell below the tolerance.
    balance_iterations : int
        Harmonic-balance iterations in all.
    background_lines : int or None
        Lines out of the processed band whose measured motion was kept (None: no noise
        estimate to judge them by, all kept).
    weighted : bool
        Residuals weighted by ``1 / sigma`` (else by each output's RMS over the lines).
    frequency_map : list of (float, float or None)
        ``(start, refined)`` natural frequency (Hz) of every pole of the start model; None
        for a dropped one.
    dropped_hz : list of float
        Start frequencies (Hz) of the modes the fit dropped: they wandered by more than
        :data:`MAX_POLE_SHIFT` bandwidths, i.e. the output error does not determine them.
    below_band : str
        How the motion under the processed band entered: ``predicted`` by the model, or
        ``measured`` (and why).
    below_band_misfit : float or None
        Where predicted: the mean ``|measured - predicted|^2`` over the noise variance there
        (about 1 when the model holds the structure under the band).
    timings_s : dict
    weighted_residual : complex ndarray, shape (n_lines, n_outputs), or None
        The refined model's residual on the data's lines, weighted as in ``V``.
    excitation : complex ndarray, shape (n_lines, n_inputs + n_basis), or None
        The inputs and the refined steady state's basis functions on the data's lines (what
        each mode's input vector multiplies); with ``weighted_residual`` it is what
        :func:`omitted_mode_evidence` reads.
    residual_weights : ndarray, shape (n_lines, n_outputs), or None
        The weights of ``weighted_residual`` (``1 / sigma`` of each line and output).
    """

    model: StateSpaceModel
    basis: tuple[Nonlinearity, ...]
    parameters: list = field(default_factory=list)
    misfit_start: float = float("nan")
    misfit: float = float("nan")
    iterations: int = 0
    converged: bool = False
    balance_iterations: int = 0
    background_lines: int | None = None
    weighted: bool = True
    frequency_map: list = field(default_factory=list)
    dropped_hz: list = field(default_factory=list)
    below_band: str = "measured"
    below_band_misfit: float | None = None
    timings_s: dict = field(default_factory=dict)
    weighted_residual: np.ndarray | None = field(default=None, repr=False)
    excitation: np.ndarray | None = field(default=None, repr=False)
    residual_weights: np.ndarray | None = field(default=None, repr=False)

    def refined_frequency(self, start_hz: float) -> float | None:
        """The refined natural frequency of the start model's pole at ``start_hz`` (None if
        the fit dropped it)."""
        best = min(self.frequency_map, key=lambda fr: abs(fr[0] - start_hz), default=None)
        return start_hz if best is None else best[1]

    def parameter_std(self, element: str, parameter: str) -> float | None:
        """Standard deviation of a refined basis parameter (None if it was not refined)."""
        for p in self.parameters:
            if p.name == element and p.parameter == parameter:
                return p.std
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (the timings go to the result's ``timings_s``)."""
        return {"misfit_start": self.misfit_start, "misfit": self.misfit,
                "weighted": self.weighted,
                "iterations": self.iterations, "converged": self.converged,
                "dropped_modes_hz": list(self.dropped_hz),
                "below_band": self.below_band, "below_band_misfit": self.below_band_misfit,
                "balance_iterations": self.balance_iterations,
                "background_lines": self.background_lines,
                "parameters": [p.to_dict() for p in self.parameters]}
