"""The live identification service: blocks in, identification updates out, never in the way.

Two stages, each in its own thread, so that acquisition is never blocked and no recorded
sample depends on the analysis keeping up:

1. the *assembler* (:class:`PeriodAssembler`, cheap) takes blocks from a bounded,
   drop-oldest queue (a :class:`daq.acquisition.Tap` or the service's own), places them by
   ``(realization, first_sample)`` and cuts complete multisine periods of N samples;
2. the *identifier* runs the (slow) identification on a snapshot of every complete period
   so far, with a one-slot mailbox: when a newer snapshot arrives while it is busy, the
   older pending one is replaced (counted as ``skipped``), so it always works on the
   newest complete data.

Estimates improve as periods accumulate because every snapshot holds all complete periods
(the identification averages them and estimates the noise covariance). A snapshot is the
same :class:`daq.recording.reader.PeriodicRecord` that :func:`daq.recording.reader.read_periodic`
builds from the finished file, so the last update of a complete run is bit-identical to
an offline identification of its recording.

Rooms: this module runs the threads; the assembly itself is pure (:mod:`replay.assembly`),
what runs on each snapshot is in :mod:`replay.identifiers`, and the views of an update for
Rerun and the terminal are formatted by :mod:`viewer.views`.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from fnsi_lab.daq.acquisition import put_drop_oldest
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.replay.assembly import (
    CompletePeriod,
    PeriodAssembler,
    build_record,
    periodicity_error,
)

from fnsi_lab.errors import ConfigError

_END = object()

#: Relative period-to-period RMS difference below which a period counts as steady state,
#: when the recording does not say how many periods are transient.
DEFAULT_STEADY_TOLERANCE = 0.05




# ---------------------------------------------------------------------------- service
@dataclass
class ServiceStatus:
    """Counters of the service (read at any time; the status line prints them)."""

    blocks: int = 0
    samples: int = 0
    #: Blocks dropped by the input queue (the service fell behind acquisition).
    dropped_blocks: int = 0
    #: Samples missing between consecutive blocks (lost upstream or dropped here).
    lost_samples: int = 0
    periods: int = 0
    steady_periods: int = 0
    updates: int = 0
    #: Snapshots replaced by a newer one before the identifier got to them.
    skipped: int = 0
    failures: int = 0
    last_error: str = ""
    last_ident_s: float = math.nan
    last_latency_s: float = math.nan
    max_latency_s: float = 0.0
    signal_s: float = 0.0
    started_s: float = field(default_factory=time.monotonic)
    #: Drive vs acquisition clock of the latest snapshot (daq.periodicity.ClockCheck).
    clock: Any = None
    #: Wall-clock seconds between complete steady periods as they arrive (median of the
    #: last few; one period of signal for a real-time source).
    period_interval_s: float = math.nan
    #: Time an identification may take to keep pace: ``every`` period intervals.
    update_budget_s: float = math.nan
    #: Identifications that took longer than ``update_budget_s`` (the service could not
    #: identify every due update; the newer snapshots replaced the waiting ones).
    behind: int = 0

    @property
    def keeping_up(self) -> bool:
        """The last identification finished within the budget (True before any)."""
        return not (self.last_ident_s > self.update_budget_s)

    @property
    def rate(self) -> float:
        """Signal seconds processed per wall-clock second."""
        wall = time.monotonic() - self.started_s
        return self.signal_s / wall if wall > 0 else 0.0

    def line(self, file_size_bytes: int | None = None) -> str:
        """One status line (rate, periods, drops, file size, last identification time)."""
        parts = [f"t={self.signal_s:7.1f}s", f"{self.rate:6.1f}x",
                 f"periods {self.periods} ({self.steady_periods} steady)",
                 f"updates {self.updates}", f"skipped {self.skipped}",
                 f"dropped {self.dropped_blocks}"]
        if file_size_bytes is not None:
            parts.append(f"file {file_size_bytes / 1e6:.1f} MB")
        if not math.isnan(self.last_ident_s):
            parts.append(f"ident {self.last_ident_s:.2f}s")
        if not math.isnan(self.last_latency_s):
            parts.append(f"latency {self.last_latency_s:.2f}s")
        if self.behind:
            parts.append(f"BEHIND {self.behind}x: " + (
                f"ident {self.last_ident_s:.2f}s > {self.update_budget_s:.2f}s per update"
                if not self.keeping_up else "keeping up again"))
        if self.failures:
            parts.append(f"failures {self.failures}")
        if self.clock is not None and math.isfinite(self.clock.offset_ppm):
            parts.append(f"clock {self.clock.offset_ppm:+.1f} ppm"
                         + (" WARNING: drive/acquisition clocks differ" if self.clock.warning else ""))
        return " | ".join(parts)


@dataclass(frozen=True)
class ServiceUpdate:
    """One identification update, handed to ``on_update``.

    Attributes
    ----------
    update : int
        1 for the first identification.
    record : PeriodicRecord
        The data identified (every complete period so far, transients included and flagged).
    result : object
        What ``identify`` returned.
    n_periods : int
        Steady-state periods per realization in ``record``.
    acq_time_s : float
        Source time at the end of the newest period used, seconds.
    ident_s : float
        Wall time spent in ``identify``.
    period_received_s : float
        ``time.monotonic()`` when the newest period's last block arrived.
    """

    update: int
    record: Any
    result: Any
    n_periods: int
    acq_time_s: float
    ident_s: float
    period_received_s: float


Identifier = Callable[[Any], Any]


class IdentService:
    """Assemble periods from a block stream and re-identify as they accumulate.

    Parameters
    ----------
    channels : sequence of ChannelInfo
        Columns of every block (force channels are inputs).
    sample_rate_hz : float
    samples_per_period : int
        N of the multisine.
    identify : callable
        ``identify(record) -> result`` on a :class:`~daq.recording.reader.PeriodicRecord`
        (e.g. ``ident.robust.auto``'s pipeline via :func:`replay.identifiers.auto_identifier`).
    on_update : callable, optional
        ``on_update(ServiceUpdate)``, called in the identifier thread (log to Rerun here).
    transient_periods : int
        Leading periods of each realization that are not in steady state.
    steady_state_tolerance : float or None
        If given, additionally wait until two consecutive periods differ by less than this
        (relative RMS) before the first identification of a realization.
    every : int
        Identify after every ``every``-th new steady-state period (the last period of a
        run always triggers one).
    min_periods : int
        Steady-state periods needed before the first identification.
    max_periods : int
        Keep at most this many periods per realization in memory (the oldest go).
    queue_blocks : int
        Capacity of the input queue (drop-oldest, counted) when blocks come via :meth:`offer`.
    excited_lines, truth, excitation
        Passed into every record (from the recording metadata).
    on_block : callable, optional
        ``on_block(block, acq_t0_s)``, called in the assembler thread for every block (e.g.
        to log the signals to Rerun); keep it cheap. ``acq_t0_s`` is the block start on a
        clock that keeps running across realizations (sources restart ``t0_ns`` at each
        realization).
    """

    def __init__(self, channels: Sequence[ChannelInfo], sample_rate_hz: float,
                 samples_per_period: int, identify: Identifier, *,
                 on_update: Callable[[ServiceUpdate], None] | None = None,
                 transient_periods: int = 0, steady_state_tolerance: float | None = None,
                 every: int = 1, min_periods: int = 1, max_periods: int = 64,
                 queue_blocks: int = 1024, excited_lines: Any = (), truth: Any = None,
                 excitation: Any = None,
                 on_block: Callable[[Block, float], None] | None = None) -> None:
        if every < 1 or min_periods < 1 or max_periods < 2:
            raise ConfigError("every and min_periods must be >= 1, max_periods >= 2",
                              field="service")
        self.channels = tuple(channels)
        self.sample_rate_hz = float(sample_rate_hz)
        self.n = int(samples_per_period)
        self.identify = identify
        self.on_update = on_update
        self.on_block = on_block
        self.transient_periods = int(transient_periods)
        self.tolerance = steady_state_tolerance
        self.every = int(every)
        self.min_periods = int(min_periods)
        self.max_periods = int(max_periods)
        self.excited_lines = excited_lines
        self.truth = truth
        self.excitation = excitation
        self.status = ServiceStatus()
        self._last_arrival_s: float | None = None
        self._intervals: list[float] = []
        self.updates: list[ServiceUpdate] = []
        self._assembler = PeriodAssembler(self.n, len(self.channels))
        self._periods: dict[int, list[CompletePeriod]] = {}
        self._steady_from: dict[int, int] = {}
        self._since_update = 0
        self._acq_offset_s: dict[int, float] = {}
        self._acq_end_s = 0.0
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=max(int(queue_blocks), 1))
        self._mailbox: list[tuple[Any, CompletePeriod]] = []
        self._mail_cv = threading.Condition()
        self._closing = False
        self._feeder: threading.Thread | None = None
        self._worker: threading.Thread | None = None
        self._source: Iterable[Block] | None = None
        self._feed_error: BaseException | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_recording_metadata(cls, channels: Sequence[ChannelInfo], sample_rate_hz: float,
                               metadata: Mapping[str, Any], identify: Identifier,
                               **kwargs: Any) -> "IdentService":
        """Build from recording metadata (``excitation``: N, transient periods, lines; ``truth``).

        Without a recorded number of transient periods, steady state is detected
        (``steady_state_tolerance`` defaults to :data:`DEFAULT_STEADY_TOLERANCE`).
        """
        from fnsi_lab.daq.periodic import excited_lines_of

        exc = metadata.get("excitation") or {}
        n = kwargs.pop("samples_per_period", None) or exc.get("samples_per_period")
        if not n:
            raise ConfigError("the period length is unknown (no excitation metadata)",
                              field="samples_per_period",
                              fix="pass samples_per_period (e.g. --samples-per-period 8192)")
        if exc.get("transient_periods") is None:
            # nothing says when the transient ends: wait until two periods agree
            kwargs.setdefault("steady_state_tolerance", DEFAULT_STEADY_TOLERANCE)
        kwargs.setdefault("transient_periods", int(exc.get("transient_periods", 0) or 0))
        return cls(channels, sample_rate_hz, int(n), identify,
                   excited_lines=excited_lines_of(exc or None, int(n), sample_rate_hz),
                   truth=metadata.get("truth"), excitation=exc or None, **kwargs)

    # ------------------------------------------------------------------ feeding
    def start(self, source: Iterable[Block] | None = None) -> "IdentService":
        """Start the threads; blocks come from ``source`` (e.g. a Tap) or :meth:`offer`."""
        self._source = source
        self.status.started_s = time.monotonic()
        self._worker = threading.Thread(target=self._work, name="fnsi-lab-ident", daemon=True)
        self._worker.start()
        self._feeder = threading.Thread(target=self._feed, name="fnsi-lab-assemble", daemon=True)
        self._feeder.start()
        return self

    def offer(self, block: Block) -> None:
        """Hand over a block without ever blocking (drop-oldest when full, counted)."""
        self.status.dropped_blocks += put_drop_oldest(self._queue, block)

    def finish(self, timeout: float | None = None) -> ServiceStatus:
        """End of input: identify the last snapshot, stop the threads, return the status.

        Raises
        ------
        Exception
            Whatever the block source raised in the assembler thread (after the periods
            received before it were identified).
        """
        if self._source is None:
            self._put_end()
        if self._feeder is not None:
            self._feeder.join(timeout)
        with self._mail_cv:
            self._closing = True
            self._mail_cv.notify_all()
        if self._worker is not None:
            self._worker.join(timeout)
        dropped = getattr(self._source, "dropped", None)
        if isinstance(dropped, int):
            self.status.dropped_blocks += dropped
        if self._feed_error is not None:
            error, self._feed_error = self._feed_error, None
            raise error
        return self.status

    def close(self) -> None:
        """Stop without waiting for pending identifications (idempotent)."""
        with self._mail_cv:
            self._mailbox.clear()
            self._closing = True
            self._mail_cv.notify_all()
        if self._source is None:
            self._put_end()

    def _put_end(self) -> None:
        self.status.dropped_blocks += put_drop_oldest(self._queue, _END)

    def _blocks(self) -> Iterable[Block]:
        if self._source is not None:
            yield from self._source
            return
        while True:
            item = self._queue.get()
            if item is _END:
                return
            yield item

    def _feed(self) -> None:
        last: CompletePeriod | None = None
        try:
            for block in self._blocks():
                if self._closing:
                    break
                period = self.push(block)
                last = period or last
        except BaseException as exc:  # a bad file, a failing source: re-raised by finish()
            self._feed_error = exc
        if last is not None and self._since_update:  # the tail always gets identified
            self._post(last)

    # ------------------------------------------------------------------ assembly (inline)
    def push(self, block: Block) -> CompletePeriod | None:
        """Assemble one block (no thread); post a snapshot when an update is due.

        Returns the last period the block completed, if any.
        """
        self.status.blocks += 1
        self.status.samples += block.n_samples
        acq_t0 = self.acq_time_s(block.realization, block.t0_ns)
        self._acq_end_s = max(self._acq_end_s, acq_t0 + block.duration_s)
        self.status.signal_s = self._acq_end_s
        if self.on_block is not None:
            self.on_block(block, acq_t0)
        done = self._assembler.add(block)
        self.status.lost_samples = self._assembler.lost_samples
        last = None
        for p in done:
            last = p
            self.status.periods += 1
            kept = self._periods.setdefault(p.realization, [])
            kept.append(p)
            if len(kept) > self.max_periods:
                del kept[0]
            if self._is_steady(p, kept):
                self._note_arrival(p.received_s)
                self.status.steady_periods += 1
                self._since_update += 1
                if self._since_update >= self.every and self._n_steady() >= self.min_periods:
                    self._post(p)
        return last

    def _note_arrival(self, received_s: float) -> None:
        """Track the wall-clock interval between steady periods (the identification budget)."""
        if self._last_arrival_s is not None:
            self._intervals.append(received_s - self._last_arrival_s)
            del self._intervals[:-8]
            self.status.period_interval_s = float(np.median(self._intervals))
            self.status.update_budget_s = self.every * self.status.period_interval_s
        self._last_arrival_s = received_s

    def acq_time_s(self, realization: int, time_ns: int) -> float:
        """Source time -> acquisition time running on across realizations (seconds)."""
        r = int(realization)
        if r not in self._acq_offset_s:
            self._acq_offset_s[r] = max(0.0, self._acq_end_s - time_ns / 1e9)
        return time_ns / 1e9 + self._acq_offset_s[r]

    def _is_steady(self, p: CompletePeriod, kept: list[CompletePeriod]) -> bool:
        r = p.realization
        if r in self._steady_from:
            return p.index >= self._steady_from[r]
        if p.index < self.transient_periods:
            return False
        if self.tolerance is not None:
            if len(kept) < 2 or kept[-2].index != p.index - 1:
                return False
            if periodicity_error(kept[-2].data, p.data) > self.tolerance:
                return False
        self._steady_from[r] = p.index
        return True

    def _n_steady(self) -> int:
        counts = [sum(1 for p in ps if p.index >= self._steady_from[r])
                  for r, ps in self._periods.items() if r in self._steady_from]
        return min(counts) if counts else 0

    def snapshot(self) -> Any:
        """The current :class:`~daq.recording.reader.PeriodicRecord` (None before steady state)."""
        usable = {r: ps for r, ps in self._periods.items() if r in self._steady_from}
        if not usable:
            return None
        transient = max(self._steady_from.values())
        return build_record(usable, self.channels, self.sample_rate_hz, self.n,
                            transient_periods=transient, excited_lines=self.excited_lines,
                            truth=self.truth, excitation=self.excitation)

    def _post(self, period: CompletePeriod) -> None:
        self._since_update = 0
        record = self.snapshot()
        if record is None:
            return
        from fnsi_lab.daq.periodicity import check_record_clock
        self.status.clock = check_record_clock(record)
        with self._mail_cv:
            if self._mailbox:
                self.status.skipped += 1
                self._mailbox.clear()
            self._mailbox.append((record, period))
            self._mail_cv.notify_all()
        if self._worker is None:  # inline use (no threads): identify now
            self._identify_pending()

    # ------------------------------------------------------------------ identification
    def _work(self) -> None:
        while True:
            with self._mail_cv:
                while not self._mailbox and not self._closing:
                    self._mail_cv.wait()
                if not self._mailbox and self._closing:
                    return
            self._identify_pending()

    def _identify_pending(self) -> None:
        with self._mail_cv:
            if not self._mailbox:
                return
            record, period = self._mailbox.pop()
        t0 = time.perf_counter()
        try:
            result = self.identify(record)
        except Exception as exc:  # keep serving; report it
            self.status.failures += 1
            self.status.last_error = f"{type(exc).__name__}: {exc}"
            return
        ident_s = time.perf_counter() - t0
        self.status.updates += 1
        self.status.last_ident_s = ident_s
        if ident_s > self.status.update_budget_s:  # NaN budget (one period so far): no verdict
            self.status.behind += 1
        update = ServiceUpdate(update=self.status.updates, record=record, result=result,
                               n_periods=int(record.n_periods - record.transient_periods),
                               acq_time_s=self.acq_time_s(period.realization, period.end_ns),
                               ident_s=ident_s,
                               period_received_s=period.received_s)
        self.updates.append(update)
        if self.on_update is not None:
            try:
                self.on_update(update)
            except Exception as exc:
                self.status.failures += 1
                self.status.last_error = f"on_update: {type(exc).__name__}: {exc}"
        latency = time.monotonic() - period.received_s
        self.status.last_latency_s = latency
        self.status.max_latency_s = max(self.status.max_latency_s, latency)

    def run(self, blocks: Iterable[Block]) -> ServiceStatus:
        """Inline, deterministic use: assemble and identify every due update, in this thread."""
        last = None
        for block in blocks:
            last = self.push(block) or last
        if last is not None and self._since_update:
            self._post(last)
        return self.status
