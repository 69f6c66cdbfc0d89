"""Replay an MCAP recording as a :class:`~daq.source.Source`: live and replayed data take one path.

The recording is read record by record with mcap's streaming reader, so the same code
reads a finished file, a file whose writer crashed (every complete chunk, then the end)
and a file that is still being written (``follow=True``: the reader waits for new bytes
until the footer arrives or the file stops growing for ``follow_timeout_s``). Pacing is the
base class's (``speed`` = recorded time per wall-clock time; ``None`` = as fast as possible),
in the pattern of python-can's ``MessageSync``.
"""

from __future__ import annotations

import logging

import json
import os
import queue
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.exceptions import EndOfFile
from mcap.stream_reader import StreamReader

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.recording import schema as block_schema
from fnsi_lab.daq.recording import topics
from fnsi_lab.daq.source import Source
from fnsi_lab.errors import ConfigError, DataFileError

if TYPE_CHECKING:  # pragma: no cover
    from fnsi_lab.daq.config import ExperimentConfig

#: Default seconds without file growth after which a followed recording is considered over.
DEFAULT_FOLLOW_TIMEOUT_S = 10.0
_POLL_S = 0.02
_MAGIC = b"\x89MCAP0\r\n"
_END = object()


class ReplayError(DataFileError):
    """The recording cannot be replayed (not MCAP, no sample channel, no channel table)."""


class _TailReader:
    """A ``read(n)`` over a file that may still grow: waits for bytes instead of hitting EOF.

    Raises mcap's ``EndOfFile`` on a short read: at once when ``follow`` is False, else once
    ``stop`` is set or after ``timeout_s`` without growth.
    """

    def __init__(self, path: Path, *, follow: bool, timeout_s: float,
                 stop: threading.Event) -> None:
        self._f = open(path, "rb")
        self._follow = follow
        self._timeout_s = timeout_s
        self._stop = stop
        self.timed_out = False
        #: Set to stop waiting as soon as no new byte is available (header scans).
        self.stop_when_idle = False

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        if n is None or n < 0 or len(data) == n:
            return data
        if not self._follow:  # short read: the file ends inside a record
            raise EndOfFile()
        parts = [data]
        got = len(data)
        last_growth = time.monotonic()
        while got < n and not self._stop.is_set():
            time.sleep(_POLL_S)
            more = self._f.read(n - got)
            if more:
                parts.append(more)
                got += len(more)
                last_growth = time.monotonic()
            elif self.stop_when_idle:
                break
            elif time.monotonic() - last_growth > self._timeout_s:
                self.timed_out = True
                break
        if got < n:  # gave up waiting: the record is cut (see _iter_records)
            raise EndOfFile()
        return b"".join(parts)

    def close(self) -> None:
        self._f.close()


def _iter_records(path: Path, *, follow: bool, timeout_s: float, stop: threading.Event,
                  on_end: Callable[[str], None],
                  tail_out: list[_TailReader] | None = None,
                  validate_crcs: bool = True) -> Iterator[Any]:
    """Yield MCAP records (chunk contents broken up) until the footer or the end of data.

    ``on_end`` receives why the stream ended: ``footer``, ``timeout``, ``stopped``,
    ``truncated``, or ``damaged: <what>`` (a CRC mismatch or a record that does not
    decode although it was read whole).
    """
    tail = _TailReader(path, follow=follow, timeout_s=timeout_s, stop=stop)
    if tail_out is not None:
        tail_out.append(tail)
    reason = "truncated"
    try:
        for record in StreamReader(tail, validate_crcs=validate_crcs).records:  # type: ignore[arg-type]
            yield record
            if isinstance(record, (Footer, DataEnd)):
                reason = "footer"
                return
    except EndOfFile:  # a cut-off file (crashed writer) or a followed file that stopped
        pass
    except Exception as exc:  # noqa: BLE001 - CRC, decompression, struct: damaged bytes
        if not (stop.is_set() or tail.timed_out):
            reason = f"damaged: {type(exc).__name__}: {exc}"
    finally:
        if reason == "truncated":
            reason = "stopped" if stop.is_set() else "timeout" if tail.timed_out else "truncated"
        tail.close()
        on_end(reason)


