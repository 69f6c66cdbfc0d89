"""Basis parameters from the data: accuracy and cost of ``clearances: auto``.

Cases (simulated with daq.sim, truth known):

- the 39-channel SmallSat (NC2-Z stop, noise-free), packaged config ``smallsat39``, robust
  pipeline (orders 2..60): clearances given vs ``auto``, wall time of the whole run;
- the same SmallSat with 1 % white noise on every output (6 steady periods averaged; the
  run before 2026-11-25 07:00 had 1, the config dropping 5 transient periods of 6);
- the 3-DOF chain with a relative two-sided stop (``lumped-stop``), noise-free and with 1 %
  white output noise (16 periods averaged, 8 noise seeds), clearances ``auto``, against the
  same identification with the clearances given, at the fixed order 6 and with the robust
  pipeline (orders 2..60);
- the same chain with gaps of 1.2 / 1.5 mm (0.7 / 0.9 of the relative motion's RMS, contact
  at the peaks only), 1 % noise, 16 periods, order 6 and robust pipeline;
- ``offset: auto`` on the same chain with the clearances given: accelerations (noise-free
  and 0.1 % noise, 16 periods), and displacements whose sensors carry DC offsets (1 %
  noise, 16 periods), against offset 0;
- the chain with velocity outputs, 1 % noise, 16 periods (``--only velocity``).

On noisy data every run ends with the output-error refinement where ``refine: auto`` runs
it (docs/ident.md, "The output-error refinement"): the values printed are the answer's.

Coefficient errors are those of the JSON's ``value`` (what outside checks read).

Timing ratios are measured within one run (auto and known interleaved, best of ``--repeat``);
absolute times depend on the machine's load.

    python bench/bench_parameter_search.py [--repeat 2] [--quick] [--only offset]
    python bench/bench_parameter_search.py --only chain --periods 16,32,64
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import replace

import numpy as np

from fnsi_lab.blas import limit_blas_threads

limit_blas_threads(1)

import fnsi_lab  # noqa: E402
from fnsi_lab.daq.multisine import multisine  # noqa: E402
from fnsi_lab.daq.sim import lumped_model, simulate  # noqa: E402
from fnsi_lab.daq.sim.smallsat import DEFAULT_CLEARANCES, NC2Z_CONTACT, smallsat_model  # noqa: E402
from fnsi_lab.ident.core.basis import ParameterSpace  # noqa: E402
from fnsi_lab.ident.config import load_ident_config, packaged_config  # noqa: E402


#: Chain gaps at 0.7 / 0.9 of the relative motion's RMS (the default 0.4 / 0.5 mm are a
#: third of it): the stop is touched only at the motion's peaks.
PEAK_CONTACT_GAPS = (1.2e-3, 1.5e-3)


def with_auto_clearances(cfg):
    """The same configuration with every stop's clearances left to the data."""
    nls = tuple(replace(nl, unknown=(ParameterSpace("g_neg"), ParameterSpace("g_pos")))
                if nl.kind == "trilinear" else nl for nl in cfg.nonlinearities)
    return replace(cfg, nonlinearities=nls)


def run(src, cfg, **kw):
    t0 = time.perf_counter()
    res = fnsi_lab.identify(src, cfg, **kw).to_json()
    return time.perf_counter() - t0, res


def errors(res, gaps, contact):
    nl = res["nonlinearities"][0]
    g_err = [100 * (g / t - 1) for g, t in zip(nl["clearances"], gaps)]
    c_err = [100 * (c.get("value", c["mean_real"]) / t - 1)
             for c, t in zip(res["coefficients"], contact)]
    return g_err, c_err, nl.get("clearance_std")


