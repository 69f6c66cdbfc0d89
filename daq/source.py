"""The abstract data source, in the pattern of python-can's ``BusABC``.

The base class owns the public life cycle (``start``/``stop``/``close``, all idempotent),
the context manager, ``read(timeout)``, optional wall-clock pacing, block numbering,
statistics and the event queue. An adapter implements one private hook,
:meth:`Source._read_block`, and optionally ``_start``/``_stop``/``_close`` for its device.
"""

from __future__ import annotations

import logging

import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterator, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.errors import ConfigError, SourceError


class SourceClosedError(SourceError):
    """``read`` was called on a closed source."""


@dataclass
class SourceStats:
    """Counters a source keeps while it runs (read them at any time)."""

    blocks: int = 0
    samples: int = 0
    #: Blocks lost between the device and this process (driver overrun, missing frames...).
    lost_blocks: int = 0
    #: Named problem counters (``error_frames``, ``unknown_ids``, ``resyncs``...).
    problems: dict[str, int] = field(default_factory=dict)

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to the problem counter ``name``."""
        self.problems[name] = self.problems.get(name, 0) + n


@dataclass(frozen=True)
class SourceEvent:
    """Something worth recording next to the samples (an error frame, a reconnect...)."""

    time_ns: int
    kind: str
    detail: dict[str, Any]


class Source(ABC):
    """Abstract source of sample blocks.

    Parameters
    ----------
    channels : sequence of ChannelInfo
        Metadata of the columns every block will have.
    sample_rate_hz : float
        Nominal sampling rate.
    pace : float or None, optional
        If given, :meth:`read` never returns a block before its end time divided by
        ``pace`` has elapsed on the wall clock since the first read (1.0 = real time).
        Hardware delivers at its own pace and leaves this ``None``; simulated sources and
        replays use it to behave like hardware.

    Notes
    -----
    Adapters are registered by name in :mod:`daq.registry` and built from the experiment
    configuration with :func:`daq.registry.make_source`.
    """

    #: Name under which the adapter is registered.
    kind: ClassVar[str] = "abstract"

    def __init__(self, channels: Sequence[ChannelInfo], sample_rate_hz: float, *,
                 pace: float | None = None) -> None:
        if not channels:
            raise ConfigError("a source needs at least one channel", field="channels")
        names = [c.name for c in channels]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ConfigError(f"duplicate channel names {plain.names(dup)}", field="channels",
                              fix="give every channel a unique name")
        if not sample_rate_hz > 0:
            raise ConfigError(f"sample rate must be > 0, got {sample_rate_hz}",
                              field="sample_rate_hz")
        if pace is not None and not pace > 0:
            raise ConfigError(f"must be > 0, got {pace}", field="pace (--speed)",
                              fix="give recorded seconds per wall second, e.g. 1 for real "
                                  "time, or none (--fast) for as fast as possible")
        self._channels = tuple(channels)
        self._sample_rate_hz = float(sample_rate_hz)
        self._pace = pace
        self._state = "created"
        self._finished = False
        self._sequence = 0
        self._wall_start: float | None = None
        self._time_origin_ns: int | None = None
        self._events: deque[SourceEvent] = deque(maxlen=100_000)
        self._lock = threading.Lock()
        self.stats = SourceStats()

    # ------------------------------------------------------------------ properties
    @property
    def channels(self) -> tuple[ChannelInfo, ...]:
        """Metadata of the block columns."""
        return self._channels

    @property
    def channel_names(self) -> list[str]:
        """Column names, in order."""
        return [c.name for c in self._channels]

    @property
    def sample_rate_hz(self) -> float:
        """Nominal sampling rate."""
        return self._sample_rate_hz

    @property
    def finished(self) -> bool:
        """True once the source has delivered its last block (finite sources only)."""
        return self._finished

    @property
    def is_running(self) -> bool:
        """True between :meth:`start` and :meth:`stop`."""
        return self._state == "running"

    @property
    def is_closed(self) -> bool:
        """True after :meth:`close`."""
        return self._state == "closed"

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Open the device and start delivering (idempotent)."""
        with self._lock:
            if self._state == "running":
                return
            if self._state == "closed":
                raise SourceClosedError(f"{self.kind} source is closed; create a new one")
            self._start()
            self._state = "running"

    def stop(self) -> None:
        """Stop delivering; :meth:`start` may resume (idempotent)."""
        with self._lock:
            if self._state != "running":
                return
            try:
                self._stop()
            finally:
                self._state = "stopped"

    def close(self) -> None:
        """Stop and release the device (idempotent)."""
        self.stop()
        with self._lock:
            if self._state == "closed":
                return
            try:
                self._close()
            finally:
                self._state = "closed"

    def __enter__(self) -> "Source":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort only
        try:
            if getattr(self, "_state", "closed") != "closed":
                self.close()
        except Exception as exc:  # noqa: BLE001 - nothing may escape __del__; still said
            logging.getLogger("fnsi_lab.daq").debug("closing %r at collection: %s", self, exc)

    # ------------------------------------------------------------------ reading
    def read(self, timeout: float | None = None) -> Block | None:
        """Return the next block, or ``None`` on timeout or at the end of the data.

        Parameters
        ----------
        timeout : float or None
            Seconds to wait for a block; ``None`` waits as long as the adapter needs.

        Returns
        -------
        Block or None
            ``None`` when nothing arrived in time, or when :attr:`finished` is True.

        Raises
        ------
        SourceClosedError
            If the source was closed.
        """
        if self._state == "closed":
            raise SourceClosedError(f"read() on a closed {self.kind} source")
        if self._state != "running":
            self.start()
        if self._finished:
            return None
        if self._wall_start is None:
            self._wall_start = time.monotonic()
        block = self._read_block(timeout)
        if block is None:
            return None
        if self._pace is not None:
            self._wait_for(block, timeout)
        self.stats.blocks += 1
        self.stats.samples += block.n_samples
        return block

    def __iter__(self) -> Iterator[Block]:
        """Yield blocks until the source is finished (blocking reads)."""
        while not self._finished:
            block = self.read(timeout=1.0)
            if block is not None:
                yield block

    def drain_events(self) -> list[SourceEvent]:
        """Return and forget the events emitted since the last call."""
        out = []
        while self._events:
            out.append(self._events.popleft())
        return out

    def describe(self) -> dict[str, Any]:
        """JSON-able metadata to store with a recording (excitation, model, truth...).

        Each top-level key becomes one MCAP metadata record ``fnsi_lab.<key>``.
        Adapters extend the base dict.
        """
        return {"source": {"kind": self.kind, "sample_rate_hz": self._sample_rate_hz,
                           "n_channels": len(self._channels)}}

    # ------------------------------------------------------------------ helpers for adapters
    def _make_block(self, data: np.ndarray, first_sample: int, *, t0_ns: int | None = None,
                    realization: int = 0) -> Block:
        """Wrap an array into a :class:`Block` with the next sequence number."""
        data = np.asarray(data)
        if data.ndim != 2 or data.shape[1] != len(self._channels):
            raise SourceError(f"{self.kind} source produced a block of shape {data.shape}, "
                              f"expected (n_samples, {len(self._channels)})")
        if t0_ns is None:
            t0_ns = int(round(first_sample * 1e9 / self._sample_rate_hz))
        block = Block(data=data, channels=self._channels, sample_rate_hz=self._sample_rate_hz,
                      sequence=self._sequence, first_sample=int(first_sample), t0_ns=int(t0_ns),
                      realization=int(realization))
        self._sequence += 1
        return block

    def _emit_event(self, kind: str, time_ns: int | None = None, **detail: Any) -> None:
        """Queue an event for the recorder and count it under ``kind``."""
        if time_ns is None:
            time_ns = time.time_ns()
        self._events.append(SourceEvent(time_ns=int(time_ns), kind=kind, detail=detail))
        self.stats.count(kind)

    def _mark_finished(self) -> None:
        """Adapters call this when the data are exhausted."""
        self._finished = True

    def _wait_for(self, block: Block, timeout: float | None) -> None:
        """Sleep until the block's end would have been acquired in paced wall time."""
        if self._time_origin_ns is None:
            self._time_origin_ns = block.t0_ns
        assert self._wall_start is not None and self._pace is not None
        due = self._wall_start + (block.end_ns - self._time_origin_ns) / 1e9 / self._pace
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    # ------------------------------------------------------------------ hooks
    @abstractmethod
    def _read_block(self, timeout: float | None) -> Block | None:
        """Return the next block, ``None`` on timeout; call :meth:`_mark_finished` at the end."""

    def _start(self) -> None:
        """Open the device (default: nothing to do)."""

    def _stop(self) -> None:
        """Pause the device (default: nothing to do)."""

    def _close(self) -> None:
        """Release the device (default: nothing to do)."""
