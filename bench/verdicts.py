"""Coefficient verdicts against a known answer: Monte Carlo over noise seeds (issue 29).

The 3-DOF chain of ``daq.sim.lumped`` (force on X3, element between X2 and X3), a full
multisine 3-60 Hz, 6 steady periods of 4096 samples at 1024 Hz, white output noise of
1 % of each channel's RMS, fixed order 6, no refinement. Per case and force level: how
often each verdict came out, the worst coefficient error, the ranges of ``rho``,
``std_real / |value|`` and ``log10 |Re/Im|``, and the worst ratio ``|error| / rho``. With
``--nested`` also the nonlinear-vs-linear test of every run (``nonlinear_vs_linear``).

Usage::

    python bench/verdicts.py [--seeds 8] [--nested]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections import defaultdict

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

import fnsi_lab  # noqa: E402
from fnsi_lab.daq.multisine import multisine  # noqa: E402
from fnsi_lab.daq.sim import lumped_model, simulate  # noqa: E402

FS, N, PERIODS = 1024.0, 4096, 6
BASE = {"band_hz": [3, 120], "transient_periods": 1, "refine": "none",
        "inputs": [{"name": "F", "driving_point": "X3"}]}
CUBIC = [{"name": "knl", "kind": "polynomial", "exponent": 3, "channels": {"X2": 1, "X3": -1}}]


def stop(clearances):
    return [{"name": "stop", "kind": "trilinear", "clearances": list(clearances),
             "channels": {"X2": 1, "X3": -1}}]


#: (label, simulated variant, force RMS N, basis, clearances, truths)
CASES = [(f"cubic {r:g} N", "cubic", r, CUBIC, (4e-4, 5e-4), (1e9,)) for r in (0.2, 0.5, 1, 2, 5)] \
    + [("linear, cubic basis", "none", 5.0, CUBIC, (4e-4, 5e-4), (0.0,))] \
    + [(f"stop {r:g} N", "trilinear", r, stop((4e-4, 5e-4)), (4e-4, 5e-4), (2e4, 1.5e4))
       for r in (1.5, 2.5, 5)] \
    + [("stop always in contact (2 um gaps)", "trilinear", 5.0, stop((2e-6, 2e-6)), (2e-6, 2e-6),
        (2e4, 1.5e4))]


def run(seeds: int, nested: bool) -> list[dict]:
    rows = []
    for label, variant, rms, basis, gaps, truths in CASES:
        ms = multisine(N, FS, (3, 60), rms, n_periods=PERIODS + 1, seed=1)
        u = ms.signal[0][:, None]
        y0 = simulate(lumped_model(variant, clearances=gaps), u, FS, periodic=N,
                      quantities=("displacement",)).displacement
        for seed in range(seeds):
            y = y0 + 0.01 * y0.std(axis=0) * np.random.default_rng(seed).standard_normal(y0.shape)
            arrays = {"u": u, "y": y, "fs": FS, "N": N, "channels": np.array(["X1", "X2", "X3"]),
                      "input_channels": np.array(["F"])}
            res = fnsi_lab.identify(arrays, {**BASE, "nonlinearities": basis,
                                             "compare_linear": True if nested else "auto"},
                                    order=6)
            doc = res.to_json()
            nvl = doc.get("nonlinear_vs_linear") or {}
            for c, t in zip(doc["coefficients"], truths):
                rows.append({"case": label, "seed": seed, "name": c["name"],
                             "verdict": c["verdict"], "spread": c["spread"],
                             "std_rel": c["relative_std"], "re_im": c["log10_re_im"],
                             "error": (c["value"] / t - 1) if t else None,
                             "decision": nvl.get("decision"), "p_value": nvl.get("p_value")})
    return rows


def table(rows: list[dict], nested: bool) -> str:
    groups: dict = defaultdict(list)
    for r in rows:
        groups[(r["case"], r["name"])].append(r)
    head = ("| case | coefficient | identified / weak / not identifiable | worst error | rho | "
            "std / value | log10 Re/Im | worst error / rho |")
    if nested:
        head += " nonlinear vs linear (nonlinear / linear) |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for (case, name), g in groups.items():
        n = [sum(r["verdict"] == v for r in g) for v in ("identified", "weak", "not identifiable")]
        errs = [abs(r["error"]) for r in g if r["error"] is not None]
        ratio = [abs(r["error"]) / r["spread"] for r in g if r["error"] is not None and r["spread"] > 0]
        rng = lambda k: f"{min(r[k] for r in g):.3g}-{max(r[k] for r in g):.3g}"  # noqa: E731
        row = (f"| {case} | {name} | {n[0]} / {n[1]} / {n[2]} | "
               f"{100 * max(errs):.3g} % | {rng('spread')} | {rng('std_rel')} | {rng('re_im')} | "
               f"{max(ratio):.2g} |" if errs else
               f"| {case} | {name} | {n[0]} / {n[1]} / {n[2]} | (truth 0) | {rng('spread')} | "
               f"{rng('std_rel')} | {rng('re_im')} | - |")
        if nested:
            row += (f" {sum(r['decision'] == 'nonlinear' for r in g)} / "
                    f"{sum(r['decision'] == 'linear' for r in g)} |")
        lines.append(row)
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--nested", action="store_true", help="also the nonlinear-vs-linear test")
    args = ap.parse_args(argv)
    t0 = time.time()
    rows = run(args.seeds, args.nested)
    print(f"{time.strftime('%Y-%m-%d %H:%M')}, {platform.node()}, {os.cpu_count()} cores, "
          f"{args.seeds} seeds, {time.time() - t0:.0f} s")
    print(table(rows, args.nested))
    return 0


if __name__ == "__main__":
    sys.exit(main())
