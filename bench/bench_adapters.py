"""Benchmark: sustained decode rate of the CAN and serial adapters.

CAN (``daq/data/example_can.dbc``, 2 mapped messages per sample row, counter mode):

- ``decode``: frames handed to ``CanSource.feed`` in a loop: the adapter's own cost
  (DBC decode + row assembly + blocks), frames/s and CPU time per frame;
- ``virtual bus, flat out``: a sender thread pushes frames through python-can's virtual
  bus as fast as it can; the receive thread + decoding keep up or count overflows. The
  sender's CPU (``time.thread_time`` in its thread, mostly python-can's per-frame
  deepcopy) is subtracted to get the adapter's CPU;
- ``virtual bus, 20 000 frames/s``: the sender paces to 20 000 frames/s (the goal: a
  saturated 1 Mbit/s bus, with CPU to spare) for ``--seconds``; the adapter's CPU share
  of one core is reported.

Serial: CSV lines (counter + 2 values) and binary frames (sync + ``<Hhh`` + CRC-16) fed
in 4 KiB chunks to ``SerialSource.feed``, and lines through ``loop://`` end to end.

Run:  python bench/bench_adapters.py [--frames 200000] [--seconds 3] [--results]
"""

from __future__ import annotations

import argparse
import binascii
import os
import platform
import re
import struct
import threading
import time
import uuid
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np

from fnsi_lab.daq.config import parse_experiment
from fnsi_lab.daq.sources.can_source import CanSource
from fnsi_lab.daq.sources.serial_source import SerialSource

ROOT = Path(__file__).resolve().parent.parent
DBC = ROOT / "daq" / "data" / "example_can.dbc"
GOAL_FPS = 20_000
CHANNELS = [{"name": "F", "quantity": "force", "unit": "N"},
            {"name": "X1", "quantity": "displacement", "unit": "m"},
            {"name": "X2", "quantity": "displacement", "unit": "m"},
            {"name": "A1", "quantity": "acceleration", "unit": "m/s^2"}]


def can_source(channel: str, row_rate: float) -> CanSource:
    config = parse_experiment({
        "sample_rate_hz": row_rate, "block_size": 100, "channels": CHANNELS,
        "source": {"kind": "can", "options": {
            "interface": "virtual", "channel": channel, "dbc": str(DBC), "counter": "Counter",
            "signals": {"F": "Excitation.Force", "X1": "Response.Disp1",
                        "X2": "Response.Disp2", "A1": "Response.Acc1"}}}})
    return CanSource.from_config(config)


