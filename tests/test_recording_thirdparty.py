"""Our sample messages decode with independent stacks: google.protobuf and Rerun's MCAP reader."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from fnsi_lab.daq.recording import schema, topics


def _class_from_file_descriptor_set(data: bytes, full_name: str) -> type:
    fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for fdp in fds.file:
        pool.Add(fdp)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(full_name))


def _independent_class() -> type:
    """The message written by hand from docs/recording-format.md's .proto text."""
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="independent.proto", package="fnsi_lab",
                                             syntax="proto3")
    m = fdp.message_type.add(name="SampleBlock")
    m.field.add(name="data", number=1, type=F.TYPE_FLOAT, label=F.LABEL_REPEATED)
    for name, number, t in [("n_channels", 2, F.TYPE_UINT32), ("n_samples", 3, F.TYPE_UINT32),
                            ("first_sample", 4, F.TYPE_INT64), ("realization", 5, F.TYPE_UINT32),
                            ("sample_rate_hz", 6, F.TYPE_DOUBLE), ("t0_ns", 7, F.TYPE_INT64),
                            ("sequence", 8, F.TYPE_UINT64)]:
        m.field.add(name=name, number=number, type=t, label=F.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("fnsi_lab.SampleBlock"))


def test_protobuf_runtime_decodes_the_recorded_messages(write_recording):
    path, blocks = write_recording(realizations=2, noise=1e-3)
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = list(reader.iter_messages(topics=[topics.TOPIC_SAMPLES], log_time_order=False))
    sch = msgs[0][0]
    assert (sch.name, sch.encoding) == (topics.SAMPLES_SCHEMA_NAME, "protobuf")
    from_file = _class_from_file_descriptor_set(sch.data, sch.name)
    independent = _independent_class()
    assert len(msgs) == len(blocks)
    for (_, _, message), block in zip(msgs, blocks):
        for cls in (from_file, independent):
            m = cls.FromString(message.data)
            data = np.asarray(m.data, dtype=np.float32).reshape(m.n_samples, m.n_channels)
            assert data.tobytes() == block.data.tobytes()
            assert (m.first_sample, m.realization, m.t0_ns, m.sequence, m.sample_rate_hz) == \
                   (block.first_sample, block.realization, block.t0_ns, block.sequence, 1000.0)
        # our fast encoder writes the canonical bytes of the protobuf runtime
        ref = independent(data=block.data.ravel().tolist(), n_channels=block.n_channels,
                          n_samples=block.n_samples, first_sample=block.first_sample,
                          realization=block.realization, sample_rate_hz=1000.0,
                          t0_ns=block.t0_ns, sequence=block.sequence)
        assert ref.SerializeToString() == message.data


@pytest.mark.parametrize("fields", [
    dict(first_sample=-3, realization=0, sample_rate_hz=0.0, t0_ns=-(2**62), sequence=2**64 - 1),
    dict(first_sample=2**40, realization=7, sample_rate_hz=51200.0, t0_ns=1, sequence=0),
])
def test_codec_edge_values(fields):
    data = np.random.default_rng(0).standard_normal((3, 5)).astype(np.float32)
    raw = schema.encode_block(data, **fields)
    m = _independent_class().FromString(raw)
    assert m.first_sample == fields["first_sample"] and m.t0_ns == fields["t0_ns"]
    assert m.sequence == fields["sequence"]
    assert m.SerializeToString() == raw
    d = schema.decode_block(raw)
    assert d.data.tobytes() == data.tobytes() and d.sequence == fields["sequence"]
    assert d.t0_ns == fields["t0_ns"] and d.first_sample == fields["first_sample"]


def test_decoder_accepts_unpacked_and_reordered_encodings():
    """Other writers may emit unpacked floats or another field order: still decoded."""
    data = np.arange(6, dtype=np.float32).reshape(2, 3)
    # field 3 (n_samples=2), then field 2 (n_channels=3), then six unpacked floats (tag 0x0d)
    raw = b"\x18\x02\x10\x03" + b"".join(b"\x0d" + v.tobytes() for v in data.ravel())
    d = schema.decode_block(raw)
    assert d.data.tobytes() == data.tobytes()
    with pytest.raises(schema.MalformedMessageError):
        schema.decode_block(b"\x0a\x08\x00\x00")  # packed field longer than the message


def test_rerun_mcap_info_reads_our_file(write_recording, tmp_path):
    rerun = shutil.which("rerun")
    if rerun is None:
        pytest.skip("the `rerun` binary (rerun-sdk) is not on PATH")
    path, blocks = write_recording()
    subprocess.run([rerun, "analytics", "disable"], capture_output=True, timeout=60)
    out = subprocess.run([rerun, "mcap", "info", str(path)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert topics.TOPIC_SAMPLES in out.stdout and topics.SAMPLES_SCHEMA_NAME in out.stdout
    assert f"Messages                 {len(blocks)}" in out.stdout


def test_rerun_decodes_the_protobuf_samples(write_recording, tmp_path):
    rerun = shutil.which("rerun")
    if rerun is None:
        pytest.skip("the `rerun` binary (rerun-sdk) is not on PATH")
    pytest.importorskip("pyarrow")
    from rerun.chunk import RrdReader
    path, blocks = write_recording()
    rrd = tmp_path / "rec.rrd"
    subprocess.run([rerun, "analytics", "disable"], capture_output=True, timeout=60)
    out = subprocess.run([rerun, "mcap", "convert", str(path), "-o", str(rrd)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    rows = []
    for chunk in RrdReader(str(rrd)).stream():
        batch = chunk.to_record_batch()
        cols = [c for c in batch.schema.names if topics.SAMPLES_SCHEMA_NAME in c]
        if cols:
            for cell in batch.column(cols[0]).to_pylist():
                rows.extend(cell)
    rows.sort(key=lambda r: r["sequence"])
    assert len(rows) == len(blocks)
    for row, block in zip(rows, blocks):
        data = np.asarray(row["data"], dtype=np.float32).reshape(row["n_samples"], row["n_channels"])
        assert data.tobytes() == block.data.tobytes()
        assert row["t0_ns"] == block.t0_ns and row["first_sample"] == block.first_sample
