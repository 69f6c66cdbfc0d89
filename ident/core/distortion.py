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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import special

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.excitation import MAINS_HZ
from fnsi_lab.ident.core.noise import resolution_variance

__all__ = ["LineSets", "Evidence", "OutputAnalysis", "Resonance", "RecordAnalysis",
           "line_sets", "period_statistics", "best_linear_approximation",
           "detection_windows", "realisation_windows", "find_resonances", "analyse_arrays",
           "compare_levels", "DEFAULT_ALPHA", "WINDOW_LINES"]

#: Family-wise false-alarm probability per record: a linear record gets a "nonlinear"
#: verdict on any output with at most this probability.
DEFAULT_ALPHA = 0.01
#: Lines (per realisation) pooled in one test window: 8 lines, 16 degrees of freedom per
#: realisation, detect a distortion at the noise level with p ~ 1e-4 while localising it.
WINDOW_LINES = 8


@dataclass(frozen=True)
class LineSets:
    """The DFT bins of the analysed band by role.

    Attributes
    ----------
    excited : int ndarray
        Excited bins inside the band.
    odd, even : int ndarray
        Non-excited odd / even bins (only when every excited bin is odd: ``parity``).
    mixed : int ndarray
        Non-excited bins when odd and even products cannot be told apart (not ``parity``).
    band : int ndarray
        Every bin of the analysed band (mains zones included).
    hum : bool ndarray, shape like ``band``
        Bins within the mains zones (left out of the band's noise level).
    parity : bool
        Every excited bin is odd (an odd multisine).
    """

    excited: np.ndarray
    odd: np.ndarray
    even: np.ndarray
    mixed: np.ndarray
    band: np.ndarray
    parity: bool
    hum: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


@dataclass(frozen=True)
class Evidence:
    """One test window of one output.

    ``kind`` is ``'odd'``, ``'even'``, ``'mixed'`` (detection lines) or ``'realisations'``;
    ``band_hz`` the window's span, ``frequency_hz`` its centre; ``level_db`` the power
    measured there (noise included), ``noise_db`` the noise, ``output_db`` the output near
    it (excited lines in the window, else the band's), ``p_value`` the probability of a
    ratio this large from noise alone; ``significant`` against the record's corrected level.
    """

    kind: str
    frequency_hz: float
    band_hz: tuple[float, float]
    level_db: float
    noise_db: float
    output_db: float
    p_value: float
    significant: bool = False
    in_band: bool = True

    def to_dict(self) -> dict:
        return {"kind": self.kind, "frequency_hz": self.frequency_hz,
                "band_hz": list(self.band_hz), "level_db": self.level_db,
                "noise_db": self.noise_db, "output_db": self.output_db,
                "p_value": self.p_value, "significant": self.significant,
                "in_excited_band": self.in_band}


@dataclass
class OutputAnalysis:
    """Levels, per-line spectra and the verdict of one output.

    Levels are ``10 log10`` of mean powers over the lines of the analysed band, in dB re
    one output unit (DFT / N of a period average): ``output_db`` on the excited lines,
    ``noise_db`` the variance of the period average (every band line but the mains zones),
    ``odd_distortion_db``
    / ``even_distortion_db`` what the odd / even detection lines hold (noise included: equal
    to ``noise_db`` without distortion; with realisations and no odd detection line, the
    realisations' spread on the excited lines of an odd multisine), ``distortion_db`` every
    detection line, or the realisations' spread (total distortion). ``None``: not measurable
    with this excitation.
    """

    name: str
    output_db: float
    noise_db: float
    odd_distortion_db: float | None
    even_distortion_db: float | None
    distortion_db: float | None
    verdict: str
    nonlinear: bool | None
    evidence: list[Evidence] = field(default_factory=list)
    spectra: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dict(self, spectra: bool = False) -> dict:
        out = {"name": self.name, "output_db": self.output_db, "noise_db": self.noise_db,
               "odd_distortion_db": self.odd_distortion_db,
               "even_distortion_db": self.even_distortion_db,
               "distortion_db": self.distortion_db, "verdict": self.verdict,
               "nonlinear": self.nonlinear,
               "evidence": [e.to_dict() for e in self.evidence if e.significant][:5]}
        if spectra:
            out["spectra"] = {k: np.asarray(v).tolist() for k, v in self.spectra.items()}
        return out


