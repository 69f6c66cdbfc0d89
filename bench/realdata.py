"""Identification on real and lab-realistic data: consistency, truth, fixed order vs automatic.

``python bench/realdata.py [--write] [--quick]``

Cases (every identification goes through :func:`fnsi_lab.identify`, default options):

1. **Silverbox, Schroeder record** (real measurement, ``bench/data/silverbox-schroeder``):
   an electronic Duffing oscillator, 10 steady periods of 1024 samples. Each period is
   identified on its own as a one-period realisation (the lab layout of issue 11: no
   period-to-period noise estimate), with ``--order 2`` and ``--auto``; the cubic
   coefficient must agree across periods (no truth exists) and the answer must hold one mode.
   Reference: the 10 periods averaged (noise-weighted) in one identification.
2. **Simulated lab Duffing** (:mod:`fnsi_lab.daq.sim.lab`): the Silverbox's linear part
   (68 Hz, 4.8 %) with k3 = 3.9, 10 realisations of an odd random-phase multisine
   (N = 8192, fs = 610.35 Hz, 0-200 Hz), one period each after a transient; variants from
   an ideal acquisition to a lab one (DAC hold, 6th-order Butterworth anti-alias filter at
   0.4 fs, pink noise 60 dB on the output and the drive, hum 3 % of RMS at 50 and 150 Hz,
   DC offsets 5 % of RMS) and a noisy lab (40 dB). Error against the truth and spread.
3. **3-channel SmallSat at order 10** (``bench/reproduce_paper.py``'s simulation, default
   options): the NC2-Z values against the exact stiffnesses.
4. **Simulated lab stop**: the 3-DOF chain with a relative two-sided stop
   (``lumped_model('trilinear')``, full multisine 5-60 Hz) through the same lab defects
   (DAC hold, anti-alias filter, pink noise 60 dB, hum 3 % at 50 Hz, synchronous with the
   period, or at 49.9 Hz, drifting; DC offsets 5 % of RMS); displacements or
   accelerations, 8 periods or 8 one-period realisations; the clearances given (offset 0),
   the offset ``auto``, and the clearances ``auto``.

Speed: the 10 one-period realisations in one identification (R = 10) against one
(R = 1), ``--auto``, same run (target: at most 2x).

``--write`` replaces the "Real data" section of ``bench/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from datetime import datetime, timezone
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "bench" / "data" / "silverbox-schroeder"
sys.path.insert(0, str(ROOT / "bench"))

#: Silverbox linear part read from an order-2 model of the record (mass, damping, stiffness
#: in its voltage units) and the cubic coefficient of the same circuit (README).
DUFFING = dict(mass=5.33e-6, damping=2.2e-4, stiffness=0.98, k3=3.9)
FS, N_LAB = 610.35, 8192
CUBIC = {"band_hz": [0.5, 200.0], "inputs": [{"name": "u0", "driving_point": "y0"}],
         "nonlinearities": [{"name": "k3", "kind": "polynomial", "channels": {"y0": 1},
                             "exponent": 3}]}
LAB_VARIANTS = {
    "ideal acquisition": dict(),
    "lab (hold, AA, 60 dB pink, hum 3 %, offsets)": dict(
        dac_hold=True, antialias_order=6, snr_db=60, input_snr_db=60, noise_colour="pink",
        hum_hz=50.0, hum_level=0.03, offset=0.05),
    "noisy lab (40 dB)": dict(
        dac_hold=True, antialias_order=6, snr_db=40, input_snr_db=50, noise_colour="pink",
        hum_hz=50.0, hum_level=0.03, offset=0.05),
}


def _physical_modes(ident, band=(0.5, 200.0)) -> int:
    return sum(band[0] <= m["frequency_hz"] <= band[1] for m in ident.modes)


def _one(source, cfg, order):
    import fnsi_lab
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = fnsi_lab.identify(source, cfg, order=order)
    dt = time.perf_counter() - t0
    c = r.coefficients[0] if r.coefficients else {}
    out = {"value": c.get("value"), "mean_real": c.get("mean_real"), "order": r.order,
           "modes": _physical_modes(r), "seconds": dt,
           "time_base": r.data.time_base}
    if r.auto is not None:
        out["confidence"] = r.auto.confidence["level"]
    return out


def _stats(rows, key, truth=None):
    v = np.array([r[key] for r in rows], float)
    s = {"mean": float(v.mean()), "spread_pct": float(100 * v.std(ddof=1) / abs(v.mean()))}
    if truth is not None:
        s["error_pct"] = float(100 * (v.mean() - truth) / truth)
        s["max_abs_error_pct"] = float(np.max(np.abs(100 * (v - truth) / truth)))
    return s


def _realisations(u, y, fs, N, cfg, truth=None):
    """Identify every realisation alone, fixed order 2 and automatic."""
    res = {}
    for label, order in (("--order 2", 2), ("--auto", None)):
        rows = [_one({"u": u[r], "y": y[r], "fs": fs, "N": N}, cfg, order)
                for r in range(u.shape[0])]
        res[label] = {"rows": rows, "value": _stats(rows, "value", truth),
                      "mean_real": _stats(rows, "mean_real", truth),
                      "modes": [r["modes"] for r in rows], "orders": [r["order"] for r in rows],
                      "confidence": [r.get("confidence") for r in rows],
                      "seconds": float(np.median([r["seconds"] for r in rows])),
                      "time_base": sorted({r["time_base"] for r in rows})}
    return res


def _speed(u, y, fs, N, cfg, repeat):
    """--auto on R = 10 one-period realisations in one call against R = 1 (best of repeat)."""
    one = min(_one({"u": u[:1], "y": y[:1], "fs": fs, "N": N}, cfg, None)["seconds"]
              for _ in range(repeat))
    many = min(_one({"u": u, "y": y, "fs": fs, "N": N}, cfg, None)["seconds"]
               for _ in range(repeat))
    return {"one_s": one, "all_s": many, "ratio": many / one, "R": int(u.shape[0])}


def silverbox(quick=False):
    import yaml
    z = np.load(DATA / "schroeder.npz")
    N = int(z["N"])
    cfg = yaml.safe_load((DATA / "schroeder.yaml").read_text())
    cfg.pop("transient_periods", None)   # each realisation is one steady period
    cfg.pop("samples_per_period", None)
    u = z["u"].reshape(-1, 1, N, 1)[1:]  # period 0 is the transient
    y = z["y"].reshape(-1, 1, N, 1)[1:]
    fs = float(z["fs"])
    out = {"per_period": _realisations(u, y, fs, N, cfg)}
    out["averaged"] = {lab: _one({"u": u[:, 0][None], "y": y[:, 0][None], "fs": fs, "N": N},
                                 cfg, order) for lab, order in (("--order 2", 2), ("--auto", None))}
    out["speed"] = _speed(u, y, fs, N, cfg, 1 if quick else 3)
    return out


def lab_duffing(variant, quick=False, seed=1):
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.lab import LabRealism, duffing_model, lab_experiment
    ms = multisine(N_LAB, FS, (0.05, 200.0), 0.03, n_realizations=10, seed=seed, grid="odd")
    model = duffing_model(DUFFING["mass"], DUFFING["damping"], DUFFING["stiffness"],
                          DUFFING["k3"])
    rec = lab_experiment(model, ms, LabRealism(**LAB_VARIANTS[variant]), seed=seed)
    out = {"per_realisation": _realisations(rec.u, rec.y, FS, N_LAB, CUBIC, DUFFING["k3"])}
    if not quick:
        out["speed"] = _speed(rec.u, rec.y, FS, N_LAB, CUBIC, 2)
    return out


LAB_STOP = dict(dac_hold=True, antialias_order=6, snr_db=60, input_snr_db=60,
                noise_colour="pink", hum_hz=50.0, hum_level=0.03, offset=0.05)
STOP_LAYOUTS = {"displacements, 8 periods": ("displacement", 8, 1, 50.0),
                "displacements, 8 periods, hum at 49.9 Hz (drifting)": ("displacement", 8, 1, 49.9),
                "accelerations, 8 periods": ("acceleration", 8, 1, 50.0),
                "displacements, 8 one-period realisations": ("displacement", 1, 8, 50.0)}


def lab_stop(layout, seed=0):
    """Coefficient errors (and estimated gaps/offset) of the lab stop, three ways."""
    from dataclasses import replace
    import fnsi_lab
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim import lumped_model
    from fnsi_lab.daq.sim.lab import LabRealism, lab_experiment
    from fnsi_lab.ident.core.basis import ParameterSpace
    from fnsi_lab.ident.config import load_ident_config, packaged_config

    quantity, periods, R, hum_hz = STOP_LAYOUTS[layout]
    model = lumped_model("trilinear")
    fs, N = 1024.0, 8192
    gaps, contact = np.array((4e-4, 5e-4)), np.array((2.0e4, 1.5e4))
    ms = multisine(N, fs, (5, 60), 20.0, n_realizations=R, seed=1)
    lab = LabRealism(quantity=quantity, periods=periods, transient_periods=2,
                     **{**LAB_STOP, "hum_hz": hum_hz})
    rec = lab_experiment(model, ms, lab, seed=seed)
    u, y = (rec.u[0], rec.y[0]) if R == 1 else (rec.u, rec.y)
    if R == 1:   # one realisation: its periods as one record
        u, y = u.reshape(-1, u.shape[-1]), y.reshape(-1, y.shape[-1])
    src = {"u": u, "y": y, "fs": fs, "N": N, "quantity": quantity,
           "channels": list(model.measured_names), "input_channels": list(model.input_names)}
    known = replace(load_ident_config(packaged_config("lumped-stop")), transient_periods=0,
                    output_quantity=quantity)

    def unknown(*pars):
        return replace(known, nonlinearities=tuple(
            replace(nl, unknown=tuple(ParameterSpace(p) for p in pars))
            for nl in known.nonlinearities))

    out = {}
    for label, cfg in (("clearances given, offset 0", known), ("offset auto", unknown("offset")),
                       ("clearances auto", unknown("g_neg", "g_pos"))):
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = fnsi_lab.identify(src, cfg).to_json()
        except Exception as exc:   # a refusal is a result too
            out[label] = {"refused": str(exc)}
            continue
        nl = res["nonlinearities"][0]
        values = np.array([c["value"] for c in res["coefficients"]])
        out[label] = {"coef_err_pct": 100 * (values / contact - 1),
                      "gap_err_pct": 100 * (np.array(nl["clearances"]) / gaps - 1),
                      "offset": nl.get("offset"), "seconds": time.perf_counter() - t0,
                      "mains_dropped_hz": res["excitation"].get("mains_dropped_hz")}
    return out


def smallsat_order10():
    import reproduce_paper as rp
    from fnsi_lab.daq.sim.smallsat import DEFAULT_CLEARANCES, NC2Z_CONTACT
    u, y, names, _ = rp._simulate(100.0, nonlinear=True, seed=1, periods=rp.P_TR + 1)
    idx = [names.index(c) for c in rp.THREE]
    cfg = {"band_hz": list(rp.PROC_BAND), "transient_periods": rp.P_TR,
           "inputs": [{"name": "F-NC2W-Z", "driving_point": rp.DRIVE}],
           "nonlinearities": [{"name": "NC2-Z", "kind": "trilinear",
                               "channels": {"NC2W-Z": 1, "NC2B-Z": -1},
                               "clearances": list(DEFAULT_CLEARANCES["NC2-Z"])}]}
    src = {"u": u, "y": y[:, idx], "fs": rp.FS, "N": rp.N, "channels": np.array(rp.THREE),
           "input_channels": np.array(["F-NC2W-Z"])}
    import fnsi_lab
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = fnsi_lab.identify(src, cfg, order=10)
    exact = {"NC2-Z:neg": NC2Z_CONTACT["neg"], "NC2-Z:pos": NC2Z_CONTACT["pos"]}
    return {"time_base": r.data.time_base,
            "choice": r.session.evidence.get("time_base_choice"),
            "coefficients": {c["name"]: {"value_error_pct": 100 * (c["value"] / exact[c["name"]] - 1),
                                         "mean_error_pct": 100 * (c["mean_real"] / exact[c["name"]] - 1)}
                             for c in r.coefficients}}


# --------------------------------------------------------------------------- report
def _fmt_case(name, res, truth=False):
    rows = []
    for label, r in res.items():
        v, m = r["value"], r["mean_real"]
        err = (f"{v['error_pct']:+.3f} % (max {v['max_abs_error_pct']:.2f} %)" if truth else "-")
        merr = f"{m['error_pct']:+.2f} %" if truth else "-"
        conf = ", ".join(f"{c}: {r['confidence'].count(c)}" for c in ("clear", "moderate", "ambiguous")
                         if r["confidence"].count(c)) if r["confidence"][0] else "-"
        rows.append(f"| {name} | {label} | {v['mean']:.4f} | {v['spread_pct']:.3f} % | {err} | "
                    f"{m['spread_pct']:.2f} % / {merr} | {min(r['modes'])}-{max(r['modes'])} | "
                    f"{min(r['orders'])}-{max(r['orders'])} | {conf} | {'/'.join(r['time_base'])} | "
                    f"{r['seconds']:.1f} |")
    return rows


def _stop_rows(stops):
    rows = ["", "**Simulated lab stop** (3-DOF chain, relative two-sided stop 0.4 / 0.5 mm, "
            "2.0 / 1.5e4 N/m; full multisine 5-60 Hz; DAC hold, 6th-order anti-alias filter, "
            "pink noise 60 dB, hum 3 % at 50 Hz (synchronous with the 8 s period, the hard "
            "case, unless said), DC offsets 5 % of RMS; robust pipeline, the "
            "config's order 6 for the search). The sensors' offsets put the relative motion "
            "about 0.04 mm off (10 % of a gap); integrated outputs lose the static position.",
            "", "| layout | method | stiffness errors | gaps | offset (mm) | s |",
            "|---|---|---|---|---|---|"]
    for layout, res in stops.items():
        for label, r in res.items():
            if "refused" in r:
                rows.append(f"| {layout} | {label} | refused: {r['refused'][:90]} | | | |")
                continue
            c, g = r["coef_err_pct"], r["gap_err_pct"]
            rows.append(f"| {layout} | {label} | {c[0]:+.2f} / {c[1]:+.2f} % | "
                        + (f"{g[0]:+.1f} / {g[1]:+.1f} %" if label == "clearances auto" else "given")
                        + f" | {1e3 * (r['offset'] or 0.0):+.4f} | {r['seconds']:.1f} |")
    return rows


def markdown(sb, lab, ss, load, stops=None):
    day = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = [f"## Real data ({day})", "",
           "`python bench/realdata.py --write` on the shared 2-core x86_64 machine (load average "
           f"{load:.1f} at start; timings are +-30 %, compare ratios within the run). Every "
           "identification is `fnsi_lab.identify` with default options, one realisation "
           "(one steady period) at a time. `value` is the declared coefficient (the LS constant, "
           "docs/ident.md); `mean Re` the plain mean over the excited lines. Spread: standard "
           "deviation over the realisations / mean. Modes: physical modes of the answer in "
           "0.5-200 Hz (one expected); order: the answer's order.", "",
           "| data | method | value (mean) | value spread | value error vs truth | mean Re: spread / error | modes | order | confidence | time base | s per identification |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    out += _fmt_case("Silverbox (real), 10 periods as one-period realisations, N 1024",
                     sb["per_period"])
    for variant, r in lab.items():
        out += _fmt_case(f"lab Duffing, {variant}, 10 x N 8192", r["per_realisation"], truth=True)
    av = sb["averaged"]
    out += ["", "Silverbox, the 10 periods averaged in one identification (noise from the "
            "periods): `--order 2` value "
            f"{av['--order 2']['value']:.4f} (mean Re {av['--order 2']['mean_real']:.4f}), "
            f"`--auto` value {av['--auto']['value']:.4f}, order {av['--auto']['order']}, "
            f"{av['--auto']['modes']} mode(s). The per-period values scatter around it by the "
            "spread above (one period has 1/10 of the averaged data).", ""]
    out += ["**Speed with many realisations** (`--auto`, the 10 one-period realisations in one "
            "call against one realisation, best of the repeats):", "",
            "| data | R = 1 (s) | R = 10 (s) | ratio (target <= 2) |", "|---|---|---|---|"]
    out.append(f"| Silverbox, N 1024 | {sb['speed']['one_s']:.2f} | {sb['speed']['all_s']:.2f} | "
               f"{sb['speed']['ratio']:.2f} |")
    for variant, r in lab.items():
        if "speed" in r:
            s = r["speed"]
            out.append(f"| lab Duffing, {variant}, N 8192 | {s['one_s']:.2f} | {s['all_s']:.2f} | "
                       f"{s['ratio']:.2f} |")
    if ss:
        c = ss["coefficients"]
        ch = ss["choice"] or {}
        ve = ch.get("model_error", {})
        out += ["", "**3-channel SmallSat at order 10, default options** (target within "
                "+0.34 % / -0.10 %, the paper's): time base chosen "
                f"`{ss['time_base']}` (model error band-limited {ve.get('band-limited', float('nan')):.3g}, "
                f"bilinear {ve.get('bilinear', float('nan')):.3g}); NC2-Z value "
                + " / ".join(f"{c[k]['value_error_pct']:+.3f} %" for k in ("NC2-Z:neg", "NC2-Z:pos"))
                + " (mean Re " + " / ".join(f"{c[k]['mean_error_pct']:+.3f} %"
                                             for k in ("NC2-Z:neg", "NC2-Z:pos")) + ")."]
    if stops:
        out += _stop_rows(stops)
    out += ["", NOTES]
    return "\n".join(out) + "\n"


#: What changed the figures since the first real-data run (kept with the table it explains).
NOTES = """Since the first run (2026-11-23): the Silverbox spreads were 0.49 % (`--order 2`) and \
1.03 % (`--auto`, orders 2-4) with block rows at 54-81 % of the data matrix's columns; the \
rows are now capped at 15 % of them for few outputs and the automatic answer is re-estimated \
with its order's rows when the sweep had to exceed that (docs/ident.md, "Block rows"). The \
realisation ratios were 1.4-3.7x: stacked realisations are now folded per line before the \
subspace QR (exact; docs/ident.md, "Many channels, many realisations")."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="replace the 'Real data' section of "
                    "bench/RESULTS.md")
    ap.add_argument("--quick", action="store_true", help="one lab variant, no speed repeats")
    a = ap.parse_args(argv)
    load = os.getloadavg()[0]
    sb = silverbox(a.quick)
    variants = list(LAB_VARIANTS)[1:2] if a.quick else list(LAB_VARIANTS)
    lab = {v: lab_duffing(v, a.quick) for v in variants}
    ss = None if a.quick else smallsat_order10()
    stops = {layout: lab_stop(layout) for layout in STOP_LAYOUTS}
    text = markdown(sb, lab, ss, load, stops)
    print(text)
    if a.write:
        from reproduce_paper import replace_section
        replace_section(ROOT / "bench" / "RESULTS.md", "Real data", text)
        print("wrote bench/RESULTS.md (Real data)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
