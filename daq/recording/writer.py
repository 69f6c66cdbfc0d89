"""``Recorder``: writes sample blocks, events and metadata into one MCAP file.

Layout (see ``docs/recording-format.md``): the header, the metadata records and the
attachments come first, so a crashed recording keeps them; then zstd-compressed chunks of
sample blocks (protobuf), events and auxiliary JSON topics; the summary (schemas, channels,
statistics, chunk/metadata/attachment indexes) is written by :meth:`Recorder.close`.

Threading: a Recorder is written from ONE thread (mcap's ``Writer`` has no locking); the
acquisition loop owns it. :meth:`Recorder.close` may be called from another thread or from a
signal-triggered path: if a write is in progress it only requests the close, which the
writing call performs as soon as it returns.
"""

from __future__ import annotations

import os
import threading
import time
import weakref
from pathlib import Path
from typing import Any, Iterable, Literal, Mapping, Sequence

import numpy as np
from mcap.writer import CompressionType, Writer

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.recording import schema, topics
from fnsi_lab.daq.recording.errors import (RecorderClosedError, RecordingError,
                                           RecordingWriteError)
from fnsi_lab.errors import ConfigError
from fnsi_lab.outputs import dumps as _dumps

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}

#: Recorders not closed yet (tests use it to fail a test that leaks an open file).
_OPEN: "weakref.WeakSet[Recorder]" = weakref.WeakSet()


def open_recorders() -> list["Recorder"]:
    """Recorders created in this process and not closed yet."""
    return [r for r in list(_OPEN) if not r.closed]


#: An attachment: (name, media type, content).
Attachment = tuple[str, str, bytes]


def software_version() -> str:
    """Version of fnsi-lab stored in every recording."""
    from fnsi_lab import __version__
    return __version__


def dumps(obj: Any) -> str:
    """JSON text of a metadata record, event or auxiliary message: the one encoder
    (:func:`fnsi_lab.outputs.dumps`: strict JSON, NaN and infinities as null, numpy values
    as Python ones), compact, and a ``TypeError`` for values that are not data.

    Recordings written before used Python's ``NaN``/``Infinity`` tokens; the reader
    (Python's ``json``) still reads them.
    """
    return _dumps(obj, unknown="error", separators=(",", ":"))


