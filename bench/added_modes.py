"""The modes a kept nonlinear answer adds to the linear fit's: what tells the real ones from the
spurious ones (issue 29: "adding a basis function must never ... invent" a mode).

For each record and config (a simulated record whose truth lists the modes of the structure
with the joint slipping, the underlying linear model of a Jenkins element, and stuck:
bench/aircraft.py, bench/independent_beam.py, bench/independent_joint.py), the
answer of ``fnsi_lab.identify`` (robust pipeline, no validation record) and per mode of the
nonlinear model's physical classification (those left out for lack of evidence included):

- ``lin``: paired with a linear-fit mode within 5 % (``kept``) or not (``added``);
- ``zeta``, ``MDI``, stabilisation class, ``detection`` (sigmas above the model's residual
  in its bandwidth: ``ident.robust.mdi.modal_detection``);
- ``dp``: the phase of its modal mass at the driving point, ``el``: at the element's own pair
  (with the coefficient's sign; ``-`` where the element shifts the mode by less than a line),
  degrees, 0 for a real normal mode, beyond +-90 for a negative modal mass; ``shift``: how
  far the element's stiffness moves the mode, in lines ``fs / N``
  (``ident.robust.mode_support``);
- ``truth``: the nearest mode of the structure with the joint slipping (and stuck), error %.

Run (about 15-40 s per record; one record at a time)::

    python bench/added_modes.py beam/beam-rms1.npz beam/judge/jenkins.yaml \\
        gvt/stat-rms55.mcap gvt/aircraft-jenkins.yaml

Records come in pairs ``RECORD CONFIG``; ``--json OUT`` writes the rows. The tables go to
bench/RESULTS_beam.md ("Defect 11: the modes a kept nonlinear answer adds") by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _truth(record: Path) -> dict:
    """The record's truth: a sibling ``.truth.json`` (bench/independent_beam.py) or the
    recording's own (bench/aircraft.py)."""
    side = record.with_suffix(".truth.json")
    if side.is_file():
        return json.loads(side.read_text())
    import fnsi_lab

    with fnsi_lab.open_recording(record) as rec:
        return dict(getattr(rec, "truth", None) or {})


def _nearest(f: float, truth_hz) -> tuple[float | None, float | None]:
    truth_hz = [t for t in truth_hz or [] if t > 0]
    if not truth_hz:
        return None, None
    t = min(truth_hz, key=lambda x: abs(x - f))
    return float(t), 100.0 * (f / t - 1.0)


