"""Salvage an unfinished MCAP recording (writer crashed, killed, power cut) into a valid one.

A recording killed mid-run has no summary and no footer, so indexed readers refuse it.
Its data section, however, is a sequence of self-delimiting records; every chunk carries a
CRC of its uncompressed content. :func:`recover` reads the records in order with mcap's
``StreamReader`` (CRC checks on), re-registers schemas and channels, and copies every
message of every intact chunk, plus metadata and attachments, into a new, indexed file.
It stops at the first record that is truncated, fails its CRC or does not parse; the
report says where. Messages are copied byte for byte with their log/publish times and
sequence numbers.
"""

from __future__ import annotations

import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import EndOfFile, McapError
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message,
                          Metadata, Schema)
from mcap.stream_reader import MAGIC_SIZE, StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

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

    @property
    def bytes_lost(self) -> int:
        """Input bytes after the last intact record (not recovered)."""
        return max(self.file_size - self.bytes_recovered, 0)

    def summary(self) -> str:
        """Human-readable multi-line report (printed by ``fnsi-lab recover``)."""
        state = ("input was complete; copied and re-indexed" if self.complete else
                 f"stopped at byte {self.bytes_recovered} of {self.file_size} "
                 f"({self.bytes_lost} bytes lost): {self.stop_reason}")
        lines = [f"recovered {self.source} -> {self.output}",
                 f"  {self.messages} messages in {self.chunks} chunks, {self.metadata} metadata "
                 f"records, {self.attachments} attachments",
                 f"  {state}"]
        for topic, n in sorted(self.messages_by_topic.items()):
            lines.append(f"  {topic}: {n} messages")
        if self.last_log_time_ns is not None:
            lines.append(f"  last sample block at log time {self.last_log_time_ns} ns")
        if self.skipped_messages:
            lines.append(f"  {self.skipped_messages} messages skipped (channel record lost)")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__} | {
            "bytes_lost": self.bytes_lost}


class _ExactReader:
    """File wrapper whose ``read(n)`` returns exactly n bytes or raises ``EndOfFile``.

    mcap's stream reader accepts short reads silently (a truncated record would then
    parse as garbage); here a record cut by the crash is detected as such.
    """

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f
        self.pos = 0

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        if n is not None and n >= 0 and len(data) < n:
            raise EndOfFile()
        self.pos += len(data)
        return data


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
        if target is None:
            self.skipped += 1
            return
        self.writer.add_message(target[0], log_time=m.log_time, data=m.data,
                                publish_time=m.publish_time, sequence=m.sequence)
        self.messages += 1
        self.by_topic[target[1]] = self.by_topic.get(target[1], 0) + 1
        if target[1] == topics.TOPIC_SAMPLES:
            self.last_sample_ns = max(m.log_time, self.last_sample_ns or 0)


def recover(broken: str | os.PathLike[str], out: str | os.PathLike[str] | IO[bytes]) -> RecoverReport:
    """Copy every intact record of a (possibly unfinished) MCAP file into a new indexed file.

    Parameters
    ----------
    broken : str or Path
        The damaged or unfinished recording (not modified).
    out : str or Path or binary stream
        Where to write the recovered recording (a path is overwritten).

    Returns
    -------
    RecoverReport
        Counts and the byte offset where reading stopped (see ``.summary()``).

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
    Exactly the messages of the chunks written completely are recovered: a chunk is
    copied only after its CRC matched, and a record cut short raises ``EndOfFile``.
    A file finished normally is copied whole (``complete=True``).
    """
    src = Path(broken)
    if not src.is_file():
        raise RecordingNotFoundError(f"{src}: no such recording; check the path")
    if not isinstance(out, (str, os.PathLike)) and not hasattr(out, "write"):
        raise TypeError("out must be a path or a binary stream")
    if isinstance(out, (str, os.PathLike)):
        out_path = Path(out)
        if out_path.exists() and out_path.resolve() == src.resolve():
            raise RecordingError(f"{src}: recover needs a different output file, "
                                 f"e.g. `fnsi-lab recover {src} {src.stem}.recovered.mcap`")
    file_size = src.stat().st_size
    with open(src, "rb") as f:
        if f.read(MAGIC_SIZE) != MCAP_MAGIC:
            raise NotMcapError(f"{src}: not an MCAP file (bad magic bytes); nothing to recover")
        f.seek(0)
        stream = _ExactReader(f)
        out_stream: IO[bytes]
        if isinstance(out, (str, os.PathLike)):
            try:
                out_stream = open(out, "wb")
            except OSError as exc:
                raise RecordingError(f"{out}: cannot create the recovered file ({exc.strerror})") from None
            out_name, close_out = str(out), True
        else:
            out_stream, out_name, close_out = out, "<stream>", False
        try:
            report = _copy(src, stream, out_stream, out_name, file_size)
        finally:
            if close_out:
                out_stream.close()
    return report


