"""SmallSat simulator benchmark: speed (x real time), internal rate, errors.

Usage::

    python bench/bench_smallsat.py            # speed + errors (about 30 s)
    python bench/bench_smallsat.py --figures  # also writes docs/img/smallsat_*.png
    python bench/bench_smallsat.py --quick    # speed only

Speed is measured on one core (BLAS threads pinned to 1 before numpy is imported),
excluding numba compilation (cached on disk after the first run), for the default
experiment: 6 periods x 8192 samples at 1 kHz = 49.152 s of signal, 39 displacement
channels, internal rate 20 kHz.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from fnsi_lab.daq.config import load_experiment  # noqa: E402
from fnsi_lab.daq.multisine import multisine  # noqa: E402
from fnsi_lab.daq.sim.integrate import lowpass_decimate_periodic, newmark, simulate  # noqa: E402
from fnsi_lab.daq.sim.smallsat import TABLE1, smallsat_model  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    """max over channels of rms(a - b) / rms(b)."""
    return float((np.sqrt(np.mean((a - b) ** 2, axis=0)) / np.sqrt(np.mean(b ** 2, axis=0))).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figures", action="store_true", help="write docs/img/smallsat_*.png")
    ap.add_argument("--quick", action="store_true", help="speed only")
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()

    cfg = load_experiment(None)
    exc = cfg.excitation
    fs, n, periods = cfg.sample_rate_hz, exc.samples_per_period, exc.periods
    oversample = int(os.environ.get("BENCH_OVERSAMPLE", cfg.source.options.get("oversample", 20)))
    t0 = time.perf_counter()
    model = smallsat_model()
    t_build = time.perf_counter() - t0
    ms = multisine(n, fs, exc.band_hz, exc.rms, n_periods=periods, seed=exc.seed)
    p = ms.signal[0][:, None]
    duration = p.shape[0] / fs

    def run(os_: int = oversample, force: np.ndarray = p, m=model, **kw):
        return simulate(m, force, fs, oversample=os_, periodic=n,
                        quantities=kw.pop("quantities", ("displacement",)), **kw)

    t0 = time.perf_counter()
    run()  # compile (or load the numba cache) + per-model preparation
    t_first = time.perf_counter() - t0
    times, cpu = [], []
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        res = run(count_from=(periods - 1) * n)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    best, med = min(times), float(np.median(times))
    print(f"date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    print(f"model build (Table 1 placement): {t_build:.2f} s; first run (compile/cache + "
          f"prepare): {t_first:.2f} s")
    print(f"signal: {duration:.3f} s, 39 channels, internal rate {fs * oversample:.0f} Hz")
    print(f"simulation time: best {best:.3f} s, median {med:.3f} s of {args.repeat} -> "
          f"{duration / best:.0f}x real time (best), {duration / med:.0f}x (median); "
          f"CPU time best {min(cpu):.3f} s -> {duration / min(cpu):.0f}x; "
          f"load average at start {load:.1f}")
    print("contact fraction (last period): " + ", ".join(
        f"{k} {v:.3f}" for k, v in res.contact_fraction.items() if v > 0) + " (others 0)")
    y = res.displacement
    print(f"steady state: rms(last - previous period)/rms(last) = "
          f"{rel_rms(y[-n:], y[-2 * n:-n]):.2e}")
    if args.quick:
        return

    # ---- errors (reference: 80 kHz internal rate)
    ref = run(80).displacement[-n:]
    dbl = run(2 * oversample).displacement[-n:]
    print(f"error vs 2x internal rate ({2 * oversample * fs:.0f} Hz): {rel_rms(y[-n:], dbl):.2e} "
          f"(worst channel, rel rms of the last period)")
    errs = {}
    for os_ in (5, 10, 20, 40):
        errs[os_] = rel_rms(run(os_).displacement[-n:], ref)
        print(f"  internal rate {os_ * fs:.0f} Hz: error vs 80 kHz = {errs[os_]:.2e}")
    # linear: 1 N, exact frequency-domain truth
    lin = run(force=p / exc.rms).displacement[-n:]
    f = np.arange(n // 2 + 1) * fs / n
    y_true = np.fft.irfft(model.frf(f)[:, :, 0] * np.fft.rfft(p[:n, 0] / exc.rms)[:, None],
                          n=n, axis=0)
    print(f"linear 1 N run vs exact H(jw)F(w): {rel_rms(lin, y_true):.2e}")
    # the paper's method: Newmark at 20 kHz, low-pass, decimation
    os_nm = 20
    pf = np.tile(np.fft.irfft(np.fft.rfft(p[:n], axis=0), n=n * os_nm, axis=0) * os_nm,
                 (periods, 1))
    t0 = time.perf_counter()
    q = newmark(model, pf, fs * os_nm)[-n * os_nm:][:, model.measured_dofs]
    t_nm = time.perf_counter() - t0
    y_nm = lowpass_decimate_periodic(q, os_nm, fs)
    print(f"Newmark (average acceleration) at 20 kHz: error vs 80 kHz reference = "
          f"{rel_rms(y_nm, ref):.2e} (ours: {errs[10]:.2e} at 10 kHz, {errs[20]:.2e} at "
          f"20 kHz); Newmark time {t_nm:.1f} s")
    q_lin = newmark(model, pf / exc.rms, fs * os_nm)[-n * os_nm:][:, model.measured_dofs]
    print(f"Newmark 20 kHz, linear 1 N vs exact: "
          f"{rel_rms(lowpass_decimate_periodic(q_lin, os_nm, fs), y_true):.2e}")

    if args.figures:
        figures(model, p, fs, n, exc.rms, run)


def figures(model, p, fs, n, rms, run) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = ROOT / "docs" / "img"
    out.mkdir(parents=True, exist_ok=True)
    modes = model.modes
    # modes vs Table 1
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    k = np.arange(1, 12)
    ax[0].plot(k, [t[0] for t in TABLE1], "ko", mfc="none", ms=9, label="Table 1")
    ax[0].plot(k, modes.frequency_hz[:11], "r+", ms=9, label="model")
    ax[0].set(xlabel="mode", ylabel="natural frequency (Hz)")
    ax[0].legend()
    ax[1].plot(k, [100 * t[1] for t in TABLE1], "ko", mfc="none", ms=9, label="Table 1")
    ax[1].plot(k, 100 * modes.damping_ratio[:11], "r+", ms=9, label="model")
    ax[1].set(xlabel="mode", ylabel="damping ratio (%)")
    fig.tight_layout()
    fig.savefig(out / "smallsat_modes.png", dpi=110)
    plt.close(fig)
    # driving-point FRF NC2W-Z / F at 1 N and 100 N (last period), exact linear FRF
    j = model.measured_names.index("NC2W-Z")
    f = np.arange(n // 2 + 1) * fs / n
    lines = np.nonzero((f >= 5) & (f <= 50))[0]
    fig, ax = plt.subplots(figsize=(7, 4))
    h = model.frf(f[lines])[:, j, 0]
    ax.semilogy(f[lines], np.abs(h), "k-", lw=1, label="exact linear FRF")
    for scale, style, lab in ((1 / rms, "b.", "1 N RMS"), (1.0, "r.", "100 N RMS")):
        force = p * scale
        y = run(force=force).displacement[-n:, j]
        est = np.fft.rfft(y)[lines] / np.fft.rfft(force[-n:, 0])[lines]
        ax.semilogy(f[lines], np.abs(est), style, ms=2, label=lab)
    ax.set(xlabel="frequency (Hz)", ylabel="|NC2W-Z / F| (mm/N)",
           title="SmallSat driving-point FRF (axial, NC2 wheel side)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "smallsat_frf.png", dpi=110)
    plt.close(fig)
    print(f"figures written to {out}")


if __name__ == "__main__":
    main()