class ReplaySource(Source):
    """Deliver the sample blocks of an fnsi-lab MCAP recording, in recorded order.

    Parameters
    ----------
    path : str or Path
        The recording (finished, crashed, or still being written with ``follow=True``).
    speed : float or None, optional
        Recorded seconds per wall-clock second (1.0 = recorded speed); ``None`` replays as
        fast as possible.
    follow : bool, optional
        Keep reading new chunks of a file that is still being written, until its footer
        arrives or it has not grown for ``follow_timeout_s``.
    follow_timeout_s : float, optional
        See ``follow``; also how long the constructor waits for the channel table of a
        file that has just been created.
    validate_crcs : bool or None, optional
        Check chunk CRCs (default: on, unless ``--no-crc-check``); a damaged chunk ends the
        replay with ``end_reason == "damaged"``.

    Attributes
    ----------
    metadata : dict
        Metadata key (``experiment``, ``excitation``, ``truth``...) -> parsed JSON.
    end_reason : str or None
        ``footer`` (complete file), ``timeout`` (followed file stopped growing),
        ``truncated`` (file cut off, e.g. a crashed writer), ``damaged`` (CRC mismatch or
        undecodable record: ``end_detail`` says where) or ``stopped`` (closed early).

    Raises
    ------
    ReplayError
        The file does not exist, is not MCAP, or holds no fnsi-lab sample channel.

    Examples
    --------
    >>> with ReplaySource("smallsat.mcap", speed=10.0) as src:   # doctest: +SKIP
    ...     for block in src:
    ...         print(block.sequence, block.data.shape)
    """

    kind = "replay"

    def __init__(self, path: str | os.PathLike[str], *, speed: float | None = None,
                 follow: bool = False,
                 follow_timeout_s: float = DEFAULT_FOLLOW_TIMEOUT_S,
                 validate_crcs: bool | None = None) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise ReplayError(f"{self.path}: no such recording")
        if speed is not None and not speed > 0:
            raise ConfigError(f"replay speed must be > 0, got {speed}", field="speed",
                              fix="use e.g. --speed 1 for recorded speed, or omit it")
        if not follow_timeout_s > 0:
            raise ConfigError(f"follow_timeout_s must be > 0, got {follow_timeout_s}",
                              field="follow_timeout_s")
        with open(self.path, "rb") as f:
            magic = f.read(len(_MAGIC))
        if magic != _MAGIC[:len(magic)] or (len(magic) < len(_MAGIC) and not follow):
            raise ReplayError(f"{self.path}: not an MCAP recording (bad magic bytes)")
        self.follow = bool(follow)
        self.follow_timeout_s = float(follow_timeout_s)
        self.metadata: dict[str, Any] = {}
        self.end_reason: str | None = None
        #: One-line description when ``end_reason == "damaged"``.
        self.end_detail = ""
        if validate_crcs is None:
            from fnsi_lab.daq.recording import reader
            validate_crcs = reader._CHECK_CRCS_BY_DEFAULT
        self.validate_crcs = bool(validate_crcs)
        self.events_seen = 0
        channels, rate = self._read_header()
        super().__init__(channels, rate, pace=speed)
        self._stop_event = threading.Event()
        self._records: Iterator[Any] | None = None
        self._samples_channel_ids: set[int] = set()
        self._events_channel_ids: set[int] = set()
        # follow mode: a thread tails the file so read(timeout) can honour its timeout
        self._queue: queue.Queue[Any] | None = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ construction
    def _read_header(self) -> tuple[list[ChannelInfo], float]:
        """Scan the records before the first message: metadata and the samples channel."""
        stop = threading.Event()
        ended: list[str] = []
        tails: list[_TailReader] = []
        early = None
        try:
            records = _iter_records(self.path, follow=self.follow,
                                    timeout_s=self.follow_timeout_s, stop=stop,
                                    on_end=ended.append, tail_out=tails)
            for record in records:
                if isinstance(record, Metadata):
                    self._take_metadata(record)
                    early = self._header_from_metadata()
                    if early is not None and tails:
                        # every metadata record is written at once when a recording
                        # starts: read what is there, but do not wait for the first chunk
                        tails[0].stop_when_idle = True
                elif isinstance(record, Channel) and record.topic == topics.TOPIC_SAMPLES:
                    meta = record.metadata
                    try:
                        table = json.loads(meta[topics.CHANNEL_META_CHANNELS])
                        rate = float(meta[topics.CHANNEL_META_SAMPLE_RATE])
                    except (KeyError, ValueError) as exc:
                        raise ReplayError(f"{self.path}: the samples channel has no valid "
                                          f"channel table or sample rate ({exc})") from None
                    stop.set()
                    records.close()  # type: ignore[attr-defined]
                    return [ChannelInfo.from_dict(c) for c in table], rate
                elif isinstance(record, Message):
                    break
        except ReplayError:
            raise
        except Exception as exc:  # not MCAP at all (bad magic...)
            raise ReplayError(f"{self.path}: not an MCAP recording ({exc})") from None
        if early is not None:
            return early
        raise ReplayError(f"{self.path}: no {topics.TOPIC_SAMPLES} channel found "
                          f"({ended[0] if ended else 'end of file'}); is it an fnsi-lab "
                          "recording?")

    def _header_from_metadata(self) -> tuple[list[ChannelInfo], float] | None:
        """Channels and rate from the metadata records (written before any chunk), if there."""
        table = self.metadata.get(topics.META_CHANNELS)
        if not isinstance(table, list) or not table:
            return None
        for key in (topics.META_EXPERIMENT, topics.META_SOURCE, topics.META_EXCITATION):
            rec = self.metadata.get(key)
            rate = rec.get("sample_rate_hz") if isinstance(rec, dict) else None
            if isinstance(rate, (int, float)) and rate > 0:
                return [ChannelInfo.from_dict(c) for c in table], float(rate)
        return None

    def _take_metadata(self, record: Metadata) -> None:
        if record.name.startswith(topics.METADATA_PREFIX):
            key = record.name[len(topics.METADATA_PREFIX):]
            text = record.metadata.get(topics.METADATA_JSON_KEY)
            try:
                self.metadata[key] = json.loads(text) if text is not None else None
            except ValueError:
                self.metadata[key] = text

    @classmethod
    def from_config(cls, config: "ExperimentConfig", *, pace: float | None = None,
                    **kwargs: Any) -> "ReplaySource":
        """Build from ``source: {kind: replay, options: {path, speed, follow, follow_timeout_s}}``.

        ``pace`` (when given) overrides ``options.speed``.
        """
        opts = dict(config.source.options)
        unknown = sorted(set(opts) - {"path", "speed", "follow", "follow_timeout_s"})
        if unknown:
            raise config.error(f"source.options.{unknown[0]}", "unknown replay option",
                               fix="use path, speed, follow, follow_timeout_s")
        if "path" not in opts:
            raise config.error("source.options.path", "a replay source needs the recording",
                               fix="add options: {path: FILE.mcap}")
        path = Path(str(opts["path"]))
        if config.file and not path.is_absolute():
            path = Path(config.file).parent / path
        speed = pace if pace is not None else opts.get("speed")
        return cls(path, speed=None if speed is None else float(speed),
                   follow=bool(opts.get("follow", False)),
                   follow_timeout_s=float(opts.get("follow_timeout_s", DEFAULT_FOLLOW_TIMEOUT_S)),
                   **kwargs)

    # ------------------------------------------------------------------ reading
    def _next_block(self) -> Block | None:
        """Decode records up to the next sample message; None at the end of the data."""
        if self._records is None:
            self._records = _iter_records(self.path, follow=self.follow,
                                          timeout_s=self.follow_timeout_s,
                                          stop=self._stop_event, on_end=self._set_end,
                                          validate_crcs=self.validate_crcs)
        for record in self._records:
            if isinstance(record, Message):
                if record.channel_id in self._samples_channel_ids:
                    return self._decode(record)
                if record.channel_id in self._events_channel_ids:
                    self.events_seen += 1
            elif isinstance(record, Channel):
                if record.topic == topics.TOPIC_SAMPLES:
                    self._samples_channel_ids.add(record.id)
                elif record.topic == topics.TOPIC_EVENTS:
                    self._events_channel_ids.add(record.id)
            elif isinstance(record, Metadata):
                self._take_metadata(record)
            elif isinstance(record, Schema):
                continue
        return None

    def _set_end(self, reason: str) -> None:
        if reason.startswith("damaged"):
            self.end_detail = (
                f"{self.path}: damaged recording ({reason[len('damaged: '):]}); blocks up to "
                f"the damage were replayed; run `fnsi-lab recover {self.path} "
                f"{self.path.with_suffix('')}.recovered.mcap` to salvage every intact chunk "
                "(or add --no-crc-check)")
            reason = "damaged"
        self.end_reason = reason

    def _decode(self, message: Message) -> Block:
        try:
            dec = block_schema.decode_block(message.data)
        except Exception as exc:
            raise ReplayError(f"{self.path}: malformed sample message at log time "
                              f"{message.log_time} ns ({exc})") from None
        if dec.n_channels != len(self.channels):
            raise ReplayError(f"{self.path}: a block has {dec.n_channels} channels, the "
                              f"channel table {len(self.channels)}")
        return Block(data=np.asarray(dec.data, dtype=np.float64), channels=self.channels,
                     sample_rate_hz=self.sample_rate_hz, sequence=int(dec.sequence),
                     first_sample=int(dec.first_sample), t0_ns=int(dec.t0_ns),
                     realization=int(dec.realization))

    def _pump(self) -> None:
        """Follow mode: tail the file in a thread, handing blocks over a queue."""
        assert self._queue is not None
        try:
            while not self._stop_event.is_set():
                block = self._next_block()
                if block is None:
                    break
                while not self._stop_event.is_set():
                    try:
                        self._queue.put(block, timeout=0.1)
                        break
                    except queue.Full:
                        continue
        except BaseException as exc:  # re-raised by read()
            self._queue.put(exc)
        finally:
            self._queue.put(_END)

    def _read_block(self, timeout: float | None) -> Block | None:
        if not self.follow:
            block = self._next_block()
            if block is None:
                self._mark_finished()
            return block
        if self._thread is None:
            self._queue = queue.Queue(maxsize=256)
            self._thread = threading.Thread(target=self._pump, name="fnsi-lab-replay-follow",
                                            daemon=True)
            self._thread.start()
        assert self._queue is not None
        try:
            item = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is _END:
            self._mark_finished()
            return None
        if isinstance(item, BaseException):
            self._mark_finished()
            raise item
        return item

    def _close(self) -> None:
        self._stop_event.set()
        if self._thread is not None:
            while self._thread.is_alive():  # unblock a pump waiting on a full queue
                try:
                    assert self._queue is not None
                    self._queue.get_nowait()
                except queue.Empty:
                    pass
                self._thread.join(timeout=0.05)
        if self._records is not None:
            try:
                self._records.close()  # type: ignore[attr-defined]
            except Exception as exc:  # noqa: BLE001 - closing a read-only file: data safe
                logging.getLogger("fnsi_lab.replay").debug("closing the recording: %s", exc)

    def describe(self) -> dict[str, Any]:
        """The recorded metadata (excitation, truth...) plus where it was replayed from."""
        out = {k: v for k, v in self.metadata.items() if k not in ("experiment", "channels")}
        out["source"] = {"kind": self.kind, "path": str(self.path),
                         "sample_rate_hz": self.sample_rate_hz,
                         "n_channels": len(self.channels),
                         "recorded_source": self.metadata.get("source")}
        return out