@dataclass(frozen=True)
class Resonance:
    """A resonance of the BLA: ``frequency_hz``, ``damping_ratio`` and how it was read."""

    frequency_hz: float
    damping_ratio: float
    method: str

    def to_dict(self) -> dict:
        return {"frequency_hz": self.frequency_hz, "damping_ratio": self.damping_ratio,
                "method": self.method}


@dataclass
class RecordAnalysis:
    """The analysis of one record (:func:`analyse_arrays`)."""

    path: str
    input_channel: str
    input_rms: float
    sample_rate_hz: float
    samples_per_period: int
    n_realizations: int
    n_periods: int
    lines: LineSets
    noise_source: str
    outputs: list[OutputAnalysis]
    resonances: list[Resonance]
    frequency_hz: np.ndarray          # (n_excited,) excited lines of the band
    frf: np.ndarray                   # (n_excited, p) BLA
    frf_noise_var: np.ndarray         # (n_excited, p)
    frf_total_var: np.ndarray | None  # (n_excited, p), R >= 2
    alpha: float
    n_tests: int
    timings_s: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def band_hz(self) -> tuple[float, float]:
        df = self.sample_rate_hz / self.samples_per_period
        return float(self.lines.band.min() * df), float(self.lines.band.max() * df)

    def to_dict(self, spectra: bool = False) -> dict:
        df = self.sample_rate_hz / self.samples_per_period
        exc = self.lines.excited
        inside = np.arange(exc.min(), exc.max() + 1)
        if self.lines.parity:
            grid = ("odd with odd detection lines" if np.any(~np.isin(inside[inside % 2 == 1],
                                                                        exc)) else "odd")
        else:
            grid = "full" if np.all(np.isin(inside, exc)) else "sparse (not all odd)"
        return {
            "input": self.path, "input_channel": self.input_channel,
            "input_rms": self.input_rms, "sample_rate_hz": self.sample_rate_hz,
            "samples_per_period": self.samples_per_period,
            "n_realizations": self.n_realizations, "n_periods": self.n_periods,
            "excitation": {"grid": grid, "n_excited": int(exc.size),
                           "excited_band_hz": [float(exc.min() * df), float(exc.max() * df)],
                           "n_odd_detection": int(self.lines.odd.size),
                           "n_even_detection": int(self.lines.even.size),
                           "n_mixed_detection": int(self.lines.mixed.size)},
            "analysis_band_hz": list(self.band_hz), "noise_source": self.noise_source,
            "alpha": self.alpha, "n_tests": self.n_tests,
            "outputs": [o.to_dict(spectra) for o in self.outputs],
            "resonances": [r.to_dict() for r in self.resonances],
            "notes": list(self.notes), "timings_s": dict(self.timings_s),
            **({"bla": self.bla_dict()} if spectra else {})}

    def bla_dict(self) -> dict:
        """The BLA per excited line: ``frequency_hz`` (F,), ``re``/``im`` (F, p), and the
        variances of one realisation's FRF ``noise_var`` and ``total_var`` (F, p; null when
        not measured)."""
        return {"frequency_hz": self.frequency_hz.tolist(), "outputs": [o.name for o in
                                                                        self.outputs],
                "re": self.frf.real.tolist(), "im": self.frf.imag.tolist(),
                "noise_var": self.frf_noise_var.tolist(),
                "total_var": None if self.frf_total_var is None else self.frf_total_var.tolist()}


