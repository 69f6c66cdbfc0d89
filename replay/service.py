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
from fnsi_lab.errors import ConfigError

_END = object()

#: Relative period-to-period RMS difference below which a period counts as steady state,
#: when the recording does not say how many periods are transient.
DEFAULT_STEADY_TOLERANCE = 0.05


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
    from fnsi_lab.daq.recording.reader import PeriodicRecord, _periodicity

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
    errs = np.max(np.stack([_periodicity(x[i]) for i in range(len(reals))]), axis=0)
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
        (e.g. ``ident.auto``'s pipeline via :func:`replay.service.auto_identifier`).
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
        from fnsi_lab.daq.recording.reader import _excited_lines

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
                   excited_lines=_excited_lines(exc or None, int(n), sample_rate_hz),
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


# ---------------------------------------------------------------------------- identifiers
@dataclass(frozen=True)
class FrfResult:
    """Nonparametric estimate: FRFs at the excited lines from the averaged periods.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    frf : complex ndarray, shape (n_lines, n_out, n_in)
        ``Y / U`` of the period-averaged spectra (single input) or least squares over
        realizations (several inputs).
    noise_std : ndarray, shape (n_lines, n_out)
        Standard deviation of the averaged output spectrum (NaN with one period).
    n_periods : int
        Steady-state periods averaged per realization.
    output_names, input_names : tuple of str
    """

    frequencies_hz: np.ndarray
    frf: np.ndarray
    noise_std: np.ndarray
    n_periods: int
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]


