"""Acquisition: source -> bounded queues -> MCAP recorder and analysis taps.

Three parties run decoupled so that none can stall another:

- the *reader* (the calling thread) pulls blocks from the :class:`~daq.source.Source`;
- the *writer* thread owns the :class:`~daq.recording.writer.Recorder` (MCAP writers are
  single-threaded) and drains a bounded queue;
- each analysis :class:`Tap` (the live identification service, a viewer) has its own
  bounded queue that drops its *oldest* block when full, so a slow analysis never blocks
  acquisition; every drop is counted and reported.

A live source (hardware, or a simulated source paced at wall-clock speed) cannot wait, so
when the recorder queue is full the block is dropped and counted as an overflow; a finite
unpaced source (a simulation running as fast as it can) simply waits (back-pressure), so
nothing is ever lost. SIGINT/SIGTERM stop the reader; the writer then drains its queue and
finishes the file cleanly.
"""

from __future__ import annotations

import os
import queue
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.source import Source, SourceEvent
from fnsi_lab import __version__

if TYPE_CHECKING:  # pragma: no cover
    from fnsi_lab.daq.config import ExperimentConfig

_END = object()


def put_drop_oldest(q: "queue.Queue[Any]", item: Any) -> int:
    """Put ``item`` without ever blocking: when ``q`` is full, drop its oldest entries.

    Returns
    -------
    int
        How many entries were dropped (0 when there was room).
    """
    dropped = 0
    while True:
        try:
            q.put_nowait(item)
            return dropped
        except queue.Full:
            try:
                q.get_nowait()
                dropped += 1
            except queue.Empty:  # the consumer emptied it meanwhile
                pass


class Tap:
    """A bounded, drop-oldest queue of blocks for one analysis consumer.

    Parameters
    ----------
    name : str
        Shown in reports (``ident``, ``viewer``).
    maxsize : int
        Blocks held at most; when full, the oldest block is dropped and counted.
    """

    def __init__(self, name: str, maxsize: int = 256) -> None:
        self.name = name
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=max(int(maxsize), 1))
        self.dropped = 0
        self.closed = False

    def offer(self, block: Block) -> None:
        """Enqueue without ever blocking (drops and counts the oldest block if full)."""
        self.dropped += put_drop_oldest(self._queue, block)

    def close(self) -> None:
        """Signal the end of the stream to the consumer."""
        self.closed = True
        while True:
            try:
                self._queue.put_nowait(_END)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout: float | None = None) -> Block | None:
        """Next block; ``None`` on timeout. Raises :class:`StopIteration` at the end."""
        try:
            item = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is _END:
            raise StopIteration
        return item

    def __iter__(self) -> Iterator[Block]:
        while True:
            try:
                block = self.get(timeout=0.5)
            except StopIteration:
                return
            if block is not None:
                yield block


