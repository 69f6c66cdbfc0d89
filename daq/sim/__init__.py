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
    "StructuralModel": "fnsi_lab.daq.sim.model",
    "NonlinearElement": "fnsi_lab.daq.sim.nonlinear",
    "simulate": "fnsi_lab.daq.sim.integrate",
    "SimulationResult": "fnsi_lab.daq.sim.integrate",
    "lumped_model": "fnsi_lab.daq.sim.lumped",
    "smallsat_model": "fnsi_lab.daq.sim.smallsat",
    "SimulatedSource": "fnsi_lab.daq.sim.source",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'fnsi_lab.daq.sim' has no attribute {name!r}")