def smallsat(repeat: int, noise: float = 0.0) -> None:
    model = smallsat_model()
    fs, n = 1000.0, 8192
    # the packaged config drops 5 transient periods: 6 steady ones with noise, 1 without
    periods = 11 if noise else 6
    u = np.asarray(multisine(n, fs, (5, 50), 100.0, n_periods=periods, seed=1).signal[0], float)
    y = simulate(model, u[:, None], fs, periodic=n, quantities=("displacement",)).displacement
    if noise:
        y = y + np.random.default_rng(0).standard_normal(y.shape) * np.std(y, axis=0) * noise
    src = {"u": u[:, None], "y": y, "fs": fs, "N": n, "channels": list(model.measured_names),
           "input_channels": ["F-NC2W-Z"]}
    known = load_ident_config(packaged_config("smallsat39"))
    auto = with_auto_clearances(known)
    gaps = DEFAULT_CLEARANCES["NC2-Z"]
    contact = (NC2Z_CONTACT["neg"], NC2Z_CONTACT["pos"])
    t = {"known": [], "auto": []}
    out = {}
    for _ in range(repeat):
        for name, cfg in (("known", known), ("auto", auto)):
            dt, res = run(src, cfg)
            t[name].append(dt)
            out[name] = res
    gk, ck, _ = errors(out["known"], gaps, contact)
    ga, ca, sa = errors(out["auto"], gaps, contact)
    ps = out["auto"]["parameter_search"]
    label = "noise-free" if noise == 0 else f"{100 * noise:g} % noise, 6 steady periods"
    print(f"SmallSat, 39 channels, {label}, robust pipeline (orders 2..60):")
    print(f"  known clearances: {min(t['known']):.2f} s; coefficient errors "
          f"{ck[0]:+.4f} % / {ck[1]:+.4f} %")
    print(f"  clearances auto:  {min(t['auto']):.2f} s (search {ps['timings_s']['total']:.2f} s, "
          f"{ps['n_evaluations']} fits at order {ps['order']}, i = {ps['block_rows']}); "
          f"ratio {min(t['auto']) / min(t['known']):.2f}x")
    print(f"  gaps {out['auto']['nonlinearities'][0]['clearances']} (truth {list(gaps)}): "
          f"errors {ga[0]:+.4f} % / {ga[1]:+.4f} %, std {sa[0]:.2g} / {sa[1]:.2g} mm; "
          f"coefficient errors {ca[0]:+.4f} % / {ca[1]:+.4f} %")


def chain(noise: float, seeds: range, periods: int, repeat: int, order: int | None = 6,
          gaps: tuple[float, float] = (4e-4, 5e-4), quantity: str = "displacement") -> None:
    """The 3-DOF chain, clearances given and ``auto``. For velocity outputs the known
    clearances are given from the mean relative position (its offset), and the ``auto``
    gaps are compared with the gaps counted from it (integrated outputs carry no static
    position)."""
    model = lumped_model("trilinear", clearances=gaps)
    fs, n = 1024.0, 8192
    u = np.asarray(multisine(n, fs, (5, 60), 20.0, n_periods=3, seed=1).signal).reshape(-1, 1)
    out = simulate(model, u, fs, periodic=n, quantities=("displacement", quantity))
    y0 = getattr(out, quantity)
    mean = float(np.mean(out.displacement[-n:, 1] - out.displacement[-n:, 2]))
    u, y0 = np.tile(u[-n:], (periods, 1)), np.tile(y0[-n:], (periods, 1))
    known = load_ident_config(packaged_config("lumped-stop"))
    known = replace(known, transient_periods=0, output_quantity=quantity,
                    nonlinearities=tuple(replace(nl, clearances=tuple(gaps),
                                                 offset=mean if quantity != "displacement"
                                                 else 0.0)
                                         for nl in known.nonlinearities))
    auto = with_auto_clearances(replace(known, nonlinearities=tuple(
        replace(nl, offset=0.0) for nl in known.nonlinearities)))
    if quantity != "displacement":
        gaps = (gaps[0] + mean, gaps[1] - mean)
    contact = (2.0e4, 1.5e4)
    label = "noise-free" if noise == 0 else f"{100 * noise:g} % noise, {periods} periods"
    label += f", gaps {gaps[0] * 1e3:g} / {gaps[1] * 1e3:g} mm"
    if quantity != "displacement":
        label += f" ({quantity} outputs; gaps from the mean position)"
    how = f"order {order}" if order else "robust pipeline (orders 2..60)"
    print(f"3-DOF chain, relative two-sided stop, {label}, {how}:")
    kw = {"order": order} if order else {}
    for seed in seeds:
        y = y0 + (np.random.default_rng(seed).standard_normal(y0.shape) * np.std(y0, axis=0)
                  * noise)
        src = {"u": u, "y": y, "fs": fs, "N": n, "channels": list(model.measured_names),
               "input_channels": list(model.input_names), "quantity": quantity}
        tk, ta = [], []
        for _ in range(repeat):
            dt, rk = run(src, known, **kw)
            tk.append(dt)
            dt, ra = run(src, auto, **kw)
            ta.append(dt)
        _, ck, _ = errors(rk, gaps, contact)
        ga, ca, sa = errors(ra, gaps, contact)
        print(f"  seed {seed}: gaps {ga[0]:+.3f} % / {ga[1]:+.3f} % (std "
              f"{100 * sa[0] / gaps[0]:.2g} / {100 * sa[1] / gaps[1]:.2g} %); coefficients auto "
              f"{ca[0]:+.3f} / {ca[1]:+.3f} %, known {ck[0]:+.3f} / {ck[1]:+.3f} %; time "
              f"{min(ta):.2f} s vs {min(tk):.2f} s ({min(ta) / min(tk):.1f}x)")


