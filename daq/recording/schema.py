"""The protobuf schema of a sample block, built at run time, and a fast codec for it.

The schema is equivalent to this ``.proto`` file (proto3)::

    syntax = "proto3";
    package fnsi_lab;
    message SampleBlock {
      repeated float data = 1;      // packed, row-major (n_samples, n_channels)
      uint32 n_channels = 2;
      uint32 n_samples = 3;
      int64 first_sample = 4;       // index of row 0 within its realization
      uint32 realization = 5;
      double sample_rate_hz = 6;
      int64 t0_ns = 7;              // time of row 0, integer nanoseconds
      uint64 sequence = 8;          // block counter of the source
    }

No ``protoc`` and no generated code: the descriptor is assembled with ``descriptor_pb2``
and the message class obtained from ``message_factory``; the serialized
``FileDescriptorSet`` is the MCAP schema (encoding ``protobuf``), so any protobuf stack can
decode the messages.

Why a hand-written codec: building ``data`` through the protobuf API converts every float
to a Python object (~400x real time for 39 channels at 1 kHz); writing the packed field as
tag + length + the little-endian float32 bytes of the numpy array is the same wire format
(proto3 packs repeated scalars) and runs at memory speed. :func:`encode_block` produces
exactly the bytes ``SerializeToString`` would (fields in number order, zero scalars
omitted); the tests check this against the protobuf runtime.
"""

from __future__ import annotations

import functools
import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from fnsi_lab.daq.recording import topics
from fnsi_lab.errors import ConfigError

_F = descriptor_pb2.FieldDescriptorProto

#: (name, number, type) of every field, in number order.
FIELDS: tuple[tuple[str, int, int], ...] = (
    ("data", 1, _F.TYPE_FLOAT),
    ("n_channels", 2, _F.TYPE_UINT32),
    ("n_samples", 3, _F.TYPE_UINT32),
    ("first_sample", 4, _F.TYPE_INT64),
    ("realization", 5, _F.TYPE_UINT32),
    ("sample_rate_hz", 6, _F.TYPE_DOUBLE),
    ("t0_ns", 7, _F.TYPE_INT64),
    ("sequence", 8, _F.TYPE_UINT64),
)

#: JSON schema of the events topic (one :class:`daq.source.SourceEvent` per message).
EVENT_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": topics.EVENTS_SCHEMA_NAME,
    "type": "object",
    "properties": {
        "time_ns": {"type": "integer", "description": "event time, integer nanoseconds"},
        "kind": {"type": "string", "description": "event kind (error_frame, reconnect...)"},
        "detail": {"type": "object", "description": "kind-specific details"},
    },
    "required": ["time_ns", "kind", "detail"],
}

#: Permissive JSON schema shared by auxiliary JSON topics (raw CAN frames...).
AUX_JSON_SCHEMA: dict[str, Any] = {"title": topics.AUX_JSON_SCHEMA_NAME}


def file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """The ``FileDescriptorProto`` of :data:`topics.SAMPLES_SCHEMA_NAME` (a fresh copy)."""
    fdp = descriptor_pb2.FileDescriptorProto(
        name=topics.SAMPLES_PROTO_FILE, package=topics.PROTO_PACKAGE, syntax="proto3")
    msg = fdp.message_type.add(name=topics.SAMPLES_SCHEMA_NAME.rsplit(".", 1)[1])
    for name, number, ftype in FIELDS:
        label = _F.LABEL_REPEATED if name == "data" else _F.LABEL_OPTIONAL
        msg.field.add(name=name, number=number, type=ftype, label=label, json_name=_camel(name))
    return fdp


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(p.capitalize() for p in rest)


@functools.lru_cache(maxsize=1)
def schema_bytes() -> bytes:
    """Serialized ``FileDescriptorSet``: the MCAP schema data of the samples channel."""
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.append(file_descriptor_proto())
    return fds.SerializeToString(deterministic=True)


@functools.lru_cache(maxsize=1)
def message_class() -> type:
    """The protobuf message class of a sample block (own descriptor pool, built once)."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_descriptor_proto())
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(topics.SAMPLES_SCHEMA_NAME))


def event_schema_bytes() -> bytes:
    """JSON schema text of the events topic, UTF-8."""
    return json.dumps(EVENT_JSON_SCHEMA, sort_keys=True).encode()


def aux_schema_bytes() -> bytes:
    """JSON schema text shared by auxiliary topics, UTF-8."""
    return json.dumps(AUX_JSON_SCHEMA, sort_keys=True).encode()


# ---------------------------------------------------------------------------- encoding
_U64 = 1 << 64


def _varint(value: int) -> bytes:
    """Base-128 varint; negative int64 values use their 64-bit two's complement (10 bytes)."""
    if value < 0:
        value += _U64
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def encode_block(data: np.ndarray, *, first_sample: int, realization: int,
                 sample_rate_hz: float, t0_ns: int, sequence: int) -> bytes:
    """Serialize one sample block as a ``fnsi_lab.SampleBlock`` protobuf message.

    Parameters
    ----------
    data : ndarray, shape (n_samples, n_channels)
        Samples; converted to little-endian float32 (a no-op for float32 input, which is
        therefore stored bit for bit).
    first_sample, realization, sample_rate_hz, t0_ns, sequence
        The :class:`daq.block.Block` fields of the same names.

    Returns
    -------
    bytes
        Canonical protobuf bytes (identical to ``SerializeToString``).
    """
    arr = np.ascontiguousarray(data, dtype="<f4")
    if arr.ndim != 2:
        raise ConfigError(f"sample block must be 2-D (n_samples, n_channels), got shape {arr.shape}")
    n_samples, n_channels = arr.shape
    parts: list[bytes | memoryview] = []
    if arr.size:
        raw = memoryview(arr).cast("B")
        parts += [b"\x0a", _varint(raw.nbytes), raw]
    # proto3 omits scalars equal to their default (0), so we do too: canonical bytes.
    for tag, value in ((b"\x10", n_channels), (b"\x18", n_samples), (b"\x20", first_sample),
                       (b"\x28", realization)):
        if value:
            parts += [tag, _varint(int(value))]
    if sample_rate_hz != 0.0:
        parts += [b"\x31", struct.pack("<d", sample_rate_hz)]
    if t0_ns:
        parts += [b"\x38", _varint(int(t0_ns))]
    if sequence:
        parts += [b"\x40", _varint(int(sequence))]
    return b"".join(parts)


