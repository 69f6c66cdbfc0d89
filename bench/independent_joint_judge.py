"""Judge the documented CLI on the independent joint campaign (bench/independent_joint.py).

Runs, as an outside user would (subprocesses of ``fnsi-lab``), for every level ``L``:

- ``ident L --config indep-linear.yaml --auto``: the linear fit's modes against the truth;
- for each nonlinear config (Jenkins ``slip: auto``, cubic, Coulomb on the joint's relative
  motion): ``ident L --config C --auto --validation NEXT`` (the decision reads ``NEXT``: the
  next level up, or down with ``--direction down``), then ``validate RESULT THIRD`` on a
  record neither the fit nor the decision read;
- with ``--matrix``: every kept answer validated on every level's record (the answer minus
  the linear fit, dB per output: negative is better).

and prints a markdown table: decision, order, modes matched to the truth (joint stuck and
joint free), coefficient verdicts, and the validation error (dB below the output) of the
answer against the linear fit on THIRD, per output.

Run::

    python bench/independent_joint.py --out indep
    python bench/independent_joint_judge.py --dir indep [--configs jenkins cubic coulomb]
    python bench/independent_joint_judge.py --dir indep --configs jenkins --direction down --matrix
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

CONFIGS = ("jenkins", "cubic", "coulomb")


def _cli() -> list[str]:
    """The fnsi-lab command of this interpreter's environment."""
    exe = Path(sys.executable).with_name("fnsi-lab")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "fnsi_lab"]


