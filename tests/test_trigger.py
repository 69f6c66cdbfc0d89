"""Software trigger (daq.trigger) on python-can's virtual bus, pyserial loop:// and a simulation."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fnsi_lab.daq.acquisition import record_experiment
from fnsi_lab.daq.config import parse_experiment
from fnsi_lab.daq.recording.reader import open_recording
from fnsi_lab.daq.registry import make_source
from fnsi_lab.daq.trigger import TriggeredSource, find_crossing
from fnsi_lab.errors import ConfigError
import test_can_source as can_t
import test_serial_source as ser_t
from test_can_source import channel, no_adapter_leaks  # noqa: F401  (fixtures)


def first_crossing(x: np.ndarray, level: float, slope: str) -> int:
    """Reference: the first i with x[i-1] < level <= x[i] (rising) or the reverse (falling)."""
    for i in range(1, x.size):
        if slope == "rising" and x[i - 1] < level <= x[i]:
            return i
        if slope == "falling" and x[i - 1] > level >= x[i]:
            return i
    return -1



def _check_triggered_recording(out, expected, k0: int, pre: int, kept: int):
    """The recording holds the signal from ``pre`` samples before the crossing at ``k0``
    (samples are stored as float32: bit for bit after that rounding); its first block
    starts at sample 0. Returns the metadata, the trigger events and the blocks."""
    with open_recording(out) as rec:
        data = rec.read_samples()
        metadata = rec.metadata
        events = [e for e in rec.iter_events() if e["kind"] == "trigger"]
        blocks = list(rec.iter_blocks())
    assert data.shape[0] >= kept
    np.testing.assert_array_equal(
        data, expected[k0 - pre:k0 - pre + data.shape[0]].astype(np.float32))
    assert blocks[0].first_sample == 0
    return metadata, events, blocks

def test_find_crossing_slopes_and_block_boundary() -> None:
    x = np.array([0.0, 0.5, 1.0, 2.0, 1.0, 0.0, np.nan, 3.0])
    assert find_crossing(x, 1.0, "rising") == 2          # 0.5 < 1 <= 1.0
    assert find_crossing(x, 1.0, "falling") == 4         # 2 > 1 >= 1.0
    assert find_crossing(x, 1.5, "either") == 3
    assert find_crossing(x[6:], 1.0, "rising", previous=0.0) is None  # NaN never crosses
    assert find_crossing(x[3:], 1.5, "rising", previous=None) is None  # x[0] cannot trigger
    assert find_crossing(x[3:], 1.5, "rising", previous=1.0) == 0      # ...unless the previous block says so
    assert find_crossing(np.zeros(5), 0.0, "rising") is None           # touching is not crossing


def can_config(tmp_path: Path, channel: str, trigger: dict) -> object:
    base = can_t.make_config(tmp_path, channel)
    data = {"name": "can-trigger", "sample_rate_hz": can_t.FS, "block_size": 100,
            "source": {"kind": "can", "options": dict(base.source.options)},
            "channels": can_t.CHANNELS, "trigger": trigger}
    return parse_experiment(data, file=str(tmp_path / "exp.yaml"))


def test_trigger_on_virtual_can_bus_recorded(tmp_path: Path, channel: str,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    n = 1500
    multisine_signals = can_t.signals_for

    def shaker_starts_at_437(n: int) -> dict[str, np.ndarray]:
        gate = (np.arange(n) >= 437).astype(float)  # quiet bus values, then the drive
        return {k: v * gate for k, v in multisine_signals(n).items()}

    monkeypatch.setattr(can_t, "signals_for", shaker_starts_at_437)
    frames, expected = can_t.build_frames(n)
    force = expected[:, 0]
    level = 10.0  # N
    k0 = first_crossing(force, level, "rising")
    pre = 130  # from the blocks before the crossing's block
    assert 437 <= k0 < 500
    config = can_config(tmp_path, channel, {"channel": "F-NC2W-Z", "level": level,
                                            "slope": "rising", "pre_samples": pre})
    stop = threading.Event()
    kept = n - (k0 - pre) - 200  # stop well before the sender runs out

    def on_block(block, report) -> None:
        if report.samples >= kept:
            stop.set()

    out = tmp_path / "trig.mcap"
    source = make_source(config)
    source.start()  # the virtual bus delivers only to buses open before the frames are sent
    watchdog = threading.Timer(30.0, stop.set)  # a failing test must not hang
    watchdog.start()
    try:
        with can_t.Sender(channel, frames):
            report = record_experiment(config, out, stop=stop, on_block=on_block, source=source)
    finally:
        watchdog.cancel()
    assert report.events >= 1 and "trigger" not in report.source_problems  # not a problem
    # the recording starts exactly pre samples before the crossing
    metadata, events, blocks = _check_triggered_recording(out, expected, k0, pre, kept)
    assert metadata["trigger"] == {"channel": "F-NC2W-Z", "level": level,
                                   "slope": "rising", "pre_samples": pre}
    assert abs(blocks[0].t0_ns - (can_t.T0 + (k0 - pre) / can_t.FS) * 1e9) < 1e3  # bus time
    assert len(events) == 1
    detail = events[0]["detail"]
    assert detail["source_sample"] == k0 and detail["sample"] == pre
    assert detail["value"] == force[k0]  # the decoded value (before storage rounding)
    assert abs(events[0]["time_ns"] - (can_t.T0 + k0 / can_t.FS) * 1e9) < 1e3


def test_trigger_on_serial_loop_falling_slope(tmp_path: Path) -> None:
    n = 600
    lines, expected = ser_t.text_lines(n)
    force = expected[:, 0]
    level = 0.7 * float(np.min(force[:300]))  # negative level, falling
    k0 = first_crossing(force, level, "falling")
    pre = 40
    base = ser_t.make_config(tmp_path)
    data = {"name": "serial-trigger", "sample_rate_hz": ser_t.FS, "block_size": 50,
            "source": {"kind": "serial", "options": dict(base.source.options)},
            "channels": ser_t.CHANNELS,
            "trigger": {"channel": "F-NC2W-Z", "level": level, "slope": "falling",
                        "pre_samples": pre}}
    src = make_source(parse_experiment(data, file=str(tmp_path / "exp.yaml")))
    assert isinstance(src, TriggeredSource)
    with src:
        # the port attribute is the serial source's (loop:// echoes what is written); the
        # source drops the first line as possibly partial, as when joining a running stream
        src.port.write(b"tail of an earlier line\n" + b"".join(lines))
        got, blocks = ser_t.read_rows(src, n - (k0 - pre) - 50)
    np.testing.assert_array_equal(got, expected[k0 - pre:k0 - pre + got.shape[0]])
    assert [b.first_sample for b in blocks][:2] == [0, blocks[0].n_samples]
    assert src.triggered["source_sample"] == k0 and src.triggered["pre_samples"] == pre
    assert [e.kind for e in src.drain_events()].count("trigger") == 1



def test_trigger_on_serial_loop_recorded(tmp_path: Path) -> None:
    """The serial trigger through record_experiment (what ``fnsi-lab acquire`` runs): the
    MCAP starts pre_samples before the crossing and holds the ``trigger`` metadata record
    and one ``trigger`` event, as on the CAN bus."""
    n, quiet = 600, 150
    lines, expected = ser_t.text_lines(n)
    for k in range(quiet):  # the shaker is off: zero force, zero displacement
        lines[k] = f"{k},0.000,{-0.5:.9f}\r\n".encode()
        expected[k] = [0.0, 0.0]
    force = expected[:, 0]
    level = 10.0  # N, rising
    k0 = first_crossing(force, level, "rising")
    pre = 40
    assert quiet <= k0 < quiet + 100
    base = ser_t.make_config(tmp_path)
    trigger = {"channel": "F-NC2W-Z", "level": level, "slope": "rising", "pre_samples": pre}
    data = {"name": "serial-trigger", "sample_rate_hz": ser_t.FS, "block_size": 50,
            "source": {"kind": "serial", "options": dict(base.source.options)},
            "channels": ser_t.CHANNELS, "trigger": trigger}
    config = parse_experiment(data, file=str(tmp_path / "exp.yaml"))
    stop = threading.Event()
    kept = n - (k0 - pre) - 100  # stop before the instrument's stream ends

    def on_block(block, report) -> None:
        if report.samples >= kept:
            stop.set()

    out = tmp_path / "trig.mcap"
    source = make_source(config)
    assert isinstance(source, TriggeredSource)
    source.start()
    # loop:// echoes what is written; the first line is dropped as possibly partial
    source.port.write(b"tail of an earlier line\n" + b"".join(lines))
    watchdog = threading.Timer(30.0, stop.set)  # a failing test must not hang
    watchdog.start()
    try:
        report = record_experiment(config, out, stop=stop, on_block=on_block, source=source)
    finally:
        watchdog.cancel()
    assert report.events >= 1 and "trigger" not in report.source_problems
    metadata, events, blocks = _check_triggered_recording(out, expected, k0, pre, kept)
    assert metadata["trigger"] == trigger and metadata["source"]["kind"] == "serial"
    assert len(events) == 1
    detail = events[0]["detail"]
    assert detail["source_sample"] == k0 and detail["sample"] == pre
    assert detail["value"] == force[k0]

def test_trigger_on_simulation_fewer_pre_samples_than_asked(tmp_path: Path) -> None:
    data = {"name": "sim", "sample_rate_hz": 1000, "block_size": 64,
            "source": {"kind": "simulated", "options": {"model": "lumped",
                                                         "lumped": {"variant": "none"}}},
            "excitation": {"band_hz": [5, 50], "rms": 5.0, "samples_per_period": 512,
                           "periods": 2},
            "trigger": {"channel": "F-X3", "level": 0.0, "slope": "rising", "pre_samples": 10_000}}
    config = parse_experiment(data, file=str(tmp_path / "exp.yaml"))
    src = make_source(config)
    full = make_source(parse_experiment({k: v for k, v in data.items() if k != "trigger"}))
    with full:
        reference = np.concatenate([b.data for b in full])
    with src:
        got = np.concatenate([b.data for b in src])
    k0 = first_crossing(reference[:, 0], 0.0, "rising")
    # only k0 samples existed before the crossing: all of them are kept, nothing invented
    np.testing.assert_array_equal(got, reference)
    assert src.triggered["pre_samples"] == k0


@pytest.mark.parametrize("trigger, field", [
    ({"channel": "nope", "level": 1.0}, "trigger.channel"),
    ({"channel": "F-X3", "level": 1.0, "slope": "up"}, "trigger.slope"),
    ({"channel": "F-X3", "level": 1.0, "pre_samples": -1}, "trigger.pre_samples"),
    ({"channel": "F-X3"}, "trigger.level"),
])
def test_trigger_config_errors(trigger: dict, field: str) -> None:
    data = {"name": "sim", "sample_rate_hz": 1000,
            "source": {"kind": "simulated", "options": {"model": "lumped"}},
            "excitation": {"band_hz": [5, 50], "rms": 5.0, "samples_per_period": 512},
            "trigger": trigger}
    with pytest.raises(ConfigError) as err:
        make_source(parse_experiment(data, file="exp.yaml"))
    assert field in str(err.value)


def test_untriggered_source_ends_without_data(tmp_path: Path) -> None:
    data = {"name": "sim", "sample_rate_hz": 1000, "block_size": 100,
            "source": {"kind": "simulated", "options": {"model": "lumped"}},
            "excitation": {"band_hz": [5, 50], "rms": 5.0, "samples_per_period": 512},
            "trigger": {"channel": "F-X3", "level": 1e9}}
    src = make_source(parse_experiment(data))
    t0 = time.monotonic()
    with src:
        assert list(src) == []
    assert src.finished and src.triggered is None and time.monotonic() - t0 < 30


def test_adapter_tests_collect_from_any_folder(tmp_path: Path) -> None:
    """The test modules import each other by module name (pytest puts tests/ on sys.path),
    never as the package ``tests`` (which only resolves from the repository root): pytest
    run from another folder collects them (issue 18)."""
    import subprocess
    import sys

    here = Path(__file__).resolve().parent
    offenders = [p.name for p in here.glob("test_*.py")
                 if any(line.lstrip().startswith(("from tests ", "from tests.", "import tests"))
                        for line in p.read_text().splitlines())]
    assert offenders == []
    files = [str(here / f) for f in ("test_trigger.py", "test_serial_source.py",
                                     "test_can_serial_docs.py")]
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                           "-p", "no:cacheprovider", *files],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert " tests collected" in proc.stdout  # exit code 0: no collection error