def with_auto_offset(cfg):
    """The same configuration with every stop's offset left to the data (clearances given)."""
    nls = tuple(replace(nl, unknown=(ParameterSpace("offset"),))
                if nl.kind == "trilinear" else nl for nl in cfg.nonlinearities)
    return replace(cfg, nonlinearities=nls)


def chain_offset(quantity: str, noise: float, seeds: range, sensor_offset: float = 0.0,
                 periods: int = 16) -> None:
    """Clearances given, offset 0 vs ``auto``; ``sensor_offset`` (m) is added to X2 and
    subtracted from X3 (the relative motion reads 2x it too high)."""
    model = lumped_model("trilinear")
    fs, n = 1024.0, 8192
    u = np.asarray(multisine(n, fs, (5, 60), 20.0, n_periods=3, seed=1).signal).reshape(-1, 1)
    out = simulate(model, u, fs, periodic=n, quantities=("displacement", quantity))
    y0 = np.tile(getattr(out, quantity)[-n:], (periods, 1))
    u = np.tile(u[-n:], (periods, 1))
    names = list(model.measured_names)
    rel = out.displacement[-n:, names.index("X2")] - out.displacement[-n:, names.index("X3")]
    truth = (-2 * sensor_offset if quantity == "displacement" else float(np.mean(rel)))
    known = replace(load_ident_config(packaged_config("lumped-stop")), transient_periods=0,
                    output_quantity=quantity)
    auto = with_auto_offset(known)
    gaps, contact = (4e-4, 5e-4), (2.0e4, 1.5e4)
    print(f"3-DOF chain, clearances given, offset auto, {quantity}, "
          f"{100 * noise:g} % noise, {periods} periods"
          + (f", sensor offsets +-{1e3 * sensor_offset:g} mm" if sensor_offset else "")
          + f", order 6 (true offset {1e3 * truth:+.4f} mm):")
    for seed in seeds:
        y = y0 + np.random.default_rng(seed).standard_normal(y0.shape) * np.std(y0, axis=0) * noise
        if sensor_offset:
            y[:, names.index("X2")] += sensor_offset
            y[:, names.index("X3")] -= sensor_offset
        src = {"u": u, "y": y, "fs": fs, "N": n, "channels": names, "quantity": quantity,
               "input_channels": list(model.input_names)}
        tk, rk = run(src, known, order=6)
        ta, ra = run(src, auto, order=6)
        _, ck, _ = errors(rk, gaps, contact)
        _, ca, _ = errors(ra, gaps, contact)
        nl = ra["nonlinearities"][0]
        print(f"  seed {seed}: offset {1e3 * nl['offset']:+.4f} mm (error "
              f"{100 * (nl['offset'] - truth) / min(gaps):+.2f} % of the smaller gap, std "
              f"{100 * nl['offset_std'] / min(gaps):.2g} %); coefficients auto {ca[0]:+.3f} / "
              f"{ca[1]:+.3f} %, offset 0 {ck[0]:+.2f} / {ck[1]:+.2f} %; time {ta:.2f} s vs "
              f"{tk:.2f} s ({ta / tk:.1f}x)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="one noise seed")
    ap.add_argument("--only", choices=("smallsat", "chain", "offset", "velocity"),
                    help="run one group of cases")
    ap.add_argument("--periods", default="16",
                    help="periods averaged in the noisy chain runs, comma list (e.g. 16,32,64)")
    args = ap.parse_args()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
          f"{os.cpu_count()} cores, one BLAS thread, load average {load:.1f}; "
          f"python {platform.python_version()}, numpy {np.__version__}")
    seeds = range(1 if args.quick else 8)
    if args.only in (None, "smallsat"):
        smallsat(args.repeat)
        smallsat(1, noise=0.01)
    if args.only in (None, "chain"):
        chain(0.0, range(1), 3, args.repeat)
        for periods in (int(p) for p in args.periods.split(",")):
            chain(0.01, seeds, periods, 1)
        chain(0.01, seeds, 16, 1, order=None)
        # gaps near the relative motion's RMS (contact at the peaks only)
        chain(0.01, seeds, 16, 1, gaps=PEAK_CONTACT_GAPS)
        chain(0.01, seeds, 16, 1, order=None, gaps=PEAK_CONTACT_GAPS)
    if args.only in (None, "velocity"):
        chain(0.01, range(1 if args.quick else 3), 16, 1, quantity="velocity")
    if args.only in (None, "offset"):
        few = range(1 if args.quick else 3)
        chain_offset("acceleration", 0.0, range(1))
        chain_offset("acceleration", 0.001, few)
        chain_offset("displacement", 0.01, few, sensor_offset=1.35e-4)


if __name__ == "__main__":
    main()
