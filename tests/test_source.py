"""Source base (BusABC pattern), lazy registry, taps and the acquisition loop."""

import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from fnsi_lab.daq import registry
from fnsi_lab.daq.acquisition import Tap, acquire
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.source import SourceClosedError
from fnsi_lab.daq.sources.array_source import ArraySource
from fnsi_lab.errors import ConfigError

CHANNELS = [ChannelInfo("u", "force"), ChannelInfo("y1"), ChannelInfo("y2")]


def _source(n=1000, block=100, **kw):
    data = np.arange(n * 3, dtype=np.float32).reshape(n, 3)
    return ArraySource(data, CHANNELS, 1000.0, block_size=block, **kw), data


def test_blocks_are_numbered_timestamped_and_complete():
    src, data = _source(1050, 100)
    with src:
        blocks = list(src)
    assert [b.sequence for b in blocks] == list(range(11))
    assert [b.first_sample for b in blocks] == list(range(0, 1100, 100))
    assert blocks[3].t0_ns == 300_000_000  # 300 samples at 1 kHz
    assert np.array_equal(np.concatenate([b.data for b in blocks]), data)
    assert src.stats.blocks == 11 and src.stats.samples == 1050
    assert blocks[0].channels == tuple(CHANNELS)


def test_life_cycle_is_idempotent_and_closed_read_raises():
    src, _ = _source()
    src.start(); src.start()
    assert src.is_running
    src.stop(); src.stop()
    src.close(); src.close()
    assert src.is_closed
    with pytest.raises(SourceClosedError):
        src.read()
    with pytest.raises(SourceClosedError):
        src.start()


def test_pacing_follows_wall_clock():
    # 0.3 s of signal paced at 2x real time must take ~0.15 s; sleep granularity is ~1 ms.
    src, _ = _source(300, 50, pace=2.0)
    t0 = time.monotonic()
    with src:
        list(src)
    elapsed = time.monotonic() - t0
    assert 0.14 < elapsed < 0.6


def test_duplicate_channels_rejected():
    with pytest.raises(ConfigError, match="duplicate"):
        ArraySource(np.zeros((3, 2)), [ChannelInfo("a"), ChannelInfo("a")], 10.0)


def test_registry_is_lazy_and_names_missing_modules(monkeypatch):
    code = ("import sys, daq; bad = [m for m in ('can', 'serial', 'cantools', 'rerun', 'numba') "
            "if m in sys.modules]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stderr
    monkeypatch.setitem(registry.SOURCES, "ghost", ("fnsi_lab.daq.sources.no_such_driver", "Ghost"))
    with pytest.raises(ConfigError, match="cannot be loaded") as info:
        registry.source_class("ghost")
    assert "no_such_driver" in str(info.value)
    with pytest.raises(ConfigError, match="unknown source kind"):
        registry.source_class("nope")


def test_tap_drops_oldest_and_counts():
    tap = Tap("slow", maxsize=3)
    src, _ = _source(1000, 100)
    with src:
        for block in src:
            tap.offer(block)
    tap.close()
    kept = list(tap)
    # 10 blocks into 3 slots, the end marker takes one more slot: the newest blocks survive.
    assert tap.dropped == 10 - len(kept)
    assert [b.sequence for b in kept] == list(range(10 - len(kept), 10))


def test_acquire_feeds_taps_and_reports():
    src, data = _source(2000, 100)
    tap = Tap("analysis", maxsize=1000)
    got = []
    consumer = threading.Thread(target=lambda: got.extend(tap))
    consumer.start()
    report = acquire(src, None, taps=[tap])
    consumer.join(timeout=10)
    src.close()
    assert report.blocks == 20 and report.samples == 2000 and tap.dropped == 0
    assert np.array_equal(np.concatenate([b.data for b in got]), data)
    assert "20 blocks" in report.summary()


def test_acquire_stops_on_event():
    src, _ = _source(100_000, 10, pace=1.0)  # 100 s of paced signal
    stop = threading.Event()
    threading.Timer(0.2, stop.set).start()
    report = acquire(src, None, stop=stop)
    src.close()
    assert report.interrupted and 0 < report.samples < 5000
