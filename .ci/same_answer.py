"""Compare two printed answers of `fnsi-lab run` (issue 27): the same structure, values within
their standard deviations. Usage: python .ci/same_answer.py A.txt B.txt (exit 1 if not)."""

from __future__ import annotations

import re
import sys

STRUCTURE = ("selected order (IC)", "MDI order", "physical modes", "reduced order", "confidence")


def parse(path: str) -> tuple[dict, dict, list]:
    structure, values, table = {}, {}, []
    in_table = False
    for line in open(path, encoding="utf-8"):
        key = line[:26].strip()
        if key in STRUCTURE:
            structure[key] = line[26:].strip()
        m = re.match(r"(\S+, (?:full|reduced) model)\s+(\S+) ± (\S+)", line)
        if m:
            values[m.group(1)] = (float(m.group(2)), float(m.group(3)))
        if line.startswith("f (Hz)"):
            in_table = True
            continue
        if in_table:
            cols = line.split()
            if not cols:
                in_table = False
                continue
            # frequency to its printed precision's neighbourhood, and the verdict
            table.append((round(float(cols[0]), 1), cols[-1]))
    if not structure or not values or not table:
        sys.exit(f"{path}: no result table found (did the run fail?)")
    return structure, values, table


def main(a: str, b: str) -> int:
    (sa, va, ta), (sb, vb, tb) = parse(a), parse(b)
    problems = [f"{k}: {sa.get(k)} vs {sb.get(k)}" for k in STRUCTURE if sa.get(k) != sb.get(k)]
    if ta != tb:
        problems.append(f"modes differ: {ta} vs {tb}")
    for name, (x, sx) in va.items():
        y, sy = vb.get(name, (float("nan"), 0.0))
        if not abs(x - y) <= max(sx, sy):
            problems.append(f"{name}: {x} ± {sx} vs {y} ± {sy}")
    for p in problems:
        print(f"{a} vs {b}: {p}")
    print("same answer" if not problems else "DIFFERENT answers", f"({a}, {b})")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
