"""Nonlinear distortion analysis of periodic multisine records, before any model.

The best linear approximation (BLA) of a structure driven by a random-phase multisine, its
noise variance and its nonlinear-distortion variance per line (Pintelon and Schoukens,
*System Identification: a frequency domain approach*, 2nd ed., ch. 3-4: the robust and the
fast methods):

* **noise**: the period-to-period spread of each realisation (``P >= 2`` steady periods);
  the variance of the period average is ``s^2 / P``. One period: the noise is not
  measured, and only the 24-bit resolution floor (:func:`ident.core.noise.resolution_variance`)
  is known.
* **distortion from realisations** (robust method, ``R >= 2``): the spread of the
  realisations' FRFs ``G_r = Y_r / U_r`` around their mean, on the excited lines, holds
  noise and the stochastic nonlinear distortion; the excess over the noise is the
  distortion.
* **distortion on detection lines** (fast method): lines of the analysed band that the
  multisine does not excite carry only noise on a linear structure. With an odd multisine
  (every excited line odd), odd-order nonlinearities put power on the odd lines left out
  (odd detection lines), even-order ones on the even lines; with any other grid the
  non-excited lines carry both (``mixed``). The band reaches beyond the excitation (its
  third harmonics, up to 0.45 fs by default): a full multisine has detection lines there.

Decision rule (no threshold tuned on a data set): under "linear" a detection line's period
average and the noise estimate are independent circular Gaussians, so in a window of ``n``
(line, realisation) terms ``T = sum |Y|^2 / sum (s^2 / P)`` follows Fisher's
``F(2 n, 2 n (P - 1))`` law (the resolution floor, a known bound, gives
``chi2(2 n) / 2 n``); on the excited lines the realisations' spread over the noise follows
``F(2 n (R - 1) / R ... )`` likewise (:func:`realisation_windows`). A window is nonlinear
when its p-value is below ``alpha`` divided by the number of windows tested in the record
(Bonferroni: a linear record is called nonlinear anywhere with probability at most
``alpha``, 1 % by default).

Pure numpy/scipy. Time records ``(R, P, N, channels)``; spectra ``(..., n_bins, channels)``
with ``n_bins = N // 2 + 1`` (numpy DFT divided by N); per-line results
``(n_lines, n_outputs)``.

Modules: :mod:`ident.core.bla` (line sets, period statistics, the BLA),
:mod:`ident.core.distortion_windows` (the F tests over windows of lines),
:mod:`ident.core.resonances` (resonances of the BLA), :mod:`ident.core.distortion_records`
(the records and their JSON), :mod:`ident.core.level_comparison` (records compared by
level); this module runs them on one record (:func:`analyse_arrays`, with the verdict
sentences) and re-exports their public names.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.bla import (LineSets, best_linear_approximation, line_sets,
                                     period_statistics)
from fnsi_lab.ident.core.distortion_records import Evidence, OutputAnalysis, RecordAnalysis
from fnsi_lab.ident.core.distortion_windows import (DEFAULT_ALPHA, WINDOW_LINES,
                                                    detection_windows, realisation_windows)
from fnsi_lab.ident.core.level_comparison import compare_levels
from fnsi_lab.ident.core.noise import resolution_variance
from fnsi_lab.ident.core.resonances import Resonance, find_resonances

__all__ = ["LineSets", "Evidence", "OutputAnalysis", "Resonance", "RecordAnalysis",
           "line_sets", "period_statistics", "best_linear_approximation",
           "detection_windows", "realisation_windows", "find_resonances", "analyse_arrays",
           "compare_levels", "DEFAULT_ALPHA", "WINDOW_LINES"]


def _db(x: float) -> float:
    return float(10.0 * np.log10(x)) if x > 0 else float("-inf")


# --------------------------------------------------------------------------- verdict
_KIND_WORD = {"odd": "odd distortion", "even": "even distortion", "mixed": "distortion",
              "realisations": "distortion"}


def _verdict(evidence: list[Evidence], tested: bool, noise_measured: bool,
             parity: bool) -> tuple[str, bool | None]:
    """The plain sentence of one output and its flag (None: cannot tell)."""
    if not tested:
        return ("undetermined: no detection line and one realisation (excite an odd "
                "random-phase multisine with detection lines, 'excitation: {grid: "
                "random-odd}', or record several realisations)"), None
    hits = [e for e in evidence if e.significant]
    if not hits:
        if noise_measured:
            return "linear within the noise", False
        return ("linear within the resolution floor (one period: the noise is not "
                "measured)"), False
    def word(kind: str) -> str:
        return "odd distortion" if kind == "realisations" and parity else _KIND_WORD[kind]

    parts = []
    for w in ("odd distortion", "even distortion", "distortion"):
        ks = [e for e in hits if word(e.kind) == w]
        if not ks:
            continue
        best = max(ks, key=lambda e: e.level_db - e.noise_db)
        excess = 10 * np.log10(max(10 ** (best.level_db / 10) - 10 ** (best.noise_db / 10),
                                   1e-300))
        below = best.output_db - excess
        where = (f"around {best.frequency_hz:.3g} Hz" if best.in_band
                 else f"at {best.frequency_hz:.3g} Hz (beyond the excited band; relative to "
                      "the band's output)")
        rel = (f"{below:.0f} dB below" if below >= 0.5 else f"{-below:.0f} dB above"
               if below <= -0.5 else "at the level of")   # never "-0 dB above"
        parts.append(f"{w} {rel} the output {where}")
    text = "; ".join(parts)
    if noise_measured:
        return "nonlinear: " + text, True
    return ("nonlinear or noisy (one period: the noise is not measured; record 2 or more "
            "steady periods): " + text), None


def _mean_db(x: np.ndarray | None) -> float | None:
    if x is None or x.size == 0:
        return None
    return _db(float(np.mean(x)))


# ----------------------------------------------------------------------- entry point
def analyse_arrays(u: np.ndarray, y: np.ndarray, sample_rate_hz: float,
                   excited_lines: np.ndarray, *, input_name: str = "u0",
                   output_names: Sequence[str] | None = None,
                   band_hz: tuple[float, float] | None = None, path: str = "",
                   alpha: float = DEFAULT_ALPHA, window: int = WINDOW_LINES,
                   keep_spectra: bool = True) -> RecordAnalysis:
    """Distortion analysis of one periodic record with one input.

    Parameters
    ----------
    u : ndarray, shape (R, P, N) or (R, P, N, 1)
        Input (force) of the steady periods (transient periods already dropped).
    y : ndarray, shape (R, P, N, p)
        Outputs.
    sample_rate_hz : float
    excited_lines : int ndarray
        Excited DFT bins of one period.
    input_name, output_names : str, sequence of str
    band_hz : (float, float), optional
        Analysed band. Default: from the lowest excited line to three times the highest
        (third-order distortion), at most 0.45 fs.
    path : str
        Where the record came from (messages, JSON).
    alpha : float
        Family-wise false-alarm probability of the record's "nonlinear" verdicts.
    window : int
        Lines pooled per test window.
    keep_spectra : bool
        Keep the per-line levels (``OutputAnalysis.spectra``) for plots.

    Returns
    -------
    RecordAnalysis
    """
    import time

    t0 = time.perf_counter()
    u = np.asarray(u, float)
    if u.ndim == 4:
        if u.shape[3] != 1:
            raise IdentError(f"{path}: the analysis takes one input, got {u.shape[3]}")
        u = u[..., 0]
    y = np.asarray(y, float)
    R, P, N = u.shape
    if y.shape[:3] != (R, P, N):
        raise IdentError(f"{path}: u {u.shape} and y {y.shape} do not match")
    p = y.shape[3]
    names = tuple(output_names) if output_names is not None else tuple(f"y{i}" for i in range(p))
    fs = float(sample_rate_hz)
    df = fs / N
    exc = np.unique(np.asarray(excited_lines, int))
    if exc.size == 0:
        raise IdentError(f"{path}: no excited line")
    if band_hz is None:
        band_hz = (float(exc.min()) * df, min(3.0 * float(exc.max()) * df, 0.45 * fs))
    elif not 0 <= band_hz[0] < band_hz[1]:
        raise IdentError(f"{path}: analysed band {plain.band_hz(band_hz)} is not f_low-f_high "
                         "with 0 <= f_low < f_high")
    n_bins = N // 2 + 1
    band_bins = (int(np.ceil(band_hz[0] / df - 1e-9)), int(np.floor(band_hz[1] / df + 1e-9)))
    sets = line_sets(exc, band_bins, n_bins, fs, N)
    if sets.excited.size == 0:
        raise IdentError(f"{path}: no excited line inside the analysed band "
                         f"{plain.band_hz(band_hz)}")
    U = np.fft.rfft(u, axis=2) / N                                     # (R, P, bins)
    Y = np.fft.rfft(y, axis=2) / N                                     # (R, P, bins, p)
    Ym, Yvar = period_statistics(Y)
    floor = resolution_variance(np.abs(y).max(axis=(0, 1, 2)), N)      # (p,)
    G, g_noise, g_total, u_pow = best_linear_approximation(U, Y, sets.excited)
    t_fft = time.perf_counter()

    windows: list[tuple[str, np.ndarray, list]] = []
    for kind, bins in (("odd", sets.odd), ("even", sets.even), ("mixed", sets.mixed)):
        if bins.size:
            pw = np.abs(Ym[:, bins]) ** 2
            nv = Yvar[:, bins] if Yvar is not None else None
            windows.append((kind, bins, detection_windows(pw, nv, floor, bins, exc, P,
                                                          window=window)))
    if g_total is not None:
        windows.append(("realisations", sets.excited,
                        realisation_windows(g_total, g_noise, floor, u_pow, sets.excited,
                                            R, P, window=window)))
    n_tests = sum(len(w[2]) for w in windows) * p
    level_alpha = alpha / max(n_tests, 1)

    out_pow = (np.abs(Ym[:, sets.excited]) ** 2).mean(axis=0)         # (F, p)
    noise_all = (Yvar[:, sets.band].mean(axis=0) if Yvar is not None
                 else np.zeros((sets.band.size, p)))
    noise_all = np.maximum(noise_all, floor)
    quiet = ~sets.hum if np.any(~sets.hum) else np.ones(sets.band.size, bool)
    band_out_db = [_db(float(out_pow[:, o].mean())) for o in range(p)]
    outputs = []
    for o in range(p):
        evidence = _evidence(windows, sets, out_pow[:, o], band_out_db[o], df, o,
                             level_alpha)
        verdict, flag = _verdict(evidence, bool(windows), Yvar is not None, sets.parity)
        levels = _output_levels(Ym, g_total, u_pow, sets, o)
        spectra = (_line_levels(sets, df, out_pow[:, o], noise_all[:, o], Ym[..., o],
                                g_total[:, o] * u_pow if g_total is not None else None)
                   if keep_spectra else {})
        outputs.append(OutputAnalysis(
            name=names[o], output_db=band_out_db[o],
            noise_db=_db(float(noise_all[quiet, o].mean())), verdict=verdict, nonlinear=flag,
            evidence=sorted(evidence, key=lambda e: e.p_value), spectra=spectra, **levels))
    res = find_resonances(sets.excited * df, G,
                          relative_std=_bla_relative_std(G, g_noise, g_total, u_pow, Ym, sets))
    t_end = time.perf_counter()
    return RecordAnalysis(
        # the force's RMS about its mean: a load cell's DC offset is not excitation (a
        # 0.002 N multisine with a 0.004 N offset read 0.0043 N, bench/RESULTS_beam.md)
        path=path, input_channel=input_name,
        input_rms=float(np.sqrt(np.mean((u - u.mean(axis=2, keepdims=True)) ** 2))),
        sample_rate_hz=fs, samples_per_period=N, n_realizations=R, n_periods=P, lines=sets,
        noise_source="period spread" if Yvar is not None else
        "resolution floor (one period: noise not measured)",
        outputs=outputs, resonances=res, frequency_hz=sets.excited * df, frf=G,
        frf_noise_var=g_noise if g_noise is not None else np.full(G.shape, np.nan),
        frf_total_var=g_total, alpha=float(alpha), n_tests=int(n_tests),
        timings_s={"spectra": t_fft - t0, "tests": t_end - t_fft, "total": t_end - t0})


def _evidence(windows: list, sets: LineSets, out_pow: np.ndarray, band_out_db: float,
              df: float, o: int, level_alpha: float) -> list[Evidence]:
    """Every test window of output ``o`` as :class:`Evidence` (``out_pow`` (F,): its power
    on the excited lines)."""
    exc = sets.excited
    evidence = []
    for kind, bins, wins in windows:
        for idx, level, nlev, pv in wins:
            span = bins[idx]
            near = (exc >= span.min()) & (exc <= span.max())
            o_db = _db(float(out_pow[near].mean())) if np.any(near) else band_out_db
            in_band = bool(exc.min() <= span.mean() <= exc.max())
            evidence.append(Evidence(kind, float(span.mean() * df),
                                     (float(span.min() * df), float(span.max() * df)),
                                     _db(float(level[o])), _db(float(nlev[o])), o_db,
                                     float(pv[o]), bool(pv[o] < level_alpha), in_band))
    return evidence


def _line_levels(sets: LineSets, df: float, out_pow: np.ndarray, noise_var: np.ndarray,
                 Ym: np.ndarray, realisations: np.ndarray | None) -> dict[str, np.ndarray]:
    """Per-line levels of one output for the plots (``OutputAnalysis.spectra``); ``Ym``
    (R, n_bins) its period averages."""
    spectra = {"excited_hz": sets.excited * df, "output_power": out_pow,
               "band_hz": sets.band * df, "noise_var": noise_var}
    for kind in ("odd", "even", "mixed"):
        bins = getattr(sets, kind)
        if bins.size:
            spectra[f"{kind}_hz"] = bins * df
            spectra[f"{kind}_power"] = (np.abs(Ym[:, bins]) ** 2).mean(axis=0)
    if realisations is not None:
        spectra["realisations_power"] = realisations
    return spectra


def _bla_relative_std(G: np.ndarray, g_noise: np.ndarray | None,
                      g_total: np.ndarray | None, u_pow: np.ndarray, Ym: np.ndarray,
                      sets: LineSets) -> np.ndarray:
    """Standard deviation of one realisation's FRF over ``|G|``, shape (F, p): the
    realisations' spread, else the noise plus the distortion of the nearest odd (or mixed)
    detection lines inside the excited range (fast method), else the noise; at least the
    BLA's own line-to-line raggedness (a full multisine's distortion has no detection line
    inside the band)."""
    if g_total is not None:
        var = g_total
    else:
        var = g_noise if g_noise is not None else np.zeros(G.shape)
        det = sets.odd if sets.odd.size else sets.mixed
        exc = sets.excited
        det = det[(det > exc.min()) & (det < exc.max())]
        if det.size >= 2:
            pw = (np.abs(Ym[:, det]) ** 2).mean(axis=0)                 # (L, p)
            dist = np.stack([np.interp(exc, det, pw[:, o]) for o in range(pw.shape[1])], 1)
            var = var + dist / u_pow[:, None]
    rel = np.sqrt(var) / np.maximum(np.abs(G), 1e-300)
    if G.shape[0] >= 5:
        # the BLA's own raggedness: the second difference of independent scatter of
        # standard deviation s has an RMS of s sqrt(1.5), and the median of a circular
        # Gaussian's modulus is sqrt(ln 2) of its RMS (robust to the resonances' curvature)
        d2 = np.abs(G[1:-1] - 0.5 * (G[:-2] + G[2:])) / np.maximum(np.abs(G[1:-1]), 1e-300)
        ragged = np.median(d2, axis=0) / np.sqrt(1.5 * np.log(2.0))
        rel = np.maximum(rel, ragged[None, :])
    return rel


def _output_levels(Ym: np.ndarray, g_total: np.ndarray | None, u_pow: np.ndarray,
                   sets: LineSets, o: int) -> dict:
    """Band levels of one output's detection lines and realisation spread (dB)."""
    def det(bins: np.ndarray) -> float | None:
        return _mean_db((np.abs(Ym[:, bins, o]) ** 2).ravel()) if bins.size else None

    real = _mean_db(g_total[:, o] * u_pow) if g_total is not None else None
    odd = det(sets.odd)
    if odd is None and sets.parity:
        odd = real
    every = np.concatenate([sets.odd, sets.even, sets.mixed])
    total = real if real is not None else det(every)
    return {"odd_distortion_db": odd, "even_distortion_db": det(sets.even),
            "distortion_db": total}
