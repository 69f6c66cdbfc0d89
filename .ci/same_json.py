"""The result JSON of a few identifications, written before a change and compared after it
(issue 28: "to_json() writes the documented layout unchanged").

    python .ci/same_json.py write DIR          # the cases' JSON files into DIR
    python .ci/same_json.py compare DIR_A DIR_B  # exit 1 if a document differs

The cases cover every kind of answer ``Identification.to_json`` writes: a fixed order and the
robust pipeline on the 3-DOF chain with a cubic spring (1 % output noise), the linear chain
fitted with a cubic basis (the nested test keeps the linear fit's modes), the chain with a
stop whose gaps are left to the data and refined by the output error, a spline element
(its force curve and suggested config), the real Silverbox measurement
(bench/data/silverbox-schroeder: order 2 and the robust pipeline), and the simulated
SmallSat through the command line (``fnsi-lab acquire`` + ``fnsi-lab ident --config
smallsat39 --auto``). ``compare`` checks the same keys everywhere, equal strings and
booleans, and numbers to ``RTOL`` relative (same machine and code: the numbers should be
identical; the tolerance only forgives the last bits). Timings (``timings_s``) are left out.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

RTOL = 1e-9
SKIP = {"timings_s"}


def _chain_arrays(variant: str, noise: float, seed: int) -> dict:
    import numpy as np

    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim import lumped_model, simulate

    fs, n, periods = 1024.0, 4096, 6
    ms = multisine(n, fs, (3, 60), 5.0 if variant != "trilinear" else 20.0,
                   n_periods=periods + 1, seed=11)
    u = ms.signal[0][:, None]
    y = simulate(lumped_model(variant), u, fs, periodic=n,
                 quantities=("displacement",)).displacement
    y = y + noise * y.std(axis=0) * np.random.default_rng(50 + seed).standard_normal(y.shape)
    return {"u": u, "y": y, "fs": fs, "N": n, "channels": np.array(["X1", "X2", "X3"]),
            "input_channels": np.array(["F"])}


CUBIC = {"band_hz": [3, 120], "transient_periods": 1,
         "inputs": [{"name": "F", "driving_point": "X3"}],
         "nonlinearities": [{"name": "knl", "kind": "polynomial", "exponent": 3,
                             "channels": {"X2": 1, "X3": -1}}]}
STOP = {"band_hz": [3, 120], "transient_periods": 1,
        "inputs": [{"name": "F", "driving_point": "X3"}],
        "nonlinearities": [{"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
                            "clearances": "auto"}]}
SPLINE = {**CUBIC, "nonlinearities": [{"name": "knl", "kind": "spline", "knots": 6,
                                       "channels": {"X2": 1, "X3": -1}}]}


def write(folder: str) -> None:
    import fnsi_lab
    from fnsi_lab.outputs import json_safe

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    cases = {
        "chain_cubic_order6": (("cubic", 0.01, 0), CUBIC, {"order": 6}),
        "chain_cubic_auto": (("cubic", 0.01, 0), CUBIC, {"orders": "2:16"}),
        "chain_cubic_compare": (("cubic", 0.01, 1), {**CUBIC, "compare_linear": True},
                                {"order": 6}),
        "chain_linear_cubic_basis": (("none", 0.01, 0), CUBIC, {"order": 6}),
        "chain_linear_cubic_basis_auto": (("none", 0.01, 2), CUBIC, {"orders": "2:16"}),
        "chain_stop_gaps_auto": (("trilinear", 0.01, 0), STOP, {"order": 6}),
        "chain_cubic_spline": (("cubic", 0.01, 0), SPLINE, {"order": 6}),
    }
    for name, (args, cfg, kw) in cases.items():
        doc = fnsi_lab.identify(_chain_arrays(*args), cfg, **kw).to_json()
        (out / f"{name}.json").write_text(json.dumps(json_safe(doc)))
        print(name, "written", flush=True)
    root = Path(fnsi_lab.__file__).resolve().parents[1]   # the checkout under test
    silverbox = root / "bench" / "data" / "silverbox-schroeder"
    for name, kw in (("silverbox_order2", {"order": 2}), ("silverbox_auto", {})):
        doc = fnsi_lab.identify(str(silverbox / "schroeder.npz"),
                                str(silverbox / "schroeder.yaml"), **kw).to_json()
        (out / f"{name}.json").write_text(json.dumps(json_safe(doc)))
        print(name, "written", flush=True)
    rec = out / "smallsat.mcap"
    cli = [sys.executable, "-m", "fnsi_lab"]
    subprocess.run(cli + ["acquire", "--out", str(rec), "--force"], check=True,
                   stdout=subprocess.DEVNULL)
    subprocess.run(cli + ["ident", str(rec), "--config", "smallsat39", "--auto", "--json",
                          str(out / "smallsat39_auto.json"), "--force"], check=True,
                   stdout=subprocess.DEVNULL)
    rec.unlink()
    print("smallsat39_auto written")


def differences(a, b, path: str = "") -> list[str]:
    """Where two JSON documents differ (keys, types, values; numbers to RTOL)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}: key {k!r} only in the first" for k in a.keys() - b.keys()]
        out += [f"{path}: key {k!r} only in the second" for k in b.keys() - a.keys()]
        if list(a) != list(b) and not out:
            out.append(f"{path}: key order {list(a)} vs {list(b)}")
        for k in a.keys() & b.keys():
            if k not in SKIP:
                out += differences(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} vs {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    numbers = (int, float)
    if (isinstance(a, numbers) and isinstance(b, numbers)
            and not isinstance(a, bool) and not isinstance(b, bool)):
        if type(a) is not type(b):
            return [f"{path}: {type(a).__name__} {a} vs {type(b).__name__} {b}"]
        if a == b or (math.isnan(a) and math.isnan(b)):
            return []
        return [] if math.isclose(a, b, rel_tol=RTOL, abs_tol=0.0) else [f"{path}: {a} vs {b}"]
    return [] if a == b and type(a) is type(b) else [f"{path}: {a!r} vs {b!r}"]


def compare(first: str, second: str) -> int:
    names = sorted(p.name for p in Path(first).glob("*.json"))
    if not names:
        sys.exit(f"{first}: no JSON file (run 'write' first)")
    bad = 0
    for name in names:
        other = Path(second) / name
        if not other.exists():
            print(f"{name}: missing in {second}")
            bad += 1
            continue
        a, b = json.loads((Path(first) / name).read_text()), json.loads(other.read_text())
        for doc in (a, b):   # the recording's folder differs between the two runs
            doc["input"] = Path(doc.get("input") or "").name
        diff = differences(a, b)
        print(f"{name}: {'identical (timings and the recording folder aside)' if not diff else f'{len(diff)} differences'}")
        for d in diff[:20]:
            print("   ", d)
        bad += bool(diff)
    return 1 if bad else 0


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if len(sys.argv) == 3 and sys.argv[1] == "write":
        write(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)