class Recorder:
    """Context manager that records one experiment into one MCAP file.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten if it exists).
    channels : sequence of ChannelInfo, length n_channels
        Columns of every block; stored in the samples channel's metadata and in the
        ``fnsi_lab.channels`` metadata record.
    sample_rate_hz : float
        Nominal sampling rate.
    metadata : dict of str to JSON-able, optional
        Each key ``k`` becomes the metadata record ``fnsi_lab.k`` = ``{"json": <text>}``.
        Standard keys: ``experiment``, ``excitation``, ``truth``, ``source``; ``channels``
        is written from ``channels`` and the software version is always added to
        ``experiment``.
    attachments : list of (name, media_type, bytes), optional
        E.g. ``("experiment.yaml", "application/yaml", text.encode())`` or a truth FRF
        as ``.npz`` bytes.
    flush_interval_s : float, optional
        The open chunk is closed and written at least this often (wall clock, checked at
        every write), so a crash loses at most about this much data.
    chunk_size : int, optional
        Uncompressed bytes after which a chunk is closed anyway (bounds memory).
    max_chunk_signal_s : float, optional
        Seconds of signal a chunk holds at most: the open chunk is closed before a block
        would take it past this (a single longer block is a chunk of its own), so a damaged
        chunk costs at most this much signal however fast the source runs (docs/cli.md).
    compression : {'zstd', 'lz4', 'none'}, optional
        Chunk compression.

    Raises
    ------
    RecordingError
        If the file cannot be created.

    Notes
    -----
    Log and publish times of sample messages are wall-clock UTC nanoseconds: the
    acquisition start (``start_utc_ns``) plus the block's sample time since the first block
    (``block.t0_ns - first.t0_ns``); the sample clock ``t0_ns`` itself stays in the payload.
    Events use their own ``time_ns`` (wall clock). Data are stored as float32: float32 blocks
    round-trip bit for bit, float64 blocks are rounded once.

    Examples
    --------
    >>> with Recorder("run.mcap", channels, 1000.0, metadata={"excitation": exc}) as rec:
    ...     for block in source:
    ...         rec.write_block(block)
    """

    def __init__(self, path: str | os.PathLike[str], channels: Sequence[ChannelInfo],
                 sample_rate_hz: float, *, metadata: Mapping[str, Any] | None = None,
                 attachments: Iterable[Attachment] = (), flush_interval_s: float = 1.0,
                 chunk_size: int = 1 << 20,
                 compression: Literal["zstd", "lz4", "none"] = "zstd",
                 start_utc_ns: int | None = None, max_chunk_signal_s: float = 1.0) -> None:
        channels = tuple(channels)
        if not channels:
            raise ConfigError("a recording needs at least one channel")
        names = [c.name for c in channels]
        if len(set(names)) != len(names):
            raise ConfigError(f"duplicate channel names in {plain.names(names)}")
        if not sample_rate_hz > 0:
            raise ConfigError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        if compression not in _COMPRESSION:
            raise ConfigError(f"compression must be one of {plain.names(sorted(_COMPRESSION))}, got {plain.value(compression)}")
        if not flush_interval_s > 0:
            raise ConfigError(f"flush_interval_s must be > 0, got {flush_interval_s}")
        if not max_chunk_signal_s > 0:
            raise ConfigError(f"max_chunk_signal_s must be > 0, got {max_chunk_signal_s}")
        self.path = Path(path)
        self.channels = channels
        self.sample_rate_hz = float(sample_rate_hz)
        self.flush_interval_s = float(flush_interval_s)
        self.max_chunk_signal_s = float(max_chunk_signal_s)
        self._chunk_samples = 0  # samples in the open chunk (integer: no rounding drift)
        self._names = tuple(names)
        self._lock = threading.Lock()  # held during each write; close() never blocks on it
        self._close_requested = False
        self._closed = False
        self.blocks_written = 0
        self.samples_written = 0
        self.events_written = 0
        #: Blocks handed to the OS by the last flush (what survives a crash of this process).
        self.blocks_flushed = 0
        #: Wall-clock UTC ns of the acquisition start: log time of the first sample block.
        self.start_utc_ns = int(time.time_ns() if start_utc_ns is None else start_utc_ns)
        self._log_time_offset_ns: int | None = None  # log time - t0_ns, set by the 1st block
        try:
            self._stream = open(self.path, "wb")
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot create the recording ({exc.strerror}); "
                                 "check that the folder exists and is writable") from None
        try:
            self._writer = Writer(self._stream, chunk_size=int(chunk_size),
                                  compression=_COMPRESSION[compression])
            self._writer.start(profile=topics.PROFILE,
                               library=f"{topics.LIBRARY_PREFIX} {software_version()}")
            self._write_metadata(dict(metadata or {}))
            now = time.time_ns()
            for name, media_type, data in attachments:
                self._writer.add_attachment(create_time=now, log_time=now, name=name,
                                            media_type=media_type, data=bytes(data))
            self._register_channels()
            self._aux_channels: dict[str, int] = {}
            self._aux_schema_id: int | None = None
            # Header, metadata and attachments reach the OS now: a crash keeps them.
            self._writer.flush()
        except BaseException:
            self._stream.close()
            raise
        self._last_flush = time.monotonic()
        _OPEN.add(self)

    # ------------------------------------------------------------------ setup
    def _write_metadata(self, metadata: dict[str, Any]) -> None:
        experiment = dict(metadata.pop(topics.META_EXPERIMENT, None) or {})
        experiment.setdefault(topics.SOFTWARE_VERSION_KEY, software_version())
        metadata.pop(topics.META_CHANNELS, None)  # always the table actually recorded
        clock = {"acquisition_start_utc_ns": self.start_utc_ns,
                 "log_time": "wall-clock UTC ns = acquisition_start_utc_ns + (t0_ns - t0_ns of "
                             "the first sample block); t0_ns (sample clock) is in the payload"}
        records = {topics.META_EXPERIMENT: experiment,
                   topics.META_CHANNELS: [c.to_dict() for c in self.channels],
                   topics.META_CLOCK: clock, **metadata}
        for key, value in records.items():
            self._add_metadata_record(key, value)

    def _add_metadata_record(self, key: str, value: Any) -> None:
        try:
            text = dumps(value)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"metadata {key!r} is not JSON-able: {exc}") from None
        name = topics.metadata_record_name(key)
        self._writer.add_metadata(name, {topics.METADATA_JSON_KEY: text,
                                         topics.METADATA_CRC_KEY: topics.metadata_crc(name, text)})

    def _register_channels(self) -> None:
        sid = self._writer.register_schema(topics.SAMPLES_SCHEMA_NAME,
                                           topics.SCHEMA_ENCODING_PROTOBUF, schema.schema_bytes())
        meta = {topics.CHANNEL_META_CHANNELS: dumps([c.to_dict() for c in self.channels]),
                topics.CHANNEL_META_SAMPLE_RATE: repr(self.sample_rate_hz),
                topics.CHANNEL_META_LAYOUT: topics.LAYOUT_ROW_MAJOR,
                topics.CHANNEL_META_FORMAT: topics.FORMAT_VERSION}
        self._samples_channel = self._writer.register_channel(
            topics.TOPIC_SAMPLES, topics.MESSAGE_ENCODING_PROTOBUF, sid, meta)
        eid = self._writer.register_schema(topics.EVENTS_SCHEMA_NAME,
                                           topics.SCHEMA_ENCODING_JSONSCHEMA,
                                           schema.event_schema_bytes())
        self._events_channel = self._writer.register_channel(
            topics.TOPIC_EVENTS, topics.MESSAGE_ENCODING_JSON, eid, {})

    # ------------------------------------------------------------------ state
    @property
    def closed(self) -> bool:
        """True once the file is finished (summary and footer written)."""
        return self._closed

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc: object) -> None:
        # Finish the file even on an exception: what was recorded stays readable.
        self.close()

    def _begin(self) -> None:
        # Only close() competes for the lock (one writing thread by contract), and it
        # holds it for the time of finish() at most.
        self._lock.acquire()
        if self._closed or self._close_requested:
            self._lock.release()
            raise RecorderClosedError(f"{self.path}: write to a closed recorder; "
                                      "open a new Recorder")

    def _flush_chunk(self) -> None:
        """Close the open chunk and hand it to the OS (the lock is held)."""
        self._writer.flush()
        self._last_flush = time.monotonic()
        self.blocks_flushed = self.blocks_written
        self._chunk_samples = 0

    def _end(self) -> None:
        try:
            now = time.monotonic()
            if now - self._last_flush >= self.flush_interval_s:
                self._flush_chunk()
        finally:
            self._lock.release()
        if self._close_requested:  # close() arrived (signal/other thread) during the write
            self.close()

    # ------------------------------------------------------------------ writing
    def write_block(self, block: Block) -> None:
        """Append one block of samples (one protobuf message on the samples topic).

        Parameters
        ----------
        block : Block
            ``block.data`` shape (n_samples, n_channels) with the recorder's channels;
            ``block.t0_ns`` (>= 0) is stored in the payload; the message log time is
            ``start_utc_ns`` plus ``t0_ns`` since the first block.

        Raises
        ------
        RecorderClosedError
            After :meth:`close`.
        ValueError
            If the block's columns do not match the recorder's channels.
        """
        data = block.data
        if data.ndim != 2 or data.shape[1] != len(self._names):
            raise ConfigError(f"block of shape {data.shape} does not match the "
                             f"{len(self._names)} recorded channels")
        if block.channels is not self.channels and tuple(c.name for c in block.channels) != self._names:
            raise ConfigError("block channels differ from the recorder's channel table")
        if block.t0_ns < 0:
            raise ConfigError(f"block t0_ns must be >= 0 (MCAP log times are unsigned), got {block.t0_ns}")
        payload = schema.encode_block(data, first_sample=block.first_sample,
                                      realization=block.realization,
                                      sample_rate_hz=block.sample_rate_hz, t0_ns=block.t0_ns,
                                      sequence=block.sequence)
        if self._log_time_offset_ns is None:
            self._log_time_offset_ns = self.start_utc_ns - int(block.t0_ns)
        log_time = max(int(block.t0_ns) + self._log_time_offset_ns, 0)
        n = int(data.shape[0])
        limit = max(int(round(self.max_chunk_signal_s * float(block.sample_rate_hz
                                                              or self.sample_rate_hz))), 1)
        self._begin()
        try:
            if self._chunk_samples and self._chunk_samples + n > limit:
                self._flush_chunk()  # this block would take the chunk past the limit
            # MCAP's message sequence is uint32; the full counter is in the payload.
            self._writer.add_message(self._samples_channel, log_time=log_time,
                                     data=payload, publish_time=log_time,
                                     sequence=int(block.sequence) & 0xFFFFFFFF)
            self.blocks_written += 1
            self.samples_written += n
            self._chunk_samples += n
            if self._chunk_samples >= limit:
                self._flush_chunk()
        finally:
            self._end()

    def write_event(self, event: Any) -> None:
        """Append a :class:`daq.source.SourceEvent` (JSON on the events topic).

        Its ``time_ns`` is the log time (clamped at 0).
        """
        payload = dumps({"time_ns": int(event.time_ns), "kind": str(event.kind),
                         "detail": dict(event.detail)}).encode()
        self._begin()
        try:
            t = max(int(event.time_ns), 0)
            self._writer.add_message(self._events_channel, log_time=t, data=payload,
                                     publish_time=t, sequence=self.events_written & 0xFFFFFFFF)
            self.events_written += 1
        finally:
            self._end()

    def write_json(self, topic: str, time_ns: int, obj: Any) -> None:
        """Append a JSON message on an auxiliary topic (raw CAN frames, instrument status...).

        The channel is registered on first use, with a permissive JSON schema.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``/can/raw``; not one of the fnsi-lab topics.
        time_ns : int
            Log time, integer nanoseconds (>= 0).
        obj : JSON-able
            Message content (numpy scalars and arrays are converted).
        """
        if topic in (topics.TOPIC_SAMPLES, topics.TOPIC_EVENTS):
            raise ConfigError(f"topic {topic!r} is reserved; use write_block/write_event")
        payload = dumps(obj).encode()
        self._begin()
        try:
            cid = self._aux_channels.get(topic)
            if cid is None:
                if self._aux_schema_id is None:
                    self._aux_schema_id = self._writer.register_schema(
                        topics.AUX_JSON_SCHEMA_NAME, topics.SCHEMA_ENCODING_JSONSCHEMA,
                        schema.aux_schema_bytes())
                cid = self._writer.register_channel(topic, topics.MESSAGE_ENCODING_JSON,
                                                    self._aux_schema_id, {})
                self._aux_channels[topic] = cid
            t = max(int(time_ns), 0)
            self._writer.add_message(cid, log_time=t, data=payload, publish_time=t)
        finally:
            self._end()

    def add_metadata(self, key: str, value: Any) -> None:
        """Write one more metadata record ``fnsi_lab.<key>`` now (e.g. run statistics at the
        end). A key written twice: readers keep the last record."""
        self._begin()
        try:
            self._add_metadata_record(key, value)
        finally:
            self._end()

    def add_attachment(self, name: str, media_type: str, data: bytes) -> None:
        """Write one more attachment now (e.g. a truth FRF known only at the end of a run)."""
        self._begin()
        try:
            now = time.time_ns()
            self._writer.add_attachment(create_time=now, log_time=now, name=name,
                                        media_type=media_type, data=bytes(data))
        finally:
            self._end()

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS now (no fsync)."""
        self._begin()
        try:
            self._flush_chunk()
        finally:
            self._lock.release()
        if self._close_requested:
            self.close()

    def maybe_flush(self) -> None:
        """Flush if ``flush_interval_s`` has passed since the last flush.

        Call it when the writing thread is idle (e.g. on a queue timeout): writes already
        check the interval, but a stalled source produces no writes.
        """
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()

    def close(self) -> bool:
        """Finish the file (summary, indexes, footer), fsync and close it. Idempotent.

        Safe from a signal handler or another thread: if a write is in progress, the close
        is deferred to the end of that write.

        Returns
        -------
        bool
            True if the file is finished, False if the close was deferred.

        Raises
        ------
        RecordingError
            If the summary cannot be written (disk full...); the data already flushed
            remain recoverable with ``fnsi-lab recover``.
        """
        if self._closed:
            return True
        if not self._lock.acquire(blocking=False):
            self._close_requested = True
            return False
        try:
            if self._closed:
                return True
            self._closed = True
            try:
                self._writer.finish()
                self._stream.flush()
                self.blocks_flushed = self.blocks_written
                os.fsync(self._stream.fileno())
            except OSError as exc:
                raise RecordingWriteError(f"{self.path}: could not finish the recording ({exc}); "
                                     f"run `fnsi-lab recover {self.path} FIXED.mcap`") from None
            finally:
                try:
                    self._stream.close()
                except OSError:  # its buffer could not be written either (disk full)
                    pass
                _OPEN.discard(self)
        finally:
            self._lock.release()
        return True

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return (f"Recorder({str(self.path)!r}, {len(self.channels)} channels, "
                f"{self.blocks_written} blocks, {state})")


def experiment_attachment(text: str) -> Attachment:
    """The ``experiment.yaml`` attachment for an experiment's YAML text."""
    return (topics.ATTACHMENT_EXPERIMENT_YAML, topics.MEDIA_TYPE_YAML, text.encode())
