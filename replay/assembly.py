"""Period assembly, pure: blocks placed by ``(realization, first_sample)`` and cut into
complete multisine periods, their periodicity, and the snapshot record of every complete
period so far (the same :class:`daq.recording.reader.PeriodicRecord` that
:func:`daq.recording.reader.read_periodic` builds from a finished file). No threads: the
running service (:mod:`replay.service`) calls it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo

from fnsi_lab.errors import ConfigError


# ---------------------------------------------------------------------------- assembly
@dataclass(frozen=True)
class CompletePeriod:
    """One complete period of every channel.

    Attributes
    ----------
    realization : int
    index : int
        Period number within its realization (``first_sample // N``).
    data : ndarray, shape (N, n_channels)
    end_ns : int
        Source time just after its last sample.
    received_s : float
        ``time.monotonic()`` when its last block reached the service (for latency).
    """

    realization: int
    index: int
    data: np.ndarray
    end_ns: int
    received_s: float


class PeriodAssembler:
    """Cut a stream of blocks into complete periods of ``samples_per_period`` samples.

    Periods start at ``first_sample`` multiples of N (the excitation's phase), as in
    :func:`daq.recording.reader.read_periodic`. A gap (lost blocks) discards the partial
    period it falls in and is counted in :attr:`lost_samples`.

    Parameters
    ----------
    samples_per_period : int
        N.
    n_channels : int
        Columns of every block.
    """

    def __init__(self, samples_per_period: int, n_channels: int) -> None:
        if samples_per_period < 1:
            raise ConfigError(f"samples_per_period must be >= 1, got {samples_per_period}",
                              field="samples_per_period")
        self.n = int(samples_per_period)
        self.n_channels = int(n_channels)
        self._buf: dict[int, np.ndarray] = {}
        self._fill: dict[int, int] = {}          # samples filled in the current period
        self._period: dict[int, int] = {}        # index of the period being filled
        self._next: dict[int, int] = {}          # next expected first_sample
        self.lost_samples = 0
        self.gaps = 0

    def add(self, block: Block, received_s: float | None = None) -> list[CompletePeriod]:
        """Place one block; return the periods it completed (usually zero or one)."""
        r = int(block.realization)
        received_s = time.monotonic() if received_s is None else received_s
        data = np.asarray(block.data)
        start = int(block.first_sample)
        expected = self._next.get(r)
        if expected is not None and start != expected:
            self.gaps += 1
            if start > expected:
                self.lost_samples += start - expected
            self._fill.pop(r, None)  # the partial period cannot be completed
        self._next[r] = start + data.shape[0]
        out: list[CompletePeriod] = []
        pos = 0
        while pos < data.shape[0]:
            s = start + pos
            k, offset = divmod(s, self.n)
            if self._period.get(r) != k or r not in self._fill:
                if offset != 0:  # mid-period start (first block or after a gap): skip ahead
                    pos += self.n - offset
                    continue
                self._period[r] = k
                self._fill[r] = 0
                if r not in self._buf:
                    self._buf[r] = np.empty((self.n, self.n_channels), dtype=np.float64)
            take = min(self.n - offset, data.shape[0] - pos)
            self._buf[r][offset:offset + take] = data[pos:pos + take]
            self._fill[r] += take
            pos += take
            if self._fill[r] == self.n:
                end_ns = block.t0_ns + int(round(pos * 1e9 / block.sample_rate_hz))
                out.append(CompletePeriod(r, k, self._buf[r].copy(), end_ns, received_s))
                del self._fill[r]
        return out


def periodicity_error(previous: np.ndarray, current: np.ndarray) -> float:
    """Largest per-channel ``||x_k - x_{k-1}|| / ||x_k||`` of two consecutive periods."""
    diff = np.linalg.norm(current - previous, axis=0)
    ref = np.linalg.norm(current, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.where(ref > 0, diff / np.where(ref > 0, ref, 1.0), np.where(diff > 0, np.inf, 0.0))
    return float(np.max(err)) if err.size else 0.0


# ---------------------------------------------------------------------------- snapshot
def build_record(periods: Mapping[int, Sequence[CompletePeriod]], channels: Sequence[ChannelInfo],
                 sample_rate_hz: float, samples_per_period: int, *, transient_periods: int,
                 excited_lines: Any = (), truth: Any = None, excitation: Any = None) -> Any:
    """A :class:`daq.recording.reader.PeriodicRecord` of consecutive complete periods.

    Each realization contributes its longest run of consecutive periods starting at its
    first kept one; all realizations are cut to the shortest, as ``read_periodic`` does.
    """
    from fnsi_lab.daq.periodic import periodicity_per_channel
    from fnsi_lab.daq.recording.reader import PeriodicRecord

    reals = sorted(r for r, ps in periods.items() if ps)
    runs = {}
    for r in reals:
        ps = periods[r]
        run = [ps[0]]
        for p in ps[1:]:
            if p.index != run[-1].index + 1:
                break
            run.append(p)
        runs[r] = run
    n_p = min(len(v) for v in runs.values())
    x = np.stack([np.stack([p.data for p in runs[r][:n_p]]) for r in reals])
    is_in = np.array([c.is_force for c in channels], dtype=bool)
    errs = np.max(np.stack([periodicity_per_channel(x[i]) for i in range(len(reals))]), axis=0)
    err = float(np.max(errs)) if errs.size and not np.all(np.isnan(errs)) else math.nan
    first_index = min(runs[r][0].index for r in reals)
    return PeriodicRecord(
        u=x[..., is_in], y=x[..., ~is_in],
        input_channels=tuple(c for c in channels if c.is_force),
        output_channels=tuple(c for c in channels if not c.is_force),
        sample_rate_hz=float(sample_rate_hz), samples_per_period=int(samples_per_period),
        transient_periods=max(int(transient_periods) - first_index, 0),
        excited_lines=np.asarray(excited_lines, dtype=np.int64), truth=truth,
        periodicity_error=err, periodicity_error_per_channel=errs, realizations=tuple(reals),
        notes=(), excitation=excitation)
