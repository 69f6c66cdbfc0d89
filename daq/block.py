"""The unit of data every source delivers: a time-stamped block of samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fnsi_lab.daq.channels import ChannelInfo


@dataclass(frozen=True, eq=False)
class Block:
    """A block of consecutive samples of every channel.

    Attributes
    ----------
    data : ndarray, shape (n_samples, n_channels)
        Samples, row-major, in the physical units of ``channels``.
    channels : tuple of ChannelInfo, length n_channels
        Metadata of each column.
    sample_rate_hz : float
        Sampling rate.
    sequence : int
        Block counter of the source, from 0, without gaps unless blocks were lost.
    first_sample : int
        Index of the first row since the start of the current realization (or of the
        acquisition, for sources that know no realizations). Periods are assembled from it.
    t0_ns : int
        Time stamp of the first row in integer nanoseconds (source clock; bus time for
        hardware, ``first_sample / sample_rate_hz`` for simulated sources).
    realization : int
        Multisine realization index (0 for single-realization or hardware sources).
    """

    data: np.ndarray
    channels: tuple[ChannelInfo, ...]
    sample_rate_hz: float
    sequence: int
    first_sample: int
    t0_ns: int
    realization: int = 0

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return int(self.data.shape[0])

    @property
    def n_channels(self) -> int:
        """Number of columns."""
        return int(self.data.shape[1])

    @property
    def duration_s(self) -> float:
        """Time span covered by the block."""
        return self.n_samples / self.sample_rate_hz

    @property
    def end_ns(self) -> int:
        """Time stamp one sample past the last row."""
        return self.t0_ns + int(round(self.n_samples * 1e9 / self.sample_rate_hz))
