"""Write the aircraft-like GVT campaign: 7 level recordings + ident configs in one folder.

Run::

    python bench/aircraft.py --out aircraft-gvt            # 12, 26, 40, 55, 69, 84, 98 N RMS
    python bench/aircraft.py --out gvt --levels 12 98 --force

Each level is the packaged experiment ``daq/data/aircraft.yaml`` (source kind ``aircraft``,
``docs/aircraft.md``) at that measured-force RMS, recorded by the same entry point as
``fnsi-lab acquire`` (:func:`fnsi_lab.acquire`) to ``aircraft-rms<level>.mcap`` with its
truth. Like the real test, every level is its own multisine realisation (phase seed = level
index; ``--same-phases`` keeps one seed). The folder also gets:

- ``aircraft-joint.yaml``: ident config with the joint's relative motion
  ``channels: {wing: 1, payload: -1}`` (Coulomb friction ``tanh(delta'/v0)`` + cubic spring);
- ``aircraft-jenkins.yaml``: the joint as a Jenkins element (hysteretic friction, a spring in
  series with a slider) with ``slip: auto`` (docs/discovery.md, bolted joints);
- ``aircraft-jenkins-stop.yaml``: the Jenkins element and a two-sided stop (the joint's
  clearance), ``slip: auto`` and ``clearances: auto``;
- ``aircraft-linear.yaml``: the same without nonlinear elements;
- ``levels.json``: per level the file, commanded/measured force RMS, joint slip, friction
  energy, contact fraction and period-to-period differences (the truth's ``run``).

About 1-2 s per level on one core.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

#: What every config of the campaign shares: the band, the drive, the outputs' quantity.
_COMMON = """\
band_hz: [2, 15]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {name: F-shaker, driving_point: drive}
"""


def _config(comment: str, nonlinearities: str) -> str:
    """An ident config of the campaign: a comment, the common part, the elements."""
    return f"{comment}{_COMMON}{nonlinearities}max_order: 30\n"


IDENT_JOINT = _config("""\
# Aircraft-like GVT (daq.sim.aircraft): the bolted wing-to-payload joint.
# Accelerations (m/s^2), measured force (N); relative motion wing - payload.
""", """\
nonlinearities:
  - name: joint-friction
    kind: coulomb
    channels: {wing: 1, payload: -1}
    velocity_scale: 1.0e-3      # m/s
  - name: joint-cubic
    kind: polynomial
    exponent: 3
    channels: {wing: 1, payload: -1}
""")

IDENT_JENKINS = _config("""\
# Aircraft-like GVT (daq.sim.aircraft): the bolted wing-to-payload joint as hysteretic
# friction (a spring in series with a slider; the slip displacement from the data).
""", """\
nonlinearities:
  - name: joint
    kind: jenkins
    channels: {wing: 1, payload: -1}
    slip: auto                  # m (F_s / k), by the information criterion
""")

IDENT_JENKINS_STOP = _config("""\
# Aircraft-like GVT (daq.sim.aircraft): the bolted joint as friction with memory (a Jenkins
# element) and a clearance (a two-sided stop), all parameters from the data.
""", """\
nonlinearities:
  - name: joint
    kind: jenkins
    channels: {wing: 1, payload: -1}
    slip: auto                  # m (F_s / k)
  - name: gap
    kind: trilinear
    channels: {wing: 1, payload: -1}
    clearances: auto            # m, each side
""")

IDENT_LINEAR = _config("""\
# Aircraft-like GVT (daq.sim.aircraft): linear identification (no nonlinear element).
""", "nonlinearities: []\n")


def write_campaign(out: Path, levels: list[float], *, same_phases: bool = False,
                   force: bool = False, phase_seed: int = 0) -> list[dict]:
    """Record every level into ``out`` and write the ident configs; returns levels.json.

    Level ``i`` is driven by the multisine realisation ``phase_seed + i`` (with
    ``same_phases``: the experiment's own seed + ``phase_seed`` at every level), so another
    ``phase_seed`` gives the same campaign with other realisations.
    """
    from fnsi_lab import acquire
    from fnsi_lab.daq.config import load_experiment
    from fnsi_lab.daq.recording.info import recording_info

    out.mkdir(parents=True, exist_ok=True)
    base = load_experiment("aircraft")
    rows = []
    for i, level in enumerate(levels):
        exc = replace(base.excitation, rms=float(level), levels=(),
                      seed=(base.excitation.seed if same_phases else i) + phase_seed)
        path = out / f"aircraft-rms{level:g}.mcap"
        cfg = replace(base, excitation=exc, output=str(path))
        print(f"level {i + 1}/{len(levels)}: {level:g} N RMS -> {path}", file=sys.stderr)
        acquire(cfg, path, force=force)
        run = recording_info(str(path)).get("truth", {}).get("run", {})
        rows.append({"file": path.name, "level_n_rms": float(level), "phase_seed": exc.seed,
                     **run})
    for name, text in (("aircraft-joint.yaml", IDENT_JOINT), ("aircraft-jenkins.yaml", IDENT_JENKINS),
                       ("aircraft-jenkins-stop.yaml", IDENT_JENKINS_STOP),
                       ("aircraft-linear.yaml", IDENT_LINEAR)):
        p = out / name
        if p.exists() and not force:
            print(f"{p} exists: kept (--force replaces it)", file=sys.stderr)
            continue
        p.write_text(text)
    (out / "levels.json").write_text(json.dumps(rows, indent=2))
    return rows


def main(argv: list[str] | None = None) -> int:
    from fnsi_lab.daq.sim.aircraft import LEVELS_N_RMS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example:\n  python bench/aircraft.py --out aircraft-gvt")
    ap.add_argument("--out", type=Path, default=Path("aircraft-gvt"), help="campaign folder")
    ap.add_argument("--levels", type=float, nargs="+", default=list(LEVELS_N_RMS),
                    metavar="N_RMS", help="measured force levels (default 12 26 40 55 69 84 98)")
    ap.add_argument("--same-phases", action="store_true",
                    help="one multisine realisation for every level (default: one per level)")
    ap.add_argument("--phase-seed", type=int, default=0,
                    help="first multisine realisation (level i uses PHASE_SEED + i; default 0)")
    ap.add_argument("--force", action="store_true", help="replace existing recordings")
    args = ap.parse_args(argv)
    rows = write_campaign(args.out, args.levels, same_phases=args.same_phases, force=args.force,
                          phase_seed=args.phase_seed)
    for r in rows:
        diff = r.get("period_difference_last", {})
        print(f"{r['file']:24s} force {r.get('force_rms_n', float('nan')):6.2f} N RMS  "
              f"slip {r.get('slip_m', 0):.3f} m  friction {r.get('friction_energy_j', 0):6.2f} J  "
              f"contact {100 * r.get('contact_fraction', 0):5.2f} %  last period diff "
              f"{100 * max(diff.values(), default=0):5.2f} %")
    print(f"folder {args.out}: next: fnsi-lab ident {args.out}/aircraft-rms98.mcap --config "
          f"{args.out}/aircraft-joint.yaml --auto --json result.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
