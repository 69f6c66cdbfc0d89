"""Localisation and nonparametric characterisation (issue 30, points 2 and 3; docs/discovery.md).

Runs, through the public API (the same entry points as the CLI):

- ``fnsi_lab.locate`` on the simulated SmallSat (39 channels, 273 candidates) and on the
  aircraft-like GVT at several levels (3 accelerometers, 6 candidates): the rank of the true
  location, its verdict, the margin to the next candidate and the time;
- ``kind: spline`` on the SmallSat (12 and 24 knots): the clearances and contact stiffnesses
  read off the curve against the truth, then the suggested config run as is against the
  known-form answer;
- the whole discovery on the SmallSat, in one process and as the four CLI commands of
  docs/discovery.md's worked example.

Usage: ``python bench/locate_spline.py [--out DIR] [--quick]`` (``--quick``: 98 N only, 12
knots). Prints markdown tables for bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fnsi_lab
from fnsi_lab.blas import limit_blas_threads

GVT_CONFIG = {"band_hz": [2, 15], "transient_periods": 1, "output_quantity": "acceleration",
              "inputs": [{"name": "F-shaker", "driving_point": "drive"}],
              "nonlinearities": [], "max_order": 30}
SMALLSAT_GAPS, SMALLSAT_STIFF = (1.5, 1.3), (116.73, 88.41)


def _located_row(name: str, truth: dict, loc, seconds: float) -> str:
    names = [c.channels for c in loc.candidates]
    rank = names.index(truth) + 1 if truth in names else None
    best = loc.candidates[0]
    margin = loc.candidates[1].rss_ratio_to_best if len(loc.candidates) > 1 else float("nan")
    return (f"| {name} | {len(loc.candidates)} | {rank} | {best.name} | {best.verdict} | "
            f"{best.score:.3f} | {margin:.3f} | {seconds:.1f} |")


def bench_locate(folder: Path, levels) -> list[str]:
    rows = ["| record | candidates | rank of the truth | first | verdict | score | "
            "RSS next / first | time (s) |", "|---|---|---|---|---|---|---|---|"]
    ss = folder / "smallsat.mcap"
    if not ss.exists():
        fnsi_lab.acquire(out=ss)
    t = time.perf_counter()
    loc = fnsi_lab.locate(ss, "smallsat39")
    rows.append(_located_row("SmallSat 39 ch, 100 N", {"NC2W-Z": 1.0, "NC2B-Z": -1.0}, loc,
                             time.perf_counter() - t))
    for level in levels:
        path = folder / f"aircraft-{level}.mcap"
        if not path.exists():   # the CLI's --level: the measured force's RMS (docs/aircraft.md)
            subprocess.run([sys.executable, "-m", "fnsi_lab", "acquire", "--config", "aircraft",
                            "--level", str(level), "--out", str(path)], check=True,
                           capture_output=True)
        t = time.perf_counter()
        loc = fnsi_lab.locate(path, GVT_CONFIG)
        rows.append(_located_row(f"aircraft GVT {level} N", {"wing": 1.0, "payload": -1.0},
                                 loc, time.perf_counter() - t))
    return rows


def bench_spline(folder: Path, knots_list) -> list[str]:
    import yaml

    from fnsi_lab.ident.config import packaged_config

    ss = folder / "smallsat.mcap"
    known = {c["name"]: c["value"]
             for c in fnsi_lab.identify(ss, "smallsat39", order=22).coefficients}
    rows = ["| knots | clearances read (mm) | error % | stiffnesses read (N/mm) | error % | "
            "suggested config vs known form % | spline time (s) | suggested run (s) |",
            "|---|---|---|---|---|---|---|---|"]
    base = yaml.safe_load(packaged_config("smallsat39-spline").read_text())
    for knots in knots_list:
        cfg = dict(base)
        cfg["nonlinearities"] = [dict(base["nonlinearities"][0], knots=knots)]
        t = time.perf_counter()
        res = fnsi_lab.identify(ss, cfg, order=cfg["order"])    # the config's order, 22
        t_spline = time.perf_counter() - t
        s = res.spline_curves[0].suggestion
        gaps, stiff = np.asarray(s["clearances"]), np.asarray(s["values"])
        gerr = 100 * (gaps / SMALLSAT_GAPS - 1)
        kerr = 100 * (stiff / SMALLSAT_STIFF - 1)
        mapping, _ = res.suggested_config()
        t = time.perf_counter()
        sug = fnsi_lab.identify(ss, mapping, order=mapping["order"])
        t_sug = time.perf_counter() - t
        got = {c["name"]: c["value"] for c in sug.coefficients}
        serr = [100 * (got[n] / known[n] - 1) for n in ("NC2-Z:neg", "NC2-Z:pos")]
        rows.append(f"| {knots} | {gaps[0]:.4f} / {gaps[1]:.4f} | {gerr[0]:+.2f} / "
                    f"{gerr[1]:+.2f} | {stiff[0]:.2f} / {stiff[1]:.2f} | {kerr[0]:+.2f} / "
                    f"{kerr[1]:+.2f} | {serr[0]:+.4f} / {serr[1]:+.4f} | {t_spline:.1f} | "
                    f"{t_sug:.1f} |")
    return rows


def bench_chain(folder: Path) -> list[str]:
    """The whole discovery on the SmallSat: analyse, locate, spline, parametric (seconds)."""
    ss = folder / "smallsat.mcap"
    times = {}
    t = time.perf_counter()
    fnsi_lab.analyse(ss, config="smallsat39")
    times["analyse"] = time.perf_counter() - t
    t = time.perf_counter()
    where = fnsi_lab.locate(ss, "smallsat39")
    times["locate"] = time.perf_counter() - t
    t = time.perf_counter()
    shape = fnsi_lab.identify(ss, "smallsat39-spline", order=22)
    times["spline"] = time.perf_counter() - t
    mapping, _ = shape.suggested_config()
    t = time.perf_counter()
    fnsi_lab.identify(ss, mapping, order=22)
    times["parametric"] = time.perf_counter() - t
    total = sum(times.values())
    return ["| analyse | locate | spline (12 knots) | parametric (searched gaps) | total | located |",
            "|---|---|---|---|---|---|",
            "| " + " | ".join(f"{v:.1f}" for v in times.values()) + f" | {total:.1f} | "
            f"{where.located.name if where.located else '-'} |"]


def bench_cli_chain(folder: Path, runs: int = 3) -> list[str]:
    """The worked example of docs/discovery.md as a user runs it: four ``fnsi-lab``
    commands, each a process with its start-up, MCAP read and result file (seconds)."""
    ss, cli = folder / "smallsat.mcap", [sys.executable, "-m", "fnsi_lab"]
    sugg = folder / "chain-nc2.yaml"
    steps = [("analyse", ["analyse", ss, "--config", "smallsat39"]),
             ("locate", ["locate", ss, "--config", "smallsat39"]),
             ("spline", ["ident", ss, "--config", "smallsat39-spline", "--order", "22",
                         "--suggest", sugg, "--force"]),
             ("parametric", ["ident", ss, "--config", sugg, "--order", "22"])]
    rows = ["| run | analyse | locate | spline (12 knots) | parametric (searched gaps) | total |",
            "|---|---|---|---|---|---|"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    for run in range(runs):
        times = []
        for name, args in steps:
            t = time.perf_counter()
            r = subprocess.run(cli + [str(a) for a in args], capture_output=True, text=True,
                               env=env)
            times.append(time.perf_counter() - t)
            if r.returncode != 0:
                raise SystemExit(f"fnsi-lab {name} failed: {r.stderr.strip()}")
        rows.append(f"| {run + 1} | " + " | ".join(f"{v:.2f}" for v in times)
                    + f" | {sum(times):.2f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="folder for the recordings (default: temporary)")
    ap.add_argument("--quick", action="store_true", help="98 N only, 12 knots")
    args = ap.parse_args()
    limit_blas_threads(1)
    folder = Path(args.out or tempfile.mkdtemp(prefix="locate-bench-"))
    folder.mkdir(parents=True, exist_ok=True)
    levels = (98,) if args.quick else (12, 40, 69, 98)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores\n")
    print("\n".join(bench_locate(folder, levels)))
    print()
    print("\n".join(bench_spline(folder, (12,) if args.quick else (12, 24))))
    print()
    print("\n".join(bench_chain(folder)))
    print()
    print("\n".join(bench_cli_chain(folder)))


if __name__ == "__main__":
    main()
