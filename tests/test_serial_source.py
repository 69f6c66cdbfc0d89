"""SerialSource over pyserial's loop:// and a pseudo-terminal with a fake instrument."""

from __future__ import annotations

import binascii
import os
import struct
import threading
import time
import tty
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fnsi_lab.daq.config import parse_experiment
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sources.serial_source import SerialSource
from fnsi_lab.errors import ConfigError
from test_can_source import no_adapter_leaks  # noqa: F401  (autouse fixture)

FS = 1000.0
CHANNELS = [
    {"name": "F-NC2W-Z", "quantity": "force", "unit": "N"},
    {"name": "NC2W-Z", "quantity": "displacement", "unit": "m"},
]


def make_config(tmp_path: Path, **options: Any):
    opts = {"url": "loop://", "baudrate": 921600, "fields": ["counter", "F-NC2W-Z", "NC2W-Z"],
            "counter": "counter", "scale": {"F-NC2W-Z": 0.001}, "offset": {"NC2W-Z": 0.5},
            "stall_timeout_s": 0.2, "reconnect_interval_s": 0.05}
    opts.update(options)
    opts = {k: v for k, v in opts.items() if v is not None}
    data = {"name": "serial-test", "sample_rate_hz": FS, "block_size": 50,
            "source": {"kind": "serial", "options": opts}, "channels": CHANNELS}
    return parse_experiment(data, file=str(tmp_path / "exp.yaml"))


