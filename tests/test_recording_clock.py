"""MCAP log times are wall-clock UTC (acquisition start + sample time); t0_ns stays in the payload."""

from __future__ import annotations

import json
import time

import numpy as np
from mcap.reader import make_reader

from fnsi_lab.daq.recording import Recorder, open_recording, schema, topics
from conftest import blocks_from_array, make_channels, periodic_signal


def _write(path, t_offset_ns=0, start_utc_ns=None):
    chans = make_channels(2, 1)
    data = periodic_signal(chans, 100, 6)
    blocks = blocks_from_array(data, chans, 1000.0, 50, t_offset_ns=t_offset_ns)
    with Recorder(path, chans, 1000.0, start_utc_ns=start_utc_ns) as rec:
        for b in blocks:
            rec.write_block(b)
    return blocks


def test_log_time_is_wall_clock_and_payload_keeps_the_sample_clock(tmp_path):
    before = time.time_ns()
    blocks = _write(tmp_path / "r.mcap")
    after = time.time_ns()
    with open(tmp_path / "r.mcap", "rb") as f:
        reader = make_reader(f)
        msgs = [m for _, _, m in reader.iter_messages(topics=[topics.TOPIC_SAMPLES],
                                                       log_time_order=False)]
        stats = reader.get_summary().statistics
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    first = msgs[0].log_time
    assert before <= first <= after  # the acquisition start, not 1970
    assert stats.message_start_time >= before  # what `mcap info` shows as the start
    for m, b in zip(msgs, blocks):
        assert m.log_time - first == b.t0_ns  # + sample time
        assert m.publish_time == m.log_time
        assert schema.decode_block(m.data).t0_ns == b.t0_ns  # sample clock in the payload
    clock = json.loads(meta["fnsi_lab.clock"]["json"])
    assert clock["acquisition_start_utc_ns"] == first


def test_time_range_queries_use_the_sample_clock(tmp_path):
    blocks = _write(tmp_path / "r.mcap", start_utc_ns=1_700_000_000_000_000_000)
    with open_recording(tmp_path / "r.mcap") as rec:
        assert rec.log_time_offset_ns == 1_700_000_000_000_000_000
        got = list(rec.iter_blocks(100_000_000, 300_000_000))
        assert [b.t0_ns for b in got] == [b.t0_ns for b in blocks
                                          if 100_000_000 <= b.t0_ns < 300_000_000]
        np.testing.assert_array_equal(rec.read_samples(0.1, 0.2),
                                      np.concatenate([b.data for b in blocks])[100:200])


def test_a_source_with_its_own_clock_starts_at_the_acquisition_start(tmp_path):
    # a bus time stamp (e.g. CAN, seconds since an arbitrary epoch) is not added twice
    blocks = _write(tmp_path / "r.mcap", t_offset_ns=5_000_000_000_000, start_utc_ns=10**18)
    with open_recording(tmp_path / "r.mcap") as rec:
        assert rec.log_time_offset_ns == 10**18 - blocks[0].t0_ns
        assert [b.t0_ns for b in rec.iter_blocks()] == [b.t0_ns for b in blocks]


def test_recordings_with_sample_clock_log_times_still_read(tmp_path):
    """Files written before the change (log time = t0_ns) read and slice as before."""
    path = tmp_path / "old.mcap"
    _write(path, start_utc_ns=0)  # log time = 0 + t0_ns: the former layout
    with open(path, "rb") as f:
        first = next(make_reader(f).iter_messages(topics=[topics.TOPIC_SAMPLES]))[2]
    assert first.log_time == 0
    with open_recording(path) as rec:
        assert rec.log_time_offset_ns == 0
        assert [b.t0_ns for b in rec.iter_blocks(50_000_000, 150_000_000)] == [50_000_000,
                                                                             100_000_000]
