"""Salvage an unfinished MCAP recording (writer crashed, killed, power cut) into a valid one.

A recording killed mid-run has no summary and no footer, so indexed readers refuse it.
Its data section, however, is a sequence of self-delimiting records; every chunk carries a
CRC of its uncompressed content. :func:`recover` walks the records in order, re-registers
schemas and channels, and copies every message of every intact chunk (CRC checked before
anything of the chunk is copied), plus metadata and attachments, into a new, indexed file.
A damaged record does not end the salvage: the walk resynchronises on the next record that
parses and passes its CRC (a chunk whose framing is intact is skipped exactly; otherwise
the bytes are scanned for the next valid chunk header), so every intact chunk after a
damaged one is kept. The report gives the damaged byte ranges and the seconds of signal
missing between the recovered blocks. Messages are copied byte for byte with their
log/publish times and sequence numbers.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (Attachment, Channel, Chunk, Header, Message, Metadata, Schema)
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from fnsi_lab.daq.recording import schema as sample_schema
from fnsi_lab.daq.recording import topics
from fnsi_lab.daq.recording.errors import NotMcapError, RecordingError, RecordingNotFoundError
from fnsi_lab.daq.recording.writer import dumps, software_version

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class RecoverReport:
    """What :func:`recover` salvaged.

    Attributes
    ----------
    source, output : str
        Input and output files.
    complete : bool
        True if the input was a finished file (footer reached): nothing was lost.
    messages : int
        Messages copied.
    messages_by_topic : dict of str to int
        Messages copied per topic.
    chunks : int
        Intact chunks copied.
    metadata, attachments : int
        Metadata and attachment records copied.
    bytes_recovered : int
        Offset just past the last intact record of the input.
    file_size : int
        Size of the input, bytes.
    stop_reason : str
        Why reading stopped (``"end of file"`` for a complete file).
    last_log_time_ns : int or None
        Largest log time among the copied sample messages.
    """

    source: str
    output: str
    complete: bool
    messages: int
    messages_by_topic: dict[str, int]
    chunks: int
    metadata: int
    attachments: int
    bytes_recovered: int
    file_size: int
    stop_reason: str
    last_log_time_ns: int | None = None
    skipped_messages: int = 0
    #: Byte ranges ``(start, end, reason)`` of the damaged records that were skipped.
    damaged: tuple[tuple[int, int, str], ...] = ()
    #: Seconds of signal missing between recovered sample blocks (gaps inside the data).
    seconds_skipped: float = 0.0
    #: Seconds of signal in the recovered sample blocks.
    seconds_recovered: float = 0.0
    #: Chunks copied without a CRC to check (another writer's file; fnsi-lab always
    #: writes one, so in its own files a zero CRC is damage and the chunk is skipped).
    unchecked_chunks: int = 0

    @property
    def bytes_skipped(self) -> int:
        """Bytes of damaged records skipped before the end of the readable data."""
        return sum(end - start for start, end, _ in self.damaged)

    @property
    def sample_messages(self) -> int:
        """Sample blocks recovered (0: nothing usable was salvaged)."""
        return int(self.messages_by_topic.get(topics.TOPIC_SAMPLES, 0))

    @property
    def bytes_lost(self) -> int:
        """Input bytes after the last intact record (not recovered)."""
        return max(self.file_size - self.bytes_recovered, 0)

    def summary(self) -> str:
        """Human-readable multi-line report (printed by ``fnsi-lab recover``)."""
        state = ("input was complete; copied and re-indexed" if self.complete else
                 f"readable data end at byte {self.bytes_recovered} of {self.file_size} "
                 f"({self.bytes_lost} bytes after it lost): {self.stop_reason}")
        lines = [f"recovered {self.source} -> {self.output}",
                 f"  {self.messages} messages in {self.chunks} chunks, {self.metadata} metadata "
                 f"records, {self.attachments} attachments; {self.seconds_recovered:.2f} s of signal",
                 f"  {state}"]
        if self.damaged:
            lines.append(f"  skipped {len(self.damaged)} damaged record(s), {self.bytes_skipped} "
                         f"bytes, {self.seconds_skipped:.2f} s of signal missing between the "
                         "recovered blocks:")
            lines += [f"    bytes {a}-{b}: {why}" for a, b, why in self.damaged[:20]]
            if len(self.damaged) > 20:
                lines.append(f"    ... {len(self.damaged) - 20} more")
        for topic, n in sorted(self.messages_by_topic.items()):
            lines.append(f"  {topic}: {n} messages")
        if self.last_log_time_ns is not None:
            lines.append(f"  last sample block at log time {self.last_log_time_ns} ns")
        if self.skipped_messages:
            lines.append(f"  {self.skipped_messages} messages skipped (channel record lost)")
        if self.unchecked_chunks:
            lines.append(f"  note: {self.unchecked_chunks} chunk(s) carry no CRC (written "
                         "without CRCs by another program): copied unchecked")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__} | {
            "bytes_lost": self.bytes_lost, "bytes_skipped": self.bytes_skipped}


@dataclass
class _Copier:
    """Re-registers schemas/channels under new ids and copies records into ``writer``."""

    writer: Writer
    schemas: dict[int, int] = field(default_factory=dict)  # old id -> new id
    channels: dict[int, tuple[int, str]] = field(default_factory=dict)  # old -> (new, topic)
    by_topic: dict[str, int] = field(default_factory=dict)
    messages: int = 0
    skipped: int = 0
    last_sample_ns: int | None = None
    #: Schemas/channels of the input's summary section: used when the chunk that
    #: declared them is damaged.
    spare_schemas: dict[int, Schema] = field(default_factory=dict)
    spare_channels: dict[int, Channel] = field(default_factory=dict)
    #: (realization, first_sample, n_samples, sample_rate_hz) of each sample block copied.
    blocks: list[tuple[int, int, int, float]] = field(default_factory=list)

    def schema(self, s: Schema) -> None:
        if s.id not in self.schemas:
            self.schemas[s.id] = self.writer.register_schema(s.name, s.encoding, s.data)

    def channel(self, c: Channel) -> None:
        if c.id in self.channels:
            return
        sid = self.schemas.get(c.schema_id, 0) if c.schema_id else 0
        if c.schema_id and not sid:
            return  # its schema was lost: messages of this channel are skipped
        new = self.writer.register_channel(c.topic, c.message_encoding, sid, dict(c.metadata))
        self.channels[c.id] = (new, c.topic)

    def message(self, m: Message) -> None:
        target = self.channels.get(m.channel_id)
        if target is None and m.channel_id in self.spare_channels:
            c = self.spare_channels[m.channel_id]
            if c.schema_id in self.spare_schemas:
                self.schema(self.spare_schemas[c.schema_id])
            self.channel(c)
            target = self.channels.get(m.channel_id)
        if target is None:
            self.skipped += 1
            return
        self.writer.add_message(target[0], log_time=m.log_time, data=m.data,
                                publish_time=m.publish_time, sequence=m.sequence)
        self.messages += 1
        self.by_topic[target[1]] = self.by_topic.get(target[1], 0) + 1
        if target[1] == topics.TOPIC_SAMPLES:
            self.last_sample_ns = max(m.log_time, self.last_sample_ns or 0)
            with contextlib.suppress(Exception):  # a foreign payload: no duration accounting
                d = sample_schema.decode_block(m.data)
                self.blocks.append((d.realization, d.first_sample, d.n_samples, d.sample_rate_hz))

    def seconds(self) -> tuple[float, float]:
        """(seconds recovered, seconds missing between recovered blocks) of the samples."""
        have = missing = 0.0
        by_real: dict[int, list[tuple[int, int, float]]] = {}
        for r, first, n, fs in self.blocks:
            by_real.setdefault(r, []).append((first, n, fs))
        for blocks in by_real.values():
            blocks.sort()
            end = None
            for first, n, fs in blocks:
                if fs <= 0:
                    continue
                have += n / fs
                if end is not None and first > end:
                    missing += (first - end) / fs
                end = max(end or 0, first + n)
        return have, missing


def recover(broken: str | os.PathLike[str], out: str | os.PathLike[str] | IO[bytes]) -> RecoverReport:
    """Copy every intact record of a damaged or unfinished MCAP file into a new indexed file.

    Parameters
    ----------
    broken : str or Path
        The damaged or unfinished recording (not modified).
    out : str or Path or binary stream
        Where to write the recovered recording. A path is written through a temporary
        sibling renamed at the end (a crash never leaves a half-written output); when no
        sample block could be salvaged, nothing is written under that name.

    Returns
    -------
    RecoverReport
        Counts, damaged byte ranges, seconds recovered and skipped (see ``.summary()``).

    Raises
    ------
    RecordingNotFoundError
        If ``broken`` does not exist.
    NotMcapError
        If it does not start with the MCAP magic.
    RecordingError
        If ``out`` is the input file or cannot be written.

    Notes
    -----
    Exactly the messages of the chunks that pass their CRC are recovered. A damaged
    record is skipped and the walk resumes at the next valid record (see the module
    docstring). A file finished normally is copied whole (``complete=True``).
    """
    src = Path(broken)
    if not src.is_file():
        raise RecordingNotFoundError(f"{src}: no such recording; check the path")
    if not isinstance(out, (str, os.PathLike)) and not hasattr(out, "write"):
        raise TypeError("out must be a path or a binary stream")
    file_size = src.stat().st_size
    with open(src, "rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise NotMcapError(f"{src}: not an MCAP file (bad magic bytes); nothing to recover")
        data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        if not isinstance(out, (str, os.PathLike)):
            return _copy(src, data, out, "<stream>", file_size)
        out_path = Path(out)
        if out_path.exists() and out_path.resolve() == src.resolve():
            raise RecordingError(f"{src}: recover needs a different output file, "
                                 f"e.g. `fnsi-lab recover {src} {src.stem}.recovered.mcap`")
        tmp = out_path.with_name(f".{out_path.name}.partial-{os.getpid()}")
        try:
            with open(tmp, "wb") as out_stream:
                report = _copy(src, data, out_stream, str(out_path), file_size)
            if report.sample_messages:
                os.replace(tmp, out_path)
        except OSError as exc:
            raise RecordingError(f"{out_path}: cannot write the recovered file "
                                 f"({exc.strerror or exc}); nothing was written under that "
                                 "name") from None
        finally:
            with contextlib.suppress(OSError):
                tmp.unlink()
        return report
    finally:
        data.close()


_HEAD = struct.Struct("<BQ")  # opcode, record length
#: Opcodes that may follow a record in the data section (a framing plausibility check).
_DATA_OPCODES = {Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK,
                 Opcode.MESSAGE_INDEX, Opcode.ATTACHMENT, Opcode.METADATA, Opcode.DATA_END}


def _framing_ok(data: Any, pos: int, size: int) -> int | None:
    """End offset of the record at ``pos`` if its length leads to a plausible next record."""
    if pos + 9 > size:
        return None
    opcode, length = _HEAD.unpack_from(data, pos)
    end = pos + 9 + length
    if opcode not in _DATA_OPCODES or end > size:
        return None
    if end == size or (end + 9 <= size and data[end] in _DATA_OPCODES):
        return end
    return None


def _chunk_at(data: Any, pos: int, size: int) -> tuple[Chunk, int] | None:
    """The chunk record at ``pos`` if its header is self-consistent and its CRC matches."""
    if pos + 9 + 40 > size or data[pos] != Opcode.CHUNK:
        return None
    length = int.from_bytes(data[pos + 1:pos + 9], "little")
    end = pos + 9 + length
    if end > size or length < 40:
        return None
    comp_len = int.from_bytes(data[pos + 37:pos + 41], "little")
    if comp_len > 8 or pos + 41 + comp_len + 8 > end:
        return None
    compression = bytes(data[pos + 41:pos + 41 + comp_len])
    if compression not in (b"zstd", b"lz4", b""):
        return None
    records_len = int.from_bytes(data[pos + 41 + comp_len:pos + 49 + comp_len], "little")
    if pos + 49 + comp_len + records_len != end:
        return None
    try:
        chunk = Chunk.read(ReadDataStream(_BytesReader(data[pos + 9:end])))
        return chunk, end
    except Exception:  # noqa: BLE001 - any parse failure: not a chunk
        return None


class _BytesReader:
    """Minimal ``read(n)`` over bytes (exact reads, for mcap's record parsers)."""

    def __init__(self, b: bytes) -> None:
        self._b = b
        self._pos = 0

    def read(self, n: int) -> bytes:
        out = self._b[self._pos:self._pos + n]
        if len(out) != n:
            raise McapError("record cut short")
        self._pos += n
        return out


#: Records a resynchronisation may land on: each carries a CRC that proves it intact.
_RESYNC_OPCODES = re.compile(bytes([ord("["), Opcode.CHUNK, Opcode.ATTACHMENT, Opcode.METADATA,
                                    ord("]")]))


def _intact_at(data: Any, i: int, size: int) -> bool:
    """True if a chunk, attachment or fnsi-lab metadata record at ``i`` passes its CRC."""
    opcode = data[i]
    if opcode == Opcode.CHUNK:
        found = _chunk_at(data, i, size)
        if found is None:
            return False
        if not found[0].uncompressed_crc:  # no CRC proves nothing
            return False
        try:
            breakup_chunk(found[0], validate_crc=True)
            return True
        except Exception:  # noqa: BLE001 - not an intact chunk
            return False
    end = _framing_ok(data, i, size)
    if end is None or end - i < 9 + 8:
        return False
    content = data[i + 9:end]
    if opcode == Opcode.ATTACHMENT:
        crc = int.from_bytes(content[-4:], "little")
        return crc != 0 and zlib.crc32(content[:-4]) == crc
    try:  # metadata: only fnsi-lab's, whose crc32 entry proves it
        record = Metadata.read(ReadDataStream(_BytesReader(content)))
    except Exception:  # noqa: BLE001 - not a metadata record
        return False
    crc = record.metadata.get(topics.METADATA_CRC_KEY)
    text = record.metadata.get(topics.METADATA_JSON_KEY)
    return crc is not None and text is not None and topics.metadata_crc(record.name, text) == crc


def _resync(data: Any, pos: int, size: int) -> int | None:
    """Offset of the next intact chunk, attachment or metadata record (or of the data end)
    after ``pos``; None if there is none."""
    j = data.find(bytes([Opcode.DATA_END]) + (4).to_bytes(8, "little"), pos + 1)
    for match in _RESYNC_OPCODES.finditer(data, pos + 1, j if j != -1 else size):
        if _intact_at(data, match.start(), size):
            return match.start()
    return j if j != -1 else None


def _read_spares(data: Any, size: int, copier: "_Copier") -> None:
    """Schemas and channels of the summary section, if the file has an intact footer."""
    footer_at = size - len(MCAP_MAGIC) - 29
    if footer_at < 0 or bytes(data[size - len(MCAP_MAGIC):]) != MCAP_MAGIC \
            or data[footer_at] != Opcode.FOOTER:
        return
    summary_start = int.from_bytes(data[footer_at + 9:footer_at + 17], "little")
    pos = summary_start
    with contextlib.suppress(Exception):
        while 0 < pos < footer_at:
            opcode, length = _HEAD.unpack_from(data, pos)
            content = data[pos + 9:pos + 9 + length]
            if opcode == Opcode.SCHEMA:
                s = Schema.read(ReadDataStream(_BytesReader(content)))
                copier.spare_schemas[s.id] = s
            elif opcode == Opcode.CHANNEL:
                c = Channel.read(ReadDataStream(_BytesReader(content)))
                copier.spare_channels[c.id] = c
            pos += 9 + length


def _copy(src: Path, data: Any, out_stream: IO[bytes], out_name: str,
          file_size: int) -> RecoverReport:
    size = len(data)
    writer = Writer(out_stream, compression=CompressionType.ZSTD)
    copier = _Copier(writer)
    _read_spares(data, size, copier)
    chunks = metadata = attachments = 0
    damaged: list[tuple[int, int, str]] = []
    complete = False
    header_seen = False
    # fnsi-lab always writes CRCs: in its files a zero CRC field is damage. Known from the
    # header's library, or from metadata records carrying their crc32 (a damaged header).
    fnsi_written = False
    unchecked = 0
    stop_reason = "file ends without footer"
    pos = len(MCAP_MAGIC)
    good_end = pos
    while pos < size:
        if pos + 9 > size:
            stop_reason = "record cut short (file ends inside it)"
            break
        opcode, length = _HEAD.unpack_from(data, pos)
        end = pos + 9 + length
        problem = None
        try:
            if end > size:
                raise McapError("record runs past the end of the file")
            content = data[pos + 9:end]
            stream = ReadDataStream(_BytesReader(content))
            if opcode == Opcode.HEADER:
                header = Header.read(stream)
                fnsi_written |= header.library.startswith(topics.LIBRARY_PREFIX)
                if not header_seen:
                    writer.start(profile=header.profile, library=header.library)
                    header_seen = True
            elif not header_seen:
                raise McapError("records before the MCAP header")
            elif opcode == Opcode.CHUNK:
                if _chunk_at(data, pos, size) is None:
                    raise McapError("inconsistent chunk header")
                chunk = Chunk.read(stream)
                if not chunk.uncompressed_crc:
                    if fnsi_written:
                        raise McapError("its CRC field is zero (fnsi-lab always writes one)")
                    unchecked += 1
                # Decompress and check the CRC before copying anything of the chunk.
                inner = breakup_chunk(chunk, validate_crc=True)
                for r in inner:
                    if isinstance(r, Schema):
                        copier.schema(r)
                    elif isinstance(r, Channel):
                        copier.channel(r)
                    elif isinstance(r, Message):
                        copier.message(r)
                # Keep the input's chunk boundaries (about one per flush interval).
                writer.flush()
                chunks += 1
            elif opcode == Opcode.SCHEMA:
                copier.schema(Schema.read(stream))
            elif opcode == Opcode.CHANNEL:
                copier.channel(Channel.read(stream))
            elif opcode == Opcode.MESSAGE:
                copier.message(Message.read(stream, length))
            elif opcode == Opcode.METADATA:
                record = Metadata.read(stream)
                crc = record.metadata.get(topics.METADATA_CRC_KEY)
                text = record.metadata.get(topics.METADATA_JSON_KEY)
                if crc is not None and (text is None or topics.metadata_crc(record.name, text) != crc):
                    raise McapError(f"metadata record {record.name!r}: CRC mismatch")
                fnsi_written |= crc is not None
                writer.add_metadata(record.name, dict(record.metadata))
                metadata += 1
            elif opcode == Opcode.ATTACHMENT:
                crc = int.from_bytes(content[-4:], "little")
                if crc and zlib.crc32(content[:-4]) != crc:
                    raise McapError("attachment CRC mismatch")
                if not crc and fnsi_written:
                    raise McapError("attachment: its CRC field is zero (fnsi-lab always "
                                    "writes one)")
                record = Attachment.read(stream)
                writer.add_attachment(record.create_time, record.log_time, record.name,
                                      record.media_type, record.data)
                attachments += 1
            elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                complete = not damaged
                good_end = end if opcode == Opcode.DATA_END else pos
                stop_reason = "end of file"
                break
            elif opcode not in _DATA_OPCODES and opcode not in (
                    Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                    Opcode.STATISTICS, Opcode.SUMMARY_OFFSET):
                raise McapError(f"unknown opcode 0x{opcode:02x}")
            # message indexes (and any summary record) are rebuilt by the writer
        except Exception as exc:  # noqa: BLE001 - zstd/lz4/struct raise their own classes
            problem = f"{_record_name(opcode)}: {type(exc).__name__}: {exc}"
        if problem is None:
            pos = good_end = end
            continue
        if not header_seen:  # a damaged header: the data after it may still be intact
            writer.start(profile=topics.PROFILE, library=f"{topics.LIBRARY_PREFIX} (recovered)")
            header_seen = True
        # Skip exactly this record when its framing is intact, else scan for a valid chunk.
        nxt = _framing_ok(data, pos, size)
        if nxt is None or opcode != Opcode.CHUNK and opcode not in _DATA_OPCODES:
            nxt = _resync(data, pos, size)
        if nxt is None:  # nothing intact after it: the bytes from here on are lost
            stop_reason = ("record cut short (file ends inside it)" if end > size else
                           f"{problem}; no intact chunk after it")
            break
        damaged.append((pos, nxt, problem))
        pos = nxt
    if not header_seen:
        raise RecordingError(f"{src}: no readable MCAP header; nothing to recover")
    if not complete:
        name = topics.metadata_record_name("recovery")
        text = dumps({"source_file": str(src), "bytes_recovered": good_end,
                      "file_size": file_size, "stop_reason": stop_reason,
                      "software_version": software_version(),
                      "damaged_byte_ranges": [[a, b] for a, b, _ in damaged]})
        writer.add_metadata(name, {topics.METADATA_JSON_KEY: text,
                                   topics.METADATA_CRC_KEY: topics.metadata_crc(name, text)})
    try:
        writer.finish()
        out_stream.flush()
    except OSError as exc:
        raise RecordingError(f"{out_name}: cannot write the recovered file ({exc})") from None
    have_s, missing_s = copier.seconds()
    return RecoverReport(source=str(src), output=out_name, complete=complete,
                         messages=copier.messages, messages_by_topic=dict(copier.by_topic),
                         chunks=chunks, metadata=metadata, attachments=attachments,
                         bytes_recovered=good_end if not complete else file_size,
                         file_size=file_size, stop_reason=stop_reason,
                         last_log_time_ns=copier.last_sample_ns, skipped_messages=copier.skipped,
                         damaged=tuple(damaged), seconds_skipped=missing_s,
                         seconds_recovered=have_s, unchecked_chunks=unchecked)


def _record_name(opcode: int) -> str:
    try:
        return f"{Opcode(opcode).name.lower().replace('_', ' ')} record"
    except ValueError:
        return f"record with opcode 0x{opcode:02x}"
