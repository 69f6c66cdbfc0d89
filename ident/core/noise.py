"""Output noise level without repeated periods: the non-excited lines of the band.

With ``P >= 2`` steady periods the noise of the averaged output is measured directly from
the period-to-period spread (:func:`ident.core.periodic.prepare_frequency_data`). Lab tests often
record one period per realisation (a new random-phase multisine each time), so there is no
spread to measure. An odd (or any sparse-grid) multisine leaves lines inside its band that
the force does not drive: a linear system puts nothing there, an odd nonlinearity (cubic
spring, symmetric stop) only odd lines, so the off-grid lines of an odd multisine carry the
noise, plus mains hum and even-order distortion. Their level, smoothed over neighbouring
lines, is the noise variance at the excited lines next to them (noise spectra are smooth).

What it cannot see: noise on a full multisine (no off-grid line in the band), and the part
of the odd distortion the basis does not model (it sits on the excited lines). Both are
said in the result (``noise.source``, docs/ident.md).

Neither estimate can go below the resolution of the record (:func:`resolution_variance`):
a spread below it is the numerical residue of noise-free data (a simulation's round-off
and settling), not measurement noise, and is not used to weight the fit.

Pure numpy; spectra ``(n_lines, n_channels)``.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.ident.core.excitation import MAINS_HZ

__all__ = ["noise_lines", "noise_from_nonexcited", "mains_contaminated_lines",
           "resolution_variance", "RESOLUTION_BITS"]

#: Median of ``|X|^2`` for circular complex Gaussian noise of variance 1 (exponential law).
_MEDIAN_TO_MEAN = 1.0 / np.log(2.0)

#: Bits of the finest acquisition a noise estimate is judged against: a 24-bit converter
#: (the widest in vibration testing; real ones reach 18-21 effective bits) and float32
#: sample storage (24-bit mantissa) both resolve 2^-23 of the full scale.
RESOLUTION_BITS = 24


def resolution_variance(peak: np.ndarray, samples_per_period: int, *,
                        bits: int = RESOLUTION_BITS) -> np.ndarray:
    """Variance per DFT line of the quantisation error of an ideal ``bits``-bit record.

    Parameters
    ----------
    peak : ndarray, shape (p,)
        Full scale of each channel: its largest ``|y|`` in the record.
    samples_per_period : int
        ``N`` (the spectra are the numpy DFT / N of one period).

    Returns
    -------
    ndarray, shape (p,)
        ``q^2 / (12 N)`` with the step ``q = 2 peak / 2^bits``: the variance of ``Y(k)``
        of white quantisation error at every line.

    Notes
    -----
    A noise estimate below this is not measurement noise: no acquisition records a channel
    that finely. It is the residue of noise-free data (a simulation's round-off and
    residual transient), whose inverse would weight the channels and lines at random (the
    simulated SmallSat: 1e-31 to 1e-19 of the signal power across its 39 channels, 5e-5 to
    1e-16 of this floor). The quantisation error of a periodic signal repeats every period,
    so averaging periods does not lower it and their spread does not show it: the floor
    applies to the average as it is (no ``1 / P``).
    """
    q = 2.0 * np.asarray(peak, float) / 2.0 ** int(bits)
    return q ** 2 / (12.0 * int(samples_per_period))


def noise_lines(excited_lines: np.ndarray, step: int, offset: int, n_bins: int,
                sample_rate_hz: float, samples_per_period: int, *,
                mains_zone: float = 3.0) -> np.ndarray:
    """Off-grid bins inside the excited range, away from mains harmonics.

    Parameters
    ----------
    excited_lines : int ndarray
        Excited DFT bins of one period.
    step, offset : int
        Excitation grid ``k = offset (mod step)``; ``step == 1`` leaves no off-grid line.
    n_bins : int
        ``N // 2 + 1``.
    sample_rate_hz : float
    samples_per_period : int
    mains_zone : float
        Bins within this many lines of a 50/60 Hz harmonic are left out (hum).

    Returns
    -------
    int ndarray
        Bins usable as noise lines (empty when there are none).
    """
    exc = np.asarray(excited_lines, int)
    if exc.size == 0 or step <= 1:
        return np.zeros(0, int)
    k = np.arange(max(int(exc.min()), 1), min(int(exc.max()) + 1, n_bins - 1))
    k = k[k % step != offset]
    df = float(sample_rate_hz) / int(samples_per_period)
    f = k * df
    hum = np.zeros(k.size, bool)
    for f_m in MAINS_HZ:
        h = np.round(f / f_m)
        hum |= (h >= 1) & (np.abs(f - h * f_m) <= mains_zone * df)
    return k[~hum]


def noise_from_nonexcited(Y: np.ndarray, bins: np.ndarray, lines: np.ndarray, *,
                          half_width: int = 16) -> np.ndarray:
    """Noise variance of each output at each processed line from the noise lines.

    Parameters
    ----------
    Y : complex ndarray, shape (R, N // 2 + 1, p)
        Output spectra of one (averaged) period per realisation, every bin (numpy DFT / N).
    bins : int ndarray, shape (K,)
        Noise lines (:func:`noise_lines`), ``K >= 1``.
    lines : int ndarray, shape (F0,)
        Processed lines where the variance is wanted.
    half_width : int
        Each noise line's estimate is the median of ``|Y|^2`` over +-``half_width``
        neighbouring noise lines and every realisation, divided by ``ln 2`` (the median of
        an exponential law): robust to the odd hum or distortion line, and smooth.

    Returns
    -------
    ndarray, shape (F0, p)
        Variance of ``Y(k)`` (output units squared), linearly interpolated between noise
        lines and held constant beyond them.
    """
    P2 = np.abs(np.asarray(Y)[:, bins, :]) ** 2                    # (R, K, p)
    K = bins.size
    est = np.empty((K, P2.shape[2]))
    for j in range(K):
        lo, hi = max(j - half_width, 0), min(j + half_width + 1, K)
        est[j] = np.median(P2[:, lo:hi, :].reshape(-1, P2.shape[2]), axis=0)
    est *= _MEDIAN_TO_MEAN
    return np.stack([np.interp(lines, bins, est[:, i]) for i in range(est.shape[1])], axis=1)


def mains_contaminated_lines(Y: np.ndarray, U: np.ndarray, bins: np.ndarray,
                             excited_lines: np.ndarray, step: int, offset: int,
                             sample_rate_hz: float, samples_per_period: int, *,
                             mains_zone: float = 3.0, ratio: float = 30.0,
                             half_width: int = 16) -> tuple[np.ndarray, list[float]]:
    """Lines near a mains harmonic where hum stands out of the noise, in output or drive.

    Parameters
    ----------
    Y, U : complex ndarray, shapes (R, N // 2 + 1, p) and (R, N // 2 + 1, m)
        Output and drive spectra of one period per realisation (every bin).
    bins : int ndarray
        Noise lines away from mains harmonics (:func:`noise_lines`); the reference level.
    excited_lines : int ndarray
    step, offset : int
        Excitation grid (hum is looked for on the off-grid lines of a harmonic's zone).
    sample_rate_hz : float
    samples_per_period : int
    mains_zone : float
        Half-width (lines) of a harmonic's zone.
    ratio : float
        Hum is present when an off-grid line of the zone carries more than ``ratio`` times
        the noise variance there (noise alone exceeds 30x its mean with probability
        ``exp(-30)`` per line).
    half_width : int
        Smoothing of the reference level (:func:`noise_from_nonexcited`).

    Returns
    -------
    lines : int ndarray
        Every bin within ``mains_zone`` of a contaminated harmonic (on or off the grid).
    harmonics_hz : list of float
        The contaminated harmonics.

    Notes
    -----
    Hum is not driven by the force: on the excited lines next to it the output is
    ``G U + hum``, which a model can only explain with a near-undamped pole at the
    harmonic (the automatic pipeline kept such poles at 50.00 Hz and 149.99 Hz, damping
    < 0.01 %, on a simulated Duffing with hum at 3 % of the output RMS), and the
    coefficients absorb the rest. Leaving those few lines out removes the cause.
    """
    exc = np.asarray(excited_lines, int)
    if bins.size == 0 or exc.size == 0 or step <= 1:
        return np.zeros(0, int), []
    N = int(samples_per_period)
    df = float(sample_rate_hz) / N
    k_lo, k_hi = int(exc.min()), int(exc.max())
    zones: list[tuple[float, np.ndarray, np.ndarray]] = []
    for f_m in MAINS_HZ:
        for h in range(1, int(k_hi * df / f_m) + 1):
            f_h = h * f_m
            zone = np.arange(int(np.ceil(f_h / df - mains_zone)),
                             int(np.floor(f_h / df + mains_zone)) + 1)
            zone = zone[(zone >= k_lo) & (zone <= k_hi)]
            off = zone[zone % step != offset]
            if off.size:
                zones.append((float(f_h), zone, off))
    if not zones:
        return np.zeros(0, int), []
    every_off = np.unique(np.concatenate([z[2] for z in zones]))
    # reference noise level at every off-grid zone line, once per signal
    refs = [(np.asarray(X), noise_from_nonexcited(X, bins, every_off, half_width=half_width))
            for X in (Y, U)]
    out: list[np.ndarray] = []
    found: list[float] = []
    for f_h, zone, off in zones:
        pos = np.searchsorted(every_off, off)
        hit = False
        for X, ref in refs:
            pw = np.mean(np.abs(X[:, off, :]) ** 2, axis=0)                    # (z, c)
            hit |= bool(np.any(pw > ratio * np.maximum(ref[pos], np.finfo(float).tiny)))
        if hit:
            out.append(zone)
            found.append(f_h)
    lines = np.unique(np.concatenate(out)) if out else np.zeros(0, int)
    return lines, found


def mains_outlier_lines(Y: np.ndarray, U: np.ndarray, excited_lines: np.ndarray,
                        processed_lines: np.ndarray, sample_rate_hz: float,
                        samples_per_period: int, *, spread: np.ndarray | None = None,
                        mains_zone: float = 3.0, ratio: float = 30.0, half_width: int = 8
                        ) -> tuple[np.ndarray, list[float]]:
    """Mains harmonics that stand out of the outputs' own neighbourhood, where
    :func:`mains_contaminated_lines` has no off-grid line to look at.

    Two places: the excited lines of a full multisine (every line excited), and processed
    lines beyond the excitation's range. On an excited line the output's ratio to the drive
    ``Y / U`` (one input; several: ``Y`` over the drive's RMS on that line) is compared with
    the mean of its two neighbours; the harmonic is contaminated when that jump exceeds
    ``ratio`` times its median over the excited lines on a line of its zone. On processed
    lines that are not excited, ``|Y|^2`` is compared with the median over the
    ``half_width`` lines on each side of the zone. With several periods, a zone line whose
    period-to-period variance exceeds ``ratio`` times that median on the neighbouring
    lines is hum too: mains that is not synchronous with the record drifts in phase from
    period to period, so the average smears it over the zone (no jump) and the spread
    shows it.

    Parameters
    ----------
    Y, U : complex ndarray, shapes (R, N // 2 + 1, p) and (R, N // 2 + 1, m)
        Output and drive spectra of one period per realisation (every bin).
    excited_lines, processed_lines : int ndarray
        DFT bins excited by the multisine, and kept for the fit.
    sample_rate_hz : float
    samples_per_period : int
    spread : ndarray, shape (N // 2 + 1, p), optional
        Variance of the period average per line and output (from the period-to-period
        spread, unsmoothed; ``P >= 2``).
    mains_zone : float
        Smallest half-width (lines) of a harmonic's zone, widened to +-0.5 % of the
        harmonic's frequency (every line of the zone is tested and returned).
    ratio : float
        Outlier threshold (above).
    half_width : int
        Neighbours of a non-excited line.

    Returns
    -------
    lines : int ndarray
        Every bin within ``mains_zone`` of a contaminated harmonic.
    harmonics_hz : list of float

    Notes
    -----
    3-DOF chain with a stop, full multisine 5-60 Hz processed 3-150 Hz, 8 periods, pink
    noise 60 dB and hum at 3 % of each channel's RMS (50 Hz on an excited line, 150 Hz
    beyond the excitation): undetected, the contact stiffnesses came out -9 % / +32 %;
    without the lines around 50 and 150 Hz -0.02 % / -0.06 %. At 50 Hz the jump was 54-290
    times its median on the three outputs, the largest of any excited line; a resonance or
    antiresonance exactly on a harmonic can also exceed the threshold, which costs the few
    lines of that zone.
    """
    exc = np.asarray(excited_lines, int)
    kept = np.asarray(processed_lines, int)
    if exc.size < 3 or kept.size == 0:
        return np.zeros(0, int), []
    N = int(samples_per_period)
    df = float(sample_rate_hz) / N
    n_bins = Y.shape[1]
    full = np.isin(np.arange(exc.min(), exc.max() + 1), exc).all()
    drive = U[..., 0] if U.shape[2] == 1 else np.sqrt(np.sum(np.abs(U) ** 2, axis=2))
    inner = exc[(exc > 0) & (exc < n_bins - 1)]
    inner = inner[np.isin(inner - 1, exc) & np.isin(inner + 1, exc)]
    tiny = np.finfo(float).tiny
    jump = None
    if full and inner.size:
        H = Y / np.where(np.abs(drive) > 0, drive, np.inf)[..., None]        # (R, bins, p)
        dev = np.abs(H[:, inner] - 0.5 * (H[:, inner - 1] + H[:, inner + 1]))
        scale = 0.5 * (np.abs(H[:, inner - 1]) + np.abs(H[:, inner + 1]))
        rel = dev / np.maximum(scale, tiny)                                 # (R, n, p)
        jump = rel / np.maximum(np.median(rel, axis=(0, 1)), tiny)
    power = np.mean(np.abs(Y) ** 2, axis=0)                                 # (bins, p)
    out: list[np.ndarray] = []
    found: list[float] = []
    for f_m in MAINS_HZ:
        for h in range(1, int(kept.max() * df / f_m) + 1):
            f_h = h * f_m
            # the mains frequency wanders by up to +-0.5 %: at the higher harmonics that is
            # more lines than the zone
            half = max(mains_zone, 0.005 * f_h / df)
            zone = np.arange(int(np.ceil(f_h / df - half)), int(np.floor(f_h / df + half)) + 1)
            zone = zone[(zone > 0) & (zone < n_bins - 1)]
            at = zone[np.isin(zone, inner)] if jump is not None else zone[:0]
            hit = (jump is not None and bool(at.size)
                   and bool(np.any(jump[:, np.searchsorted(inner, at)] > ratio)))
            beyond = zone[np.isin(zone, kept) & ~np.isin(zone, exc)
                          & ((zone < exc.min()) | (zone > exc.max()))]
            side = np.r_[max(zone[0] - half_width, 1):zone[0],
                         zone[-1] + 1:min(zone[-1] + half_width + 1, n_bins)]
            if not hit and beyond.size:
                near = side[~np.isin(side, exc)]
                if near.size:
                    ref = np.maximum(np.median(power[near], axis=0), tiny)
                    hit = bool(np.any(power[beyond] > ratio * ref))
            tested = np.union1d(at, beyond)
            if not hit and spread is not None and tested.size and side.size:
                ref = np.maximum(np.median(spread[side], axis=0), tiny)
                hit = bool(np.any(spread[tested] > ratio * ref))
            if hit:
                out.append(zone)
                found.append(float(f_h))
    lines = np.unique(np.concatenate(out)) if out else np.zeros(0, int)
    return lines, found
