"""Simulated structures: models, integrator, built-in lumped chain and SmallSat, source.

Modules (one job each): :mod:`daq.sim.model` (``StructuralModel``, modes, exact FRF),
:mod:`daq.sim.nonlinear` (``NonlinearElement`` and its basis functions),
:mod:`daq.sim.integrate` (``simulate``), :mod:`daq.sim.lumped` (small chain),
:mod:`daq.sim.smallsat` (the seed paper's satellite), :mod:`daq.sim.source`
(``SimulatedSource``). Heavy modules (numba) are imported lazily.
"""

from __future__ import annotations

from typing import Any

__all__ = ["StructuralModel", "NonlinearElement", "simulate", "SimulationResult",
           "lumped_model", "smallsat_model", "SimulatedSource"]

_LAZY = {
    "StructuralModel": "daq.sim.model",
    "NonlinearElement": "daq.sim.nonlinear",
    "simulate": "daq.sim.integrate",
    "SimulationResult": "daq.sim.integrate",
    "lumped_model": "daq.sim.lumped",
    "smallsat_model": "daq.sim.smallsat",
    "SimulatedSource": "daq.sim.source",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'daq.sim' has no attribute {name!r}")
