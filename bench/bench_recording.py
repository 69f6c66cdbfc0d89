"""Benchmark: MCAP recording write/read throughput against numpy.save/numpy.load.

Two streams, float32, zstd chunks, one Python thread (one core):

- ``slow``: 39 channels @ 1 kHz, 100-sample blocks (the SmallSat test);
- ``fast``: 64 channels @ 51.2 kHz, 512-sample blocks (13.1 MB/s, a large DAQ).

Write = encode + compress + write + fsync at close (``Recorder``); read = open + decode
every block into one ``(n_samples, n_channels)`` array (``Recording.read_samples``).
The reference is ``numpy.save`` (+ fsync) / ``numpy.load`` of the same array in the same
run. Best of ``--repeat`` runs. Goal: write >= 10x real time on ``fast``, read at least
as fast as write.

Run:  python bench/bench_recording.py [--seconds-fast 10] [--repeat 3] [--results]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.recording import Recorder, open_recording


@dataclass
class Stream:
    name: str
    n_channels: int
    sample_rate_hz: float
    block_size: int
    seconds: float


def signal(stream: Stream, seed: int = 0) -> np.ndarray:
    """Realistic test data, float32 (n_samples, n_channels): a few tones per channel plus
    sensor noise 60 dB below (measurement data do not compress like zeros)."""
    rng = np.random.default_rng(seed)
    n = int(stream.seconds * stream.sample_rate_hz)
    t = np.arange(n) / stream.sample_rate_hz
    x = np.empty((n, stream.n_channels), dtype=np.float32)
    for c in range(stream.n_channels):
        f = rng.uniform(5, stream.sample_rate_hz / 10, size=3)
        col = sum(np.sin(2 * np.pi * fk * t + rng.uniform(0, 6.28)) for fk in f)
        x[:, c] = col + 1e-3 * rng.standard_normal(n)
    return x


def best(fn, repeat: int) -> tuple[float, float]:
    """Best wall-clock and best CPU (process) time of ``repeat`` calls, seconds.

    CPU time is the "one core" figure on a shared machine (wall time includes the time
    other jobs held the core); it excludes waiting for the disk (fsync).
    """
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def run(stream: Stream, repeat: int, folder: Path) -> dict[str, float]:
    x = signal(stream)
    chans = tuple(ChannelInfo(f"ch{i:02d}", "force" if i == 0 else "acceleration")
                  for i in range(stream.n_channels))
    blocks = [Block(x[s:s + stream.block_size], chans, stream.sample_rate_hz, k, s,
                    int(round(s * 1e9 / stream.sample_rate_hz)))
              for k, s in enumerate(range(0, x.shape[0], stream.block_size))]
    mcap_path = folder / f"{stream.name}.mcap"
    npy_path = folder / f"{stream.name}.npy"

    def write_mcap() -> None:
        with Recorder(mcap_path, chans, stream.sample_rate_hz) as rec:
            for b in blocks:
                rec.write_block(b)

    def write_npy() -> None:
        with open(npy_path, "wb") as f:
            np.save(f, x)
            f.flush()
            os.fsync(f.fileno())

    out: dict[str, np.ndarray] = {}

    def read_mcap() -> None:
        with open_recording(mcap_path) as rec:
            out["mcap"] = rec.read_samples()

    def read_npy() -> None:
        out["npy"] = np.load(npy_path)

    w_mcap, w_mcap_cpu = best(write_mcap, repeat)
    w_npy, _ = best(write_npy, repeat)
    r_mcap, r_mcap_cpu = best(read_mcap, repeat)
    r_npy, _ = best(read_npy, repeat)
    assert out["mcap"].tobytes() == x.tobytes(), "MCAP round trip is not bit exact"
    mb = x.nbytes / 1e6
    return {"stream_mb_s": mb / stream.seconds, "mb": mb, "seconds": stream.seconds,
            "values": float(x.size), "file_ratio": mcap_path.stat().st_size / x.nbytes,
            "w_mcap": w_mcap, "w_npy": w_npy, "r_mcap": r_mcap, "r_npy": r_npy,
            "w_mcap_cpu": w_mcap_cpu, "r_mcap_cpu": r_mcap_cpu,
            "blocks": float(len(blocks))}


def report(name: str, s: Stream, r: dict[str, float]) -> list[str]:
    rows = []
    for op, key_m, key_n in (("write", "w_mcap", "w_npy"), ("read", "r_mcap", "r_npy")):
        tm, tn, tc = r[key_m], r[key_n], r[key_m + "_cpu"]
        rows.append(f"| {name}: {s.n_channels} ch @ {s.sample_rate_hz / 1000:g} kHz "
                    f"({r['stream_mb_s']:.2f} MB/s, {s.seconds:g} s) | {op} "
                    f"| {r['mb'] / tm:.0f} MB/s | {r['values'] / tm / 1e6:.1f} M | "
                    f"{s.seconds / tm:.0f}x | {s.seconds / tc:.0f}x "
                    f"| {r['mb'] / tn:.0f} MB/s | {tn / tm:.2f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds-slow", type=float, default=120.0)
    ap.add_argument("--seconds-fast", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--results", action="store_true",
                    help="append the table to bench/RESULTS.md (section 'MCAP recording')")
    args = ap.parse_args()
    streams = [Stream("slow", 39, 1000.0, 100, args.seconds_slow),
               Stream("fast", 64, 51200.0, 512, args.seconds_fast)]
    header = ["| stream | op | MCAP throughput (wall) | values/s (wall) | x real time (wall) "
              "| x real time (CPU) | numpy.save/load (wall) | MCAP speed / numpy speed (wall) |",
              "|---|---|---|---|---|---|---|---|"]
    rows = []
    ratios = []
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        for s in streams:
            r = run(s, args.repeat, Path(tmp))
            rows += report(s.name, s, r)
            ratios.append(f"{s.name}: file size {r['file_ratio']:.2f}x raw float32, "
                          f"{r['blocks']:.0f} blocks of {s.block_size} samples")
    print("\n".join(header + rows))
    ratios.append(f"load average at start {load:.1f} (other jobs share the 2 cores: +-30 %)")
    print("\n".join(ratios))
    if args.results:
        path = Path(__file__).with_name("RESULTS.md")
        text = path.read_text() if path.exists() else "# Benchmark results\n"
        date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        cpu = platform.processor() or platform.machine()
        section = [f"\n## MCAP recording ({date})\n",
                   f"`python bench/bench_recording.py` on a 2-core machine ({cpu}, "
                   f"{os.cpu_count()} CPUs visible), Python {platform.python_version()}, one "
                   "thread, zstd chunks, best of "
                   f"{args.repeat}. Write = encode + compress + write + fsync; read = decode "
                   "into one (n_samples, n_channels) float32 array. The last column is MCAP "
                   "speed divided by numpy.save/numpy.load speed on the same array in the "
                   "same run (1.0 = as fast as an uncompressed .npy). 'x real time (CPU)' divides by the "
                   "process CPU time, i.e. what one core does when it is not shared.\n", *header, *rows, "",
                   *(f"- {x}" for x in ratios), ""]
        path.write_text(text.rstrip("\n") + "\n" + "\n".join(section))
        print(f"appended to {path}")


if __name__ == "__main__":
    main()
