"""Time a test campaign: 20 SmallSat recordings identified serially and on 2 Dask workers.

Run::

    python bench/campaign.py                 # 20 recordings, --auto, serial vs 2 workers
    python bench/campaign.py --n 6 --orders 2:40   # a quicker look

Steps, each a real ``fnsi-lab`` command in a subprocess (what a user runs):

1. record the campaign once (``excitation.levels``: ``--n`` force levels of the packaged
   SmallSat experiment, 40..200 N RMS) into ``--work`` (kept between runs);
2. ``fnsi-lab batch DIR --config smallsat39 --auto --scheduler serial`` (one process, no
   Dask) -> wall time T1;
3. the same with ``--workers 2`` (a local cluster of 2 processes, one BLAS thread each),
   into a fresh results folder -> wall time T2 (cluster start-up included);
4. the same command again, nothing new -> wall time T3 (resume);
5. identity: every coefficient, order and mode count of step 3 equals step 2 bit for bit,
   and equals a one-by-one ``fnsi-lab ident --json`` of 3 of the inputs.

Writes ``bench/out/campaign.json``; the figures go to ``bench/RESULTS.md`` by hand (the
machine is shared, so ratios within one run are what counts).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(cmd: list[str]) -> tuple[float, int]:
    """Wall time and exit status of one command (output discarded, errors shown)."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return wall, proc.returncode


def record(work: Path, n: int) -> Path:
    """The campaign's recordings (made once; kept in ``work``)."""
    import numpy as np
    import yaml

    folder = work / f"smallsat-{n}"
    if folder.is_dir() and len(list(folder.glob("*.mcap"))) == n:
        return folder
    from fnsi_lab.daq.config import packaged_experiment

    exp = yaml.safe_load(packaged_experiment("smallsat.yaml").read_text())
    exp["name"] = "smallsat"
    exp["excitation"].pop("rms")
    exp["excitation"]["levels"] = [round(float(v), 3) for v in np.linspace(40, 200, n)]
    work.mkdir(parents=True, exist_ok=True)
    config = work / f"sweep-{n}.yaml"
    config.write_text(yaml.safe_dump(exp))
    wall, _ = run(["fnsi-lab", "acquire", "--config", str(config), "--out", str(folder),
                   "--quiet", "--force"])
    print(f"recorded {n} recordings in {wall:.1f} s -> {folder}")
    return folder


def table(path: Path) -> list[dict]:
    import pyarrow.parquet as pq

    return sorted(pq.read_table(path).to_pylist(), key=lambda r: r["file"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20, help="recordings (default 20)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--orders", default=None, help="order sweep (default: the config's)")
    parser.add_argument("--work", default="/tmp/fnsi-lab-bench-campaign",
                        help="recordings and results (kept between runs)")
    parser.add_argument("--out", default=str(ROOT / "bench" / "out" / "campaign.json"))
    args = parser.parse_args()

    work = Path(args.work)
    data = record(work, args.n)
    common = ["--config", "smallsat39", "--auto", "--quiet"] + \
             (["--orders", args.orders] if args.orders else [])
    for name in ("serial", "parallel"):
        shutil.rmtree(work / name, ignore_errors=True)
        (work / name).mkdir()
    serial_s, st1 = run(["fnsi-lab", "batch", str(data), *common, "--scheduler", "serial",
                         "--out", str(work / "serial" / "campaign.parquet")])
    parallel_cmd = ["fnsi-lab", "batch", str(data), *common, "--workers", str(args.workers),
                    "--out", str(work / "parallel" / "campaign.parquet")]
    parallel_s, st2 = run(parallel_cmd)
    serial, parallel = table(work / "serial" / "campaign.parquet"), \
        table(work / "parallel" / "campaign.parquet")
    resume_s, st3 = run(parallel_cmd)
    resumed = table(work / "parallel" / "campaign.parquet")
    ignore = {"worker", "wall_time_s", "result", "status"}
    identical = all({k: v for k, v in a.items() if k not in ignore}
                    == {k: v for k, v in b.items() if k not in ignore}
                    for a, b in zip(serial, parallel)) and len(serial) == len(parallel)
    # one by one with fnsi-lab ident on 3 inputs
    one_by_one = []
    for row in parallel[:: max(len(parallel) // 3, 1)][:3]:
        out = work / "parallel" / (Path(row["file"]).stem + ".ident.json")
        run(["fnsi-lab", "ident", row["file"], *common, "--json", str(out), "--force"])
        ref = json.loads(out.read_text())
        one_by_one.append(ref["order"] == row["order"] and all(
            row[c["name"]] == c["mean_real"] and row[c["name"] + ":std"] == c["std_real"]
            for c in ref["coefficients"]))
    workers = sorted({r["worker"] for r in parallel})
    result = {
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "machine": f"{os.cpu_count()} cores (shared)", "n_recordings": args.n,
        "workers": args.workers, "orders": args.orders or "config (2:60)",
        "serial_s": round(serial_s, 2), "parallel_s": round(parallel_s, 2),
        "speedup": round(serial_s / parallel_s, 2),
        "resume_s": round(resume_s, 2), "resume_fraction": round(resume_s / parallel_s, 3),
        "statuses": {"serial": sorted({r["status"] for r in serial}),
                     "parallel": sorted({r["status"] for r in parallel}),
                     "resumed": sorted({r["status"] for r in resumed})},
        "exit_codes": [st1, st2, st3], "workers_used": workers,
        "identical_serial_vs_parallel": identical,
        "identical_to_ident_one_by_one": all(one_by_one),
        "per_input_wall_s_median": sorted(r["wall_time_s"] for r in serial
                                          if r["wall_time_s"])[len(serial) // 2],
    }
    from fnsi_lab.outputs import write_json

    write_json(result, args.out)
    write_json(result, "-")


if __name__ == "__main__":
    main()
