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

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.config import ExcitationConfig, ExperimentConfig, SourceConfig, load_experiment
from fnsi_lab.daq.multisine import Multisine, multisine
from fnsi_lab.daq.registry import make_source, source_class
from fnsi_lab.daq.source import Source, SourceEvent, SourceStats

__all__ = [
    "Block", "ChannelInfo", "ExcitationConfig", "ExperimentConfig", "SourceConfig",
    "load_experiment", "Multisine", "multisine", "make_source", "source_class", "Source",
    "SourceEvent", "SourceStats",
]
