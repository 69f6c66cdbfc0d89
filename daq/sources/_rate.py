"""Helpers shared by the hardware adapters: row-to-block assembly, the rate check and the
receive thread.

Hardware delivers one sample row at a time (a CAN frame set, a serial line); the rest of
fnsi-lab wants fixed-size ``(n_samples, n_channels)`` blocks and a warning when the
device does not run at the configured rate. Both jobs are the same for CAN and serial, so
they live here, free of any driver import.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np


class ReceiveThread:
    """The receive thread of an adapter: started by its ``_start``, stopped by its ``_stop``.

    Parameters
    ----------
    target : callable
        The receive loop; it runs until :attr:`stop_event` is set.
    name : str
        Thread name (``can-rx``, ``serial-rx``).
    """

    def __init__(self, target: Callable[[], None], name: str) -> None:
        self._target = target
        self._name = name
        self.stop_event = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start a fresh thread (after a previous :meth:`stop`, too)."""
        self.stop_event.clear()
        self._thread = threading.Thread(target=self._target, name=self._name, daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the loop to end and wait for it (idempotent)."""
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None

    @property
    def alive(self) -> bool:
        """True while the loop runs."""
        return self._thread is not None and self._thread.is_alive()


@dataclass(frozen=True)
class FullBlock:
    """A filled block waiting to be wrapped by ``Source._make_block``.

    Attributes
    ----------
    data : ndarray, shape (block_size, n_channels)
        The rows, NaN where a value was lost.
    first_sample : int
        Row index of the first row since the start of the acquisition.
    t0_ns : int
        Time stamp of the first row (device clock).
    """

    data: np.ndarray
    first_sample: int
    t0_ns: int


class RowBuffer:
    """Collect rows into blocks of ``block_size`` rows.

    Parameters
    ----------
    n_channels : int
        Columns per row.
    block_size : int
        Rows per block.

    Notes
    -----
    Rows are written into a preallocated array (no per-row allocation); a full block is
    handed out and a fresh array started, so the caller may keep the block.
    """

    def __init__(self, n_channels: int, block_size: int) -> None:
        self.n_channels = int(n_channels)
        self.block_size = int(block_size)
        self._data = np.empty((self.block_size, self.n_channels))
        self._n = 0
        self._first = 0
        self._t0 = 0
        self.ready: list[FullBlock] = []

    @property
    def pending_rows(self) -> int:
        """Rows collected for the block being filled."""
        return self._n

    def add(self, index: int, time_ns: int, values: np.ndarray | list[float] | None) -> None:
        """Append one row (``None`` appends a row of NaN: a lost sample).

        Parameters
        ----------
        index : int
            Row index since the start (must follow the previous row).
        time_ns : int
            Time stamp of the row.
        values : array-like of float, shape (n_channels,), or None
        """
        if self._n == 0:
            self._first = int(index)
            self._t0 = int(time_ns)
        if values is None:
            self._data[self._n].fill(np.nan)
        else:
            self._data[self._n] = values
        self._n += 1
        if self._n == self.block_size:
            self.ready.append(FullBlock(self._data, self._first, self._t0))
            self._data = np.empty((self.block_size, self.n_channels))
            self._n = 0

    def pop(self) -> FullBlock | None:
        """The oldest full block, or ``None``."""
        return self.ready.pop(0) if self.ready else None

    def flush(self) -> FullBlock | None:
        """Hand out the partial block (at the end of the data), or ``None`` if empty."""
        if self._n == 0:
            return None
        block = FullBlock(self._data[: self._n].copy(), self._first, self._t0)
        self._n = 0
        return block


@dataclass(frozen=True)
class RateReport:
    """Result of one rate-check window.

    Attributes
    ----------
    measured_hz, expected_hz : float
        Rows per second from the time stamps, and the configured rate.
    rows : int
        Rows in the window.
    window_s : float
        Time span of the window.
    ok : bool
        ``abs(measured / expected - 1) <= tolerance``.
    """

    measured_hz: float
    expected_hz: float
    rows: int
    window_s: float
    ok: bool


class RateMonitor:
    """Compare the row rate seen in the time stamps with the configured rate.

    Parameters
    ----------
    expected_hz : float
        Configured rate.
    tolerance : float, optional
        Accepted relative deviation (0.02 = 2 %).
    window_s : float, optional
        Span of the time stamps one check covers; long windows average out the arrival
        jitter of host-clock time stamps (serial lines arrive in USB bursts).

    Notes
    -----
    :meth:`update` returns a :class:`RateReport` only when the state changes (the first
    mismatch, or the return to the right rate), so a wrong rate gives one event, not one
    per window; :attr:`mismatches` counts every bad window.
    """

    def __init__(self, expected_hz: float, tolerance: float = 0.02, window_s: float = 1.0) -> None:
        self.expected_hz = float(expected_hz)
        self.tolerance = float(tolerance)
        self.window_ns = int(window_s * 1e9)
        self._t_start: int | None = None
        self._rows = 0
        self._ok = True
        self.last: RateReport | None = None
        self.mismatches = 0

    def reset(self) -> None:
        """Forget the current window (after a stall or reconnect the gap is not a rate)."""
        self._t_start = None
        self._rows = 0

    def update(self, time_ns: int, rows: int = 1) -> RateReport | None:
        """Count ``rows`` rows, the last one stamped ``time_ns``.

        Returns
        -------
        RateReport or None
            A report when the window closes and the verdict differs from the last one.
        """
        if self._t_start is None:
            self._t_start = time_ns
            self._rows = 0
            return None
        self._rows += rows
        span = time_ns - self._t_start
        if span < self.window_ns:
            return None
        measured = self._rows * 1e9 / span
        ok = abs(measured / self.expected_hz - 1.0) <= self.tolerance
        report = RateReport(measured, self.expected_hz, self._rows, span / 1e9, ok)
        self.last = report
        self._t_start = time_ns
        self._rows = 0
        if not ok:
            self.mismatches += 1
        if ok != self._ok:
            self._ok = ok
            return report
        return None


class RowEmitter:
    """Rows in, blocks and rate/gap events out: the part CAN and serial sources share.

    Parameters
    ----------
    emit_event : callable
        The source's ``_emit_event(kind, time_ns=..., **detail)``.
    stats : SourceStats
        The source's counters.
    n_channels, block_size : int
        Block geometry.
    expected_hz : float
        Configured row rate.
    tolerance, window_s : float
        See :class:`RateMonitor`.
    max_gap_rows : int
        Longest run of lost rows filled with NaN rows; a longer jump closes the current
        block early and starts the next one at the new index (event ``gap``).

    Notes
    -----
    Events named in :meth:`limited` are emitted at most once per second of device time
    each (they can come at frame rate); the next event carries ``suppressed``, the number
    folded into it, and ``stats`` counts every occurrence.
    """

    def __init__(self, emit_event: Any, stats: Any, n_channels: int, block_size: int,
                 expected_hz: float, tolerance: float, window_s: float,
                 max_gap_rows: int) -> None:
        self._emit_event = emit_event
        self._stats = stats
        self.rows = RowBuffer(n_channels, block_size)
        self.rate = RateMonitor(expected_hz, tolerance, window_s)
        self.period_ns = 1e9 / expected_hz
        self.max_gap = int(max_gap_rows)
        self.next_index = 0
        self.last_t: int | None = None
        self._rate_index = 0
        self._mismatch_seen = 0
        self._limited_last: dict[str, int] = {}
        self._limited_held: dict[str, int] = {}

    def limited(self, kind: str, t_ns: int, n: int = 1, **detail: Any) -> None:
        """Emit ``kind`` at most once per second of device time; always count ``n``."""
        last = self._limited_last.get(kind)
        if last is not None and 0 <= t_ns - last < 1_000_000_000:
            self._limited_held[kind] = self._limited_held.get(kind, 0) + n
            self._stats.count(kind, n)
            return
        self._limited_last[kind] = t_ns
        held = self._limited_held.pop(kind, 0)
        self._emit_event(kind, time_ns=t_ns, suppressed=held, **detail)
        if n > 1:
            self._stats.count(kind, n - 1)

    def restart_rate(self) -> None:
        """Forget the rate window (after a stall or reconnect a gap is not a rate)."""
        self.rate.reset()
        self.last_t = None

    def emit(self, index: int, t_ns: int, values: Any) -> None:
        """Append row ``index``; lost rows before it become NaN rows (or a new block).

        Parameters
        ----------
        index : int
            Row index since the start; >= every index emitted before.
        t_ns : int
            Time stamp of the row.
        values : array-like, shape (n_channels,)
        """
        gap = index - self.next_index
        if gap > 0:
            if gap <= self.max_gap:
                t0 = self.last_t if self.last_t is not None else t_ns - gap * self.period_ns
                for k in range(gap):
                    self.rows.add(self.next_index + k, int(t0 + (k + 1) * self.period_ns), None)
            else:
                tail = self.rows.flush()
                if tail is not None:
                    self.rows.ready.append(tail)
                self._emit_event("gap", time_ns=t_ns, rows=gap, from_sample=self.next_index,
                                 to_sample=index)
                self.restart_rate()
        self.rows.add(index, t_ns, values)
        self.next_index = index + 1
        self.last_t = t_ns
        report = self.rate.update(t_ns, index - self._rate_index)
        self._rate_index = index
        if report is not None:
            self._emit_event("rate_ok" if report.ok else "rate_mismatch", time_ns=t_ns,
                             measured_hz=report.measured_hz, expected_hz=report.expected_hz,
                             rows=report.rows, window_s=report.window_s)
        if self.rate.mismatches != self._mismatch_seen:  # every bad window counts
            self._stats.count("rate_mismatch_windows", self.rate.mismatches - self._mismatch_seen)
            self._mismatch_seen = self.rate.mismatches