def can_frames(n_frames: int, frame_rate: float) -> list[can.Message]:
    db = cantools.database.load_file(str(DBC))
    exc, resp = db.get_message_by_name("Excitation"), db.get_message_by_name("Response")
    rng = np.random.default_rng(0)
    frames = []
    for k in range(n_frames // 2):
        t = 1.7e9 + 2 * k / frame_rate
        u = float(rng.uniform(-100, 100))
        frames.append(can.Message(arbitration_id=exc.frame_id, is_extended_id=False, timestamp=t,
                                  data=exc.encode({"Counter": k % 256, "Force": u, "Voltage": 0})))
        frames.append(can.Message(arbitration_id=resp.frame_id, is_extended_id=False,
                                  timestamp=t + 1 / frame_rate,
                                  data=resp.encode({"Counter": k % 256, "Disp1": u * 1e-4,
                                                    "Disp2": -u * 1e-4, "Acc1": u * 0.1})))
    return frames


def bench_can_decode(frames: list[can.Message], frame_rate: float) -> dict[str, Any]:
    src = can_source("unused", frame_rate / 2)
    rows = 0
    c0, w0 = time.process_time(), time.perf_counter()
    for f in frames:
        src.feed(f)
        b = src.pop_block()
        if b is not None:
            rows += b.n_samples
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    src.close()
    assert rows >= len(frames) // 2 - 100, rows
    return {"frames": len(frames), "wall": wall, "cpu": cpu}


def bench_can_bus(frames: list[can.Message], frame_rate: float,
                  pace_fps: float | None) -> dict[str, Any]:
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    src = can_source(channel, frame_rate / 2)
    sender_cpu = [0.0]
    done = threading.Event()

    def send() -> None:
        bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        t0 = time.perf_counter()
        c0 = time.thread_time()
        try:
            for i, f in enumerate(frames):
                if pace_fps is not None and i % 100 == 0:
                    due = t0 + i / pace_fps
                    delay = due - time.perf_counter()
                    if delay > 0:
                        time.sleep(delay)
                bus.send(f)
        finally:
            sender_cpu[0] = time.thread_time() - c0
            bus.shutdown()
            done.set()

    rows = 0
    with src:
        th = threading.Thread(target=send, daemon=True)
        c0, w0 = time.process_time(), time.perf_counter()
        th.start()
        expected_rows = len(frames) // 2 - 200
        while rows < expected_rows:
            b = src.read(timeout=1.0)
            if b is not None:
                rows += b.n_samples
            elif done.is_set() and not src._queue:
                break
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        th.join()
    lost = src.stats.problems.get("lost_frames", 0)
    return {"frames": len(frames), "wall": wall, "cpu": cpu, "sender_cpu": sender_cpu[0],
            "rows": rows, "lost": lost}


def serial_source(fmt: str) -> SerialSource:
    opts: dict[str, Any] = {"url": "loop://", "fields": ["counter", "F", "X1"],
                            "counter": "counter", "scale": {"F": 0.001}}
    if fmt == "binary":
        opts.update(format="binary", sync="A55A", struct="<Hhh", checksum="crc16")
    config = parse_experiment({"sample_rate_hz": 10_000, "block_size": 100,
                               "channels": CHANNELS[:2],
                               "source": {"kind": "serial", "options": opts}})
    return SerialSource.from_config(config)


def serial_stream(n: int, fmt: str) -> bytes:
    rng = np.random.default_rng(1)
    f = rng.integers(-30000, 30000, n)
    x = rng.integers(-30000, 30000, n)
    if fmt == "line":
        return b"\n" + "".join(f"{k},{f[k]},{x[k] * 1e-6:.6f}\r\n" for k in range(n)).encode()
    out = bytearray()
    for k in range(n):
        body = struct.pack("<Hhh", k % 65536, f[k], x[k])
        out += b"\xa5\x5a" + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))
    return bytes(out)


def bench_serial_feed(n: int, fmt: str) -> dict[str, Any]:
    data = serial_stream(n, fmt)
    src = serial_source(fmt)
    rows = 0
    c0, w0 = time.process_time(), time.perf_counter()
    for i in range(0, len(data), 4096):
        src.feed(data[i:i + 4096], i)
        while (b := src.pop_block()) is not None:
            rows += b.n_samples
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    src.close()
    assert rows >= n - 100, rows
    return {"items": n, "wall": wall, "cpu": cpu, "bytes": len(data)}


def bench_serial_pty(n: int) -> dict[str, Any]:
    """Lines written to a pty master by a thread, read by the source from the slave path.

    (``loop://`` is not used here: pyserial's loop handler queues every byte separately,
    which measures pyserial, not the adapter.)
    """
    import tty
    data = serial_stream(n, "line")
    master, slave = os.openpty()
    tty.setraw(slave)
    config = parse_experiment({"sample_rate_hz": 10_000, "block_size": 100,
                               "channels": CHANNELS[:2], "source": {"kind": "serial", "options": {
                                   "url": os.ttyname(slave), "fields": ["counter", "F", "X1"],
                                   "counter": "counter", "scale": {"F": 0.001}}}})
    src = SerialSource.from_config(config)

    def write() -> None:
        for i in range(0, len(data), 4096):
            os.write(master, data[i:i + 4096])

    rows = 0
    try:
        with src:
            th = threading.Thread(target=write, daemon=True)
            c0, w0 = time.process_time(), time.perf_counter()
            th.start()
            while rows < n - 100:
                b = src.read(timeout=2.0)
                if b is None:
                    break
                rows += b.n_samples
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            th.join()
    finally:
        os.close(master)
        os.close(slave)
    return {"items": rows, "wall": wall, "cpu": cpu, "bytes": len(data)}