def text_lines(n: int, start: int = 0) -> tuple[list[bytes], np.ndarray]:
    """Instrument lines (force in mN, displacement minus 0.5 m) and the expected rows."""
    u = multisine(100, FS, (10.0, 300.0), 20.0, n_periods=-(-(start + n) // 100), seed=5).signal[0]
    lines, expected = [], np.empty((n, 2))
    for j, k in enumerate(range(start, start + n)):
        f_txt, y_txt = f"{u[k] * 1000:.3f}", f"{u[k] * 1e-3 - 0.5:.9f}"
        lines.append(f"{k},{f_txt},{y_txt}\r\n".encode())
        expected[j] = [float(f_txt) * 0.001, float(y_txt) + 0.5]  # same float ops as the source
    return lines, expected


def read_rows(src: SerialSource, n: int, timeout: float = 10.0) -> tuple[np.ndarray, list]:
    blocks = []
    deadline = time.monotonic() + timeout
    while sum(b.n_samples for b in blocks) < n:
        assert time.monotonic() < deadline, f"only {sum(b.n_samples for b in blocks)} rows"
        b = src.read(timeout=0.2)
        if b is not None:
            blocks.append(b)
    return np.concatenate([b.data for b in blocks]), blocks


def test_loop_lines_exact_with_garbage_and_partial_lines(tmp_path: Path) -> None:
    n = 400
    lines, expected = text_lines(n)
    expected[[77, 300]] = np.nan  # the lines we corrupt below are lost samples
    lines[77] = lines[77][:5] + b"\x00\xff#!" + lines[77][5:]   # corrupted inside
    lines[300] = lines[300][:7]                                  # cut off: merges with 301?
    lines[300] += b"\n"                                          # ...no: a short, bad line
    stream = b"tail of an earlier line 1,2\n" + b"".join(lines[:150]) + b"@@garbage@@\n" \
        + b"".join(lines[150:])
    rng = np.random.default_rng(0)
    cuts = np.sort(rng.choice(np.arange(1, len(stream)), size=300, replace=False))
    src = SerialSource.from_config(make_config(tmp_path))
    with src:
        for chunk in np.split(np.frombuffer(stream, np.uint8), cuts):  # partial lines
            src.port.write(chunk.tobytes())
        data, blocks = read_rows(src, n)
    assert np.array_equal(data, expected, equal_nan=True)
    assert [b.first_sample for b in blocks] == list(range(0, n, 50))
    p = src.stats.problems
    assert p["bad_line"] == 3 and p["lost_samples"] == 2
    assert p["startup_lines_discarded"] == 1
    kinds = {e.kind for e in src.drain_events()}
    assert {"bad_line", "missing_samples"} <= kinds


def test_overlong_garbage_resynchronises(tmp_path: Path) -> None:
    lines, expected = text_lines(60)
    src = SerialSource.from_config(make_config(tmp_path, max_line_bytes=64))
    src.feed(b"x\n" + b"".join(lines[:30]) + b"\x00" * 500 + lines[30][3:], 0)
    src.feed(b"".join(lines[31:]), 1)
    block = src.pop_block()
    assert block is not None and np.array_equal(
        block.data, np.vstack([expected[:30], np.full((1, 2), np.nan), expected[31:50]]),
        equal_nan=True)
    assert src.stats.problems["overlong_line"] == 1
    src.close()


def crc_frames(n: int, sync: bytes = b"\xa5\x5a") -> tuple[list[bytes], np.ndarray]:
    u = multisine(64, FS, (10.0, 300.0), 20.0, n_periods=-(-n // 64), seed=6).signal[0]
    raw_f = np.round(u * 400).astype(int)           # int16 counts, 1 mN each
    raw_y = np.round(u * 100).astype(int)           # um in int16, offset below
    frames, expected = [], np.empty((n, 2))
    for k in range(n):
        body = struct.pack("<Hhh", k % 65536, raw_f[k], raw_y[k])
        frames.append(sync + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF)))
        expected[k] = [raw_f[k] * 0.001, raw_y[k] * 1e-6 + 0.5]
    return frames, expected


def test_loop_binary_frames_resync_and_checksum(tmp_path: Path) -> None:
    n = 300
    frames, expected = crc_frames(n)
    bad = bytearray(frames[120])
    bad[5] ^= 0x40                      # corrupted payload: checksum fails, sample lost
    frames[120] = bytes(bad)
    expected[120] = np.nan
    stream = b"\x5a\x01" + b"".join(frames[:60]) + b"\xa5\x5a\x00\xa5garbage" \
        + b"".join(frames[60:])
    src = SerialSource.from_config(make_config(
        tmp_path, format="binary", sync="A55A", struct="<Hhh", checksum="crc16",
        scale={"F-NC2W-Z": 0.001, "NC2W-Z": 1e-6}))
    with src:
        for i in range(0, len(stream), 37):
            src.port.write(stream[i:i + 37])
        data, _ = read_rows(src, n)
    assert np.array_equal(data, expected, equal_nan=True)
    p = src.stats.problems
    assert p["lost_samples"] == 1 and p["bad_checksum"] >= 2  # the frame + the false sync
    assert p["skipped_bytes"] >= 2 + 9
    assert {"resync", "bad_checksum", "missing_samples"} <= {e.kind for e in src.drain_events()}


def test_rate_mismatch_from_timestamps(tmp_path: Path) -> None:
    lines, _ = text_lines(3000)
    src = SerialSource.from_config(make_config(tmp_path, expected_rate_hz=1200.0,
                                               rate_window_s=0.5))
    for k, line in enumerate([b"\n"] + lines):
        src.feed(line, 10**9 + k * 1_000_000)  # device clock: exactly 1 kHz
    events = [e for e in src.drain_events() if e.kind == "rate_mismatch"]
    assert len(events) == 1 and events[0].detail["measured_hz"] == pytest.approx(1000.0)
    assert src.stats.problems["rate_mismatch_windows"] == 5
    src.close()


class PtyInstrument:
    """A fake instrument behind a pty whose path is a symlink (like /dev/serial/by-id).

    ``unplug()`` closes the pty and points the link at a fresh one, as a USB adapter that
    re-enumerates does.
    """

    def __init__(self, link: Path) -> None:
        self.link = link
        self.lock = threading.Lock()
        self._plug()

    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no line discipline: bytes pass unchanged
        self.master, self.slave = master, slave
        tmp = self.link.with_suffix(".new")
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.link)

    def write(self, data: bytes) -> None:
        with self.lock:
            os.write(self.master, data)

    def unplug(self) -> None:
        with self.lock:
            os.close(self.master)
            os.close(self.slave)
            self._plug()

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def test_pty_stall_and_reconnect(tmp_path: Path) -> None:
    n = 900
    lines, expected = text_lines(n)
    inst = PtyInstrument(tmp_path / "ttyLAB0")
    src = SerialSource.from_config(make_config(tmp_path, url=str(tmp_path / "ttyLAB0")))
    errors: list[BaseException] = []

    def run() -> None:
        try:
            inst.write(b"half a line\n")
            for k, line in enumerate(lines):
                if k == 300:
                    time.sleep(0.5)        # stall: > stall_timeout_s
                if k == 600:
                    time.sleep(0.1)        # let the reader drain the old pty
                    inst.unplug()
                    time.sleep(0.3)        # the adapter notices and reopens
                    inst.write(b"noise after replug\n")
                inst.write(line)
                if k % 50 == 49:
                    time.sleep(0.01)
        except BaseException as exc:  # surfaced by the test thread
            errors.append(exc)

    writer = threading.Thread(target=run, daemon=True)
    try:
        with src:
            writer.start()
            data, _ = read_rows(src, n - 1, timeout=15)
            writer.join(timeout=10)
    finally:
        inst.close()
    assert not writer.is_alive() and not errors
    data = data[: n]
    got = ~np.isnan(data[:, 0])
    assert got.sum() >= n - 30  # only samples around the replug may be lost
    assert np.array_equal(data[got], expected[: len(data)][got])  # at their counter index
    assert src.stats.problems.get("lost_samples", 0) == (~got).sum()
    kinds = [e.kind for e in src.drain_events()]
    assert kinds.index("stall") < kinds.index("resumed") < kinds.index("disconnected") \
        < kinds.index("reconnected")


def test_socket_url(tmp_path: Path) -> None:
    """socket:// (a TCP serial server) goes through the same code path."""
    import socket
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    lines, expected = text_lines(120)
    src = SerialSource.from_config(make_config(tmp_path, url=f"socket://127.0.0.1:{port}"))
    try:
        with src:
            conn, _ = server.accept()
            with conn:
                conn.sendall(b"\n" + b"".join(lines))
                data, _ = read_rows(src, 100)
    finally:
        server.close()
    assert np.array_equal(data, expected[:100])


@pytest.mark.parametrize("options, field, text", [
    ({"fields": ["counter", "F-NC2W-Z"]}, "source.options.fields", "not among the fields"),
    ({"fields": ["counter", "F-NC2W-Z", "NC2W-Y"]}, "source.options.fields", "not among"),
    ({"fields": ["cnt", "F-NC2W-Z", "NC2W-Z"]}, "source.options.fields", "neither channels"),
    ({"scale": {"F-NC2W": 2.0}}, "source.options.scale", "not channels"),
    ({"format": "binary", "struct": "<Hh"}, "source.options.sync", "missing required"),
    ({"format": "binary", "sync": "A5", "struct": "<Hh"}, "source.options.fields", "2 items"),
    ({"format": "binary", "sync": "A5", "struct": "<Hhh", "checksum": "crc8"},
     "source.options.checksum", "not allowed"),
    ({"format": "binary", "sync": "zz", "struct": "<Hhh"}, "source.options.sync", "not hex"),
    ({"baud": 9600}, "source.options.baud", "unknown key"),
])
def test_config_errors(tmp_path: Path, options: dict, field: str, text: str) -> None:
    with pytest.raises(ConfigError) as info:
        SerialSource.from_config(make_config(tmp_path, **options))
    assert info.value.field == field and text in str(info.value)
    assert info.value.file == str(tmp_path / "exp.yaml")


def test_open_failure_is_a_source_error(tmp_path: Path) -> None:
    from fnsi_lab.errors import SourceError
    src = SerialSource.from_config(make_config(tmp_path, url=str(tmp_path / "no-such-tty")))
    with pytest.raises(SourceError, match="cannot open serial port"):
        src.start()
    src.close()