# ----------------------------------------------------------------------------- lines
def line_sets(excited_lines: np.ndarray, band_bins: tuple[int, int], n_bins: int,
              sample_rate_hz: float, samples_per_period: int, *,
              mains_zone: float = 3.0) -> LineSets:
    """Split the analysed band into excited and detection bins.

    Parameters
    ----------
    excited_lines : int ndarray
        Excited DFT bins of one period.
    band_bins : (int, int)
        First and last bin of the analysed band (inclusive).
    n_bins : int
        ``N // 2 + 1``.
    sample_rate_hz : float
    samples_per_period : int
    mains_zone : float
        Non-excited bins within this many lines of a 50 or 60 Hz harmonic are not detection
        lines: hum synchronous with the period repeats like distortion would.

    Returns
    -------
    LineSets
    """
    lo, hi = max(int(band_bins[0]), 1), min(int(band_bins[1]), n_bins - 2)
    band = np.arange(lo, hi + 1)
    exc_all = np.asarray(excited_lines, int)
    excited = band[np.isin(band, exc_all)]
    df = float(sample_rate_hz) / int(samples_per_period)
    f = band * df
    hum = np.zeros(band.size, bool)
    for f_m in MAINS_HZ:
        h = np.round(f / f_m)
        hum |= (h >= 1) & (np.abs(f - h * f_m) <= mains_zone * df)
    rest = band[~np.isin(band, exc_all) & ~hum]
    parity = bool(exc_all.size) and bool(np.all(exc_all % 2 == 1))
    empty = np.zeros(0, int)
    if parity:
        return LineSets(excited, rest[rest % 2 == 1], rest[rest % 2 == 0], empty, band, True,
                        hum)
    return LineSets(excited, empty, empty, rest, band, False, hum)


