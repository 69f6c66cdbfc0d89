"""MCAP recording: round trip, time ranges, periodic records, info, bad inputs."""

from __future__ import annotations

import io
import json
import signal
import threading

import numpy as np
import pytest
from mcap.writer import Writer

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.recording import (MissingChannelsError, NotMcapError, Recorder, RecorderClosedError,
                           RecordingError, RecordingNotFoundError, UnfinishedRecordingError,
                           WrongSchemaError, format_info, open_recording, read_periodic,
                           recording_info, topics)
from fnsi_lab.daq.source import SourceEvent
from fnsi_lab import __version__
from fnsi_lab.errors import DataFileError
from conftest import blocks_from_array, make_channels


def _npz_bytes(**arrays: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# ---------------------------------------------------------------------------- round trip
def test_round_trip_is_bit_exact(write_recording):
    frf = (np.arange(12) * (1 + 2j)).reshape(3, 2, 2)
    npz = _npz_bytes(frf=frf)
    path, blocks = write_recording(
        noise=1e-3, metadata={"truth": {"frequency_hz": [3.5, 7.25], "damping": [0.01, 0.02]},
                              "experiment": {"name": "unit", "source_kind": "synthetic"},
                              "source": {"kind": "synthetic"}},
        attachments=[("experiment.yaml", "application/yaml", b"name: unit\n"),
                     ("truth_frf.npz", topics.MEDIA_TYPE_NPZ, npz)])
    # special values must survive too
    with open_recording(path) as rec:
        got = list(rec.iter_blocks())
        assert len(got) == len(blocks)
        for a, b in zip(got, blocks):
            assert a.data.dtype == np.float32
            assert a.data.tobytes() == b.data.tobytes()  # bit for bit
            assert (a.sequence, a.first_sample, a.t0_ns, a.realization) == \
                   (b.sequence, b.first_sample, b.t0_ns, b.realization)
            assert a.sample_rate_hz == 1000.0
            assert a.channels == rec.channels
        assert rec.channels == make_channels()
        assert [c.quantity for c in rec.input_channels] == ["force"]
        assert rec.sample_rate_hz == 1000.0
        assert rec.truth == {"frequency_hz": [3.5, 7.25], "damping": [0.01, 0.02]}
        assert rec.experiment == {"name": "unit", "source_kind": "synthetic",
                                  "software_version": __version__}
        assert rec.metadata["channels"] == [c.to_dict() for c in make_channels()]
        assert rec.excitation["samples_per_period"] == 200
        att = rec.attachments()
        assert att["experiment.yaml"] == b"name: unit\n"
        assert rec.experiment_yaml == "name: unit\n"
        np.testing.assert_array_equal(np.load(io.BytesIO(att["truth_frf.npz"]))["frf"], frf)
        assert rec.n_blocks == len(blocks)


def test_special_float_values_and_float64_input(tmp_path):
    chans = make_channels(1, 1)
    special = np.array([[np.nan, -0.0], [np.inf, -np.inf], [1e-45, 3.4028235e38]], np.float32)
    wide = np.array([[0.1, 1 / 3]])  # float64: rounded once to float32
    with Recorder(tmp_path / "s.mcap", chans, 10.0) as rec:
        rec.write_block(Block(special, chans, 10.0, 0, 0, 0))
        rec.write_block(Block(wide, chans, 10.0, 1, 3, 300_000_000))
    with open_recording(tmp_path / "s.mcap") as r:
        a, b = list(r.iter_blocks())
    assert a.data.tobytes() == special.tobytes()
    assert b.data.tobytes() == wide.astype(np.float32).tobytes()


def test_channel_table_in_channel_metadata_and_record(write_recording):
    from mcap.reader import make_reader
    path, _ = write_recording()
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        (ch,) = [c for c in summary.channels.values() if c.topic == topics.TOPIC_SAMPLES]
        table = json.loads(ch.metadata[topics.CHANNEL_META_CHANNELS])
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert table == [c.to_dict() for c in make_channels()]
    assert json.loads(records["fnsi_lab.channels"]["json"]) == table
    assert set(records) >= {"fnsi_lab.experiment", "fnsi_lab.channels", "fnsi_lab.excitation"}
    assert all(set(v) == {"json", "crc32"} for v in records.values())
    assert summary.schemas[ch.schema_id].encoding == "protobuf"


def test_events_aux_topics_and_late_metadata(tmp_path):
    chans = make_channels(1, 1)
    with Recorder(tmp_path / "e.mcap", chans, 100.0) as rec:
        rec.write_block(Block(np.zeros((10, 2), np.float32), chans, 100.0, 0, 0, 0))
        rec.write_event(SourceEvent(time_ns=5, kind="error_frame", detail={"id": 7}))
        rec.write_event(SourceEvent(time_ns=6, kind="error_frame", detail={}))
        rec.write_event(SourceEvent(time_ns=7, kind="reconnect", detail={"n": np.int64(2)}))
        rec.write_json("/can/raw", 11, {"id": 0x123, "data": np.arange(3, dtype=np.uint8)})
        rec.write_json("/can/raw", 12, {"id": 0x124, "data": [1]})
        rec.add_metadata("stats", {"dropped": 0})
        with pytest.raises(ValueError, match="reserved"):
            rec.write_json(topics.TOPIC_SAMPLES, 0, {})
    with open_recording(tmp_path / "e.mcap") as r:
        events = list(r.iter_events())
        assert [e["kind"] for e in events] == ["error_frame", "error_frame", "reconnect"]
        assert events[2]["detail"] == {"n": 2}
        assert list(r.iter_json("/can/raw")) == [(11, {"id": 0x123, "data": [0, 1, 2]}),
                                                 (12, {"id": 0x124, "data": [1]})]
        assert r.metadata["stats"] == {"dropped": 0}
        assert r.message_counts == {topics.TOPIC_SAMPLES: 1, topics.TOPIC_EVENTS: 3, "/can/raw": 2}
    info = recording_info(tmp_path / "e.mcap")
    assert info["events"] == {"error_frame": 2, "reconnect": 1}



def _strict_json(text: str):
    """Parse as strict JSON: NaN/Infinity tokens are an error (as in JavaScript, jq...)."""
    def refuse(token):
        raise AssertionError(f"non-standard JSON token {token} in {text[:80]!r}")
    return json.loads(text, parse_constant=refuse)


def test_json_inside_recordings_is_strict_and_uses_the_one_encoder(tmp_path):
    """Metadata, events and auxiliary topics go through fnsi_lab.outputs.dumps: NaN and
    infinities become null, numpy values plain numbers, sets sorted lists (issue 10)."""
    from mcap.reader import make_reader

    from fnsi_lab import outputs
    from fnsi_lab.daq.recording import writer

    chans = make_channels(1, 1)
    path = tmp_path / "nan.mcap"
    with Recorder(path, chans, 100.0,
                  metadata={"truth": {"f": [1.0, np.nan], "g": np.float32(np.inf),
                                      "lines": {3, 1, 2}}}) as rec:
        rec.write_block(Block(np.zeros((10, 2), np.float32), chans, 100.0, 0, 0, 0))
        rec.write_event(SourceEvent(time_ns=1, kind="clock", detail={"ppm": float("-inf")}))
        rec.write_json("/aux", 2, {"x": np.array([np.nan, 1.5])})
        rec.add_metadata("stats", {"rate": np.float64("nan")})
        with pytest.raises(ValueError, match="not JSON-able"):
            rec.add_metadata("bad", {"x": object()})  # not data: refused, not stored as text
    with open(path, "rb") as f:
        texts = {m.name: m.metadata[topics.METADATA_JSON_KEY]
                 for m in make_reader(f).iter_metadata()}
        f.seek(0)
        messages = [(c.topic, m.data.decode()) for _, c, m in make_reader(f).iter_messages()
                    if c.topic != topics.TOPIC_SAMPLES]
    assert _strict_json(texts["fnsi_lab.truth"]) == {"f": [1.0, None], "g": None,
                                                     "lines": [1, 2, 3]}
    assert _strict_json(texts["fnsi_lab.stats"]) == {"rate": None}
    assert "fnsi_lab.bad" not in texts
    for _, text in messages:
        _strict_json(text)
    assert texts["fnsi_lab.truth"] == outputs.dumps({"f": [1.0, None], "g": None,
                                                     "lines": [1, 2, 3]}, separators=(",", ":"))
    assert not hasattr(writer, "json_default")  # no second encoder
    with open_recording(path) as r:
        assert r.truth == {"f": [1.0, None], "g": None, "lines": [1, 2, 3]}
        assert list(r.iter_events())[0]["detail"] == {"ppm": None}
        assert list(r.iter_json("/aux")) == [(2, {"x": [None, 1.5]})]


def test_recordings_written_with_nan_tokens_still_read(tmp_path):
    """Recordings from before the strict encoder hold NaN/Infinity tokens: still readable."""
    p = tmp_path / "old.mcap"
    table = json.dumps([ChannelInfo("a").to_dict(), ChannelInfo("b", "force").to_dict()])
    old = '{"frequency_hz":[1.0,NaN],"peak":Infinity}'
    name = topics.metadata_record_name("truth")
    _raw_recording(p, {topics.CHANNEL_META_CHANNELS: table},
                   {name: {topics.METADATA_JSON_KEY: old,
                           topics.METADATA_CRC_KEY: topics.metadata_crc(name, old)}}, 2)
    with open_recording(p) as rec:
        assert rec.truth["frequency_hz"][0] == 1.0 and np.isnan(rec.truth["frequency_hz"][1])
        assert rec.truth["peak"] == float("inf")
        assert [c.name for c in rec.channels] == ["a", "b"]

def test_recorder_close_twice_and_write_after_close(tmp_path):
    chans = make_channels(1, 1)
    rec = Recorder(tmp_path / "c.mcap", chans, 100.0)
    assert rec.close() is True
    assert rec.close() is True
    assert rec.closed
    with pytest.raises(RecorderClosedError):
        rec.write_block(Block(np.zeros((1, 2), np.float32), chans, 100.0, 0, 0, 0))
    with open_recording(tmp_path / "c.mcap") as r:  # empty but valid
        assert list(r.iter_blocks()) == []


def test_close_requested_during_a_write_is_deferred(tmp_path, monkeypatch):
    """A close from a signal handler that interrupts write_block finishes after the write."""
    chans = make_channels(1, 1)
    rec = Recorder(tmp_path / "d.mcap", chans, 100.0)
    results = []
    original = rec._writer.add_message

    def add_message_then_signal(*args, **kwargs):
        original(*args, **kwargs)
        results.append(rec.close())  # what a SIGINT handler would do mid-write

    monkeypatch.setattr(rec._writer, "add_message", add_message_then_signal)
    rec.write_block(Block(np.ones((4, 2), np.float32), chans, 100.0, 0, 0, 0))
    assert results == [False] and rec.closed
    with open_recording(tmp_path / "d.mcap") as r:
        assert r.n_blocks == 1


def test_close_from_real_signal_handler(tmp_path):
    chans = make_channels(1, 1)
    rec = Recorder(tmp_path / "sig.mcap", chans, 100.0)
    old = signal.signal(signal.SIGUSR1, lambda *a: rec.close())
    try:
        for i in range(50):
            if i == 20:
                signal.raise_signal(signal.SIGUSR1)
            try:
                rec.write_block(Block(np.full((5, 2), i, np.float32), chans, 100.0, i, 5 * i,
                                      i * 50_000_000))
            except RecorderClosedError:
                break
    finally:
        signal.signal(signal.SIGUSR1, old)
    assert rec.closed
    with open_recording(tmp_path / "sig.mcap") as r:
        assert r.n_blocks == 20


def test_recorder_rejects_mismatched_blocks(tmp_path):
    chans = make_channels(1, 1)
    with Recorder(tmp_path / "m.mcap", chans, 100.0) as rec:
        with pytest.raises(ValueError, match="does not match"):
            rec.write_block(Block(np.zeros((3, 3), np.float32), make_channels(2, 1), 100.0, 0, 0, 0))
        with pytest.raises(ValueError, match="t0_ns"):
            rec.write_block(Block(np.zeros((3, 2), np.float32), chans, 100.0, 0, 0, -1))
    with pytest.raises(RecordingError, match="cannot create"):
        Recorder(tmp_path / "no" / "dir" / "x.mcap", chans, 100.0)


def test_time_based_flush(tmp_path):
    chans = make_channels(1, 1)
    rec = Recorder(tmp_path / "f.mcap", chans, 100.0, flush_interval_s=0.05)
    rec.write_block(Block(np.zeros((2, 2), np.float32), chans, 100.0, 0, 0, 0))
    size_before = (tmp_path / "f.mcap").stat().st_size
    assert rec.blocks_flushed == 0
    threading.Event().wait(0.06)
    rec.write_block(Block(np.zeros((2, 2), np.float32), chans, 100.0, 1, 2, 20_000_000))
    assert rec.blocks_flushed == 2
    assert (tmp_path / "f.mcap").stat().st_size > size_before
    rec.write_block(Block(np.zeros((2, 2), np.float32), chans, 100.0, 2, 4, 40_000_000))
    rec.maybe_flush()  # idle writer: nothing due yet
    assert rec.blocks_flushed == 2
    threading.Event().wait(0.06)
    rec.maybe_flush()
    assert rec.blocks_flushed == 3
    rec.close()


# ---------------------------------------------------------------------------- time ranges
def test_time_range_reads_use_the_index(write_recording):
    # 1 kHz, 50-sample blocks (50 ms), small chunks so that the range touches few of them
    path, blocks = write_recording(n_periods=10, chunk_size=2_000)
    with open_recording(path) as rec:
        assert len(rec.summary.chunk_indexes) > 10
        sel = list(rec.iter_blocks(start_ns=500_000_000, end_ns=700_000_000))
        assert [b.t0_ns for b in sel] == [500_000_000, 550_000_000, 600_000_000, 650_000_000]
        full = np.concatenate([b.data for b in blocks])
        part = rec.read_samples(0.512, 0.7345)
        np.testing.assert_array_equal(part, full[512:735])
        assert rec.read_samples().tobytes() == full.tobytes()
        assert rec.read_samples(end_s=0.01).shape == (10, 4)
        assert rec.read_samples(start_s=1.995).shape == (5, 4)
        assert rec.read_samples(5.0, 6.0).shape == (0, 4)


# ---------------------------------------------------------------------------- periodic
def test_read_periodic_shapes_and_periodicity(write_recording):
    path, blocks = write_recording(samples_per_period=200, n_periods=5, realizations=3)
    pr = read_periodic(path)
    assert pr.u.shape == (3, 5, 200, 1) and pr.y.shape == (3, 5, 200, 3)
    assert pr.realizations == (0, 1, 2)
    assert pr.transient_periods == 1 and pr.samples_per_period == 200
    assert pr.periodicity_error == 0.0
    assert pr.notes == ()
    np.testing.assert_array_equal(pr.excited_lines, np.arange(1, 11))  # 5 Hz lines, 5..50 Hz
    first = np.concatenate([b.data for b in blocks if b.realization == 1])[:200]
    np.testing.assert_array_equal(pr.u[1, 0, :, 0], first[:, 0])
    np.testing.assert_array_equal(pr.y[1, 3], first[:, 1:])
    assert [c.name for c in pr.input_channels] == ["F0"]


def test_read_periodic_noise_and_wrong_period(write_recording):
    path, _ = write_recording(samples_per_period=200, n_periods=4, noise=1e-3)
    pr = read_periodic(path)
    assert 1e-4 < pr.periodicity_error < 1e-2
    with pytest.raises(RecordingError, match="disagrees"):
        read_periodic(path, samples_per_period=150)
    with pytest.raises(RecordingError, match="not periodic"):
        read_periodic(path, max_periodicity_error=1e-6)


def test_read_periodic_without_excitation_needs_n(write_recording):
    path, _ = write_recording(samples_per_period=100, n_periods=6, metadata={"excitation": None})
    with pytest.raises(RecordingError, match="pass samples_per_period"):
        read_periodic(path)
    pr = read_periodic(path, samples_per_period=100)
    assert pr.u.shape == (1, 6, 100, 1) and pr.transient_periods == 0
    assert pr.periodicity_error == 0.0 and pr.excited_lines.size == 0
    wrong = read_periodic(path, samples_per_period=120)  # 600 samples = 5 periods of 120
    assert wrong.periodicity_error > 0.5


def test_read_periodic_keeps_complete_periods_and_says_so(write_recording):
    path, _ = write_recording(samples_per_period=200, n_periods=3, extra_samples=70)
    pr = read_periodic(path)
    assert pr.u.shape[1] == 3
    assert any("70 trailing samples" in n for n in pr.notes)


def test_read_periodic_detects_gaps(tmp_path):
    chans = make_channels(1, 1)
    x = np.zeros((400, 2), np.float32)
    blocks = blocks_from_array(x, chans, 100.0, 50)
    del blocks[3]
    with Recorder(tmp_path / "g.mcap", chans, 100.0) as rec:
        for b in blocks:
            rec.write_block(b)
    with pytest.raises(RecordingError, match="missing samples at sample 150"):
        read_periodic(tmp_path / "g.mcap", samples_per_period=100)
    assert recording_info(tmp_path / "g.mcap")["lost_blocks"] == 1


# ---------------------------------------------------------------------------- info
def test_recording_info_and_format(write_recording):
    path, blocks = write_recording(samples_per_period=200, n_periods=4, realizations=2,
                                   metadata={"truth": {"modes": 2}},
                                   attachments=[("experiment.yaml", "application/yaml", b"x: 1\n")])
    info = recording_info(path)
    json.dumps(info)  # JSON-able
    assert info["channels"][0] == {"name": "F0", "unit": "N", "quantity": "force"}
    assert info["sample_rate_hz"] == 1000.0
    assert info["samples"] == 1600 and info["duration_s"] == pytest.approx(1.6)
    assert info["samples_per_period"] == 200 and info["periods"] == 4
    assert info["realizations"] == 2
    assert info["messages"] == len(blocks) and info["blocks"] == len(blocks)
    assert info["events"] == {} and info["truth"] == {"modes": 2}
    assert info["experiment"]["software_version"] == __version__
    assert info["excitation"]["band_hz"] == [5.0, 50.0]
    assert info["attachments"] == [{"name": "experiment.yaml", "media_type": "application/yaml",
                                    "size": 5}]
    text = format_info(info)
    assert "F0" in text and "N = 200" in text and "experiment.yaml" in text


# ---------------------------------------------------------------------------- bad inputs
def _one_line(exc: BaseException, path) -> str:
    msg = str(exc)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_missing_file(tmp_path):
    with pytest.raises(RecordingNotFoundError) as ei:
        open_recording(tmp_path / "nope.mcap")
    assert isinstance(ei.value, DataFileError) and isinstance(ei.value, FileNotFoundError)
    _one_line(ei.value, tmp_path / "nope.mcap")
    with pytest.raises(RecordingError, match="folder"):
        open_recording(tmp_path)


@pytest.mark.parametrize("content", [b"", b"hello world, not an mcap file at all", b"PK\x03\x04" * 10])
def test_not_mcap(tmp_path, content):
    p = tmp_path / "x.mcap"
    p.write_bytes(content)
    with pytest.raises(NotMcapError) as ei:
        open_recording(p)
    assert "not an MCAP file" in _one_line(ei.value, p)
    with pytest.raises(NotMcapError):
        recording_info(p)


def test_truncated_says_recover(write_recording):
    path, _ = write_recording()
    data = path.read_bytes()
    for cut in (len(data) - 3, len(data) // 2):
        path.write_bytes(data[:cut])
        with pytest.raises(UnfinishedRecordingError) as ei:
            open_recording(path)
        msg = _one_line(ei.value, path)
        assert f"fnsi-lab recover {path} " in msg and "unfinished recording" in msg


def test_salvage_mode_reads_an_unfinished_file(write_recording):
    path, blocks = write_recording(n_periods=10, chunk_size=2_000)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with open_recording(path, salvage=True) as rec:
        got = list(rec.iter_blocks())
        assert rec.salvaged is not None and not rec.salvaged.complete
        assert 0 < len(got) < len(blocks)
        for a, b in zip(got, blocks):
            assert a.data.tobytes() == b.data.tobytes()


def test_wrong_schema(tmp_path):
    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foo.Bar", "jsonschema", b"{}")
        cid = w.register_channel("/foo", "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()
    with pytest.raises(WrongSchemaError) as ei:
        open_recording(p)
    assert "not an fnsi-lab recording" in _one_line(ei.value, p)
    # our topic name with another schema
    p2 = tmp_path / "other2.mcap"
    with open(p2, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foo.Bar", "protobuf", b"")
        cid = w.register_channel(topics.TOPIC_SAMPLES, "protobuf", sid)
        w.add_message(cid, 1, b"", 1)
        w.finish()
    with pytest.raises(WrongSchemaError, match="expected 'fnsi_lab.SampleBlock'"):
        open_recording(p2)


def _raw_recording(path, channel_meta: dict, metadata: dict | None, n_channels: int) -> None:
    from fnsi_lab.daq.recording import schema
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        for k, v in (metadata or {}).items():
            w.add_metadata(k, v)
        sid = w.register_schema(topics.SAMPLES_SCHEMA_NAME, "protobuf", schema.schema_bytes())
        cid = w.register_channel(topics.TOPIC_SAMPLES, "protobuf", sid, channel_meta)
        data = np.zeros((5, n_channels), np.float32)
        w.add_message(cid, 0, schema.encode_block(data, first_sample=0, realization=0,
                                                  sample_rate_hz=100.0, t0_ns=0, sequence=0), 0)
        w.finish()


def test_channels_missing(tmp_path):
    p = tmp_path / "nochan.mcap"
    _raw_recording(p, {}, None, 2)
    with pytest.raises(MissingChannelsError) as ei:
        open_recording(p)
    assert "no channel table" in _one_line(ei.value, p)
    # table with fewer channels than the blocks hold
    p2 = tmp_path / "short.mcap"
    table = json.dumps([ChannelInfo("a").to_dict()])
    _raw_recording(p2, {topics.CHANNEL_META_CHANNELS: table}, None, 2)
    with pytest.raises(MissingChannelsError, match="2 columns but the channel table lists 1"):
        with open_recording(p2) as rec:
            list(rec.iter_blocks())
    # the metadata record alone is enough (channel metadata stripped by some tool)
    p3 = tmp_path / "metaonly.mcap"
    table2 = json.dumps([ChannelInfo("a").to_dict(), ChannelInfo("b", "force").to_dict()])
    _raw_recording(p3, {}, {"fnsi_lab.channels": {"json": table2}}, 2)
    with open_recording(p3) as rec:
        assert [c.name for c in rec.channels] == ["a", "b"]
        assert rec.sample_rate_hz == 100.0  # from the first block


@pytest.mark.parametrize("compression", ["zstd", "none"])  # none: only the CRC sees it
def test_damaged_chunk_is_reported_with_crc_checks(write_recording, compression):
    from mcap.reader import make_reader
    path, blocks = write_recording(chunk_size=2_000, compression=compression)
    with open(path, "rb") as f:
        ci = make_reader(f).get_summary().chunk_indexes[1]
    data = bytearray(path.read_bytes())
    data[ci.chunk_start_offset + ci.chunk_length - 10] ^= 0x01  # inside the compressed data
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="damaged chunk 2 of") as ei:
        with open_recording(path) as rec:  # CRC checks are on by default
            list(rec.iter_blocks())
    assert "fnsi-lab recover" in _one_line(ei.value, path)
