"""CanSource over python-can's virtual bus, with a sender thread encoding a multisine."""

from __future__ import annotations

import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator

import can
import cantools
import numpy as np
import pytest

from fnsi_lab.daq.config import parse_experiment
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sources.can_source import CanSource
from fnsi_lab.errors import ConfigError

DBC = Path(__file__).resolve().parent.parent / "daq" / "data" / "example_can.dbc"
FS = 1000.0
CHANNELS = [
    {"name": "F-NC2W-Z", "quantity": "force", "unit": "N"},
    {"name": "NC2W-Z", "quantity": "displacement", "unit": "m"},
    {"name": "NC3-Z", "quantity": "displacement", "unit": "m"},
    {"name": "NC2W-Z-acc", "quantity": "acceleration", "unit": "m/s^2"},
]
SIGNALS = {"F-NC2W-Z": "Excitation.Force", "NC2W-Z": "Response.Disp1",
           "NC3-Z": "Response.Disp2", "NC2W-Z-acc": "Response.Acc1"}
T0 = 1_700_000_000.0  # bus time of sample 0 (s)


def make_config(tmp_path: Path, channel: str, **options: Any):
    """An experiment in tmp_path whose DBC sits next to it (relative path)."""
    shutil.copy(DBC, tmp_path / "lab.dbc")
    opts = {"interface": "virtual", "channel": channel, "bitrate": 1_000_000,
            "dbc": "lab.dbc", "signals": dict(SIGNALS), "counter": "Counter",
            "rate_window_s": 0.2}
    opts.update(options)
    opts = {k: v for k, v in opts.items() if v is not None}
    data = {"name": "can-test", "sample_rate_hz": FS, "block_size": 100,
            "source": {"kind": "can", "options": opts}, "channels": CHANNELS}
    return parse_experiment(data, file=str(tmp_path / "exp.yaml"))


@pytest.fixture(autouse=True)
def no_adapter_leaks() -> Iterator[None]:
    """Fail a test that leaves a receive thread running or a virtual bus open."""
    from can.interfaces import virtual
    yield
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        alive = [t.name for t in threading.enumerate() if t.name in ("can-rx", "serial-rx")]
        buses = [c for c in virtual.channels if str(c).startswith("test-")]
        if not alive and not buses:
            return
        time.sleep(0.02)
    pytest.fail(f"leaked receive threads {alive} / virtual buses {buses}")


@pytest.fixture
def channel() -> str:
    """A virtual-bus channel no other test shares."""
    return f"test-{uuid.uuid4().hex[:12]}"


