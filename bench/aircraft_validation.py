"""Aircraft-like GVT: linear vs nonlinear answers per level, and validation on another level.

Run::

    python bench/aircraft_validation.py                  # 7 levels, about 2-3 minutes
    python bench/aircraft_validation.py --levels 12 55 98
    python bench/aircraft_validation.py --joint joint     # Coulomb + cubic instead of Jenkins
    python bench/aircraft_validation.py --joint jenkins-stop   # Jenkins + a stop, all auto
    python bench/aircraft_validation.py --decide-on next  # the nested test's simulation
                                                          # check on the next level's record
    python bench/aircraft_validation.py --together 40 55 69   # one model for three levels,
                                                              # validated on the others

Steps (the same entry points as the command line):

1. the campaign of ``bench/aircraft.py`` (one realisation per level) into ``--work``;
2. per level ``fnsi_lab.identify`` (robust pipeline, ``--auto``) with ``aircraft-linear.yaml``
   and with ``aircraft-jenkins.yaml`` (default: a Jenkins element, ``slip: auto``, on
   ``wing - payload``) or ``aircraft-joint.yaml`` (``--joint joint``: Coulomb + cubic);
3. the physical modes of the linear fit matched to the truth's stuck-joint modes, those of
   the nonlinear answer to the modes of the structure whose joint carries no friction force
   (the underlying linear structure of a Jenkins model: ``modes_joint_slipping_hz``), within
   4 %: level invariance of the underlying linear modes;
4. ``fnsi_lab.validate_model``: each level's two answers simulated on the *next* level's
   record (the highest level on the one below): per output the error of the nonlinear
   model, of its underlying linear model, and of the linear fit, dB below the output.

``--decide-on next`` identifies each level with ``validation=`` the next level's record (the
highest level: the one below), so the nested test keeps the nonlinear terms only if they
predict that record at least as well as the linear fit; step 4 then validates on a third
record, never the one the decision read (the level after next, else the one below).

Writes ``bench/out/aircraft_validation.json`` (``-<joint>.json`` for another ``--joint``); the
tables go to ``bench/RESULTS.md`` by hand.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))


def _modes(result, truth_hz: np.ndarray) -> dict[float, float]:
    """Physical modes matched to the nearest truth mode within 4 %: {truth Hz: found Hz}."""
    out = {}
    for m in result.modes:
        f = m["frequency_hz"]
        i = int(np.argmin(np.abs(truth_hz - f)))
        if abs(truth_hz[i] - f) < 0.04 * truth_hz[i] and truth_hz[i] not in out:
            out[float(truth_hz[i])] = float(f)
    return out


def main(argv: list[str] | None = None) -> int:
    import fnsi_lab
    from aircraft import write_campaign
    from fnsi_lab.daq.sim.aircraft import LEVELS_N_RMS, aircraft_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", type=float, nargs="+", default=list(LEVELS_N_RMS))
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "aircraft-gvt")
    ap.add_argument("--joint", choices=("jenkins", "jenkins-stop", "joint"), default="jenkins",
                    help="the nonlinear config: aircraft-jenkins.yaml, aircraft-jenkins-stop.yaml "
                         "or aircraft-joint.yaml")
    ap.add_argument("--decide-on", choices=("own", "next", "both"), default="own",
                    help="the records of the nested test's simulation check: the identified "
                         "one (default), the next level's, or both neighbours' (the level "
                         "below and the one above)")
    ap.add_argument("--together", type=float, nargs="+", default=None, metavar="LEVEL",
                    help="identify these levels together (one model; docs/ident.md, 'Several "
                         "records at once') and validate it on every other level")
    ap.add_argument("--phase-seed", type=int, default=0,
                    help="the campaign's first multisine realisation (bench/aircraft.py; "
                         "another value: the same campaign with other realisations)")
    ap.add_argument("--without-refit", action="store_true",
                    help="keep FNSI's output matrices (no own-motion refit, docs/ident.md): "
                         "the A/B measure of what the refit changes")
    args = ap.parse_args(argv)
    if args.without_refit:
        import fnsi_lab.ident.pipeline as pipeline
        pipeline.refit_on_its_record = lambda session, model: model
    rows = write_campaign(args.work, args.levels, force=True, phase_seed=args.phase_seed)
    if args.together:
        return _together(args, rows)
    model = aircraft_model()
    truth = model.structure.modes.frequency_hz
    truth = truth[(truth > 2) & (truth < 15)]
    free = np.asarray(model.joint_free_modes_hz())
    free = free[(free > 2) & (free < 15)]
    answers = {}
    decided_on, validated_on = {}, {}
    for i, row in enumerate(rows):
        if args.decide_on == "next" and len(rows) >= 3:
            d = i + 1 if i + 1 < len(rows) else i - 1
            decided_on[i] = [rows[d]]
            validated_on[i] = rows[i + 2] if i + 2 < len(rows) else rows[min(i, d) - 1]
        elif args.decide_on == "both" and len(rows) >= 4:
            near = [k for k in (i - 1, i + 1) if 0 <= k < len(rows)]
            decided_on[i] = [rows[k] for k in near]
            validated_on[i] = rows[i + 2] if i + 2 < len(rows) else rows[i - 2]
        else:
            validated_on[i] = rows[i + 1] if i + 1 < len(rows) else rows[i - 1]
    for i, row in enumerate(rows):
        path = args.work / row["file"]
        other = decided_on.get(i)
        for kind in ("linear", args.joint):
            t0 = time.perf_counter()
            # a parameter the data cannot tell leaves its element out (nonlinear_vs_linear)
            res = fnsi_lab.identify(str(path), config=str(args.work / f"aircraft-{kind}.yaml"),
                                    validation=(None if other is None or kind == "linear"
                                                else [str(args.work / o["file"])
                                                      for o in other]))
            answers[(row["level_n_rms"], "linear" if kind == "linear" else "joint")] = res
            print(f"{row['level_n_rms']:5g} N {kind:6s}: order {res.order}, "
                  f"{len(res.modes)} physical modes, {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr)
    levels = [r["level_n_rms"] for r in rows]
    table = []
    for i, row in enumerate(rows):
        level = row["level_n_rms"]
        other = validated_on[i]
        lin, nl = answers[(level, "linear")], answers[(level, "joint")]
        nl_doc = nl.to_json()
        nvl = nl_doc.get("nonlinear_vs_linear") or {}
        entry = {"level_n_rms": level, "validated_on_n_rms": other["level_n_rms"],
                 "decided_on_n_rms": ([o["level_n_rms"] for o in decided_on[i]]
                                      if i in decided_on else [level]),
                 "refused": [r["name"] for r in nvl.get("refused") or []],
                 "output_refit": nl_doc.get("output_refit"),
                 "linear": {"order": lin.order, "modes": _modes(lin, truth),
                            "damping": {float(m["frequency_hz"]): m["damping_ratio"]
                                        for m in lin.modes}},
                 "nonlinear": {"order": nl.order,
                               "modes": _modes(nl, free if args.joint != "joint" else truth),
                               "decision": nvl.get("decision"),
                               "statement": nvl.get("statement"),
                               "slip_m": [e.get("slip") for e in nl_doc["nonlinearities"]],
                               "coefficients": [{k: c.get(k) for k in
                                                 ("name", "value", "std_real", "verdict")}
                                                for c in nl.coefficients]},
                 "run": {k: row.get(k) for k in ("slip_m", "friction_energy_j",
                                                 "contact_fraction", "period_difference_last")}}
        for kind, res in (("linear", lin), ("nonlinear", nl)):
            try:
                v = fnsi_lab.validate_model(res, args.work / other["file"])
                entry[kind]["validation"] = {"converged": v.converged, "outputs": v.outputs}
            except Exception as exc:  # noqa: BLE001 - a failed validation is a result here
                entry[kind]["validation"] = {"error": str(exc)}
        table.append(entry)
    suffix = ("" if args.joint == "jenkins" else f"-{args.joint}") + (
        f"-{args.decide_on}" if args.decide_on != "own" else "") + (
        "-without-refit" if args.without_refit else "")
    out = ROOT / "out" / f"aircraft_validation{suffix}.json"
    out.parent.mkdir(exist_ok=True)
    from fnsi_lab.outputs import dumps

    out.write_text(dumps({"truth_modes_hz": truth, "truth_joint_free_modes_hz": free,
                          "joint_config": args.joint, "levels": levels, "table": table}, indent=2))
    print("truth (stuck joint):", " ".join(f"{f:.2f}" for f in truth))
    print("truth (no friction force in the joint):", " ".join(f"{f:.2f}" for f in free))
    for e in table:
        lin, nl = e["linear"], e["nonlinear"]

        def val(v, key):
            outs = v.get("validation", {}).get("outputs")
            if not outs or outs[0].get(key) is None:
                return "-"
            return "/".join(f"{o[key]:+.1f}" for o in outs)

        print(f"{e['level_n_rms']:5g} N | lin order {lin['order']:2d} modes {len(lin['modes'])} "
              f"| nl order {nl['order']:2d} modes {len(nl['modes'])} | "
              + " ".join(f"{c['name']}={c['value']:.3g}({c.get('verdict') or '?'})"
                         for c in nl["coefficients"])
              + f" [{nl['decision']}] slip {nl['slip_m']}"
              + (" decided on " + " + ".join(f"{x:g}" for x in e["decided_on_n_rms"]) + " N"
                 if e["decided_on_n_rms"] != [e["level_n_rms"]] else "")
              + f" | on {e['validated_on_n_rms']:g} N: nl {val(nl, 'error_db')}, "
                f"its linear {val(nl, 'linear_error_db')}, linear fit {val(lin, 'linear_error_db')}")
        if nl.get("statement"):
            print(f"        nonlinear vs linear: {nl['statement'][:240]}")
        nl_truth = free if args.joint != "joint" else truth
        for f0, f1 in zip(truth, nl_truth):
            a, b = lin["modes"].get(float(f0)), nl["modes"].get(float(f1))
            print(f"        {f0:6.2f} / {f1:6.2f} Hz: linear {a if a is None else round(a, 3)}, "
                  f"nonlinear {b if b is None else round(b, 3)}")
    spread = {}
    for f1 in (free if args.joint != "joint" else truth):
        found = [e["nonlinear"]["modes"][float(f1)] for e in table
                 if e["nonlinear"].get("decision") == "nonlinear"
                 and float(f1) in e["nonlinear"]["modes"]]
        if len(found) >= 2:
            spread[float(f1)] = 100 * (max(found) - min(found)) / float(np.mean(found))
            print(f"underlying linear {f1:6.2f} Hz over the levels with a nonlinear answer: "
                  f"{len(found)} levels, spread {spread[float(f1)]:.2f} %")
    print(f"wrote {out}")
    return 0


def _together(args, rows) -> int:
    """``--together``: the chosen levels identified as one input, validated on the others;
    prints the decision, the stiffness, the joint-free modes and the validation errors, and
    writes ``bench/out/aircraft_together[-JOINT].json``."""
    import fnsi_lab
    from fnsi_lab.daq.sim.aircraft import aircraft_model
    from fnsi_lab.outputs import dumps

    chosen = [r for r in rows if r["level_n_rms"] in set(args.together)]
    others = [r for r in rows if r not in chosen]
    t0 = time.perf_counter()
    res = fnsi_lab.identify([str(args.work / r["file"]) for r in chosen],
                            config=str(args.work / f"aircraft-{args.joint}.yaml"))
    seconds = time.perf_counter() - t0
    doc = res.to_json()
    nvl = doc.get("nonlinear_vs_linear") or {}
    free = np.asarray(aircraft_model().joint_free_modes_hz())
    free = free[(free > 2) & (free < 15)]
    entry = {"levels_n_rms": [r["level_n_rms"] for r in chosen], "seconds": seconds,
             "decision": nvl.get("decision"), "statement": nvl.get("statement"),
             "coefficients": [{k: c.get(k) for k in ("name", "value", "verdict")}
                              for c in res.coefficients],
             "modes": _modes(res, free), "validation": {}}
    for r in others:
        v = fnsi_lab.validate_model(res, args.work / r["file"])
        entry["validation"][r["level_n_rms"]] = {"converged": v.converged, "outputs": v.outputs}
    out = ROOT / "out" / ("aircraft_together.json" if args.joint == "jenkins"
                          else f"aircraft_together-{args.joint}.json")
    out.parent.mkdir(exist_ok=True)
    out.write_text(dumps(entry, indent=2))
    print(f"levels {entry['levels_n_rms']} together ({seconds:.0f} s): {entry['decision']}; "
          + ", ".join(f"{c['name']} {c['value']:.3g} ({c['verdict']})"
                      for c in entry["coefficients"]))
    print("  joint-free modes (truth: read): " + ", ".join(
        f"{t:.2f}: {f:.3f}" for t, f in entry["modes"].items()))
    for level, v in entry["validation"].items():
        errs = "/".join(f"{o['error_db']:+.1f}" if o.get("error_db") is not None else "-"
                        for o in v["outputs"])
        fit = "/".join(f"{o['linear_fit_error_db']:+.1f}"
                       if o.get("linear_fit_error_db") is not None else "-" for o in v["outputs"])
        print(f"  on {level:g} N: the answer {errs} dB, its linear fit {fit} dB")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
