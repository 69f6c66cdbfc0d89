"""Lazy registry of source adapters: a name maps to (module, class).

An adapter is imported only when it is asked for, so a missing optional driver (a CAN
vendor library, say) never breaks ``import daq``; the error then names the missing
package. Mirrors python-can's ``can/interfaces/__init__.py``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from fnsi_lab.daq.config import ExperimentConfig
    from fnsi_lab.daq.source import Source

#: source kind -> (module, class name)
SOURCES: dict[str, tuple[str, str]] = {
    "simulated": ("fnsi_lab.daq.sim.source", "SimulatedSource"),
    "smallsat": ("fnsi_lab.daq.sim.source", "SimulatedSource"),
    "aircraft": ("fnsi_lab.daq.sim.aircraft_source", "AircraftSource"),
    "can": ("fnsi_lab.daq.sources.can_source", "CanSource"),
    "serial": ("fnsi_lab.daq.sources.serial_source", "SerialSource"),
    "replay": ("fnsi_lab.replay.source", "ReplaySource"),
}


def source_class(kind: str) -> type["Source"]:
    """Import and return the adapter class registered as ``kind``.

    Raises
    ------
    ConfigError
        Unknown kind, or the adapter's module (or a driver it needs) cannot be imported.
    """
    try:
        module_name, class_name = SOURCES[kind]
    except KeyError:
        raise ConfigError(f"unknown source kind {kind!r}", field="source.kind",
                          fix=f"use one of {plain.names(sorted(SOURCES))}") from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"source kind {kind!r} cannot be loaded: {exc}", field="source.kind",
                          fix=f"install the missing package ({exc.name or 'see message'})") from None
    return getattr(module, class_name)


def make_source(config: "ExperimentConfig", **kwargs: Any) -> "Source":
    """Build the source an experiment configuration asks for.

    Parameters
    ----------
    config : ExperimentConfig
        Validated experiment.
    **kwargs
        Passed to the adapter's ``from_config`` (``pace=1.0`` for wall-clock pacing...).

    With a ``trigger:`` section the adapter is wrapped in a
    :class:`daq.trigger.TriggeredSource`.
    """
    cls = source_class(config.source.kind)
    source = cls.from_config(config, **kwargs)
    if getattr(config, "trigger", None) is not None:  # software trigger on any source
        from fnsi_lab.daq.trigger import TriggeredSource
        source = TriggeredSource(source, config.trigger)
    return source