def run(args: list[str], cwd: Path) -> tuple[int, str, float]:
    """Run ``fnsi-lab ARGS`` in ``cwd``; exit status, stderr+stdout, seconds."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    p = subprocess.run(_cli() + args, cwd=cwd, env=env, capture_output=True, text=True)
    return p.returncode, p.stdout + p.stderr, time.perf_counter() - t0


def match_modes(found: list[dict], truth: list[dict], band: tuple[float, float]) -> dict:
    """Each true mode in the band matched to the nearest found one (relative error)."""
    rows = []
    used = set()
    for t in truth:
        if not band[0] <= t["frequency_hz"] <= band[1]:
            continue
        best = min(((abs(m["frequency_hz"] / t["frequency_hz"] - 1), i)
                    for i, m in enumerate(found) if i not in used), default=(None, None))
        if best[1] is not None and best[0] < 0.05:
            used.add(best[1])
            rows.append(best[0])
        else:
            rows.append(None)
    extra = [round(m["frequency_hz"], 2) for i, m in enumerate(found) if i not in used
             and band[0] <= m["frequency_hz"] <= band[1]]
    return {"errors": rows, "extra_hz": extra}


def _fmt_match(m: dict) -> str:
    err = ["-" if e is None else f"{100 * e:.1f}" for e in m["errors"]]
    s = "/".join(err) + " %"
    if m["extra_hz"]:
        s += f" +{m['extra_hz']}"
    return s


def level_files(folder: Path) -> list[tuple[float, Path]]:
    files = sorted(folder.glob("indep-rms*.npz"), key=lambda p: float(p.stem[9:]))
    return [(float(p.stem[9:]), p) for p in files]


def neighbours(i: int, n: int, direction: str) -> tuple[int, int]:
    """Indices of the decision's record (the next level up or down; at the end of the
    campaign the other way) and of a third record, read by neither fit nor decision."""
    step = 1 if direction == "up" else -1
    nxt = i + step if 0 <= i + step < n else i - step
    third = i - step if 0 <= i - step < n and i - step != nxt else nxt + (nxt - i)
    return nxt, third


def judge(folder: Path, configs: tuple[str, ...], direction: str = "up") -> list[dict]:
    levels = level_files(folder)
    rows = []
    for i, (level, path) in enumerate(levels):
        inxt, ithird = neighbours(i, len(levels), direction)
        nxt, third = levels[inxt][1], levels[ithird][1]
        tr = json.loads(path.with_suffix(".truth.json").read_text())
        band = tuple(tr["band_hz"])
        code, out, sec = run(["ident", path.name, "--config", "indep-linear.yaml", "--auto",
                              "--json", f"lin-{level:g}.json", "--force", "--quiet"], folder)
        row = {"level": level, "regime": tr["run"]["regime"], "file": path.name,
               "linear": {"exit": code, "seconds": round(sec, 1)}}
        if code == 0:
            r = json.loads((folder / f"lin-{level:g}.json").read_text())
            row["linear"].update(order=r["order"], modes=[m["frequency_hz"] for m in r["modes"]],
                                 stuck=match_modes(r["modes"], tr["modes_joint_stuck"], band),
                                 free=match_modes(r["modes"], tr["modes_joint_free"], band))
        else:
            row["linear"]["error"] = out.strip().splitlines()[-1:]
        for cfg in configs:
            res = f"{cfg}-{level:g}.json"
            code, out, sec = run(["ident", path.name, "--config", f"indep-{cfg}.yaml", "--auto",
                                  "--validation", nxt.name, "--json", res, "--force", "--quiet"],
                                 folder)
            entry = {"exit": code, "seconds": round(sec, 1), "validation_record": nxt.name,
                     "third_record": third.name}
            if code != 0:
                entry["error"] = out.strip().splitlines()[-3:]
                row[cfg] = entry
                continue
            r = json.loads((folder / res).read_text())
            nvl = r.get("nonlinear_vs_linear") or {}
            entry.update(decision=nvl.get("decision"), order=r["order"],
                         statement=nvl.get("statement"),
                         coefficients=[{k: c.get(k) for k in ("name", "value", "verdict",
                                                               "relative_std")}
                                       for c in r.get("coefficients", [])],
                         slip=[e.get("slip") for e in r.get("nonlinearities", [])
                               if isinstance(e, dict)],
                         stuck=match_modes(r["modes"], tr["modes_joint_stuck"], band),
                         free=match_modes(r["modes"], tr["modes_joint_free"], band))
            vjson = f"val-{cfg}-{level:g}.json"
            code, out, sec = run(["validate", res, third.name, "--json", vjson, "--force"],
                                 folder)
            entry["validate_exit"] = code
            if (folder / vjson).exists() and code in (0, 1):
                v = json.loads((folder / vjson).read_text())
                entry["validation"] = [
                    {"name": o["name"], "answer_db": o.get("error_db"),
                     "linear_fit_db": o.get("linear_fit_error_db", o.get("linear_error_db"))}
                    for o in v["outputs"]]
            else:
                entry["validate_error"] = out.strip().splitlines()[-3:]
            row[cfg] = entry
        rows.append(row)
        print(f"level {level:g} N done", file=sys.stderr)
    return rows


def matrix(folder: Path, rows: list[dict], config: str) -> list[str]:
    """Every nonlinear answer of ``config`` validated on every level: answer - linear fit (dB)."""
    levels = level_files(folder)
    lines = ["| answer of | " + " | ".join(f"on {lv:g} N" for lv, _ in levels) + " |",
             "|---|" + "---|" * len(levels)]
    for r in rows:
        e = r.get(config, {})
        if e.get("decision") != "nonlinear":
            continue
        cells = []
        for lv, p in levels:
            out = f"x-{config}-{r['level']:g}-on-{lv:g}.json"
            code, _, _ = run(["validate", f"{config}-{r['level']:g}.json", p.name, "--json", out,
                              "--force", "--quiet"], folder)
            if code not in (0, 1) or not (folder / out).exists():
                cells.append(f"exit {code}")
                continue
            v = json.loads((folder / out).read_text())
            diff = []
            for o in v["outputs"]:
                ref = o.get("linear_fit_error_db")
                ref = o["linear_error_db"] if ref is None else ref
                diff.append("none" if o["error_db"] is None else f"{o['error_db'] - ref:+.1f}")
            cells.append(" / ".join(diff))
        lines.append(f"| {r['level']:g} N (checked on {e['validation_record'][9:-4]} N) | "
                     + " | ".join(cells) + " |")
    return lines


def markdown(rows: list[dict], configs: tuple[str, ...]) -> str:
    out = ["| level (N) | regime | linear --auto: order, modes vs stuck truth (%) | "
           + " | ".join(f"{c}: decision, order, verdicts, modes vs stuck / free | {c}: "
                        f"validation on THIRD, answer vs linear fit (dB)" for c in configs) + " |",
           "|" + "---|" * (3 + 2 * len(configs))]
    for r in rows:
        lin = r["linear"]
        cells = [f"{r['level']:g}", r["regime"],
                 f"{lin.get('order')}: {_fmt_match(lin['stuck'])}" if "stuck" in lin
                 else f"exit {lin['exit']}"]
        for c in configs:
            e = r[c]
            if "decision" not in e:
                cells += [f"exit {e['exit']}: {' '.join(e.get('error', []))[:120]}", ""]
                continue
            verd = ", ".join(f"{x['verdict']}" for x in e["coefficients"]) or "none"
            cells.append(f"{e['decision']}, {e['order']}, [{verd}], "
                         f"{_fmt_match(e['stuck'])} / {_fmt_match(e['free'])}")
            if "validation" in e:
                v = e["validation"]
                cells.append(f"{e['third_record'][9:-4]} N: "
                             + " / ".join(f"{o['answer_db']:.1f}" if o["answer_db"] is not None
                                          else "none" for o in v) + " vs "
                             + " / ".join(f"{o['linear_fit_db']:.1f}"
                                          if o["linear_fit_db"] is not None else "-" for o in v))
            else:
                cells.append(f"validate exit {e['validate_exit']}")
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python bench/independent_joint_judge.py --dir indep")
    p.add_argument("--dir", type=Path, required=True, help="folder of bench/independent_joint.py")
    p.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=CONFIGS)
    p.add_argument("--direction", choices=("up", "down"), default="up",
                   help="--validation on the next level up (default) or down")
    p.add_argument("--matrix", action="store_true",
                   help="validate every nonlinear answer on every level's record too")
    p.add_argument("--json", type=Path, help="write the rows here")
    args = p.parse_args(argv)
    rows = judge(args.dir, tuple(args.configs), args.direction)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print(markdown(rows, tuple(args.configs)))
    if args.matrix:
        for cfg in args.configs:
            print(f"\n{cfg}: answer minus linear fit (dB, drive / bracket / box) on every record")
            print("\n".join(matrix(args.dir, rows, cfg)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