def _copy(src: Path, stream: _ExactReader, out_stream: IO[bytes], out_name: str,
          file_size: int) -> RecoverReport:
    reader = StreamReader(stream, emit_chunks=True, validate_crcs=True)
    records = reader.records
    writer: Writer | None = None
    copier: _Copier | None = None
    chunks = metadata = attachments = 0
    good_end = 0
    complete = False
    stop_reason = "end of file"
    while True:
        try:
            record = next(records)
        except StopIteration:
            break
        except EndOfFile:
            stop_reason = "record cut short (file ends inside it)" if stream.pos > good_end \
                else "file ends without footer"
            break
        except Exception as exc:  # noqa: BLE001 - any parse failure ends the salvage
            stop_reason = f"unreadable record ({type(exc).__name__}: {exc})"
            break
        try:
            if isinstance(record, Header):
                writer = Writer(out_stream, compression=CompressionType.ZSTD)
                writer.start(profile=record.profile, library=record.library)
                copier = _Copier(writer)
            elif writer is None or copier is None:
                raise McapError("records before the MCAP header")
            elif isinstance(record, Chunk):
                # Decompress and check the CRC before copying anything of the chunk.
                inner = breakup_chunk(record, validate_crc=True)
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
            elif isinstance(record, Schema):
                copier.schema(record)
            elif isinstance(record, Channel):
                copier.channel(record)
            elif isinstance(record, Message):
                copier.message(record)
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, dict(record.metadata))
                metadata += 1
            elif isinstance(record, Attachment):
                writer.add_attachment(record.create_time, record.log_time, record.name,
                                      record.media_type, record.data)
                attachments += 1
            elif isinstance(record, (DataEnd, Footer)):
                complete = True
                good_end = stream.pos
                break
            # indexes, statistics and summary offsets are rebuilt by the writer
        except (McapError, zlib.error, ValueError, OSError, EOFError) as exc:
            stop_reason = f"damaged record at byte {good_end} ({type(exc).__name__}: {exc})"
            break
        except Exception as exc:  # noqa: BLE001 - zstd errors have their own classes
            stop_reason = f"damaged record at byte {good_end} ({type(exc).__name__}: {exc})"
            break
        good_end = stream.pos
    if writer is None or copier is None:
        raise RecordingError(f"{src}: no readable MCAP header; nothing to recover")
    if not complete:
        writer.add_metadata(topics.metadata_record_name("recovery"), {
            topics.METADATA_JSON_KEY: dumps({"source_file": str(src), "bytes_recovered": good_end,
                                             "file_size": file_size, "stop_reason": stop_reason,
                                             "software_version": software_version()})})
    try:
        writer.finish()
        out_stream.flush()
    except OSError as exc:
        raise RecordingError(f"{out_name}: cannot write the recovered file ({exc})") from None
    return RecoverReport(source=str(src), output=out_name, complete=complete,
                         messages=copier.messages, messages_by_topic=dict(copier.by_topic),
                         chunks=chunks, metadata=metadata, attachments=attachments,
                         bytes_recovered=good_end if not complete else file_size,
                         file_size=file_size, stop_reason=stop_reason,
                         last_log_time_ns=copier.last_sample_ns, skipped_messages=copier.skipped)
