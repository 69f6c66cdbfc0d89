"""What a periodic record is made of, beyond reading it: the period-to-period difference
of each channel, and the excited lines its excitation metadata names. Used by the recording
reader (:func:`daq.recording.reader.read_periodic`) and the live service's assembly
(:mod:`replay.assembly`), which must agree bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["periodicity_per_channel", "excited_lines_of"]


def periodicity_per_channel(x: np.ndarray) -> np.ndarray:
    """Per-channel relative difference of the last two periods, shape (n_channels,).

    ``x``: periods of one realisation, shape ``(n_periods, n_samples, n_channels)``; NaN with
    fewer than two periods, inf for a channel that is zero in the last period only.
    """
    if x.shape[0] < 2:
        return np.full(x.shape[-1], np.nan)
    last = x[-1]
    diff = np.linalg.norm(last - x[-2], axis=0)
    ref = np.linalg.norm(last, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.where(ref > 0, diff / np.where(ref > 0, ref, 1), np.where(diff > 0, np.inf, 0.0))
    return err


def excited_lines_of(exc: dict[str, Any] | None, n: int, fs: float) -> np.ndarray:
    """DFT lines (of ``n`` samples at ``fs`` Hz) that a recording's excitation metadata
    names: its ``excited_lines``, else those of its multisine ``band_hz``; none without."""
    if not exc:
        return np.zeros(0, dtype=np.int64)
    if exc.get("excited_lines") is not None:
        return np.asarray(exc["excited_lines"], dtype=np.int64)
    if exc.get("band_hz") is not None:
        from fnsi_lab.daq.multisine import excited_lines
        return excited_lines(n, float(exc.get("sample_rate_hz", fs)), tuple(exc["band_hz"]))
    return np.zeros(0, dtype=np.int64)
