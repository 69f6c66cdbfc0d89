"""Run fnsi-lab's documented workflow on bench/independent_beam.py's records, as a user would.

Only the CLI (subprocess), the documented configs and the result JSON are used::

    python bench/independent_beam.py --out beam                 # the records (seed 0)
    python bench/independent_beam.py --out beam/v --seed 100    # other phases: the third records
    python bench/independent_beam_judge.py --dir beam           # -> beam/judge.json, a table

Per level and config: ``fnsi-lab ident LEVEL --config CFG --auto --validation BELOW
--validation ABOVE --json``, then ``fnsi-lab validate RESULT THIRD --json`` on the same
level's record of other phases (``DIR/v``: no decision read it), next to the linear fit's
``validate`` on the same record. Also ``analyse`` over the levels and ``locate`` per level.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

JOINT = "{jointL: 1, jointR: -1}"
COMMON = """\
band_hz: [3, 140]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {name: F-drive, driving_point: drive}
"""
CONFIGS = {
    "linear": "nonlinearities: []\n",
    "cubic": f"nonlinearities:\n  - {{name: joint-cubic, kind: polynomial, exponent: 3, channels: {JOINT}}}\n",
    "coulomb-cubic": (f"nonlinearities:\n  - {{name: joint-friction, kind: coulomb, channels: {JOINT}, "
                      f"velocity_scale: 1.0e-3}}\n  - {{name: joint-cubic, kind: polynomial, exponent: 3, "
                      f"channels: {JOINT}}}\n"),
    "jenkins": f"nonlinearities:\n  - {{name: joint, kind: jenkins, channels: {JOINT}, slip: auto}}\n",
    "jenkins-stop": (f"nonlinearities:\n  - {{name: joint, kind: jenkins, channels: {JOINT}, slip: auto}}\n"
                     f"  - {{name: gap, kind: trilinear, channels: {JOINT}, clearances: auto}}\n"),
    "spline": f"nonlinearities:\n  - {{name: joint, kind: spline, channels: {JOINT}, knots: 8}}\n",
}


def run(cmd: list[str], log: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    with open(log, "w") as fh:
        rc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env).returncode
    return rc, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dir", type=Path, required=True)
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS))
    parser.add_argument("--fnsi-lab", default=str(Path(sys.executable).with_name("fnsi-lab")))
    args = parser.parse_args(argv)
    d = args.dir
    out = d / "judge"
    out.mkdir(exist_ok=True)
    for name, text in CONFIGS.items():
        (out / f"{name}.yaml").write_text(COMMON + text)
    levels = sorted(d.glob("beam-rms*.npz"), key=lambda p: float(p.stem[len("beam-rms"):]))
    table = {"runs": []}
    for i, rec in enumerate(levels):
        neighbours = [levels[j] for j in (i - 1, i + 1) if 0 <= j < len(levels)]
        third = d / "v" / rec.name
        for name in args.configs:
            stem = f"{rec.stem}-{name}"
            cmd = [args.fnsi_lab, "ident", str(rec), "--config", str(out / f"{name}.yaml"), "--auto",
                   "--json", str(out / f"{stem}.json"), "--force"]
            for n in neighbours:
                cmd += ["--validation", str(n)]
            rc, seconds = run(cmd, out / f"{stem}.log")
            entry = {"level": rec.name, "config": name, "rc": rc, "seconds": round(seconds, 1)}
            if rc == 0 and third.exists():
                vrc, vs = run([args.fnsi_lab, "validate", str(out / f"{stem}.json"), str(third),
                               "--json", str(out / f"{stem}.val.json"), "--force"], out / f"{stem}.val.log")
                entry.update(validate_rc=vrc, validate_seconds=round(vs, 1))
            table["runs"].append(entry)
            print(json.dumps(entry), flush=True)
    (out / "runs.json").write_text(json.dumps(table, indent=1))
    return 0


def _modes(result: dict) -> list[float]:
    return sorted(m["frequency_hz"] for m in result.get("modes") or [])


def _worst_shift_percent(modes: list[float], reference: list[float]) -> tuple[float, int]:
    """Largest |shift| (%) of each reference mode to the nearest answer mode; count of lost (> 5 %)."""
    worst, lost = 0.0, 0
    for f in reference:
        if not modes:
            lost += 1
            continue
        shift = min(abs(m - f) / f * 100 for m in modes)
        if shift > 5:
            lost += 1
        else:
            worst = max(worst, shift)
    return worst, lost


def summary(d: Path) -> str:
    """The judgement table (markdown) from DIR/judge/*.json."""
    out = d / "judge"
    runs = json.loads((out / "runs.json").read_text())["runs"] if (out / "runs.json").exists() else []
    rows = ["| level | config | s | answer | order | coefficients (value, rel. std, verdict) | modes vs linear fit: worst shift %, lost | validation dB (drive/jointL/jointR/far) | vs linear fit dB |",
            "|---|---|---|---|---|---|---|---|---|"]
    defects = []
    for entry in runs:
        stem = f"{Path(entry['level']).stem}-{entry['config']}"
        if entry["rc"] != 0:
            rows.append(f"| {entry['level']} | {entry['config']} | {entry['seconds']} | **exit {entry['rc']}** | | | | | |")
            continue
        result = json.loads((out / f"{stem}.json").read_text())
        linear = json.loads((out / f"{Path(entry['level']).stem}-linear.json").read_text())
        nvl = result.get("nonlinear_vs_linear") or {}
        answer = "linear fit" if nvl.get("decision") == "linear" else ("nonlinear" if result.get("coefficients") else "-")
        coefs = []
        for c in result.get("coefficients") or []:
            rel = c.get("relative_std")
            coefs.append(f"{c['name']} {c['value']:.3g} ({rel:.2f}, {c.get('verdict')})" if rel is not None
                         else f"{c['name']} {c['value']:.3g} ({c.get('verdict')})")
            if c.get("verdict") == "identified" and rel is not None and rel > 0.5:
                defects.append(f"{stem}: {c['name']} identified with relative std {rel:.2f}")
        if len(coefs) > 3:   # a spline: its knots in one cell
            rels = [c["relative_std"] for c in result["coefficients"] if c.get("relative_std") is not None]
            verdicts = sorted({c.get("verdict") for c in result["coefficients"]})
            coefs = [f"{len(coefs)} knots, rel. std {min(rels):.1f}-{max(rels):.1f}, {' / '.join(verdicts)}"]
        worst, lost = _worst_shift_percent(_modes(result), _modes(linear))
        val, ref = out / f"{stem}.val.json", out / f"{Path(entry['level']).stem}-linear.val.json"
        dbs = delta = ""
        if val.exists() and ref.exists():
            v, r = json.loads(val.read_text()), json.loads(ref.read_text())
            # a linear result has no nonlinear error: its linear model's is the answer's
            e = [o["error_db"] if o["error_db"] is not None else o["linear_error_db"] for o in v["outputs"]]
            el = [o["error_db"] if o["error_db"] is not None else o["linear_error_db"] for o in r["outputs"]]
            dbs = " / ".join(f"{x:.1f}" for x in e)
            delta = " / ".join(f"{a - b:+.1f}" for a, b in zip(e, el))
            if max(a - b for a, b in zip(e, el)) > 0.5:
                defects.append(f"{stem}: validation worse than the linear fit by {max(a - b for a, b in zip(e, el)):.1f} dB")
        rows.append(f"| {entry['level'][len('beam-rms'):-4]} N | {entry['config']} | {entry['seconds']} | {answer} | "
                    f"{result.get('order')} | {'; '.join(coefs)} | {worst:.2f}, {lost} | {dbs} | {delta} |")
    return "\n".join(rows) + "\n\n" + "\n".join(f"- {x}" for x in defects)


if __name__ == "__main__" and "--summary" in sys.argv:
    print(summary(Path(sys.argv[sys.argv.index("--summary") + 1])))
elif __name__ == "__main__":
    sys.exit(main())
