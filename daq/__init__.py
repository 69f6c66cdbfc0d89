"""daq: channels, sources, multisine excitation and MCAP recording.

Conventions (shared by every fnsi-lab package)
----------------------------------------------
- Time blocks are ``(n_samples, n_channels)``, row-major, physical units (SI unless a
  channel says otherwise); periodic records are ``(n_realizations, n_periods, n_samples,
  n_channels)``.
- Times are integer nanoseconds; rates are in Hz.
- Force channels (``quantity == 'force'``) are the inputs, the others the responses.

The flow: a :class:`~daq.source.Source` (simulated structure, CAN, serial, replay) yields
:class:`~daq.block.Block` objects; :func:`daq.acquisition.acquire` fans them out through
bounded queues to the MCAP recorder (:mod:`daq.recording`) and to any analysis tap.
Importing this package never imports an optional driver (see :mod:`daq.registry`).
"""

from typing import Any

#: Public name -> module defining it (imported on first use: ``import fnsi_lab.daq`` and
#: ``fnsi-lab --help`` do not load numpy).
_LAZY = {
    "Block": "block", "ChannelInfo": "channels", "ExcitationConfig": "config",
    "ExperimentConfig": "config", "SourceConfig": "config", "load_experiment": "config",
    "Multisine": "multisine", "multisine": "multisine", "make_source": "registry",
    "source_class": "registry", "Source": "source", "SourceEvent": "source",
    "SourceStats": "source",
}

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"fnsi_lab.daq.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'fnsi_lab.daq' has no attribute {name!r}")
