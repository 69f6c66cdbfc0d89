"""Reading fnsi-lab MCAP recordings: blocks, samples, metadata and periodic records.

:func:`open_recording` checks the file once (exists, is MCAP, is finished, holds the
fnsi-lab samples topic and a channel table) and raises one-line
:class:`~daq.recording.errors.RecordingError` subclasses naming the file and the fix.
Reads go through the MCAP summary and chunk index, so a time range touches only the chunks
that overlap it.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterator

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import SeekingReader, make_reader
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk
from mcap.summary import Summary

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.periodic import excited_lines_of, periodicity_per_channel
from fnsi_lab.daq.recording import schema, topics
from fnsi_lab.daq.recording.errors import (DamagedRecordingError, MissingChannelsError,
                                           NotMcapError, RecordingError,
                                           RecordingNotFoundError, UnfinishedRecordingError,
                                           WrongSchemaError)
from fnsi_lab.daq.recording.recover import MCAP_MAGIC, RecoverReport, recover

#: Whether reads check CRCs when the caller does not say (``fnsi-lab --no-crc-check``
#: turns it off for one command).
_CHECK_CRCS_BY_DEFAULT = True


def set_default_crc_check(enabled: bool) -> None:
    """Set whether :func:`open_recording` checks CRCs when ``validate_crcs`` is not given."""
    global _CHECK_CRCS_BY_DEFAULT
    _CHECK_CRCS_BY_DEFAULT = bool(enabled)


def recovered_name(path: str | os.PathLike[str]) -> str:
    """Suggested output name for ``fnsi-lab recover`` (``x.mcap`` -> ``x.recovered.mcap``)."""
    p = Path(path)
    return str(p.with_name(p.stem + ".recovered" + (p.suffix or ".mcap")))


class Recording:
    """An open fnsi-lab recording (use :func:`open_recording`).

    Attributes
    ----------
    path : Path
        The file.
    channels : tuple of ChannelInfo, length n_channels
        Channel table (column order of every block).
    sample_rate_hz : float
        Nominal sampling rate.
    metadata : dict of str to object
        Parsed JSON of every ``fnsi_lab.<key>`` metadata record, by ``key``.
    salvaged : RecoverReport or None
        Set when the file was unfinished and opened with ``salvage=True``.

    Notes
    -----
    Not thread-safe (one file handle). Close it, or use it as a context manager.
    """

    def __init__(self, path: Path, stream: IO[bytes], *,
                 salvaged: RecoverReport | None = None, validate_crcs: bool = True) -> None:
        self.path = path
        self._stream = stream
        self.salvaged = salvaged
        self.validate_crcs = validate_crcs
        self._reader: SeekingReader = make_reader(  # type: ignore[assignment]
            stream, validate_crcs=validate_crcs)
        self._summary = self._load_summary()
        #: What the reader could not check, for ``info`` and the identification's notes
        #: (a file from another writer without CRCs).
        self.notes: list[str] = []
        self._metadata_crcs = 0
        self.library = self._header_library()
        summary_crc = self._check_summary_crc() if validate_crcs else True
        self.metadata = self._load_metadata()
        if not summary_crc:  # judged once the metadata records said who wrote the file
            self._zero_crc("footer (the summary section's CRC)")
        self._samples = self._find_samples_channel()
        self.channels = self._load_channels()
        self.sample_rate_hz = self._load_rate()
        self._first_t0_ns: int | None = None
        self._log_offset_ns: int | None = None

    # ------------------------------------------------------------------ opening checks
    def _load_summary(self) -> Summary:
        try:
            summary = self._reader.get_summary()
        except (McapError, ValueError, OSError, EOFError, struct.error, UnicodeDecodeError) as exc:
            raise UnfinishedRecordingError(
                f"{self.path}: unfinished recording (no valid MCAP footer/summary: {type(exc).__name__}); "
                f"run `fnsi-lab recover {self.path} {recovered_name(self.path)}`") from None
        if summary is None:
            raise UnfinishedRecordingError(
                f"{self.path}: MCAP file without summary/index; run `fnsi-lab recover "
                f"{self.path} {recovered_name(self.path)}` to re-index it")
        return summary

    def _header_library(self) -> str:
        """The MCAP header's ``library`` text ('' when the header does not parse)."""
        try:
            return str(self._reader.get_header().library)
        except Exception:  # noqa: BLE001 - a damaged header: the other checks still run
            return ""

    @property
    def written_by_fnsi_lab(self) -> bool:
        """True when the header (or the CRC-carrying metadata records) say fnsi-lab wrote
        the file: it then always wrote every CRC, so a zero CRC field is damage."""
        return self.library.startswith(topics.LIBRARY_PREFIX) or self._metadata_crcs > 0

    def _zero_crc(self, what: str) -> None:
        """A CRC field of 0 ('not computed' in MCAP): damage in an fnsi-lab file, a note
        (nothing could be checked) in another writer's."""
        if self.written_by_fnsi_lab:
            raise self.damaged_error(f"damaged {what}: its CRC field is zero (fnsi-lab always "
                                     "writes one)")
        note = (f"written by {self.library or 'an unknown writer'} without CRCs: damage "
                "cannot be detected in this file")
        if note not in self.notes:
            self.notes.append(note)

    def damaged_error(self, what: str) -> DamagedRecordingError:
        """The one-line error for a damaged part ``what`` of this file (with the fix);
        its ``what`` attribute holds ``what``."""
        error = DamagedRecordingError(
            f"{self.path}: {what}; run `fnsi-lab recover {self.path} {recovered_name(self.path)}` "
            "to salvage every intact chunk (or add --no-crc-check to read it as it is)")
        error.what = what
        return error

    def _check_summary_crc(self) -> bool:
        """Check the footer's CRC of the summary section (schemas, channels, indexes);
        False when the footer carries none (a zero CRC field)."""
        size = self._stream.seek(0, io.SEEK_END)
        footer_at = size - len(MCAP_MAGIC) - 29  # opcode, length, two offsets, CRC
        self._stream.seek(footer_at)
        raw = self._stream.read(29)
        if len(raw) != 29 or raw[0] != Opcode.FOOTER:
            raise self.damaged_error("damaged footer")
        summary_start, _, crc = struct.unpack_from("<QQI", raw, 9)
        if summary_start == 0:
            return True  # no summary section: reported when it is needed
        if crc == 0:
            return False
        if not 0 < summary_start <= footer_at:
            raise self.damaged_error("damaged footer (summary offset out of range)")
        self._stream.seek(summary_start)
        body = self._stream.read(footer_at - summary_start)
        if zlib.crc32(raw[:25], zlib.crc32(body)) != crc:
            raise self.damaged_error(f"damaged summary section (bytes {summary_start}-{footer_at}: "
                                "CRC mismatch; channel table, statistics or chunk index)")
        return True

    def _chunk_label(self, ci: Any) -> str:
        """``chunk 12 of 49 (bytes a-b, 26.0-27.0 s)`` for error messages."""
        order = sorted(self._summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        k = next((i for i, c in enumerate(order) if c.chunk_start_offset == ci.chunk_start_offset), 0)
        t0 = min((c.message_start_time for c in order), default=0)
        end = ci.chunk_start_offset + ci.chunk_length
        return (f"chunk {k + 1} of {len(order)} (bytes {ci.chunk_start_offset}-{end}, "
                f"{(ci.message_start_time - t0) / 1e9:.1f}-{(ci.message_end_time - t0) / 1e9:.1f} s)")

    def _read_chunk(self, ci: Any) -> bytes:
        """Decompressed content of the chunk of index entry ``ci``, CRC-checked if enabled."""
        try:
            self._stream.seek(ci.chunk_start_offset)
            head = self._stream.read(9)
            if len(head) != 9 or head[0] != Opcode.CHUNK:
                raise McapError("no chunk record at the indexed offset")
            chunk = Chunk.read(ReadDataStream(self._stream))
            raw = _decompress(chunk)
        except (McapError, ValueError, OSError, EOFError, zlib.error, struct.error) as exc:
            raise self.damaged_error(f"damaged {self._chunk_label(ci)}: {exc}") from None
        if not self.validate_crcs:
            return raw
        if not chunk.uncompressed_crc:
            self._zero_crc(self._chunk_label(ci))
        elif zlib.crc32(raw) != chunk.uncompressed_crc:
            raise self.damaged_error(f"damaged {self._chunk_label(ci)}: CRC mismatch")
        return raw

    def damage(self) -> list[str]:
        """Check every chunk and attachment CRC; one line per damaged part (empty: intact).

        The summary section and the metadata records were checked when the file was opened.
        """
        problems = []
        for ci in sorted(self._summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            try:
                self._read_chunk(ci)
            except DamagedRecordingError as exc:
                problems.append(getattr(exc, "what", f"damaged {self._chunk_label(ci)}"))
        for ai in self._summary.attachment_indexes:
            if not self._attachment_intact(ai):
                problems.append(f"damaged attachment {ai.name!r} (bytes {ai.offset}-"
                                f"{ai.offset + ai.length})")
        return problems

    def _attachment_intact(self, ai: Any) -> bool:
        """Check an attachment record's own CRC (mcap's reader skips it)."""
        self._stream.seek(ai.offset)
        raw = self._stream.read(ai.length)
        if len(raw) != ai.length or len(raw) < 13 or raw[0] != Opcode.ATTACHMENT:
            return False
        crc = int.from_bytes(raw[-4:], "little")
        if crc == 0:
            if self.written_by_fnsi_lab:
                return False  # fnsi-lab always writes it
            self._zero_crc(f"attachment {ai.name!r}")
            return True
        return zlib.crc32(raw[9:-4]) == crc

    def _find_samples_channel(self) -> Channel:
        found = [c for c in self._summary.channels.values() if c.topic == topics.TOPIC_SAMPLES]
        if not found and self.metadata:
            raise WrongSchemaError(
                f"{self.path}: fnsi-lab recording without any sample block (stopped before "
                "its first flush, or recovered from such a file); record again")
        if not found:
            present = sorted({c.topic for c in self._summary.channels.values()})
            raise WrongSchemaError(
                f"{self.path}: not an fnsi-lab recording (no {topics.TOPIC_SAMPLES} topic; "
                f"topics: {present or 'none'}); record one with `fnsi-lab acquire`")
        channel = found[0]
        sch = self._summary.schemas.get(channel.schema_id)
        if (sch is None or sch.name != topics.SAMPLES_SCHEMA_NAME
                or sch.encoding != topics.SCHEMA_ENCODING_PROTOBUF
                or channel.message_encoding != topics.MESSAGE_ENCODING_PROTOBUF):
            got = f"{sch.name!r} ({sch.encoding})" if sch is not None else "no schema"
            raise WrongSchemaError(
                f"{self.path}: topic {topics.TOPIC_SAMPLES} has schema {got}, expected "
                f"{topics.SAMPLES_SCHEMA_NAME!r} (protobuf); the file was not written by "
                "fnsi-lab or by an incompatible version")
        return channel

    def _load_metadata(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        with_crc = without_crc = 0
        try:
            for record in self._reader.iter_metadata():
                text = record.metadata.get(topics.METADATA_JSON_KEY)
                crc = record.metadata.get(topics.METADATA_CRC_KEY)
                if self.validate_crcs and crc is not None:
                    # checked whatever the name: a flipped bit in the name is damage too
                    if text is None or topics.metadata_crc(record.name, text) != crc:
                        raise self.damaged_error(
                            f"damaged metadata record {record.name!r} (CRC mismatch)")
                if not record.name.startswith(topics.METADATA_PREFIX):
                    continue
                if crc is None:
                    without_crc += 1
                else:
                    with_crc += 1
                key = record.name[len(topics.METADATA_PREFIX):]
                if text is None:
                    continue
                try:
                    out[key] = json.loads(text)  # later records win
                except json.JSONDecodeError:
                    raise self.damaged_error(f"metadata record {record.name!r} is not valid JSON") from None
        except (McapError, OSError, ValueError, struct.error, UnicodeDecodeError) as exc:
            if isinstance(exc, RecordingError):
                raise
            raise self.damaged_error(f"unreadable metadata ({type(exc).__name__}: {exc})") from None
        self._metadata_crcs = with_crc
        if self.validate_crcs and with_crc and without_crc:
            # a writer that adds CRCs adds them to every record: one is missing its key
            raise self.damaged_error("damaged metadata record (its CRC key is gone)")
        return out

    def _load_channels(self) -> tuple[ChannelInfo, ...]:
        table: Any = None
        text = self._samples.metadata.get(topics.CHANNEL_META_CHANNELS)
        if text:
            try:
                table = json.loads(text)
            except json.JSONDecodeError:
                table = None
        if not table:
            table = self.metadata.get(topics.META_CHANNELS)
        if not table or not isinstance(table, list):
            raise MissingChannelsError(
                f"{self.path}: no channel table (neither in the {topics.TOPIC_SAMPLES} channel "
                f"metadata nor in the {topics.metadata_record_name(topics.META_CHANNELS)} "
                "record); the recording cannot be interpreted")
        try:
            return tuple(ChannelInfo.from_dict(d) for d in table)
        except (TypeError, KeyError) as exc:
            raise MissingChannelsError(f"{self.path}: malformed channel table ({exc})") from None

    def _load_rate(self) -> float:
        text = self._samples.metadata.get(topics.CHANNEL_META_SAMPLE_RATE)
        if text:
            try:
                return float(text)
            except ValueError:
                pass
        for block in self.iter_blocks():
            return block.sample_rate_hz
        src = self.metadata.get(topics.META_SOURCE) or {}
        if "sample_rate_hz" in src:
            return float(src["sample_rate_hz"])
        raise RecordingError(f"{self.path}: no sample rate recorded and no sample block")

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """Close the file (idempotent)."""
        self._stream.close()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"Recording({str(self.path)!r}, {len(self.channels)} channels @ "
                f"{self.sample_rate_hz:g} Hz, {self.n_blocks} blocks)")

    # ------------------------------------------------------------------ metadata views
    @property
    def summary(self) -> Summary:
        """The MCAP summary (statistics, schemas, channels, indexes)."""
        return self._summary

    @property
    def n_blocks(self) -> int:
        """Number of sample messages (from the statistics, no data read)."""
        stats = self._summary.statistics
        if stats is None:
            return sum(1 for _ in self._iter_samples())
        return int(stats.channel_message_counts.get(self._samples.id, 0))

    @property
    def excitation(self) -> dict[str, Any] | None:
        """The ``excitation`` metadata (multisine definition), or None."""
        return self.metadata.get(topics.META_EXCITATION)

    @property
    def truth(self) -> dict[str, Any] | None:
        """The ``truth`` metadata (simulated sources), or None."""
        return self.metadata.get(topics.META_TRUTH)

    @property
    def experiment(self) -> dict[str, Any]:
        """The ``experiment`` metadata (name, source kind, software version...)."""
        return self.metadata.get(topics.META_EXPERIMENT) or {}

    @property
    def input_channels(self) -> tuple[ChannelInfo, ...]:
        """Force channels (identification inputs)."""
        return tuple(c for c in self.channels if c.is_force)

    @property
    def output_channels(self) -> tuple[ChannelInfo, ...]:
        """Response channels (identification outputs)."""
        return tuple(c for c in self.channels if not c.is_force)

    def attachments(self) -> dict[str, bytes]:
        """All attachments, name -> content (each CRC-checked when ``validate_crcs``)."""
        if self.validate_crcs:
            for ai in self._summary.attachment_indexes:
                if not self._attachment_intact(ai):
                    raise self.damaged_error(f"damaged attachment {ai.name!r} (CRC mismatch)")
        try:
            return {a.name: a.data for a in self._reader.iter_attachments()}
        except (McapError, ValueError, OSError, EOFError, struct.error) as exc:
            raise self.damaged_error(f"unreadable attachment ({exc})") from None

    def attachment_info(self) -> list[dict[str, Any]]:
        """Name, media type and size of each attachment (from the index, no data read)."""
        return [{"name": a.name, "media_type": a.media_type, "size": a.data_size}
                for a in self._summary.attachment_indexes]

    @property
    def experiment_yaml(self) -> str | None:
        """Text of the ``experiment.yaml`` attachment, or None."""
        data = self.attachments().get(topics.ATTACHMENT_EXPERIMENT_YAML)
        return None if data is None else data.decode("utf-8", errors="replace")

    # ------------------------------------------------------------------ data
    def _iter_raw(self, topic: str = topics.TOPIC_SAMPLES, start_ns: int | None = None,
                  end_ns: int | None = None) -> Iterator[Any]:
        try:
            # File order (= acquisition order): several realizations may reuse log times.
            for _, _, message in self._reader.iter_messages(
                    topics=[topic], log_time_order=False, starting_at=start_ns,
                    ending_before=end_ns):
                yield message
        except (McapError, ValueError, OSError, EOFError, struct.error, zlib.error) as exc:
            raise self.damaged_error(f"damaged data on {topic} ({type(exc).__name__}: {exc})") from None

    def _iter_samples(self, start_ns: int | None = None,
                      end_ns: int | None = None) -> Iterator[tuple[int, memoryview]]:
        """``(log_time, payload)`` of the sample messages in ``[start_ns, end_ns)``, file order.

        Same selection as mcap's ``iter_messages(log_time_order=False)`` (chunk index, then
        per-message times), but the decompressed chunk is sliced with memoryviews instead of
        being copied message by message: reading runs at decompression speed.
        """
        cid = self._samples.id
        if not self._summary.chunk_indexes:  # unchunked file (other writers): generic path
            for m in self._iter_raw(start_ns=start_ns, end_ns=end_ns):
                yield m.log_time, memoryview(m.data)
            return
        indexes = [ci for ci in self._summary.chunk_indexes
                   if (start_ns is None or ci.message_end_time >= start_ns)
                   and (end_ns is None or ci.message_start_time < end_ns)
                   and (not ci.message_index_offsets or cid in ci.message_index_offsets)]
        indexes.sort(key=lambda ci: ci.chunk_start_offset)
        unpack = struct.Struct("<BQHIQQ").unpack_from  # opcode, length, channel, seq, log, pub
        for ci in indexes:
            buf = memoryview(self._read_chunk(ci))
            pos, end = 0, len(buf)
            while pos < end:
                if pos + 9 > end:
                    raise self.damaged_error(f"damaged {self._chunk_label(ci)}: cut record")
                opcode, length = buf[pos], int.from_bytes(buf[pos + 1:pos + 9], "little")
                nxt = pos + 9 + length
                if nxt > end:
                    raise self.damaged_error(f"damaged {self._chunk_label(ci)}: a record runs "
                                        "past the end of its chunk")
                if opcode == Opcode.MESSAGE:
                    _, _, channel, _, log_time, _ = unpack(buf, pos)
                    if (channel == cid and (start_ns is None or log_time >= start_ns)
                            and (end_ns is None or log_time < end_ns)):
                        yield log_time, buf[pos + 31:nxt]
                pos = nxt

    def _decode(self, message: Any) -> Block:
        log_time, payload = message
        try:
            d = schema.decode_block(payload)
        except schema.MalformedMessageError as exc:
            raise self.damaged_error(f"corrupt sample message at log time {log_time} ns ({exc})") from None
        if d.n_channels != len(self.channels):
            raise MissingChannelsError(
                f"{self.path}: sample blocks have {d.n_channels} columns but the channel table "
                f"lists {len(self.channels)} channels; the channel table is incomplete")
        return Block(data=d.data, channels=self.channels, sample_rate_hz=d.sample_rate_hz,
                     sequence=d.sequence, first_sample=d.first_sample, t0_ns=d.t0_ns,
                     realization=d.realization)

    def iter_blocks(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Block]:
        """Yield the recorded blocks, in acquisition order.

        Parameters
        ----------
        start_ns, end_ns : int or None
            Keep blocks whose ``t0_ns`` (sample clock) is in ``[start_ns, end_ns)``; only
            the chunks overlapping the range are read.

        Yields
        ------
        Block
            ``data`` is float32, shape (n_samples, n_channels), exactly as recorded
            (a read-only view on the message bytes).
        """
        if start_ns is not None or end_ns is not None:
            # message log times are wall clock (0 offset in recordings made before that)
            offset = self.log_time_offset_ns
            start_ns = None if start_ns is None else start_ns + offset
            end_ns = None if end_ns is None else end_ns + offset
        for message in self._iter_samples(start_ns, end_ns):
            yield self._decode(message)

    @property
    def log_time_offset_ns(self) -> int:
        """Message log time minus payload ``t0_ns`` of the sample blocks (reads one block).

        The recorder writes wall-clock UTC log times (acquisition start plus sample time);
        recordings made before that used ``t0_ns`` itself, giving 0 here.
        """
        if self._log_offset_ns is None:
            first = next(iter(self._iter_samples()), None)
            self._log_offset_ns = 0 if first is None else first[0] - self._decode(first).t0_ns
        return self._log_offset_ns

    def iter_events(self) -> Iterator[dict[str, Any]]:
        """Yield the recorded source events as dicts ``{time_ns, kind, detail}``."""
        for message in self._iter_raw(topics.TOPIC_EVENTS):
            yield json.loads(message.data)

    def iter_json(self, topic: str) -> Iterator[tuple[int, Any]]:
        """Yield ``(log_time_ns, object)`` of an auxiliary JSON topic."""
        for message in self._iter_raw(topic):
            yield message.log_time, json.loads(message.data)

    @property
    def message_counts(self) -> dict[str, int]:
        """Message count per topic (from the statistics)."""
        stats = self._summary.statistics
        counts = stats.channel_message_counts if stats is not None else {}
        return {c.topic: int(counts.get(cid, 0)) for cid, c in self._summary.channels.items()}

    @property
    def start_ns(self) -> int:
        """``t0_ns`` of the first block (reads one chunk); 0 for an empty recording."""
        if self._first_t0_ns is None:
            first = next(iter(self.iter_blocks()), None)
            self._first_t0_ns = first.t0_ns if first is not None else 0
        return self._first_t0_ns

    def read_samples(self, start_s: float | None = None, end_s: float | None = None) -> np.ndarray:
        """Samples between two times, as one array.

        Parameters
        ----------
        start_s, end_s : float or None
            Seconds since the first sample of the recording; rows with time in
            ``[start_s, end_s)`` are returned. None means the start/end of the file.

        Returns
        -------
        ndarray of float32, shape (n_samples, n_channels)
            Rows in acquisition order (realizations one after the other).
        """
        t_origin = self.start_ns
        lo = None if start_s is None else t_origin + int(round(start_s * 1e9))
        hi = None if end_s is None else t_origin + int(round(end_s * 1e9))
        # A block starting before `lo` may still hold rows after it: widen the index query
        # by the longest block we could meet (one second is generous; rows are cut below).
        query_lo = None if lo is None else max(lo - 1_000_000_000, 0)
        parts = []
        for block in self.iter_blocks(query_lo, hi):
            if lo is None and hi is None:
                parts.append(block.data)
                continue
            t = block.t0_ns + np.round(np.arange(block.n_samples) * (1e9 / block.sample_rate_hz)).astype(np.int64)
            keep = np.ones(block.n_samples, bool)
            if lo is not None:
                keep &= t >= lo
            if hi is not None:
                keep &= t < hi
            if keep.all():
                parts.append(block.data)
            elif keep.any():
                parts.append(block.data[keep])
        if not parts:
            return np.zeros((0, len(self.channels)), dtype=np.float32)
        return np.concatenate(parts, axis=0)

    def read_periodic(self, samples_per_period: int | None = None, **kwargs: Any) -> "PeriodicRecord":
        """Shortcut for :func:`read_periodic` on this recording."""
        return read_periodic(self, samples_per_period, **kwargs)


def _decompress(chunk: Chunk) -> bytes:
    """Uncompressed content of a chunk (zstd, lz4 or none), size-checked."""
    try:
        if chunk.compression == "zstd":
            import zstandard
            data = zstandard.ZstdDecompressor().decompress(
                chunk.data, max_output_size=chunk.uncompressed_size)
        elif chunk.compression == "lz4":
            import lz4.frame
            data = lz4.frame.decompress(chunk.data)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise McapError(f"unsupported chunk compression {chunk.compression!r}")
    except McapError:
        raise
    except Exception as exc:  # noqa: BLE001 - zstd/lz4 raise their own error classes
        raise McapError(f"chunk does not decompress ({exc})") from None
    if len(data) != chunk.uncompressed_size:
        raise McapError("chunk size does not match its header")
    return data


# ---------------------------------------------------------------------------- opening
def open_recording(path: str | os.PathLike[str], *, salvage: bool = False,
                   validate_crcs: bool | None = None) -> Recording:
    """Open an fnsi-lab MCAP recording for reading.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    salvage : bool, optional
        If the file is unfinished (writer killed), recover its intact chunks in memory
        instead of raising; ``Recording.salvaged`` then holds the report.
    validate_crcs : bool, optional
        Check the CRCs of the summary section and of every metadata record at opening, and
        of every chunk and attachment read (costs ~20 % of the read time); a mismatch
        raises :class:`DamagedRecordingError` naming the chunk, its bytes and seconds, and
        the ``fnsi-lab recover`` command. Default: on (``set_default_crc_check``).
        Recovery always checks them.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingNotFoundError
        The file does not exist.
    NotMcapError
        The file is not MCAP.
    UnfinishedRecordingError
        No footer (crash): the message names the ``fnsi-lab recover`` command.
    WrongSchemaError
        A valid MCAP file without the fnsi-lab samples topic/schema.
    MissingChannelsError
        No channel table, or one that does not match the blocks.
    """
    if validate_crcs is None:
        validate_crcs = _CHECK_CRCS_BY_DEFAULT
    p = Path(path)
    if not p.exists():
        raise RecordingNotFoundError(f"{p}: no such recording; check the path "
                                     "(record one with `fnsi-lab acquire --out FILE`)")
    if p.is_dir():
        raise RecordingError(f"{p}: is a folder, not a recording; give the .mcap file")
    try:
        stream = open(p, "rb")
    except OSError as exc:
        raise RecordingError(f"{p}: cannot open ({exc.strerror}); check the permissions") from None
    try:
        head = stream.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            kind = "an empty file" if not head else f"starts with {head[:8]!r}"
            raise NotMcapError(f"{p}: not an MCAP file ({kind}); give a recording made by "
                               "`fnsi-lab acquire`")
        stream.seek(-len(MCAP_MAGIC), io.SEEK_END)
        if stream.read() != MCAP_MAGIC:
            if not salvage:
                raise UnfinishedRecordingError(
                    f"{p}: unfinished recording (no MCAP footer: the writer crashed or was "
                    f"killed); run `fnsi-lab recover {p} {recovered_name(p)}`")
            stream.close()
            buf = io.BytesIO()
            report = recover(p, buf)
            buf.seek(0)
            return Recording(p, buf, salvaged=report, validate_crcs=validate_crcs)
        stream.seek(0)
        return Recording(p, stream, validate_crcs=validate_crcs)
    except BaseException:
        stream.close()
        raise


# ---------------------------------------------------------------------------- periodic
@dataclass(frozen=True, eq=False)
class PeriodicRecord:
    """Steady-state-ready periodic data of a multisine recording.

    Attributes
    ----------
    u : ndarray of float64, shape (n_realizations, n_periods, samples_per_period, n_inputs)
        Force (input) channels, transient periods included (exact float32 values).
    y : ndarray of float64, shape (n_realizations, n_periods, samples_per_period, n_outputs)
        Response (output) channels.
    input_channels, output_channels : tuple of ChannelInfo
        Columns of ``u`` and ``y``.
    sample_rate_hz : float
        Sampling rate.
    samples_per_period : int
        N.
    transient_periods : int
        Leading periods the identification should drop (from the excitation metadata;
        nothing is dropped here).
    excited_lines : ndarray of int, shape (n_excited,)
        DFT bins carrying excitation (empty when unknown).
    truth : dict or None
        Ground truth of a simulated source.
    periodicity_error : float
        Max over channels and realizations of ``||x_P - x_{P-1}|| / ||x_P||`` (last two
        periods); small (noise level) when the data are N-periodic; NaN if P < 2.
    periodicity_error_per_channel : ndarray, shape (n_channels,)
        The same per channel (recording column order), max over realizations.
    realizations : tuple of int
        Realization index of each first-axis entry.
    notes : tuple of str
        What was trimmed (incomplete trailing periods...), empty when nothing was.
    excitation : dict or None
        The excitation metadata as recorded.
    """

    u: np.ndarray
    y: np.ndarray
    input_channels: tuple[ChannelInfo, ...]
    output_channels: tuple[ChannelInfo, ...]
    sample_rate_hz: float
    samples_per_period: int
    transient_periods: int
    excited_lines: np.ndarray
    truth: dict[str, Any] | None
    periodicity_error: float
    periodicity_error_per_channel: np.ndarray
    realizations: tuple[int, ...]
    notes: tuple[str, ...] = ()
    excitation: dict[str, Any] | None = None

    @property
    def n_realizations(self) -> int:
        """R."""
        return int(self.u.shape[0])

    @property
    def n_periods(self) -> int:
        """P (transient periods included)."""
        return int(self.u.shape[1])

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Frequencies of the excited lines, shape (n_excited,)."""
        return self.excited_lines * self.sample_rate_hz / self.samples_per_period


def read_periodic(path_or_recording: str | os.PathLike[str] | Recording,
                  samples_per_period: int | None = None, *,
                  max_periodicity_error: float | None = None) -> PeriodicRecord:
    """Cut a multisine recording into periods: ``(R, P, N, channels)`` arrays.

    Parameters
    ----------
    path_or_recording : str or Path or Recording
        The recording.
    samples_per_period : int, optional
        N; required when the file has no excitation metadata, otherwise it must agree.
    max_periodicity_error : float, optional
        If given, raise when :attr:`PeriodicRecord.periodicity_error` exceeds it.

    Returns
    -------
    PeriodicRecord

    Raises
    ------
    RecordingError
        No N known, N disagreeing with the metadata, fewer than N samples, a gap in the
        sample indices (lost blocks), or a periodicity error above the limit.

    Notes
    -----
    Samples are placed by ``(realization, first_sample)`` of each block. Periods start
    at ``first_sample`` multiples of N; a leading or trailing partial period is not
    kept and :attr:`PeriodicRecord.notes` says so. With realizations of unequal length,
    all are cut to the shortest. No transient period is dropped here.
    """
    if isinstance(path_or_recording, Recording):
        return _read_periodic(path_or_recording, samples_per_period, max_periodicity_error)
    with open_recording(path_or_recording) as rec:
        return _read_periodic(rec, samples_per_period, max_periodicity_error)


def _read_periodic(rec: Recording, samples_per_period: int | None,
                   max_error: float | None) -> PeriodicRecord:
    exc = rec.excitation
    declared = int(exc["samples_per_period"]) if exc and "samples_per_period" in exc else None
    if samples_per_period is None:
        if declared is None:
            raise RecordingError(f"{rec.path}: no excitation metadata, so the period is "
                                 "unknown; pass samples_per_period (e.g. --samples-per-period 8192)")
        n = declared
    else:
        n = int(samples_per_period)
        if n < 1:
            raise RecordingError(f"{rec.path}: samples_per_period must be >= 1, got {n}")
        if declared is not None and declared != n:
            raise RecordingError(f"{rec.path}: samples_per_period={n} disagrees with the "
                                 f"recorded excitation (N={declared}); omit it")
    notes: list[str] = []
    per_real: dict[int, list[Block]] = {}
    for block in rec.iter_blocks():
        per_real.setdefault(block.realization, []).append(block)
    if not per_real:
        raise RecordingError(f"{rec.path}: the recording holds no sample block")
    n_ch = len(rec.channels)
    series: dict[int, np.ndarray] = {}
    for r, blocks in sorted(per_real.items()):
        blocks.sort(key=lambda b: b.first_sample)
        expected = blocks[0].first_sample
        for b in blocks:
            if b.first_sample != expected:
                what = "overlapping" if b.first_sample < expected else "missing"
                raise RecordingError(
                    f"{rec.path}: realization {r} has {what} samples at sample {expected} "
                    f"(next block starts at {b.first_sample}; lost or repeated blocks); "
                    "periods cannot be assembled")
            expected += b.n_samples
        data = np.concatenate([b.data for b in blocks], axis=0)
        # Align periods to first_sample multiples of N (the excitation's phase).
        skip = (-blocks[0].first_sample) % n
        if skip:
            notes.append(f"realization {r}: dropped {skip} leading samples (partial period)")
        usable = data[skip:]
        series[r] = usable
    counts = {r: s.shape[0] // n for r, s in series.items()}
    p = min(counts.values())
    if p < 1:
        short = min(series, key=lambda r: series[r].shape[0])
        raise RecordingError(f"{rec.path}: realization {short} holds {series[short].shape[0]} "
                             f"samples, less than one period of N={n}; record longer or check N")
    for r, s in series.items():
        extra = s.shape[0] - p * n
        if extra:
            whole = counts[r] - p
            notes.append(f"realization {r}: dropped {extra} trailing samples"
                         + (f" ({whole} whole periods beyond the shortest realization)" if whole else
                            " (incomplete last period)"))
    reals = tuple(sorted(series))
    x = np.empty((len(reals), p, n, n_ch), dtype=np.float64)
    for i, r in enumerate(reals):
        x[i] = series[r][: p * n].reshape(p, n, n_ch)
    errs = np.max(np.stack([periodicity_per_channel(x[i]) for i in range(len(reals))]), axis=0)
    err = float(np.max(errs)) if errs.size and not np.all(np.isnan(errs)) else math.nan
    if max_error is not None and not err <= max_error:
        raise RecordingError(f"{rec.path}: data are not periodic with N={n} (relative "
                             f"difference of the last two periods {err:.3g} > {max_error:g}); "
                             "check samples_per_period or record more transient periods")
    notes += [note for note in rec.notes if note not in notes]  # e.g. no CRCs to check
    is_in = np.array([c.is_force for c in rec.channels], dtype=bool)
    lines = excited_lines_of(exc, n, rec.sample_rate_hz)
    return PeriodicRecord(
        u=x[..., is_in], y=x[..., ~is_in], input_channels=rec.input_channels,
        output_channels=rec.output_channels, sample_rate_hz=rec.sample_rate_hz,
        samples_per_period=n, transient_periods=int(exc.get("transient_periods", 0)) if exc else 0,
        excited_lines=lines, truth=rec.truth, periodicity_error=err,
        periodicity_error_per_channel=errs, realizations=reals, notes=tuple(notes),
        excitation=exc)