def signals_for(n: int) -> dict[str, np.ndarray]:
    """Physical test signals (multisine force, scaled/shifted copies as responses)."""
    u = multisine(200, FS, (5.0, 200.0), 50.0, n_periods=-(-n // 200), seed=3).signal[0, :n]
    return {"Force": u, "Voltage": u / 100.0, "Disp1": u * 1e-4, "Disp2": -u * 5e-5,
            "Acc1": u * 0.05}


class Sender:
    """Encode frames with the DBC and send them on the virtual bus from a thread."""

    def __init__(self, channel: str, frames: list[can.Message]) -> None:
        # preserve_timestamps: the receiver sees our synthetic bus clock, so rates are exact
        self.bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        self.frames = frames
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        for i, frame in enumerate(self.frames):
            self.bus.send(frame)
            if i % 500 == 499:
                time.sleep(0.001)  # let the reader breathe, like a real bus would

    def __enter__(self) -> "Sender":
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.thread.join(timeout=10)
        self.bus.shutdown()
        assert not self.thread.is_alive()


def build_frames(n: int, *, counter: bool = True,
                 drop: Callable[[str, int], bool] = lambda m, k: False,
                 extra: Callable[[int], list[can.Message]] = lambda k: []
                 ) -> tuple[list[can.Message], np.ndarray]:
    """Frames for n samples and the decoded-quantised expectation (NaN where dropped)."""
    db = cantools.database.load_file(str(DBC))
    sig = signals_for(n)
    exc, resp = db.get_message_by_name("Excitation"), db.get_message_by_name("Response")
    frames: list[can.Message] = []
    expected = np.full((n, 4), np.nan)
    for k in range(n):
        t = T0 + k / FS
        for msg, names in ((exc, ("Force", "Voltage")), (resp, ("Disp1", "Disp2", "Acc1"))):
            values = {s: float(sig[s][k]) for s in names}
            values["Counter"] = k % 256
            data = msg.encode(values)
            if drop(msg.name, k):
                continue
            decoded = msg.decode(data, decode_choices=False)
            if msg is exc:
                expected[k, 0] = decoded["Force"]
            else:
                expected[k, 1:] = [decoded["Disp1"], decoded["Disp2"], decoded["Acc1"]]
            frames.append(can.Message(arbitration_id=msg.frame_id, data=data,
                                      is_extended_id=False, timestamp=t + 1e-5 * (msg is resp)))
        frames.extend(extra(k))
    return frames, expected


def read_rows(src: CanSource, n: int, timeout: float = 10.0) -> tuple[np.ndarray, list]:
    """Read blocks until n rows arrived (or fail after timeout)."""
    blocks = []
    deadline = time.monotonic() + timeout
    while sum(b.n_samples for b in blocks) < n:
        assert time.monotonic() < deadline, f"only {sum(b.n_samples for b in blocks)} rows"
        b = src.read(timeout=0.5)
        if b is not None:
            blocks.append(b)
    return np.concatenate([b.data for b in blocks])[:n], blocks


def test_exact_values_counter_mode(tmp_path: Path, channel: str) -> None:
    n = 600
    frames, expected = build_frames(n)
    src = CanSource.from_config(make_config(tmp_path, channel))
    with src, Sender(channel, frames):
        data, blocks = read_rows(src, n)
    assert np.array_equal(data, expected)  # exact: DBC quantisation reproduced bit for bit
    assert [b.first_sample for b in blocks] == list(range(0, n, 100))
    assert [b.sequence for b in blocks] == list(range(6))
    for b in blocks:  # bus time of the first frame of the block's first row
        assert abs(b.t0_ns - (T0 + b.first_sample / FS) * 1e9) < 1e3  # 1 us: float seconds
    assert src.stats.samples == n
    assert "lost_frames" not in src.stats.problems
    assert "rate_mismatch" not in src.stats.problems
    assert src.channels[1].unit == "m"


def test_dropped_frames_error_frames_unknown_ids(tmp_path: Path, channel: str) -> None:
    n = 400

    def drop(msg: str, k: int) -> bool:
        return (msg == "Response" and k in (100, 101)) or k == 200

    def extra(k: int) -> list[can.Message]:
        out = []
        if k in (50, 150, 250):
            out.append(can.Message(is_error_frame=True, arbitration_id=0x20000080,
                                   timestamp=T0 + k / FS + 5e-4))
        if k in (60, 61, 62):
            out.append(can.Message(arbitration_id=0x7F0, data=b"\x01\x02",
                                   is_extended_id=False, timestamp=T0 + k / FS + 5e-4))
        if k == 70:
            out.append(can.Message(arbitration_id=0x200, data=b"\x01\x50",
                                   is_extended_id=False, timestamp=T0 + k / FS + 5e-4))
        return out

    frames, expected = build_frames(n, drop=drop, extra=extra)
    src = CanSource.from_config(make_config(tmp_path, channel, record_raw=True))
    with src, Sender(channel, frames):
        data, _ = read_rows(src, n)
    assert np.array_equal(data, expected, equal_nan=True)
    assert np.isnan(data[100, 1:]).all() and not np.isnan(data[100, 0])
    assert np.isnan(data[200]).all()
    p = src.stats.problems
    assert p["lost_frames"] == 4  # 2 Response + 1 Excitation + 1 Response
    assert p["incomplete_rows"] == 3
    assert p["error_frame"] == 3
    assert p["unknown_id_frames"] == 3 and p["unknown_id"] == 1
    assert p["unmapped_frames"] == 1
    events = src.drain_events()
    kinds = [e.kind for e in events]
    assert kinds.count("error_frame") == 1  # the other two were within 1 s: folded in
    assert [e.detail["suppressed"] for e in events if e.kind == "error_frame"] == [0]
    assert "missing_frames" in kinds and "unknown_id" in kinds
    unknown = next(e for e in events if e.kind == "unknown_id")
    assert unknown.detail["id"] == 0x7F0 and unknown.time_ns == int((T0 + 0.0605) * 1e9)
    raw = src.drain_raw_frames()
    assert len(raw) == len(frames)
    assert raw[0][0] == "/daq/can_raw" and raw[0][1] == int(T0 * 1e9)
    assert raw[0][2] == {"id": 0x100, "extended": False, "dlc": 8,
                         "data": bytes(frames[0].data).hex(), "error": False,
                         "remote": False, "fd": False, "channel": channel}
    assert src.drain_raw_frames() == []


def test_set_mode_and_rate_gap(tmp_path: Path, channel: str) -> None:
    """Without a counter: a row is one Excitation + one Response; time gaps give NaN rows."""
    n = 300

    def drop(msg: str, k: int) -> bool:
        return (msg == "Response" and k == 50) or k in (80, 81)

    frames, expected = build_frames(n, drop=drop)
    src = CanSource.from_config(make_config(tmp_path, channel, counter=None))
    with src, Sender(channel, frames):
        data, _ = read_rows(src, n)
    assert np.array_equal(data, expected, equal_nan=True)
    p = src.stats.problems
    assert p["incomplete_rows"] == 1 and p["lost_rows"] == 2
    assert {"rate_gap", "missing_frames"} <= {e.kind for e in src.drain_events()}


def test_rate_mismatch_reported(tmp_path: Path, channel: str) -> None:
    """The device runs at 1000 Hz but the YAML expects 900 Hz."""
    n = 500
    frames, _ = build_frames(n)
    src = CanSource.from_config(make_config(tmp_path, channel, expected_rate_hz=900.0,
                                            max_gap_rows=0))
    with src, Sender(channel, frames):
        read_rows(src, n)
    events = [e for e in src.drain_events() if e.kind == "rate_mismatch"]
    assert len(events) == 1  # reported once, counted per window
    assert events[0].detail["measured_hz"] == pytest.approx(1000.0, rel=1e-3)
    assert src.stats.problems["rate_mismatch_windows"] >= 2


def test_bus_error_reported_and_reconnected(tmp_path: Path, channel: str) -> None:
    src = CanSource.from_config(make_config(tmp_path, channel, reconnect_interval_s=0.05))
    with src:
        bus = src._bus
        real = bus.recv
        calls = {"n": 0}

        def failing(timeout: float | None = None) -> Any:
            calls["n"] += 1
            if calls["n"] == 3:
                raise can.CanOperationError("bus-off (simulated)")
            return real(timeout)

        bus.recv = failing
        deadline = time.monotonic() + 5
        kinds: list[str] = []
        while "bus_reconnected" not in kinds and time.monotonic() < deadline:
            src.read(timeout=0.1)
            kinds += [e.kind for e in src.drain_events()]
        assert kinds[:2] == ["bus_error", "bus_reconnected"]
        assert src._bus is not bus and src.is_running
        # the new bus still receives
        frames, expected = build_frames(200)
        with Sender(channel, frames):
            data, _ = read_rows(src, 200)
        assert np.array_equal(data, expected)
    assert src._bus is None and not src._rx.alive   # bus shut down, receive thread gone


def test_queue_overflow_counted(tmp_path: Path, channel: str) -> None:
    n = 300
    frames, _ = build_frames(n)
    src = CanSource.from_config(make_config(tmp_path, channel, queue_size=100))
    with src:
        with Sender(channel, frames):
            pass  # the frames pile up while nobody reads
        deadline = time.monotonic() + 5
        while len(src._queue) + src._rx_overflow < len(frames) and time.monotonic() < deadline:
            time.sleep(0.01)
        src.read(timeout=0.2)
    assert src.stats.problems["lost_frames"] >= len(frames) - 100 - 1
    assert "queue_overflow" in {e.kind for e in src.drain_events()}


@pytest.mark.parametrize("options, field, text", [
    ({"signals": {"F-NC2W-Z": "Excitation.Force"}}, "source.options.signals", "have no DBC signal"),
    ({"signals": {**SIGNALS, "F-NC2W-Z": "Excitation.Forc"}}, "source.options.signals.F-NC2W-Z",
     "no signal 'Forc'"),
    ({"signals": {**SIGNALS, "F-NC2W-Z": "Excite.Force"}}, "source.options.signals.F-NC2W-Z",
     "no message"),
    ({"dbc": "missing.dbc"}, "source.options.dbc", "not found"),
    ({"interface": "sockcan"}, "source.options.interface", "not allowed"),
    ({"counter": "Force"}, "source.options.counter", "not an unsigned"),
    ({"trigger": "Response"}, "source.options.trigger", "exclude each other"),
    ({"bitrat": 500000}, "source.options.bitrat", "unknown key"),
])
def test_config_errors(tmp_path: Path, options: dict, field: str, text: str) -> None:
    config = make_config(tmp_path, "unused", **options)
    with pytest.raises(ConfigError) as info:
        CanSource.from_config(config)
    assert info.value.field == field and text in str(info.value)
    assert info.value.file == str(tmp_path / "exp.yaml")


def test_unit_mismatch_rejected(tmp_path: Path) -> None:
    config = make_config(tmp_path, "unused")
    bad = parse_experiment({"sample_rate_hz": FS, "source": {"kind": "can", "options": dict(
        config.source.options)}, "channels": [dict(c, unit="mm") if c["name"] == "NC2W-Z" else c
                                              for c in CHANNELS]},
        file=config.file)
    with pytest.raises(ConfigError, match="unit 'mm'.*'m'"):
        CanSource.from_config(bad)


def test_feed_without_bus_and_describe(tmp_path: Path) -> None:
    """feed() decodes without a bus (benchmarks, replays); describe() is JSON-able."""
    import json
    frames, expected = build_frames(250)
    src = CanSource.from_config(make_config(tmp_path, "unused"))
    for f in frames:
        src.feed(f)
    blocks = [src.pop_block(), src.pop_block()]
    assert src.pop_block() is None
    assert np.array_equal(np.concatenate([b.data for b in blocks]), expected[:200])
    meta = json.loads(json.dumps(src.describe()))
    assert meta["source"]["can"]["signals"][0]["signal"] == "Force"
    assert "BO_ 256 Excitation" in meta["source"]["can"]["dbc"]
    src.close()


def feed_all(src: CanSource, frames: list[can.Message]) -> tuple[np.ndarray, list]:
    blocks = []
    for f in frames:
        src.feed(f)
        while (b := src.pop_block()) is not None:
            blocks.append(b)
    return np.concatenate([b.data for b in blocks]), blocks


def test_trigger_mode(tmp_path: Path) -> None:
    """trigger: Response closes a row; a missing Excitation leaves NaN force only."""
    frames, expected = build_frames(300, drop=lambda m, k: m == "Excitation" and k == 40)
    src = CanSource.from_config(make_config(tmp_path, "unused", counter=None,
                                            trigger="Response"))
    data, _ = feed_all(src, frames)
    assert np.array_equal(data, expected[:300], equal_nan=True)
    assert np.isnan(data[40, 0]) and src.stats.problems["incomplete_rows"] == 1
    src.close()


def test_message_never_seen_is_reported(tmp_path: Path) -> None:
    frames, expected = build_frames(200, drop=lambda m, k: m == "Response")
    src = CanSource.from_config(make_config(tmp_path, "unused"))
    data, _ = feed_all(src, frames)
    assert data.shape[0] >= 100
    assert np.array_equal(data[:, 0], expected[: data.shape[0], 0])
    assert np.isnan(data[:, 1:]).all()
    events = [e for e in src.drain_events() if e.kind == "no_frames"]
    assert len(events) == 1 and events[0].detail["messages"] == ["Response"]
    src.close()


def test_long_outage_starts_a_new_block(tmp_path: Path) -> None:
    """A gap longer than max_gap_rows is not filled with NaN: the next block starts later."""
    frames, expected = build_frames(300, drop=lambda m, k: 100 <= k < 150)
    src = CanSource.from_config(make_config(tmp_path, "unused", max_gap_rows=20))
    _, blocks = feed_all(src, frames)
    assert [(b.first_sample, b.n_samples) for b in blocks] == [(0, 100), (150, 100)]
    assert np.array_equal(blocks[1].data, expected[150:250])
    gap = [e for e in src.drain_events() if e.kind == "gap"]
    assert len(gap) == 1 and gap[0].detail["rows"] == 50
    assert abs(blocks[1].t0_ns - (T0 + 0.150) * 1e9) < 1e3
    src.close()


def test_joining_mid_cycle_drops_the_partial_first_row(tmp_path: Path) -> None:
    frames, expected = build_frames(250, drop=lambda m, k: m == "Excitation" and k == 0)
    src = CanSource.from_config(make_config(tmp_path, "unused"))
    data, blocks = feed_all(src, frames)
    assert np.array_equal(data, expected[1:201])
    assert blocks[0].first_sample == 0 and src.stats.problems["startup_rows_discarded"] == 1
    assert "lost_frames" not in src.stats.problems
    src.close()


def test_bus_state_change_reported(tmp_path: Path, channel: str,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from can.interfaces.virtual import VirtualBus
    state = {"now": can.BusState.ACTIVE}
    monkeypatch.setattr(VirtualBus, "state", property(lambda self: state["now"]))
    src = CanSource.from_config(make_config(tmp_path, channel))
    with src:
        src.read(timeout=0.1)
        state["now"] = can.BusState.ERROR   # what a driver reports at bus-off
        deadline = time.monotonic() + 3
        events: list = []
        while not events and time.monotonic() < deadline:
            src.read(timeout=0.1)
            events = [e for e in src.drain_events() if e.kind == "bus_state"]
    assert events[0].detail == {"state": "ERROR"}


def test_a_silent_bus_is_reported(tmp_path: Path, channel: str, caplog) -> None:
    """No sender on the bus: after SILENCE_WARNING_S a bus_silent event and one warning."""
    src = CanSource.from_config(make_config(tmp_path, channel))
    src.SILENCE_WARNING_S = 0.3
    with caplog.at_level("WARNING", logger="fnsi_lab.daq"), src:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            assert src.read(timeout=0.1) is None
    kinds = [e.kind for e in src.drain_events()]
    assert kinds.count("bus_silent") == 1  # once per silence, not once per read
    assert src.stats.problems.get("bus_silent") == 1
    assert sum("no CAN frame received" in r.getMessage() for r in caplog.records) == 1