# ---------------------------------------------------------------------------- decoding
@dataclass(frozen=True)
class DecodedBlock:
    """The fields of one decoded ``SampleBlock`` message.

    Attributes
    ----------
    data : ndarray of float32, shape (n_samples, n_channels)
        Read-only view on the message bytes (no copy).
    """

    data: np.ndarray
    n_channels: int
    n_samples: int
    first_sample: int
    realization: int
    sample_rate_hz: float
    t0_ns: int
    sequence: int


class MalformedMessageError(ValueError):
    """The bytes are not a valid ``SampleBlock`` message (the reader turns it into a
    :class:`~daq.recording.errors.RecordingError` naming the file)."""


def _read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = 0
    shift = 0
    while True:
        if pos >= len(buf) or shift > 63:
            raise MalformedMessageError("truncated or overlong varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _signed64(value: int) -> int:
    return value - _U64 if value >= 1 << 63 else value


def decode_block(buf: bytes) -> DecodedBlock:
    """Parse a ``SampleBlock`` message (any valid encoding: packed or not, any field order).

    Parameters
    ----------
    buf : bytes
        Message bytes.

    Returns
    -------
    DecodedBlock

    Raises
    ------
    MalformedMessageError
        If the bytes are not valid protobuf or ``data`` does not hold
        ``n_samples * n_channels`` values.
    """
    scalars = {2: 0, 3: 0, 4: 0, 5: 0, 7: 0, 8: 0}
    rate = 0.0
    chunks: list[tuple[int, int]] = []  # (offset, n_floats) of the packed data pieces
    loose: list[float] = []  # unpacked floats (legal protobuf, not written by us)
    pos, end = 0, len(buf)
    try:
        while pos < end:
            key, pos = _read_varint(buf, pos)
            field, wire = key >> 3, key & 7
            if wire == 0:
                value, pos = _read_varint(buf, pos)
                if field in scalars:
                    scalars[field] = value
            elif wire == 1:
                if field == 6:
                    (rate,) = struct.unpack_from("<d", buf, pos)
                pos += 8
            elif wire == 2:
                length, pos = _read_varint(buf, pos)
                if field == 1:
                    if length % 4:
                        raise MalformedMessageError("packed float field length is not a multiple of 4")
                    chunks.append((pos, length // 4))
                pos += length
            elif wire == 5:
                if field == 1:
                    loose.append(struct.unpack_from("<f", buf, pos)[0])
                pos += 4
            else:
                raise MalformedMessageError(f"unsupported wire type {wire}")
    except struct.error as exc:
        raise MalformedMessageError(f"truncated message ({exc})") from None
    if pos != end:
        raise MalformedMessageError("truncated message")
    n_channels, n_samples = scalars[2], scalars[3]
    if len(chunks) == 1 and not loose:
        off, count = chunks[0]
        data = np.frombuffer(buf, dtype="<f4", count=count, offset=off)
    elif not chunks and not loose:
        data = np.zeros(0, dtype="<f4")
    else:  # several pieces: protobuf concatenates them; exact bits need the raw bytes
        pieces = [np.frombuffer(buf, dtype="<f4", count=c, offset=o) for o, c in chunks]
        if loose:
            pieces.append(np.asarray(loose, dtype="<f4"))
        data = np.concatenate(pieces)
    if data.size != n_samples * n_channels:
        raise MalformedMessageError(f"data holds {data.size} values, expected n_samples * "
                                    f"n_channels = {n_samples} * {n_channels}")
    return DecodedBlock(data=data.reshape(n_samples, n_channels), n_channels=n_channels,
                        n_samples=n_samples, first_sample=_signed64(scalars[4]),
                        realization=scalars[5], sample_rate_hz=float(rate),
                        t0_ns=_signed64(scalars[7]), sequence=scalars[8])


def decode_header(buf: bytes) -> tuple[int, int, int, int, int]:
    """``(n_samples, n_channels, first_sample, realization, sequence)`` without touching data.

    Used by ``fnsi-lab info``, which only needs the counts.
    """
    d = decode_block(buf)  # frombuffer is a view: the float bytes are not copied
    return d.n_samples, d.n_channels, d.first_sample, d.realization, d.sequence
