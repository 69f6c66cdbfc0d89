"""Benchmark: live identification latency and replay speed (39 channels at 1 kHz).

- **latency**: wall time from the arrival of the last block of a multisine period at the
  identification service to the end of the Rerun logging of the identification that used
  it (signals logged too, everything saved to an .rrd). Periods of N = 8192 samples at
  1 kHz last 8.19 s: the update must land before the next period ends (< 8.19 s); the goal
  is < 2 s. The source is paced at ``--speed`` x real time (default 1: real time).
- **replay speed**: signal seconds per wall second of (a) :class:`replay.source.ReplaySource`
  alone, (b) ``fnsi-lab replay`` without identification (``--method frf``: assembly,
  nonparametric FRF, Rerun logging of all signals to an .rrd), (c) the full ``replay`` with
  the robust pipeline (the service skips to the newest data when it falls behind).
  Goal >= 100x real time.

The data: the simulated SmallSat (``daq.config.load_experiment(None)``, 5 transient
periods plus ``--periods`` steady ones; the latency run replays that recording paced at
``--speed``, which is what the service sees from a live acquisition), or ``--data modal``:
a linear modal model with the SmallSat's shape (1 force, 39 displacement outputs, 11 modes
between 8 and 48 Hz, 1-3 % damping, multisine 5-50 Hz, output noise 0.1 %).

Run:  python bench/bench_live.py [--periods 3] [--orders 2:30] [--speed 1] [--results]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from fnsi_lab.daq.acquisition import Tap, acquire
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.recording import Recorder
from fnsi_lab.daq.sources.array_source import ArraySource

FS, N, N_OUT = 1000.0, 8192, 39


def modal_data(n_periods: int, seed: int = 0) -> tuple[np.ndarray, tuple, dict]:
    """float32 (n_periods N, 40) steady-state data of a 39-output modal model, metadata."""
    rng = np.random.default_rng(seed)
    ms = multisine(N, FS, (5.0, 50.0), 100.0, n_periods=1, seed=seed)
    u = ms.signal[0]
    f_n = np.sort(rng.uniform(8, 48, 11))
    zeta = rng.uniform(0.01, 0.03, 11)
    shapes = rng.standard_normal((N_OUT, 11))
    drive = shapes[0]  # the force acts at output 0 (driving point)
    k = np.arange(N // 2 + 1)
    w = 2 * np.pi * k * FS / N
    wn = 2 * np.pi * f_n
    h = (shapes[None] * drive[None, None, :]
         / (wn[None, None] ** 2 - w[:, None, None] ** 2 + 2j * zeta * wn * w[:, None, None]))
    H = h.sum(axis=2) * 1e-3  # (F, 39), m/N
    Y = H * np.fft.rfft(u)[:, None]
    y = np.fft.irfft(Y, n=N, axis=0)
    x = np.tile(np.c_[u, y], (n_periods, 1))
    x[:, 1:] += 1e-3 * y.std() * rng.standard_normal((x.shape[0], N_OUT))
    channels = ((ChannelInfo("F-N0-Z", "force", node="N0", direction="Z"),)
                + tuple(ChannelInfo(f"N{i}-Z", node=f"N{i}", direction="Z")
                        for i in range(N_OUT)))
    exc = {"kind": "multisine", "band_hz": [5.0, 50.0], "rms": 100.0, "samples_per_period": N,
           "periods": n_periods, "transient_periods": 1, "realizations": 1, "seed": seed,
           "phases": "random", "sample_rate_hz": FS}
    return x.astype(np.float32), channels, {"excitation": exc,
                                            "experiment": {"sample_rate_hz": FS}}


def latency(path: Path, identify, speed: float, rrd: Path) -> dict:
    """Paced replay of ``path`` (as a live source) -> Tap -> service -> Rerun (.rrd)."""
    import rerun as rr

    from fnsi_lab.replay.cli import LiveRun
    from fnsi_lab.replay.service import IdentService
    from fnsi_lab.replay.source import ReplaySource
    from fnsi_lab.viewer.blueprint import blueprint

    src = ReplaySource(path, speed=speed)
    rec = rr.RecordingStream("fnsi-lab-bench", recording_id="bench")
    rec.save(str(rrd), default_blueprint=blueprint(("force", "displacement")))
    run = LiveRun(rec, src.channels, quiet=True)
    svc = IdentService.for_recording_metadata(src.channels, src.sample_rate_hz, src.metadata,
                                              identify, on_update=run.on_update,
                                              on_block=run.on_block)
    run.service = svc
    tap = Tap("ident", maxsize=4096)
    svc.start(tap)
    t0 = time.perf_counter()
    with src:
        report = acquire(src, None, taps=[tap], live=True)
    st = svc.finish()
    run.flush_signals()
    rec.flush()
    rec.disconnect()
    return {"wall_s": time.perf_counter() - t0, "latencies": run.latencies,
            "ident_s": [u.ident_s for u in svc.updates], "updates": st.updates,
            "skipped": st.skipped, "dropped": st.dropped_blocks + report.tap_drops["ident"],
            "failures": st.failures, "error": st.last_error,
            "selected_order": svc.updates[-1].result.result.selected_order if svc.updates else None}


def smallsat_recording(path: Path, steady_periods: int) -> str | None:
    """Simulate the packaged SmallSat experiment with ``steady_periods`` steady periods."""
    from dataclasses import replace

    try:
        from fnsi_lab.daq.acquisition import record_experiment
        from fnsi_lab.daq.config import load_experiment

        config = load_experiment(None)
    except Exception as exc:  # the simulated SmallSat is not available in this checkout
        print(f"SmallSat unavailable ({exc}); using the modal model", file=sys.stderr)
        return None
    exc_cfg = replace(config.excitation,
                      periods=config.excitation.transient_periods + steady_periods)
    t0 = time.perf_counter()
    record_experiment(replace(config, excitation=exc_cfg), path)
    return (f"simulated SmallSat ({config.name}: 39 displacement outputs, trilinear/bilinear "
            f"stops, {exc_cfg.transient_periods} transient + {steady_periods} steady periods; "
            f"simulated in {time.perf_counter() - t0:.0f} s)")


def replay_speeds(path: Path, orders, tmp: Path, repeat: int) -> dict:
    """Signal seconds per wall second of the replay stages."""
    from fnsi_lab.cli import main
    from fnsi_lab.replay.source import ReplaySource

    best_src = np.inf
    n_samples = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        with ReplaySource(path) as src:
            n_samples = sum(b.n_samples for b in src)
        best_src = min(best_src, time.perf_counter() - t0)
    seconds = n_samples / FS
    out = {"signal_s": seconds, "source": seconds / best_src}
    for label, extra in (("frf", ["--method", "frf"]),
                         ("auto", ["--orders", f"{orders[0]}:{orders[-1]}"])):
        best = np.inf
        for _ in range(repeat if label == "frf" else 1):
            t0 = time.perf_counter()
            code = main(["replay", str(path), "--quiet", "--rrd", str(tmp / f"{label}.rrd"),
                         "--force", *extra])   # the repeats replace their own file
            best = min(best, time.perf_counter() - t0)
            assert code == 0
        out[label] = seconds / best
    return out


def main_bench(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--periods", type=int, default=3, help="steady-state periods")
    ap.add_argument("--data", choices=("smallsat", "modal"), default="smallsat",
                    help="simulated SmallSat (default) or a linear 39-output modal model")
    ap.add_argument("--orders", default="2:30", help="order sweep FIRST:LAST")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--speed", type=float, default=1.0,
                    help="pacing of the latency run (1 = real time, the honest figure)")
    ap.add_argument("--results", action="store_true", help="append to bench/RESULTS.md")
    args = ap.parse_args(argv)
    from fnsi_lab.ident.robust.options import parse_orders

    orders = parse_orders(args.orders)
    from fnsi_lab.blas import limit_blas_threads

    blas = limit_blas_threads(1)  # as `fnsi-lab live/replay` do (--blas-threads 1)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        from fnsi_lab.daq.recording.reader import read_periodic
        from fnsi_lab.replay.identifiers import config_identifier
        from fnsi_lab.replay.source import ReplaySource

        path = tmp / "bench.mcap"
        source_note = None if args.data == "modal" else smallsat_recording(path, args.periods)
        if source_note is None:
            data, channels, meta = modal_data(args.periods + 1)
            with Recorder(path, channels, FS, metadata=meta) as rec:
                for b in ArraySource(data, channels, FS, block_size=100):
                    rec.write_block(b)
            source_note = (f"linear 39-output modal model (SmallSat shape), 1 transient + "
                           f"{args.periods} steady periods")
        with ReplaySource(path) as src:
            identify, what = config_identifier(None, truth=src.metadata.get("truth"),
                                               orders=orders, channels=src.channels)
        t0 = time.perf_counter()
        identify(read_periodic(path))
        t_ident = time.perf_counter() - t0
        period_s = N / FS
        speed = args.speed
        print(f"{what}; one identification alone (all periods): {t_ident:.2f} s; latency run "
              f"at {speed:g}x real time", file=sys.stderr)
        lat = latency(path, identify, speed, tmp / "live.rrd")
        speeds = replay_speeds(path, orders, tmp, args.repeat)
        size_mb = path.stat().st_size / 1e6
    lats = np.asarray(lat["latencies"])
    med, worst = float(np.median(lats)), float(lats.max())
    rows = [
        ("latency end of period -> Rerun update, median", f"{med:.2f} s",
         f"{med / 2.0:.2f} (goal 2 s)", f"{med / period_s:.2f} (must < 1)"),
        ("latency, worst", f"{worst:.2f} s", f"{worst / 2.0:.2f}", f"{worst / period_s:.2f}"),
        ("service + Rerun overhead (latency - identification), median",
         f"{float(np.median(lats - np.asarray(lat['ident_s'][:len(lats)]))):.3f} s", "", ""),
        ("identification time (ident.robust.auto), median in the live run",
         f"{np.median(lat['ident_s']):.2f} s", "", ""),
        ("identification alone, all periods", f"{t_ident:.2f} s", "", ""),
        ("replay: ReplaySource read", f"{speeds['source']:.0f}x real time",
         f"{speeds['source'] / 100:.1f} (goal 100x)", ""),
        ("replay: service + Rerun logging (--method frf)", f"{speeds['frf']:.0f}x real time",
         f"{speeds['frf'] / 100:.2f}", ""),
        ("replay: full robust pipeline (skips when behind)", f"{speeds['auto']:.1f}x real time",
         f"{speeds['auto'] / 100:.2f}", ""),
    ]
    print("| measurement | value | ratio to goal | ratio to period (8.19 s) |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    notes = [
        f"data: {source_note}; periods of {N} samples at {FS:g} Hz, 40 channels, "
        f"{speeds['signal_s']:.1f} s of signal, MCAP {size_mb:.1f} MB",
        f"orders {orders[0]}-{orders[-1]}; latency run paced at {speed:g}x real time; "
        f"{lat['updates']} updates, {lat['skipped']} skipped, {lat['dropped']} blocks dropped, "
        f"{lat['failures']} failures; selected order {lat['selected_order']}; OpenBLAS threads "
        f"limited to 1 (was {blas})",
        "per update: latency " + ", ".join(f"{x:.2f}" for x in lat["latencies"])
        + " s; identification " + ", ".join(f"{x:.2f}" for x in lat["ident_s"]) + " s",
        f"load average at start {load:.1f}, at end {os.getloadavg()[0]:.1f} (other jobs share "
        f"the 2 cores; identification times vary several-fold with their load)",
    ]
    for n in notes:
        print("- " + n)
    if args.results:
        res = Path(__file__).with_name("RESULTS.md")
        text = res.read_text() if res.exists() else "# Benchmark results\n"
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        block = [f"\n## Live and replay ({stamp})\n",
                 f"`python bench/bench_live.py --periods {args.periods} --orders {args.orders} "
                 f"--speed {args.speed:g} --data {args.data}` "
                 f"on {platform.machine()}, {os.cpu_count()} CPUs visible, Python "
                 f"{platform.python_version()}.\n",
                 "| measurement | value | ratio to goal | ratio to period (8.19 s) |",
                 "|---|---|---|---|"]
        block += ["| " + " | ".join(r) + " |" for r in rows]
        block += [""] + ["- " + n for n in notes]
        res.write_text(text.rstrip("\n") + "\n" + "\n".join(block) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main_bench())