# ----------------------------------------------------------------------- statistics
def period_statistics(X: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Period average and the variance of that average.

    Parameters
    ----------
    X : complex ndarray, shape (R, P, n_bins, c)
        Spectra of every period.

    Returns
    -------
    mean : complex ndarray, shape (R, n_bins, c)
    var_of_mean : ndarray, shape (R, n_bins, c), or None when ``P == 1``
        ``sum_p |X_p - mean|^2 / ((P - 1) P)``.
    """
    P = X.shape[1]
    mean = X.mean(axis=1)
    if P < 2:
        return mean, None
    dev = X - mean[:, None]
    var = (dev.real ** 2 + dev.imag ** 2).sum(axis=1) / ((P - 1) * P)
    return mean, var


def best_linear_approximation(U: np.ndarray, Y: np.ndarray, lines: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                                         np.ndarray]:
    """BLA of one input on the given lines, with its noise and total variances.

    Parameters
    ----------
    U : complex ndarray, shape (R, P, n_bins)
        Input spectra of every period.
    Y : complex ndarray, shape (R, P, n_bins, p)
    lines : int ndarray, shape (F,)

    Returns
    -------
    G : complex ndarray, shape (F, p)
        Mean over realisations of ``G_r = Y_r / U_r`` (period averages).
    noise_var : ndarray, shape (F, p), or None (``P == 1``)
        Noise variance of one realisation's ``G_r``, from the period-to-period spread of
        the residual ``Y_p - G_r U_p`` (input noise included), averaged over realisations.
    total_var : ndarray, shape (F, p), or None (``R == 1``)
        Sample variance of ``G_r`` over realisations: noise plus nonlinear distortion of one
        realisation.
    input_power : ndarray, shape (F,)
        Mean over realisations of ``|U_r|^2`` (period averages).
    """
    Uk = U[:, :, lines]                          # (R, P, F)
    Yk = Y[:, :, lines, :]                       # (R, P, F, p)
    Um = Uk.mean(axis=1)
    Ym = Yk.mean(axis=1)
    if np.any(Um == 0):
        raise IdentError("the input is zero on an excited line: give the excited lines or "
                         "the drive channel that carries the multisine")
    Gr = Ym / Um[..., None]                      # (R, F, p)
    G = Gr.mean(axis=0)
    R, P = U.shape[:2]
    noise_var = None
    if P >= 2:
        res = Yk - Gr[:, None] * Uk[..., None]
        s2 = (res.real ** 2 + res.imag ** 2).sum(axis=1) / (P - 1)   # (R, F, p)
        noise_var = (s2 / (P * np.abs(Um[..., None]) ** 2)).mean(axis=0)
    total_var = None
    if R >= 2:
        d = Gr - G
        total_var = (d.real ** 2 + d.imag ** 2).sum(axis=0) / (R - 1)
    return G, noise_var, total_var, (np.abs(Um) ** 2).mean(axis=0)


# ---------------------------------------------------------------------------- windows
def _segments(bins: np.ndarray, excited: np.ndarray, window: int) -> list[np.ndarray]:
    """Index groups of ``bins`` (sorted) of about ``window`` lines, not straddling the
    excited range's edges (distortion inside and beyond the band is judged apart)."""
    if bins.size == 0:
        return []
    lo, hi = (int(excited.min()), int(excited.max())) if excited.size else (0, 0)
    zone = np.where(bins < lo, 0, np.where(bins > hi, 2, 1))
    groups: list[np.ndarray] = []
    for z in (0, 1, 2):
        idx = np.flatnonzero(zone == z)
        if idx.size == 0:
            continue
        n_win = max(1, int(round(idx.size / window)))
        groups.extend(np.array_split(idx, n_win))
    return groups


def _p_values(ratio: np.ndarray, d1: float, d2: float, use_f: np.ndarray) -> np.ndarray:
    """P(T >= ratio) for T ~ F(d1, d2) where ``use_f``, else T ~ chi2(d1) / d1 (a known
    variance), elementwise."""
    ratio = np.asarray(ratio, float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # F(d1, d2) survival: I_{d2 / (d2 + d1 x)}(d2 / 2, d1 / 2); chi2: Q(d1 / 2, x d1 / 2)
        pf = (special.betainc(d2 / 2, d1 / 2, d2 / (d2 + d1 * np.maximum(ratio, 0)))
              if d2 > 0 else np.ones_like(ratio))
        pc = special.gammaincc(d1 / 2, np.maximum(ratio, 0) * d1 / 2)
    pv = np.where(use_f, pf, pc)
    return np.where(np.isfinite(ratio), pv, 0.0)


def _db(x: float) -> float:
    return float(10.0 * np.log10(x)) if x > 0 else float("-inf")


def detection_windows(power: np.ndarray, noise: np.ndarray | None, floor: np.ndarray,
                      bins: np.ndarray, excited: np.ndarray, n_periods: int, *,
                      window: int = WINDOW_LINES) -> list[tuple[np.ndarray, np.ndarray,
                                                               np.ndarray, np.ndarray]]:
    """Test windows of detection lines: is there more than noise?

    Parameters
    ----------
    power : ndarray, shape (R, L, p)
        ``|Y_r(k)|^2`` of the period averages on the detection bins.
    noise : ndarray, shape (R, L, p), or None
        Variance of those averages from the period spread (None: one period).
    floor : ndarray, shape (p,)
        Resolution floor of the variance (:func:`ident.core.noise.resolution_variance`).
    bins : int ndarray, shape (L,)
    excited : int ndarray
        Excited bins (windows stay on one side of the excited range's edges).
    n_periods : int
        ``P`` (degrees of freedom of the noise estimate: ``2 (P - 1)`` per term).
    window : int
        Lines per window.

    Returns
    -------
    list of (idx, level, noise_level, p_value)
        ``idx`` indices into ``bins``; ``level`` and ``noise_level`` (p,) mean powers;
        ``p_value`` (p,): probability of a ratio ``sum power / sum noise`` this large from
        noise alone (``F(2n, 2n(P-1))``, or ``chi2(2n) / 2n`` against the floor), ``n`` the
        window's (line, realisation) terms.
    """
    out = []
    R = power.shape[0]
    for idx in _segments(bins, excited, window):
        n = R * idx.size
        s_pow = power[:, idx].sum(axis=(0, 1))
        s_floor = floor * n
        s_meas = noise[:, idx].sum(axis=(0, 1)) if noise is not None else np.zeros_like(floor)
        use_meas = s_meas > s_floor
        s_noise = np.where(use_meas, s_meas, s_floor)
        pv = _p_values(s_pow / s_noise, 2 * n, 2 * n * (n_periods - 1), use_meas)
        out.append((idx, s_pow / n, s_noise / n, pv))
    return out


def realisation_windows(total_var: np.ndarray, noise_var: np.ndarray | None,
                        floor: np.ndarray, input_power: np.ndarray, lines: np.ndarray,
                        n_realizations: int, n_periods: int, *, window: int = WINDOW_LINES
                        ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Test windows of excited lines: do the realisations spread more than the noise?

    Parameters
    ----------
    total_var, noise_var : ndarray, shape (F, p)
        Variances of one realisation's FRF (:func:`best_linear_approximation`).
    floor : ndarray, shape (p,)
        Resolution floor of the output variance.
    input_power : ndarray, shape (F,)
        ``|U|^2`` (converts FRF variances to output powers).
    lines : int ndarray, shape (F,)
    n_realizations, n_periods : int
        ``R >= 2`` and ``P``.
    window : int

    Returns
    -------
    list of (idx, level, noise_level, p_value)
        As :func:`detection_windows`, levels as output powers ``var * |U|^2``; the ratio
        follows ``F(2 F_w (R - 1), 2 F_w R (P - 1))`` under "linear" (the realisations'
        sample variance against the pooled period-spread estimate).
    """
    out = []
    R, P = int(n_realizations), int(n_periods)
    tot = total_var * input_power[:, None]
    meas = noise_var * input_power[:, None] if noise_var is not None else None
    for idx in _segments(lines, lines, window):
        n = idx.size
        s_tot = tot[idx].sum(axis=0)
        s_floor = floor * n
        s_meas = meas[idx].sum(axis=0) if meas is not None else np.zeros_like(floor)
        use_meas = s_meas > s_floor
        s_noise = np.where(use_meas, s_meas, s_floor)
        pv = _p_values(s_tot / s_noise, 2 * n * (R - 1), 2 * n * R * (P - 1), use_meas)
        out.append((idx, s_tot / n, s_noise / n, pv))
    return out


# ------------------------------------------------------------------------ resonances
def _sdof_fit(f_hz: np.ndarray, G: np.ndarray, f_peak: float) -> tuple[float, float] | None:
    """Common-denominator second-order fit ``G_o(s) = (b0 + b1 s + b2 s^2) / (s^2 + a1 s
    + a0)`` of every output on the lines around one peak (linear least squares, the
    numerators projected out); returns (frequency_hz, damping_ratio) or None."""
    s = 1j * f_hz / f_peak                               # scaled Laplace variable
    Phi = np.stack([np.ones_like(s), s, s ** 2], axis=1)  # (L, 3)
    Phi_r = np.vstack([Phi.real, Phi.imag])              # (2L, 3)
    Q = np.eye(Phi_r.shape[0]) - Phi_r @ np.linalg.pinv(Phi_r)
    AtA = np.zeros((2, 2))
    Atc = np.zeros(2)
    for o in range(G.shape[1]):
        g = G[:, o] / max(float(np.sqrt(np.mean(np.abs(G[:, o]) ** 2))), 1e-300)
        A = np.stack([g * s, g], axis=1)
        c = g * s ** 2
        A_r = Q @ np.vstack([A.real, A.imag])
        c_r = Q @ np.concatenate([c.real, c.imag])
        AtA += A_r.T @ A_r
        Atc += A_r.T @ c_r
    try:
        a1, a0 = np.linalg.solve(AtA, -Atc)
    except np.linalg.LinAlgError:
        return None
    if not a0 > 0:
        return None
    wn = float(np.sqrt(a0))
    zeta = float(a1 / (2 * wn))
    f_n = wn * f_peak
    if not (0 < zeta < 1 and f_hz.min() <= f_n <= f_hz.max()):
        return None
    return f_n, zeta


def find_resonances(frequency_hz: np.ndarray, G: np.ndarray, *,
                    relative_std: np.ndarray | None = None,
                    max_resonances: int = 12) -> list[Resonance]:
    """Resonances of a BLA: peaks of its outputs, gathered across outputs, each fitted.

    Parameters
    ----------
    frequency_hz : ndarray, shape (F,)
        Excited lines (increasing).
    G : complex ndarray, shape (F, p)
    relative_std : ndarray, shape (F, p), optional
        Standard deviation of ``G`` (noise and distortion) over ``|G|``: a peak must then
        also stand above the scatter, ``20 log10((1 + 2 r) / (1 - 2 r))`` dB more with
        ``r`` the output's median (two standard deviations up at the peak and down at the
        minimum; the BLA of one realisation of a nonlinear structure is ragged).
    max_resonances : int
        The peaks seen on the most outputs kept.

    Returns
    -------
    list of Resonance, by frequency
        A peak of one output counts when it stands at least 3 dB (half power, the
        definition of a resonance's bandwidth) above the higher of its two surrounding
        minima. Peaks of different outputs within two lines are one resonance, kept when
        seen on at least two outputs (one with a single output) or a tenth of them.
        Frequency and damping from a common-denominator second-order fit of those outputs
        over the lines within twice the peak's half-prominence width (``method: 'sdof
        fit'``), else from the half-power points of their summed normalised power
        (``'half power'``).
    """
    F, p = G.shape
    if F < 5:
        return []
    level = 10 * np.log10(np.maximum(np.abs(G) ** 2, 1e-300))          # (F, p)
    found: list[tuple[int, int, float]] = []                             # (line, output, width)
    extra = np.zeros(p)
    if relative_std is not None:
        r = np.minimum(np.nanmedian(relative_std, axis=0), 0.45)
        extra = 20 * np.log10((1 + 2 * r) / (1 - 2 * r))
    for o in range(p):
        found.extend((i, o, w) for i, w in _prominent_peaks(level[:, o], 3.0 + extra[o]))
    if not found:
        return []
    found.sort()
    clusters: list[list[tuple[int, int, float]]] = [[found[0]]]
    for item in found[1:]:
        if item[0] - clusters[-1][-1][0] <= 2:
            clusters[-1].append(item)
        else:
            clusters.append([item])
    need = 1 if p == 1 else max(2, int(np.ceil(0.1 * p)))
    clusters = [c for c in clusters if len({o for _, o, _ in c}) >= need]
    clusters = sorted(clusters, key=len, reverse=True)[:max_resonances]
    centres = sorted(int(np.median([i for i, _, _ in c])) for c in clusters)
    by_centre = {int(np.median([i for i, _, _ in c])): c for c in clusters}
    out: list[Resonance] = []
    for j, pk in enumerate(centres):
        c = by_centre[pk]
        outs = sorted({o for _, o, _ in c})
        half = max(3, int(np.ceil(2 * np.median([w for _, _, w in c]))))
        lo, hi = max(0, pk - half), min(F, pk + half + 1)
        if j > 0:
            lo = max(lo, (centres[j - 1] + pk) // 2 + 1)
        if j + 1 < len(centres):
            hi = min(hi, (centres[j + 1] + pk) // 2 + 1)
        fit = (_sdof_fit(frequency_hz[lo:hi], G[lo:hi][:, outs], float(frequency_hz[pk]))
               if hi - lo >= 5 else None)
        if fit is not None:
            out.append(Resonance(fit[0], fit[1], "sdof fit"))
            continue
        p2 = np.abs(G[:, outs]) ** 2
        cmif = 10 * np.log10(np.maximum((p2 / np.maximum(p2.mean(axis=0), 1e-300)).sum(axis=1),
                                        1e-300))
        hp = _half_power(frequency_hz, cmif, pk)
        if hp is not None:
            out.append(Resonance(float(frequency_hz[pk]), hp, "half power"))
    return out


def _prominent_peaks(x: np.ndarray, min_prominence: float) -> list[tuple[int, float]]:
    """Local maxima of ``x`` (F,) whose prominence (height above the higher of the lowest
    points between them and a higher value on each side) reaches ``min_prominence``, with
    their width in lines at half that prominence (as ``scipy.signal.find_peaks`` and
    ``peak_widths``, without importing scipy.signal: 1 s of start-up)."""
    F = x.size
    inner = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])) + 1
    out = []
    for i in inner:
        xi = x[i]
        left = i
        while left > 0 and x[left - 1] <= xi:
            left -= 1
        right = i
        while right < F - 1 and x[right + 1] <= xi:
            right += 1
        prom = xi - max(x[left:i + 1].min(), x[i:right + 1].min())
        if prom < min_prominence:
            continue
        h = xi - prom / 2
        a = i
        while a > left and x[a] > h:
            a -= 1
        b = i
        while b < right and x[b] > h:
            b += 1
        width = float(b - a)
        out.append((int(i), width))
    return out


def _half_power(f: np.ndarray, level_db: np.ndarray, pk: int) -> float | None:
    """Damping ratio from the -3 dB points around a peak (linear interpolation)."""
    target = level_db[pk] - 3.0103
    i = pk
    while i > 0 and level_db[i] > target:
        i -= 1
    j = pk
    while j < f.size - 1 and level_db[j] > target:
        j += 1
    if level_db[i] > target or level_db[j] > target:
        return None
    fl = np.interp(target, [level_db[i], level_db[i + 1]], [f[i], f[i + 1]])
    fr = np.interp(target, [level_db[j], level_db[j - 1]], [f[j], f[j - 1]])
    return float((fr - fl) / (2 * f[pk]))


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
        rel = f"{below:.0f} dB below" if below >= 0.5 else f"{-below:.0f} dB above"
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
        raise IdentError(f"{path}: analysed band {list(band_hz)} Hz is not [f_low, f_high] "
                         "with 0 <= f_low < f_high")
    n_bins = N // 2 + 1
    band_bins = (int(np.ceil(band_hz[0] / df - 1e-9)), int(np.floor(band_hz[1] / df + 1e-9)))
    sets = line_sets(exc, band_bins, n_bins, fs, N)
    if sets.excited.size == 0:
        raise IdentError(f"{path}: no excited line inside the analysed band {band_hz} Hz")
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
        path=path, input_channel=input_name, input_rms=float(np.sqrt(np.mean(u ** 2))),
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


# ----------------------------------------------------------------------------- levels
def _mutual_nearest(a: Sequence[float], b: Sequence[float], cap: float) -> dict[int, int]:
    """Pairs (i in a -> j in b) that are each other's nearest frequency, within ``cap``
    (relative)."""
    pairs = {}
    for i, fa in enumerate(a):
        if not b:
            break
        j = int(np.argmin([abs(fb - fa) for fb in b]))
        back = int(np.argmin([abs(b[j] - x) for x in a]))
        if back == i and abs(b[j] - fa) <= cap * fa:
            pairs[i] = j
    return pairs


def compare_levels(records: Sequence[RecordAnalysis], *, max_shift: float = 0.5) -> dict:
    """Several records of one structure at different levels, by increasing input RMS.

    Parameters
    ----------
    records : sequence of RecordAnalysis
        Same outputs (by name) expected; outputs missing from a record are left out.
    max_shift : float
        Resonances are followed from level to level: a resonance of the next level is the
        same one when each is the other's nearest and they differ by less than this
        fraction (a hardening stop can move a resonance by tens of percent).

    Returns
    -------
    dict
        ``order`` (record indices by level), ``input_rms``, ``resonances[]`` (per resonance
        of the lowest level: ``frequency_hz``, ``damping_ratio``, ``shift_percent`` against
        the lowest level, per level; None where it was lost) and ``outputs[]`` (per output:
        ``output_db``, ``noise_db``, ``distortion_db``, ``odd_distortion_db``,
        ``even_distortion_db``, ``relative_distortion_db`` = distortion minus output, and
        ``nonlinear`` per level).
    """
    order = sorted(range(len(records)), key=lambda i: records[i].input_rms)
    recs = [records[i] for i in order]
    base = recs[0].resonances
    tracks: list[list[Resonance | None]] = [[r] for r in base]
    for rec in recs[1:]:
        alive = [(i, t[-1]) for i, t in enumerate(tracks) if t[-1] is not None]
        pairs = _mutual_nearest([r.frequency_hz for _, r in alive],
                                [r.frequency_hz for r in rec.resonances], max_shift)
        matched = {alive[k][0]: rec.resonances[j] for k, j in pairs.items()}
        for i, t in enumerate(tracks):
            t.append(matched.get(i))
    res_rows = []
    for first, t in zip(base, tracks):
        f0 = first.frequency_hz
        res_rows.append({
            "frequency_hz": [None if r is None else r.frequency_hz for r in t],
            "damping_ratio": [None if r is None else r.damping_ratio for r in t],
            "shift_percent": [None if r is None else 100.0 * (r.frequency_hz / f0 - 1.0)
                              for r in t]})
    names = [o.name for o in recs[0].outputs]
    out_rows = []
    for name in names:
        row: dict = {"name": name}
        found = [next((o for o in rec.outputs if o.name == name), None) for rec in recs]
        per = [o for o in found if o is not None]
        if len(per) < len(found):
            continue
        for key in ("output_db", "noise_db", "distortion_db", "odd_distortion_db",
                    "even_distortion_db", "nonlinear"):
            row[key] = [getattr(o, key) for o in per]
        row["relative_distortion_db"] = [
            None if o.distortion_db is None else o.distortion_db - o.output_db for o in per]
        out_rows.append(row)
    return {"order": order, "input_rms": [r.input_rms for r in recs],
            "inputs": [r.path for r in recs], "resonances": res_rows, "outputs": out_rows}
