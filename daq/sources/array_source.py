"""A source that plays back an in-memory array: for scripts, notebooks and tests."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.source import Source
from fnsi_lab.errors import ConfigError


class ArraySource(Source):
    """Deliver the rows of an array as blocks.

    Parameters
    ----------
    data : array_like, shape (n_samples, n_channels)
        Samples in physical units.
    channels : sequence of ChannelInfo, length n_channels
        Column metadata.
    sample_rate_hz : float
        Sampling rate.
    block_size : int, optional
        Rows per block (the last block may be shorter).
    pace : float or None, optional
        Wall-clock pacing factor (see :class:`~daq.source.Source`).
    realization : int, optional
        Realization index stamped on every block.

    Examples
    --------
    >>> import numpy as np
    >>> from daq.channels import ChannelInfo
    >>> src = ArraySource(np.zeros((250, 2)), [ChannelInfo("u", "force"), ChannelInfo("y")], 100.0,
    ...                   block_size=100)
    >>> [b.n_samples for b in src]
    [100, 100, 50]
    """

    kind = "array"

    def __init__(self, data: np.ndarray, channels: Sequence[ChannelInfo], sample_rate_hz: float,
                 *, block_size: int = 100, pace: float | None = None, realization: int = 0) -> None:
        super().__init__(channels, sample_rate_hz, pace=pace)
        data = np.asarray(data)
        if data.ndim != 2 or data.shape[1] != len(self.channels):
            raise ConfigError(f"data of shape {data.shape} does not match {len(self.channels)} channels",
                              field="data", fix="pass an array of shape (n_samples, n_channels)")
        if block_size < 1:
            raise ConfigError(f"block_size must be >= 1, got {block_size}", field="block_size")
        self._data = data
        self._block_size = int(block_size)
        self._position = 0
        self._realization = int(realization)

    def _read_block(self, timeout: float | None) -> Block | None:
        start = self._position
        stop = min(start + self._block_size, self._data.shape[0])
        if stop <= start:
            self._mark_finished()
            return None
        self._position = stop
        if stop >= self._data.shape[0]:
            self._mark_finished()
        return self._make_block(self._data[start:stop], start, realization=self._realization)
