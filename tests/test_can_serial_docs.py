"""docs/hardware.md: its example experiments load and build their adapters; CAN to MCAP."""

from __future__ import annotations

import re
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest

from fnsi_lab.daq.config import load_experiment
from fnsi_lab.daq.registry import make_source
from fnsi_lab.daq.sources.can_source import CanSource
from fnsi_lab.daq.sources.serial_source import SerialSource
from test_can_source import no_adapter_leaks  # noqa: F401  (autouse fixture)

DOC = Path(__file__).resolve().parent.parent / "docs" / "hardware.md"


def doc_yaml(first_line: str) -> str:
    """The ```yaml block of docs/hardware.md that starts with ``first_line``."""
    blocks = re.findall(r"```yaml\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    matches = [b for b in blocks if b.startswith(first_line)]
    assert len(matches) == 1, f"no single yaml block starting {first_line!r}"
    return matches[0]


def test_can_example_yaml(tmp_path: Path) -> None:
    path = tmp_path / "can_experiment.yaml"
    path.write_text(doc_yaml("# can_experiment.yaml"), encoding="utf-8")
    config = load_experiment(path)
    src = make_source(config)  # the registry path the CLI takes; the bus opens on start
    assert isinstance(src, CanSource)
    assert src.channel_names == ["F-NC2W-Z", "NC2W-Z", "NC3-Z", "NC2W-Z-acc"]
    assert [s.unit for s in src.signal_map] == ["N", "m", "m", "m/s^2"]
    assert src._bus_kwargs == {"interface": "socketcan", "channel": "can0",
                               "bitrate": 1_000_000}
    src.close()


def test_serial_example_yamls(tmp_path: Path) -> None:
    text = doc_yaml("# serial_experiment.yaml")
    path = tmp_path / "serial_experiment.yaml"
    path.write_text(text, encoding="utf-8")
    src = make_source(load_experiment(path))
    assert isinstance(src, SerialSource) and src.describe()["source"]["serial"]["fields"] == [
        "counter", "F-NC2W-Z", "NC2W-Z", "_"]
    src.close()
    # the binary snippet replaces the line-format options of the same experiment
    binary = doc_yaml("    format: binary")
    head, _, tail = text.partition("    format: line\n")
    tail = "\n".join(l for l in tail.splitlines()
                     if not re.match(r"    (delimiter|line_ending|fields|counter|scale):", l))
    path.write_text(head + binary + tail + "\n", encoding="utf-8")
    src = make_source(load_experiment(path))
    info = src.describe()["source"]["serial"]
    assert (info["format"], info["sync"], info["struct"], info["checksum"]) == (
        "binary", "a55a", "<Hhh", "crc16")
    src.close()


def test_can_blocks_events_and_raw_frames_to_mcap(tmp_path: Path) -> None:
    """CAN -> acquire -> Recorder -> open_recording: exact values, events, raw frames."""
    recording = pytest.importorskip("fnsi_lab.daq.recording", reason="fnsi_lab.daq.recording not built yet")
    from fnsi_lab.daq.acquisition import acquire, recording_metadata
    from test_can_source import Sender, build_frames, make_config

    channel = f"test-{uuid.uuid4().hex[:12]}"
    n = 600
    frames, expected = build_frames(
        n, drop=lambda m, k: m == "Response" and k == 333,
        extra=lambda k: [__import__("can").Message(is_error_frame=True, arbitration_id=4,
                                                   timestamp=1_700_000_000.0 + k / 1e3)]
        if k == 10 else [])
    config = make_config(tmp_path, channel, record_raw=True)
    src = CanSource.from_config(config)
    out = tmp_path / "can.mcap"
    stop = threading.Event()
    with src, recording.Recorder(out, src.channels, src.sample_rate_hz,
                                 metadata=recording_metadata(config, src)) as rec:
        with Sender(channel, frames):
            timer = threading.Timer(10.0, stop.set)  # never hang
            timer.start()
            try:
                # one queue item per raw frame: room for all of them (see the report)
                report = acquire(src, rec, stop=stop, max_duration_s=n / 1e3,
                                 queue_blocks=4 * len(frames))
            finally:
                timer.cancel()
    assert report.samples == n and report.recorder_overflows == 0
    with recording.open_recording(out) as r:
        data = r.read_samples()
        events = list(r.iter_events())
        raw = list(r.iter_json("/daq/can_raw"))
        meta = r.metadata
    assert data.shape == (n, 4)
    # float32 on disk: the DBC-quantised values, rounded once to float32
    assert np.array_equal(data, expected.astype(np.float32), equal_nan=True)
    kinds = [e["kind"] for e in events]
    assert "error_frame" in kinds and "missing_frames" in kinds
    missing = next(e for e in events if e["kind"] == "missing_frames")
    assert missing["detail"]["message"] == "Response" and missing["detail"]["frames"] == 1
    assert len(raw) == len(frames)
    assert raw[0][0] == int(1_700_000_000.0 * 1e9) and raw[0][1]["id"] == 0x100
    assert meta["source"]["can"]["counter"] == "Counter"