def machine() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.machine()}, {os.cpu_count()} CPUs visible, Python "
            f"{platform.python_version()}, python-can {can.__version__}, cantools "
            f"{cantools.__version__}; load average at start {load:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200_000, help="CAN frames per run")
    ap.add_argument("--seconds", type=float, default=3.0, help="length of the paced CAN run")
    ap.add_argument("--lines", type=int, default=200_000, help="serial lines/frames per run")
    ap.add_argument("--results", action="store_true", help="write bench/RESULTS.md section")
    args = ap.parse_args()
    info = machine()
    print(info)
    frame_rate = float(GOAL_FPS)
    frames = can_frames(args.frames, frame_rate)
    rows_md = []

    def add(name: str, n: int, unit: str, wall: float, cpu: float, note: str = "",
            goal: bool = False) -> None:
        rate, cpu_us = n / wall, cpu / n * 1e6
        vs = f"{rate / GOAL_FPS:.1f}x" if goal else "-"
        rows_md.append(f"| {name} | {rate:,.0f} {unit}/s | {cpu_us:.1f} us | {vs} | {note} |")
        print(rows_md[-1])

    d = bench_can_decode(frames, frame_rate)
    add("CAN decode (`feed`, no bus)", d["frames"], "frames", d["wall"], d["cpu"],
        f"CPU at 20 000 frames/s: {d['cpu'] / d['frames'] * GOAL_FPS * 100:.0f} % of one core",
        goal=True)
    b = bench_can_bus(frames, frame_rate, None)
    add("CAN virtual bus, flat out", b["frames"], "frames", b["wall"], b["cpu"] - b["sender_cpu"],
        f"adapter CPU (sender's {b['sender_cpu'] / b['frames'] * 1e6:.0f} us/frame subtracted); "
        f"lost {b['lost']}; rate bounded by the sender", goal=True)
    n_paced = int(args.seconds * GOAL_FPS) // 2 * 2
    paced = can_frames(n_paced, frame_rate)
    p = bench_can_bus(paced, frame_rate, GOAL_FPS)
    share = (p["cpu"] - p["sender_cpu"]) / p["wall"] * 100
    add("CAN virtual bus, paced 20 000 frames/s", p["frames"], "frames", p["wall"],
        p["cpu"] - p["sender_cpu"],
        f"adapter uses {share:.0f} % of one core; lost {p['lost']}", goal=True)
    s = bench_serial_feed(args.lines, "line")
    add("serial CSV lines (`feed`, 4 KiB chunks)", s["items"], "lines", s["wall"], s["cpu"],
        f"{s['bytes'] / s['wall'] / 1e6:.1f} MB/s of text")
    s = bench_serial_feed(args.lines, "binary")
    add("serial binary frames + CRC-16 (`feed`)", s["items"], "frames", s["wall"], s["cpu"],
        f"{s['bytes'] / s['wall'] / 1e6:.1f} MB/s")
    s = bench_serial_pty(min(args.lines, 100_000))
    add("serial CSV lines through a pty (writer thread -> port -> rx thread -> parse)",
        s["items"], "lines", s["wall"], s["cpu"],
        f"end to end, writer included; {s['bytes'] / s['wall'] / 1e6:.1f} MB/s")

    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = "\n".join([
        f"## Hardware adapters ({stamp})", "",
        f"`python bench/bench_adapters.py` on {info}. One run each; figures are +-30 % on "
        "this shared 2-core machine. 'CPU / item' is process CPU time per frame or line "
        "(for the bus runs, minus the sender thread's own CPU). 'vs goal' is the rate "
        "divided by 20 000 frames/s (a saturated 1 Mbit/s bus; 8-byte frames top out near "
        "8 000 frames/s).", "",
        "| path | sustained rate | CPU / item | vs goal | notes |",
        "|---|---|---|---|---|", *rows_md, ""])
    print(section)
    if args.results:
        path = ROOT / "bench" / "RESULTS.md"
        text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmark results\n"
        text = re.sub(r"\n## Hardware adapters \(.*?(?=\n## |\Z)", "", text, flags=re.S)
        path.write_text(text.rstrip("\n") + "\n\n" + section, encoding="utf-8")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