def mode_rows(record: Path, config: Path) -> tuple[list[dict], str]:
    """Per physical mode of the nonlinear model: the features above; and the statement."""
    import fnsi_lab
    from fnsi_lab.ident.fit import Fit, answer_modes

    res = fnsi_lab.identify(str(record), config=str(config))
    nested = res.nested
    if nested is None or not nested.supported:
        return [], (nested.statement if nested is not None else "no nested test")
    fit = Fit(res.model, res.method, res.auto, res.decomposition)
    modes = answer_modes(fit, res.output_error)      # before the evidence: every one
    # the pipeline's own test of every mode (ident.robust.mode_support, via the nested test)
    tested = {round(float(r["frequency_hz"]), 6): r for r in nested.mode_evidence}
    evidence = [tested.get(round(m.frequency_hz, 6)) or {
        "driving_point_phase_deg": {}, "element_phase_deg": {}, "element_participation": {},
        "element_shift_hz": {}, "overlaps_hz": [], "supported": True} for m in modes]
    mdi = {round(r["frequency_hz"], 6): r for r in (res.auto.mdi_table() if res.auto else [])}
    truth = _truth(record)
    def hz(key):   # a list of Hz or of {frequency_hz, ...} (bench/independent_joint.py)
        return [m["frequency_hz"] if isinstance(m, dict) else m for m in truth.get(key) or []]

    slipping = hz("modes_joint_slipping_hz") or hz("modes_joint_free")
    stuck = hz("modes_joint_stuck_hz") or hz("modes_joint_stuck") or hz("modes")
    added = {round(f, 6) for f in nested.modes.get("added") or []}
    left = {round(f, 6) for f in nested.left_out_hz}
    rows = []
    for m, ev in zip(modes, evidence):
        key = round(m.frequency_hz, 6)
        row = mdi.get(key) or min(mdi.values(), default={},
                                  key=lambda r: abs(r["frequency_hz"] - m.frequency_hz))
        t_slip, e_slip = _nearest(m.frequency_hz, slipping)
        t_stuck, e_stuck = _nearest(m.frequency_hz, stuck)
        rows.append({
            "record": record.name, "frequency_hz": m.frequency_hz,
            "damping_ratio": m.damping_ratio,
            "linear_fit": "left out" if key in left else "added" if key in added else "kept",
            "mdi": row.get("mdi_h2"), "stabilisation": row.get("stabilisation"),
            "detection": row.get("detection"),
            "driving_point_phase_deg": next(iter(ev["driving_point_phase_deg"].values()), None),
            "element_phase_deg": next(iter(ev["element_phase_deg"].values()), None),
            "element_participation": next(iter(ev["element_participation"].values()), None),
            "element_shift_lines": (max(ev["element_shift_hz"].values())
                                    * res.data.samples_per_period / res.session.input.sample_rate_hz
                                    if ev["element_shift_hz"] else None),
            "overlaps_hz": ev.get("overlaps_hz") or [],
            "driving_point_detection": next(iter((ev.get("driving_point_detection")
                                                  or {}).values()), None),
            "passive": ev["supported"],
            "truth_slipping_hz": t_slip, "error_slipping_percent": e_slip,
            "truth_stuck_hz": t_stuck, "error_stuck_percent": e_stuck})
    return rows, nested.statement


def _fmt(x, spec: str, missing: str = "-") -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return missing
    return format(x, spec)


def _untested(r: dict) -> str:
    """Why a pair was not tested: an overlapping half-power band, or a driving point where
    the mode does not stand out of the residual (sigmas)."""
    if r["overlaps_hz"]:
        return "overlaps " + ", ".join(f"{f:.2f}" for f in r["overlaps_hz"])
    d = r.get("driving_point_detection")
    return f"dp at {d:.1f} sigma" if d is not None and r["driving_point_phase_deg"] is None \
        else ""


def print_table(rows: list[dict]) -> None:
    print("| f (Hz) | zeta % | vs linear fit | MDI | stab. | detection | dp (deg) | el (deg) "
          "| shift (lines) | not tested | passive | truth slipping (err %) | truth stuck (err %) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['frequency_hz']:.3f} | {100 * r['damping_ratio']:.2f} | {r['linear_fit']} "
              f"| {_fmt(r['mdi'], '.3g')} | {r['stabilisation'] or '-'} "
              f"| {_fmt(r['detection'], '.3g')} | {_fmt(r['driving_point_phase_deg'], '+.0f')} "
              f"| {_fmt(r['element_phase_deg'], '+.0f')} | {_fmt(r['element_shift_lines'], '.2g')} "
              f"| {_untested(r)} | {'yes' if r['passive'] else 'no'} "
              f"| {_fmt(r['truth_slipping_hz'], '.3f')} "
              f"({_fmt(r['error_slipping_percent'], '+.1f')}) "
              f"| {_fmt(r['truth_stuck_hz'], '.3f')} ({_fmt(r['error_stuck_percent'], '+.1f')}) |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pairs", nargs="+", metavar="RECORD CONFIG",
                        help="a record and its ident config, as many pairs as wanted")
    parser.add_argument("--json", type=Path, help="write every row here")
    args = parser.parse_args(argv)
    if len(args.pairs) % 2:
        parser.error("give RECORD CONFIG pairs")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    every = []
    for record, config in zip(args.pairs[::2], args.pairs[1::2]):
        t0 = time.perf_counter()
        rows, statement = mode_rows(Path(record), Path(config))
        took = time.perf_counter() - t0
        print(f"\n### {Path(record).name} ({Path(config).name}, {took:.0f} s)\n")
        print(statement + "\n")
        if rows:
            print_table(rows)
        every += rows
    if args.json:
        args.json.write_text(json.dumps(every, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
