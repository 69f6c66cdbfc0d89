"""Report and viewer export on the SmallSat run: identification vs report time, every pole out.

    fnsi-lab run --out smallsat.mcap --rrd smallsat.rrd
    python bench/bench_report.py smallsat.mcap smallsat.rrd smallsat.html

Prints the identification time and the report rendering time measured in this one process
(their ratio is what to compare on a shared machine), the report size, and the number of
stabilisation poles exported from the ``.rrd`` (static ``AnyValues`` of the figure series)
against the poles of the same run's report (the run's identification JSON).
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path


def poles_in_rrd(path: str) -> int:
    """Poles of the stabilisation diagram exported from an .rrd (one ``order`` per pole)."""
    from rerun.chunk import RrdReader

    from fnsi_lab.viewer import paths

    last: dict[str, int] = {}
    for chunk in RrdReader(path).stream().collect().stream():
        if chunk.is_static and chunk.entity_path.startswith(paths.STABILISATION + "/"):
            batch = chunk.to_record_batch()
            if "order" in batch.schema.names:
                last[chunk.entity_path] = len(batch.column("order").to_pylist()[-1])
    return sum(last.values())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mcap")
    ap.add_argument("rrd")
    ap.add_argument("html", help="the report `fnsi-lab run` wrote next to the .rrd")
    ap.add_argument("--orders", default="2:60")
    args = ap.parse_args()

    from fnsi_lab.viewer.report import render_report
    from fnsi_lab.viewer.report_cli import load_report_input

    t0 = time.perf_counter()
    # the processed band of `fnsi-lab run` (5x the excited band): the same identification
    result, metadata = load_report_input(args.mcap, orders=args.orders, harmonics=5.0)
    t1 = time.perf_counter()
    page = render_report(result, metadata)
    t2 = time.perf_counter()
    print(f"identification {t1 - t0:.2f} s, report {t2 - t1:.2f} s "
          f"(ratio {(t2 - t1) / (t1 - t0):.2f}), report {len(page) / 1e6:.2f} MB")
    run_page = Path(args.html).read_text(encoding="utf-8")
    n_run = int(re.search(r"Stabilisation diagram \((\d+) poles\)", run_page).group(1))
    print(f"stabilisation poles of the run: {n_run} in its JSON/report, "
          f"{poles_in_rrd(args.rrd)} exported from {args.rrd}")


if __name__ == "__main__":
    main()
