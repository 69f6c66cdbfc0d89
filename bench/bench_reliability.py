"""Reliability probes through the command line, on the default SmallSat recording.

Each probe runs `fnsi-lab` in a subprocess the way a user would and records the exit
status, whether stderr holds exactly one error line and no traceback, and how much signal
was lost. Prints the markdown table of bench/RESULTS.md ("Reliability probes") and the
timings (whole-process acquisition speed, `--help`, a paced recording killed after 5 s).

Run: python bench/bench_reliability.py [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fnsi_lab.daq.recording import open_recording, recover

ROWS: list[tuple[str, str, str, str, str]] = []


def cli(*args: str, timeout: float = 600, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fnsi_lab", *args], capture_output=True,
                          text=True, timeout=timeout, **kw)


def seconds(path: Path) -> float:
    with open_recording(path) as rec:
        return sum(b.n_samples for b in rec.iter_blocks()) / rec.sample_rate_hz


def probe(name: str, r: subprocess.CompletedProcess, expected: int, lost: str = "nothing") -> None:
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    clean = "Traceback" not in r.stderr and (len(errors) == 1 if expected else not errors)
    held = "held" if r.returncode == expected and clean else "FAILED"
    line = errors[0] if errors else ""
    ROWS.append((name, f"{r.returncode} ({expected})", "yes" if clean else "NO", lost,
                 f"{held}: {line[:150]}" if line else held))


def flip(src: Path, dst: Path, where: float, n: int = 8) -> None:
    data = bytearray(src.read_bytes())
    at = int(len(data) * where)
    data[at:at + n] = bytes(b ^ 0xFF for b in data[at:at + n])
    dst.write_bytes(bytes(data))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="working folder (default: a temporary one)")
    ap.add_argument("--timing", action="store_true",
                    help="only the timings (acquire, --help, kill 5 s after launch)")
    opts = ap.parse_args()
    work = Path(opts.out or tempfile.mkdtemp(prefix="fnsi-reliability-"))
    work.mkdir(parents=True, exist_ok=True)
    os.chdir(work)
    load = os.getloadavg()[0]

    # ---- whole-process acquisition speed (default SmallSat, 49.152 s of signal)
    walls = []
    for i in range(3):
        t0 = time.perf_counter()
        r = cli("acquire", "--out", f"s{i}.mcap", "--quiet", "--no-info", "--force")
        walls.append(time.perf_counter() - t0)
        assert r.returncode == 0, r.stderr
    ref = Path("s0.mcap")
    total_s = seconds(ref)
    t0 = time.perf_counter()
    cli("--help")
    help_s = time.perf_counter() - t0
    imports = subprocess.run([sys.executable, "-X", "importtime", "-m", "fnsi_lab", "acquire",
                              "--help"], capture_output=True, text=True).stderr
    acquire_imports_rerun = " rerun" in imports

    if opts.timing:
        return _timings(load, walls, total_s, help_s, acquire_imports_rerun)

    # ---- damaged and cut recordings
    flip(ref, Path("flip.mcap"), 0.5)
    for cmd in (["info", "flip.mcap"], ["ident", "flip.mcap", "--config", "smallsat39", "--auto"],
                ["replay", "flip.mcap", "--method", "frf", "--quiet", "--rrd", "f.rrd"]):
        probe(f"8 flipped bytes mid-file: {cmd[0]}", cli(*cmd), 2, "refused (nothing used)")
    r = cli("recover", "flip.mcap", "flip.recovered.mcap")
    kept = seconds(Path("flip.recovered.mcap")) if r.returncode == 0 else 0.0
    probe("recover the 8-flipped-bytes file", r, 0,
          f"{total_s - kept:.1f} of {total_s:.1f} s ({100 * kept / total_s:.0f} % kept)")
    data = ref.read_bytes()
    Path("cut.mcap").write_bytes(data[: len(data) // 2])
    probe("file cut in half: info", cli("info", "cut.mcap"), 2, "refused, recover named")
    r = cli("recover", "cut.mcap", "cut.recovered.mcap")
    kept = seconds(Path("cut.recovered.mcap")) if r.returncode == 0 else 0.0
    probe("recover the half file", r, 0, f"kept {kept:.1f} s (the cut chunk and after)")
    Path("head.mcap").write_bytes(data[:200])
    probe("recover a file cut before any chunk", cli("recover", "head.mcap", "h.mcap"), 1,
          "nothing to keep; nothing written" if not Path("h.mcap").exists() else "WROTE A FILE")

    # ---- outputs never overwritten
    Path("notes.txt").write_text("lab notes")
    for cmd in (["acquire", "--out", "notes.txt"], ["run", "--out", "notes.txt"],
                ["recover", "cut.mcap", "notes.txt"],
                ["ident", "s1.mcap", "--config", "smallsat39", "--order", "20", "--json",
                 "notes.txt"], ["replay", "s1.mcap", "--rrd", "notes.txt", "--method", "frf"]):
        probe(f"existing output without --force: {cmd[0]}", cli(*cmd), 2,
              "nothing" if Path("notes.txt").read_text() == "lab notes" else "OVERWRITTEN")
    probe('acquire --out ""', cli("acquire", "--out", ""), 2)

    # ---- configuration checked before acquiring; identification failures
    Path("wrong.yaml").write_text("band_hz: [5, 50]\noutputs: [NC2W-Z, X9]\n")
    r = cli("run", "--ident", "wrong.yaml", "--out", "w.mcap")
    probe("run --ident naming a channel not recorded", r, 2,
          "no acquisition started" if not Path("w.mcap").exists() else "ACQUIRED ANYWAY")
    Path("empty.yaml").write_text("band_hz: [100, 200]\n")
    probe("run whose identification fails (no excited line)",
          cli("run", "--ident", "empty.yaml", "--out", "e.mcap", "--orders", "2:10"), 1,
          "recording complete; reason printed")
    Path("nyq.yaml").write_text("band_hz: [5, 800]\n")
    probe("ident band above Nyquist", cli("ident", "s1.mcap", "--config", "nyq.yaml",
                                          "--order", "10"), 2)
    np.savez("fs.npz", u=np.zeros((1000, 1)), y=np.zeros((1000, 2)), fs=np.array("fast"))
    probe(".npz with a non-numeric fs", cli("ident", "fs.npz", "--config", "lumped-cubic",
                                            "--order", "4"), 2)
    np.savez("n0.npz", u=np.zeros((1000, 1)), y=np.zeros((1000, 2)), fs=1000.0, N=0)
    probe(".npz with N = 0", cli("ident", "n0.npz", "--config", "lumped-cubic", "--order", "4"), 2)
    probe("--queue-blocks 0", cli("run", "--queue-blocks", "0"), 2)

    # ---- paths and ports
    probe("unwritable --rrd (parent is a file)",
          cli("replay", "s1.mcap", "--rrd", "notes.txt/x.rrd", "--method", "frf"), 2)
    probe("--out in a missing folder", cli("acquire", "--out", "missing/x.mcap"), 2)
    probe("--web-port 99999", cli("replay", "s1.mcap", "--serve-web", "--web-port", "99999"), 2)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = str(busy.getsockname()[1])
        probe("busy --web-port", cli("replay", "s1.mcap", "--serve-web", "--web-port", port,
                                     "--method", "frf"), 2)

    # ---- full disk: RLIMIT_FSIZE 3 MB (the recording is 9.2 MB)
    def small_disk() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (3_000_000, 3_000_000))
    r = cli("acquire", "--out", "full.mcap", "--quiet", "--no-info", preexec_fn=small_disk)
    rec = recover("full.mcap", "full.recovered.mcap")
    probe("disk full during acquire (RLIMIT_FSIZE 3 MB)", r, 1,
          f"recoverable: {rec.seconds_recovered:.1f} s kept of what fit")

    # ---- signals during a paced recording
    proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "acquire", "--realtime", "--out",
                             "term.mcap", "--quiet", "--no-info"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(5)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    r = subprocess.CompletedProcess(proc.args, proc.returncode, out,
                                    err.replace("interrupted", "error: interrupted"))
    ok_file = seconds(Path("term.mcap"))
    probe("SIGTERM 5 s after `acquire --realtime`", r, 130,
          f"nothing: file finished cleanly with {ok_file:.1f} s")
    _timings(load, walls, total_s, help_s, acquire_imports_rerun)
    print()
    print("| probe | exit (expected) | one line, no traceback | data lost | outcome |")
    print("|---|---|---|---|---|")
    for row in ROWS:
        print("| " + " | ".join(c.replace("|", "/") for c in row) + " |")
    return 0 if all(row[4].startswith("held") for row in ROWS) else 1


def _timings(load: float, walls: list[float], total_s: float, help_s: float,
             imports_rerun: bool) -> int:
    kills, kills_from_open = [], []
    for i in range(6):  # 5 s after launch, then 5 s after the recording file was created
        path = Path(f"kill{i}.mcap")
        proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "acquire", "--realtime",
                                 "--out", str(path), "--quiet", "--no-info", "--force"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if i >= 3:
            while not path.exists():
                time.sleep(0.01)
        time.sleep(5)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        kept = (recover(path, f"kill{i}.recovered.mcap").seconds_recovered
                if path.exists() else 0.0)
        (kills if i < 3 else kills_from_open).append(kept)

    print(f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, 2 cores, load average "
          f"{load:.1f} at start, {os.getloadavg()[0]:.1f} at the end")
    print(f"acquire (default SmallSat, {total_s:.3f} s of signal), whole process: "
          f"{', '.join(f'{w:.2f}' for w in walls)} s -> median "
          f"{total_s / statistics.median(walls):.1f}x real time")
    print(f"fnsi-lab --help: {help_s:.2f} s; acquire imports rerun: {imports_rerun}")
    print(f"acquire --realtime killed (SIGKILL) 5 s after launch, seconds kept: "
          f"{', '.join(f'{k:.2f}' for k in kills)}")
    print(f"acquire --realtime killed (SIGKILL) 5 s after the recording was created, seconds "
          f"kept: {', '.join(f'{k:.2f}' for k in kills_from_open)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