def frf_identifier(record: Any) -> FrfResult:
    """A fast nonparametric identification of a periodic record (baseline and tests).

    Parameters
    ----------
    record : PeriodicRecord
        ``u`` (R, P, N, m), ``y`` (R, P, N, p); the first ``transient_periods`` are dropped.

    Returns
    -------
    FrfResult
    """
    t = int(record.transient_periods)
    u = np.asarray(record.u)[:, t:]
    y = np.asarray(record.y)[:, t:]
    n = record.samples_per_period
    lines = np.asarray(record.excited_lines, dtype=np.int64)
    if lines.size == 0:
        lines = np.arange(1, (n - 1) // 2 + 1)
    U = np.fft.rfft(u, axis=2)[:, :, lines] / n          # (R, P, F, m)
    Y = np.fft.rfft(y, axis=2)[:, :, lines] / n          # (R, P, F, p)
    Um, Ym = U.mean(axis=1), Y.mean(axis=1)              # (R, F, m), (R, F, p)
    p_count = U.shape[1]
    if p_count > 1:
        noise = np.sqrt(np.mean(np.var(Y, axis=1, ddof=1), axis=0) / p_count)
    else:
        noise = np.full(Ym.shape[1:], np.nan)
    # (F, p, m) = Y^T U^+ over realizations (R >= m); for R = m = 1 a plain division.
    Yf = np.transpose(Ym, (1, 2, 0))                     # (F, p, R)
    Uf = np.transpose(Um, (1, 2, 0))                     # (F, m, R)
    frf = Yf @ np.linalg.pinv(Uf)
    return FrfResult(frequencies_hz=lines * record.sample_rate_hz / n, frf=frf,
                     noise_std=noise, n_periods=p_count,
                     output_names=tuple(c.name for c in record.output_channels),
                     input_names=tuple(c.name for c in record.input_channels))


def driving_point(output_channels: Sequence[ChannelInfo], input_channels: Sequence[ChannelInfo],
                  input_index: int = 0) -> int:
    """Index of the output measured where (node, direction) the force ``input_index`` acts.

    Falls back to a name match (``F-NC2W-Z`` -> ``NC2W-Z``), then to output 0.
    """
    force = input_channels[input_index]
    for i, c in enumerate(output_channels):
        if force.node and c.node == force.node and c.direction == force.direction:
            return i
    for i, c in enumerate(output_channels):
        if force.name.endswith(c.name):
            return i
    return 0


# ---------------------------------------------------------------------------- robust pipeline
@dataclass(frozen=True)
class AutoIdentification:
    """What :func:`config_identifier` returns for one snapshot.

    Attributes
    ----------
    identification : fnsi_lab.ident.pipeline.Identification
        The answer of the one entry point (:func:`fnsi_lab.ident.pipeline.identify_input`).
    coefficient_curves : dict
        ``{'full': {name: c(f)}, 'reduced': {name: c(f)}, 'frequency_hz': f}`` when the
        configuration has basis functions, else empty.
    exact_coefficients : dict
        Known coefficient values (simulations), name -> value.
    """

    identification: Any
    coefficient_curves: dict
    exact_coefficients: dict

    @property
    def result(self) -> Any:
        """The robust pipeline's :class:`~fnsi_lab.ident.auto_result.AutoResult`."""
        return self.identification.auto

    @property
    def data(self) -> Any:
        """The :class:`~fnsi_lab.ident.periodic.FrequencyData` identified."""
        return self.identification.data


def auto_view(update: ServiceUpdate) -> dict[str, Any]:
    """Plain-dict view of an :class:`AutoIdentification` update for :func:`viewer.log.log_identification`."""
    from fnsi_lab.viewer.log import summary_markdown

    ai: AutoIdentification = update.result
    res, data = ai.result, ai.data
    record = update.record
    dp = driving_point(record.output_channels, record.input_channels)
    exc = np.asarray(data.excited, dtype=bool)
    f = data.frequencies_hz[exc]
    u = data.E_physical[exc, 0]
    view: dict[str, Any] = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        measured = data.Y[exc, dp] / u
        y_model = res.model.steady_state_output(data)[exc, dp] / u
    units = ai.identification.units
    view["frf"] = {"frequency_hz": f, "measured": measured,
                   "linear": res.model.underlying_linear_frf(f)[:, dp, 0], "model": y_model,
                   "output": getattr(record.output_channels[dp], "name",
                                     str(record.output_channels[dp])),
                   "force": getattr(record.input_channels[0], "name",
                                    str(record.input_channels[0])),
                   "unit": units.get("frf")}
    order, freq, cls = [], [], []
    for o in res.stabilisation.orders:
        for fi, c, unst in zip(o.frequency_hz, o.classes, o.unstable):
            order.append(o.order)
            freq.append(fi)
            cls.append("unstable" if unst else str(c))
    view["stabilisation"] = {"order": order, "frequency_hz": freq, "pole_class": cls}
    ic = res.information_criterion
    view["criterion"] = {"orders": ic.orders, "criterion": ic.value,
                         "selected_order": res.selected_order}
    from fnsi_lab.ident.pole_fate import pole_fates

    thr = res.threshold.threshold
    rows = res.mdi_table()  # sorted by frequency, with the decisions
    key = f"mdi_{res.modal_dominancy.norm}"
    view["mdi"] = {"frequency_hz": np.array([r["frequency_hz"] for r in rows]),
                   "mdi": np.array([r.get(key, r["mdi_h2"]) for r in rows]),
                   "kept": np.array([r["physical"] for r in rows], bool),
                   "fate": pole_fates(rows, res.confidence, left_out_hz(ai)),
                   "threshold": float(thr) if np.isfinite(thr) else None}
    if ai.coefficient_curves:
        view["coefficients"] = {"frequency_hz": ai.coefficient_curves["frequency_hz"],
                                "full": ai.coefficient_curves.get("full"),
                                "reduced": ai.coefficient_curves.get("reduced"),
                                "exact": ai.exact_coefficients,
                                "excited": data.excited,
                                "units": units.get("coefficients")}
    search = ai.identification.session.parameter_search   # clearances/exponents from the data
    if search is not None and search.estimates:
        view["parameters"] = {"profiles": [
            {"label": e.unknown.label, "values": e.profile_values,
             "objective": e.profile_objective, "estimate": e.value, "std": e.std}
            for e in search.estimates]}
    curves = ai.identification.spline_curves    # kind: spline: the force curves
    if curves:
        view["restoring_force"] = {"curves": [dict(c.to_dict(), suggestion=c.suggestion)
                                              for c in curves]}
    # the physical modes of the answer: one per-update series each ("mode 3 (28.3 Hz)")
    physical = ai.identification.modes
    modes = {"frequency_hz": np.array([m["frequency_hz"] for m in physical]),
             "damping_ratio": np.array([m["damping_ratio"] for m in physical])}
    with np.errstate(divide="ignore", invalid="ignore"):
        log_sep = np.log10(res.separation_ratio) if res.separation_ratio > 0 else np.nan
    view["convergence"] = {"update": update.update, "acq_time_s": update.acq_time_s,
                           "values": {"natural_frequency_hz": modes["frequency_hz"],
                                      "damping_ratio": modes["damping_ratio"],
                                      "selected_order": [res.selected_order],
                                      "log10_separation_ratio": [log_sep]},
                           "coefficients": coefficient_means(ai),
                           "units": units.get("coefficients")}
    view["summary"] = summary_markdown(
        f"Identification update {update.update} ({update.n_periods} steady periods)",
        summary_rows(update), mode_table(res, left_out_hz(ai)))
    return view


def coefficient_means(ai: AutoIdentification) -> dict[str, float]:
    """Mean Re c_a over the excited lines, of the reduced model when there is one."""
    curves = ai.coefficient_curves.get("reduced") or ai.coefficient_curves.get("full") or {}
    band = np.asarray(ai.data.excited, dtype=bool)
    out = {}
    for name, curve in curves.items():
        c = np.asarray(curve)
        c = c[band] if c.size == band.size else c
        if c.size:
            out[name] = float(np.mean(c.real))
    return out


def summary_rows(update: ServiceUpdate) -> list[tuple[str, str]]:
    """Key/value rows of the result summary (the paper's Table 2 headline values)."""
    ai: AutoIdentification = update.result
    res = ai.result
    rows = [("periods averaged", str(update.n_periods)),
            ("selected order (IC)", str(res.selected_order)),
            ("MDI order", str(res.mdi_order)),
            ("physical modes", str(int(np.sum(res.physical)))),
            ("reduced order", str(res.reduced.order) if res.reduced is not None else "-"),
            ("separation ratio", f"{res.separation_ratio:.3g}"),
            ("confidence", str(res.confidence.get("level", ""))),
            ("identification time", f"{update.ident_s:.2f} s")]
    units = ai.identification.units["coefficients"]
    for which in ("full", "reduced"):
        for name, curve in (ai.coefficient_curves.get(which) or {}).items():
            band = np.asarray(ai.data.excited, dtype=bool)
            c = np.asarray(curve)[band] if np.size(curve) == band.size else np.asarray(curve)
            mean, std = float(np.mean(c.real)), float(np.std(c.real))
            unit = units.get(name, "")
            text = f"{mean:.5g} ± {std:.3g}" + (f" {unit}" if unit else "")
            exact = ai.exact_coefficients.get(name)
            if exact:
                text += f" (error {100 * (mean - exact) / exact:+.3f} %)"
            rows.append((f"{name}, {which} model", text))
    return rows


def left_out_hz(ai: AutoIdentification) -> list[float]:
    """Frequencies of the split modes the output-error refinement left out (Hz)."""
    evidence = getattr(ai.identification.session, "evidence", {}) or {}
    return [float(m["frequency_hz"]) for m in
            ((evidence.get("output_error") or {}).get("left_out") or [])]


def mode_table(res: Any, left_out_hz: Sequence[float] = ()) -> list[dict[str, Any]]:
    """One row per mode of the MDI order: frequency, damping, MDI, stabilisation and its fate
    (:mod:`ident.pole_fate`: physical, spurious by MDI, not detectable...)."""
    from fnsi_lab.ident.pole_fate import fate_label, pole_fates

    out = []
    rows = res.mdi_table()
    for row, fate in zip(rows, pole_fates(rows, res.confidence, left_out_hz)):
        if not row["in_band"]:
            continue
        out.append({"f (Hz)": round(row["frequency_hz"], 3),
                    "zeta (%)": round(100 * row["damping_ratio"], 3),
                    "MDI": float(f"{row[f'mdi_{res.options.mdi_norm}']:.3g}")
                    if f"mdi_{res.options.mdi_norm}" in row else None,
                    "stabilisation": row["stabilisation"],
                    "fate": fate_label(fate)})
    return out


# ---------------------------------------------------------------------------- ident config
def config_identifier(config: Any = None, *, truth: Mapping[str, Any] | None = None,
                      orders: Sequence[int] | str | None = None,
                      channels: Sequence[ChannelInfo] = (), harmonics: float = 1.0,
                      use_truth: bool = True) -> tuple[Identifier, str]:
    """``identify(record)`` running the one identification entry point on each snapshot.

    Every snapshot goes through :func:`fnsi_lab.ident.pipeline.identify_input` with the
    same configuration as ``fnsi-lab ident --auto`` would use (its ``auto:`` section
    included), so live, replayed and offline results agree.

    Parameters
    ----------
    config : IdentConfig or None
        Band, basis functions, driving points, options. None: the excited band and, for
        simulated recordings, the basis of ``truth``
        (:func:`fnsi_lab.ident.pipeline.default_config`).
    truth : mapping, optional
        Recording truth (nonlinear elements, exact coefficients).
    orders : str or sequence of int, optional
        Order sweep; default the config's ``auto.orders``, else
        :data:`fnsi_lab.ident.request.DEFAULT_ORDERS` (2..60, as ``fnsi-lab ident --auto``).
    channels : sequence of ChannelInfo
        The recording's channels (driving point when the config names none).
    harmonics : float
        Without a config and with basis functions: process the lines up to ``harmonics``
        times the highest excited frequency (see ``default_config``). 1: the excited band.
    use_truth : bool
        False: no basis from the truth (a linear identification without a config).

    Returns
    -------
    (callable, str)
        The identifier and a one-line description.
    """
    from dataclasses import replace

    from fnsi_lab.ident.options import parse_orders
    from fnsi_lab.ident.pipeline import identify_request
    from fnsi_lab.ident.request import DEFAULT_ORDERS, resolve_request
    from fnsi_lab.inputs import input_from_record

    # for the description only: each snapshot's request is resolved as `ident` resolves it
    sweep = (parse_orders(orders) if orders is not None
             else list(config.orders) if config is not None and config.orders
             else list(DEFAULT_ORDERS))
    outputs = [c for c in channels if not c.is_force]
    inputs = [c for c in channels if c.is_force]
    dp_name = outputs[driving_point(outputs, inputs)].name if outputs and inputs else None

    def identify(record: Any) -> AutoIdentification:
        import warnings

        inp = input_from_record(record, path="<live>")
        if not use_truth:
            inp = replace(inp, truth=None)
        elif inp.truth is None and truth is not None:
            inp = replace(inp, truth=dict(truth))
        request = resolve_request(inp, config, orders=orders, harmonics=harmonics,
                                  driving_point=dp_name)
        with warnings.catch_warnings():  # steady-state warnings go to the status, not stderr
            warnings.simplefilter("ignore")
            ident = identify_request(inp, request)
        curves: dict = {}
        if ident.config.nonlinearities:
            res = ident.auto
            curves["frequency_hz"] = ident.data.frequencies_hz
            for which, model in (("full", res.full_model), ("reduced", res.reduced)):
                if model is not None:
                    sp = ident.coefficient_spectra_of(model)
                    curves[which] = {n: sp.values[:, i] for i, n in enumerate(sp.names)}
        exact = {n: float(v) for nl in ident.config.nonlinearities if nl.truth is not None
                 for n, v in zip(nl.coefficient_names, nl.truth) if v is not None}
        return AutoIdentification(identification=ident, coefficient_curves=curves,
                                  exact_coefficients=exact)

    what = (f"robust pipeline, orders {sweep[0]}-{sweep[-1]}"
            + (f", config {config.file}" if config is not None and config.file else
               ", excited band" + (", basis from the recording truth" if use_truth else "")))
    return identify, what


def auto_identifier(*, orders: Sequence[int] | str | None = None) -> Identifier:
    """A linear ``identify(record)`` over the excited band (no config, no basis functions)."""
    return config_identifier(None, orders=orders, use_truth=False)[0]