@dataclass
class AcquisitionReport:
    """What an acquisition did (printed by ``fnsi-lab acquire``)."""

    output: str
    blocks: int = 0
    samples: int = 0
    n_channels: int = 0
    sample_rate_hz: float = 0.0
    wall_time_s: float = 0.0
    #: Blocks dropped before the recorder (live sources only; 0 means nothing was lost).
    recorder_overflows: int = 0
    #: Blocks dropped per analysis tap (drop-oldest).
    tap_drops: dict[str, int] = field(default_factory=dict)
    #: Blocks the source itself reports lost (driver overrun, missing frames...).
    source_lost_blocks: int = 0
    source_problems: dict[str, int] = field(default_factory=dict)
    events: int = 0
    interrupted: bool = False
    file_size_bytes: int = 0

    @property
    def signal_duration_s(self) -> float:
        """Seconds of signal acquired."""
        return self.samples / self.sample_rate_hz if self.sample_rate_hz else 0.0

    @property
    def speed_vs_real_time(self) -> float:
        """Signal seconds per wall-clock second."""
        return self.signal_duration_s / self.wall_time_s if self.wall_time_s > 0 else float("inf")

    def summary(self) -> str:
        """Human-readable multi-line summary."""
        lines = [
            f"recorded {self.output}: {self.blocks} blocks, {self.samples} samples x "
            f"{self.n_channels} channels at {self.sample_rate_hz:g} Hz "
            f"({self.signal_duration_s:.2f} s of signal in {self.wall_time_s:.2f} s, "
            f"{self.speed_vs_real_time:.1f}x real time), {self.file_size_bytes / 1e6:.2f} MB",
            f"overflows: recorder {self.recorder_overflows}, "
            + (", ".join(f"{k} {v}" for k, v in self.tap_drops.items()) or "no analysis taps")
            + f"; source lost blocks {self.source_lost_blocks}; events {self.events}",
        ]
        if self.source_problems:
            lines.append("source problems: " + ", ".join(f"{k} {v}" for k, v in
                                                         sorted(self.source_problems.items())))
        if self.interrupted:
            lines.append("interrupted: the file was finished cleanly with everything acquired so far")
        return "\n".join(lines)


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """Set ``stop`` on SIGINT/SIGTERM while inside the block (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}

    def handler(signum: int, frame: Any) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _write_failed(recorder: Any, exc: OSError) -> Exception:
    """The one-line error of a failed write (disk full...): the file stays recoverable."""
    from fnsi_lab.daq.recording.errors import RecordingWriteError

    path = getattr(recorder, "path", "the recording")
    return RecordingWriteError(
        f"{path}: writing failed ({exc.strerror or exc}); everything flushed before stays "
        f"recoverable: free some space, then run `fnsi-lab recover {path} "
        f"{Path(str(path)).with_suffix('')}.recovered.mcap`")


def acquire(source: Source, recorder: Any, *, taps: Sequence[Tap] = (),
            live: bool | None = None, queue_blocks: int = 1024,
            max_duration_s: float | None = None, stop: threading.Event | None = None,
            on_block: Callable[[Block, AcquisitionReport], None] | None = None,
            chunk_signal_s: float = 1.0) -> AcquisitionReport:
    """Run ``source`` until it finishes (or ``stop`` is set), recording every block.

    Parameters
    ----------
    source : Source
        Started or not; it is started here and left open (the caller closes it).
    recorder : Recorder or None
        Owns the MCAP file (``write_block``, ``write_event``, ``write_json``); written
        from a dedicated thread. ``None`` acquires without recording.
    taps : sequence of Tap
        Analysis consumers; each gets every block (drop-oldest when it falls behind) and
        is closed at the end.
    live : bool or None
        True: never wait for the recorder (drop and count when its queue is full).
        None: live if the source is paced (``source._pace``) or has no natural end.
    queue_blocks : int
        Capacity of the recorder queue, in blocks.
    max_duration_s : float or None
        Stop after this much signal.
    stop : threading.Event or None
        Set it (from any thread, or via SIGINT/SIGTERM) to stop cleanly.
    on_block : callable or None
        Called in the reader thread after each block (status display).
    chunk_signal_s : float
        Seconds of signal a chunk of the recorder holds at most (besides its own wall-clock
        flush interval), so that a damaged chunk loses at most this much; applied by the
        :class:`~daq.recording.writer.Recorder` itself (``max_chunk_signal_s``).

    Returns
    -------
    AcquisitionReport
    """
    if live is None:
        live = getattr(source, "_pace", None) is not None or getattr(source, "is_live", False)
    if int(queue_blocks) < 1:
        raise ValueError(f"queue_blocks must be >= 1, got {queue_blocks}")
    stop = stop or threading.Event()
    report = AcquisitionReport(output=str(getattr(recorder, "path", "") or ""),
                               n_channels=len(source.channels),
                               sample_rate_hz=source.sample_rate_hz)
    work: queue.Queue[Any] = queue.Queue(maxsize=max(int(queue_blocks), 1))
    writer_error: list[BaseException] = []

    # at most a second of signal per chunk: a damaged chunk then costs at most one second,
    # also when a simulation is recorded far faster than real time (counted in samples by
    # the recorder: ten 0.1 s blocks summed in floats stayed below 1.0 and made 1.1 s chunks)
    if recorder is not None and hasattr(recorder, "max_chunk_signal_s"):
        recorder.max_chunk_signal_s = float(chunk_signal_s)

    def writer() -> None:
        while True:
            item = work.get()
            if item is _END:
                return
            if writer_error:
                continue  # keep draining so the reader never blocks on a dead writer
            try:
                kind, payload = item
                if kind == "block":
                    recorder.write_block(payload)
                elif kind == "event":
                    recorder.write_event(payload)
                else:
                    topic, time_ns, obj = payload
                    recorder.write_json(topic, time_ns, obj)
            except OSError as exc:  # disk full, file too large, I/O error
                writer_error.append(_write_failed(recorder, exc))
            except BaseException as exc:  # reported by the reader thread
                writer_error.append(exc)

    thread = None
    if recorder is not None:
        thread = threading.Thread(target=writer, name="fnsi-lab-recorder", daemon=True)
        thread.start()

    def put(item: Any, essential: bool) -> None:
        if recorder is None:
            return
        if live:
            try:
                work.put_nowait(item)
            except queue.Full:
                if essential:
                    report.recorder_overflows += 1
        else:
            work.put(item)

    t_start = time.monotonic()
    try:
        with stop_on_signals(stop):
            source.start()
            while not stop.is_set() and not source.finished:
                if writer_error:
                    raise writer_error[0]
                block = source.read(timeout=0.2)
                for event in source.drain_events():
                    report.events += 1
                    put(("event", event), essential=False)
                drain_raw = getattr(source, "drain_raw_frames", None)
                if drain_raw is not None:
                    for topic, time_ns, obj in drain_raw():
                        put(("json", (topic, time_ns, obj)), essential=False)
                if block is None:
                    continue
                put(("block", block), essential=True)
                for tap in taps:
                    tap.offer(block)
                report.blocks += 1
                report.samples += block.n_samples
                if on_block is not None:
                    on_block(block, report)
                if max_duration_s is not None and report.signal_duration_s >= max_duration_s:
                    break
            report.interrupted = stop.is_set()
            for event in source.drain_events():
                report.events += 1
                put(("event", event), essential=False)
    finally:
        for tap in taps:
            tap.close()
        if thread is not None:
            work.put(_END)  # blocking: the writer is draining
            thread.join()
        report.wall_time_s = time.monotonic() - t_start
        report.tap_drops = {tap.name: tap.dropped for tap in taps}
        report.source_lost_blocks = source.stats.lost_blocks
        report.source_problems = dict(source.stats.problems)
    if writer_error:
        raise writer_error[0]
    return report


def recording_metadata(config: "ExperimentConfig", source: Source) -> dict[str, Any]:
    """The metadata records of a recording: experiment, channels, then ``source.describe()``."""
    metadata: dict[str, Any] = {
        "experiment": {"name": config.name, "source_kind": config.source.kind,
                       "config_file": config.file, "software": "fnsi-lab",
                       "software_version": __version__,
                       "sample_rate_hz": source.sample_rate_hz, "block_size": config.block_size},
        "channels": [c.to_dict() for c in source.channels],
    }
    # a source may hold back what it knows only after the run (describe_at_end)
    metadata.update(getattr(source, "describe_at_start", source.describe)())
    if "excitation" not in metadata and config.excitation is not None:
        metadata["excitation"] = {**config.excitation.to_dict(),
                                  "sample_rate_hz": config.sample_rate_hz}
    return metadata


def record_experiment(config: "ExperimentConfig", output: str | os.PathLike[str] | None = None, *,
                      realtime: bool = False, taps: Sequence[Tap] = (),
                      stop: threading.Event | None = None,
                      on_block: Callable[[Block, AcquisitionReport], None] | None = None,
                      source: Source | None = None) -> AcquisitionReport:
    """Build the experiment's source, record it to MCAP and return the report.

    Parameters
    ----------
    config : ExperimentConfig
        The experiment.
    output : path, optional
        MCAP file (default ``config.output``).
    realtime : bool
        Pace a simulated source at wall-clock speed, as hardware would deliver.
    taps, stop, on_block
        See :func:`acquire`.
    source : Source, optional
        Use this source instead of building one from ``config`` (it is closed here).
    """
    from fnsi_lab.daq.recording.writer import Recorder
    from fnsi_lab.daq.registry import make_source

    path = Path(output if output is not None else config.output)
    if source is None:
        source = make_source(config, pace=1.0) if realtime else make_source(config)
    with source:
        attachments = []
        if config.text:
            attachments.append(("experiment.yaml", "application/yaml", config.text.encode()))
        at_end = getattr(source, "describe_at_end", None)
        truth_attachments = getattr(source, "truth_attachments", None)
        if at_end is None and truth_attachments is not None:
            attachments.extend(truth_attachments())
        # paced: a chunk every 0.25 s, so a killed recording loses at most that much
        with Recorder(path, source.channels, source.sample_rate_hz,
                      metadata=recording_metadata(config, source),
                      attachments=attachments,
                      flush_interval_s=0.25 if realtime else 1.0) as recorder:
            report = acquire(source, recorder, taps=taps, stop=stop, on_block=on_block,
                             live=True if realtime else None)
            if at_end is not None:  # the complete truth: readers keep the last record
                metadata, late = at_end(finished=not report.interrupted)
                try:
                    for key, value in metadata.items():
                        recorder.add_metadata(key, value)
                    for name, media_type, data in late:
                        recorder.add_attachment(name, media_type, data)
                except OSError as exc:
                    raise _write_failed(recorder, exc) from None
    report.output = str(path)
    report.file_size_bytes = path.stat().st_size if path.exists() else 0
    return report
