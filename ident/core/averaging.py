"""Periods: records cut into periods, their steady state, and the noise of their average.

:func:`as_periodic` and :func:`cut_realizations` (records -> ``(R, P, N, channels)``),
:func:`steady_state_error` (period-to-period difference of the kept outputs),
:func:`output_noise` (the noise of the averaged output spectrum per line: from the
period-to-period spread when ``P >= 2``, else from the off-grid lines of a sparse multisine,
:mod:`ident.core.noise`), :func:`floor_noise` (that estimate held at the record resolution)
and :func:`smooth_lines` (a noise spectrum averaged over neighbouring lines). Steps of
:func:`ident.core.periodic.prepare_frequency_data` (docs/method.md §1.2).
"""

from __future__ import annotations

import warnings
from typing import Any, Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.excitation import ExcitationGrid
from fnsi_lab.ident.core.noise import noise_from_nonexcited, noise_lines
from fnsi_lab.ident.errors import IdentError, IdentWarning

#: Above this size the noise covariance keeps only its diagonal when ``P - 1 < 2 p`` (then
#: the weighting uses the variances anyway, ident.core.weights.inverse_covariance).
FULL_COV_MAX_BYTES = 256 * 2 ** 20


def as_periodic(x: Any, samples_per_period: int | None, name: str) -> np.ndarray:
    """Promote a signal to ``(n_realizations, n_periods, n_samples, n_channels)``.

    ``(n_samples,)`` and ``(n_samples, n_channels)`` are cut into periods of
    ``samples_per_period`` (default: one period); 3-D arrays are one realization.
    """
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim == 2:
        n_samples = arr.shape[0]
        N = int(samples_per_period or n_samples)
        if N <= 0 or n_samples % N:
            raise IdentError(f"{name}: {n_samples} samples is not a whole number of periods of "
                             f"{N} samples (fix samples_per_period)")
        arr = arr.reshape(n_samples // N, N, arr.shape[1])
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4:
        raise IdentError(f"{name}: expected 1-4 dimensions (realizations, periods, samples, "
                         f"channels), got shape {np.shape(x)}")
    if samples_per_period and arr.shape[2] != samples_per_period:
        raise IdentError(f"{name}: period length {arr.shape[2]} != samples_per_period "
                         f"{samples_per_period}")
    if not np.all(np.isfinite(arr)):
        raise IdentError(f"{name}: contains NaN or infinite samples")
    return arr


def cut_realizations(x: np.ndarray, starts: Sequence[int] | np.ndarray,
                     samples_per_period: int, *, transient_samples: int = 0, periods: int | None = None) -> np.ndarray:
    """Cut a long record with several realisations into ``(R, P, N, channels)``.

    Lab multisine tests often record every realisation in one file: realisation ``r``
    starts at sample ``starts[r]`` (a new phase draw, often after a pause), its first
    ``transient_samples`` samples are the switch-on transient, then come whole periods.

    Parameters
    ----------
    x : ndarray, shape (n_samples, n_channels) or (n_samples,)
    starts : sequence of int
        First sample of each realisation (0-based, increasing).
    samples_per_period : int
        ``N``.
    transient_samples : int
        Samples dropped after each start.
    periods : int, optional
        Periods kept per realisation; default as many whole periods as fit before the next
        start (the same for every realisation: the smallest).

    Returns
    -------
    ndarray, shape (R, P, N, n_channels)

    Raises
    ------
    IdentError
        Starts not increasing or outside the record, no whole period after a transient.
    """
    arr = np.asarray(x, float)
    if arr.ndim == 1:
        arr = arr[:, None]
    n = arr.shape[0]
    s = [int(v) for v in np.asarray(starts).reshape(-1)]
    N = int(samples_per_period)
    tr = int(transient_samples)
    if not s or any(b <= a for a, b in zip(s, s[1:])) or s[0] < 0 or s[-1] >= n:
        raise IdentError(f"realization_starts {plain.names(s, limit=8)} must be increasing "
                         f"sample indices inside the record of {n} samples")
    if tr < 0 or N < 1:
        raise IdentError("transient_samples must be >= 0 and N >= 1")
    ends = s[1:] + [n]
    fit = min((e - (a + tr)) // N for a, e in zip(s, ends))
    P = fit if periods is None else int(periods)
    if P < 1 or P > fit:
        raise IdentError(f"realization_starts/transient_samples leave {fit} whole period(s) of "
                         f"{N} samples per realisation (asked {P}); fix the starts, "
                         "transient_samples or N")
    return np.stack([arr[a + tr:a + tr + P * N].reshape(P, N, arr.shape[1]) for a in s])


def steady_state_error(Y4: np.ndarray, tolerance: float, periods_statement: str) -> float:
    """Largest relative period-to-period RMS difference of the kept outputs.

    Parameters
    ----------
    Y4 : ndarray, shape (R, P, N, p)
        The periods kept for the average.
    tolerance : float
        Warn when the difference exceeds it.
    periods_statement : str
        Which periods were kept and why (:attr:`ident.core.steady.PeriodSelection.statement`),
        quoted in the warning.

    Returns
    -------
    float
        0 with one period.

    Warns
    -----
    IdentWarning
        The outputs may not be in periodic steady state (difference above ``tolerance``).
    """
    ss_err = 0.0
    if Y4.shape[1] >= 2:
        diff = np.sqrt(np.mean((Y4[:, 1:] - Y4[:, :-1]) ** 2, axis=(2, 3)))
        ref = np.sqrt(np.mean(Y4 ** 2, axis=(1, 2, 3)))[:, None]
        ss_err = float(np.max(diff / np.where(ref > 0, ref, 1.0)))
        if ss_err > tolerance:
            warnings.warn(f"outputs may not be in periodic steady state: relative "
                          f"period-to-period RMS difference {ss_err:.3g} > "
                          f"{tolerance:g} over the periods used ("
                          f"{periods_statement})", IdentWarning, stacklevel=3)
    return ss_err


def output_noise(Yq_all: np.ndarray | None, y_avg: np.ndarray, Yf: np.ndarray,
                 lines: np.ndarray, grid: ExcitationGrid, n_periods: int,
                 noise_estimate: Literal["auto", "periods", "lines", "none"],
                 sample_rate_hz: float) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Noise of the averaged output spectrum on the processed lines (docs/method.md §1.2).

    Parameters
    ----------
    Yq_all : complex ndarray, shape (R, P, N // 2 + 1, p) or None
        Spectrum of every kept period (numpy DFT divided by ``N``); None when the periods
        give no noise estimate (one period, or ``noise_estimate`` 'lines' or 'none').
    y_avg : ndarray, shape (R, N, p)
        The averaged outputs.
    Yf : complex ndarray, shape (R, F0, p)
        Spectrum of the averages on the processed lines.
    lines : int ndarray, shape (F0,)
        The processed DFT bins.
    grid : ExcitationGrid
        The excited lines (the off-grid lines are the noise lines of a sparse multisine).
    n_periods : int
        ``P``, the periods averaged.
    noise_estimate : {'auto', 'periods', 'lines', 'none'}
        As in :func:`ident.core.periodic.prepare_frequency_data`.
    sample_rate_hz : float

    Returns
    -------
    noise : complex ndarray, shape (R F0, p, p), real ndarray, shape (R F0, p), or None
        The covariance of the average per line (the periods' spread; only the variances
        when the full matrices would exceed :data:`FULL_COV_MAX_BYTES` and ``P - 1 < 2 p``),
        or the off-grid lines' variances as a diagonal with ``'lines'``.
    noise_var : ndarray, shape (R F0, p) or None
        The variances, whatever their source.
    noise_source : {'periods', 'non-excited lines', 'none'}

    Raises
    ------
    IdentError
        Unknown ``noise_estimate``, or ``'periods'`` with fewer than 2 periods.
    """
    R, N, p = y_avg.shape
    K = lines
    fs = sample_rate_hz
    noise: np.ndarray | None = None
    noise_source = "none"
    if noise_estimate not in ("auto", "periods", "lines", "none"):
        raise IdentError(f"noise_estimate {noise_estimate!r} is not one of "
                         "auto, periods, lines, none")
    P = n_periods
    if P >= 2 and noise_estimate in ("auto", "periods"):
        if Yq_all is None:   # computed above whenever the periods give the noise
            raise IdentError("the per-period spectra for the noise estimate are missing")
        Yq = Yq_all[:, :, K]  # (R, P, F0, p)
        dev = Yq - Yf[:, None]
        if P - 1 < 2 * p and R * K.size * p * p * 16 > FULL_COV_MAX_BYTES:
            noise = (np.sum(np.abs(dev) ** 2, axis=1) / (P * (P - 1))).reshape(-1, p)
        else:
            noise = np.einsum("rqki,rqkj->rkij", dev, dev.conj()) / (P * (P - 1))
            noise = noise.reshape(-1, p, p)
        noise_source = "periods"
    noise_var = (None if noise is None else noise if noise.ndim == 2
                 else np.real(np.einsum("kii->ki", noise)))
    if noise is None and noise_estimate in ("auto", "lines"):
        bins = noise_lines(grid.lines, grid.step, grid.offset, N // 2 + 1, fs, N)
        if bins.size:
            var = noise_from_nonexcited(np.fft.rfft(y_avg, axis=1) / N, bins, K)  # (F0, p)
            noise_var = np.tile(var, (R, 1))
            noise_source = "non-excited lines"
            if noise_estimate == "lines":
                noise = np.einsum("ki,ij->kij", noise_var, np.eye(p)).astype(complex)
    if noise_estimate == "periods" and noise is None:
        raise IdentError("noise_estimate 'periods' needs at least 2 steady-state periods")
    return noise, noise_var, noise_source


def floor_noise(noise: np.ndarray | None, noise_var: np.ndarray, floor: np.ndarray):
    """Noise estimates held at the record resolution; None to weight with if nothing is above.

    Parameters
    ----------
    noise : complex ndarray, shape (F, p, p), real ndarray, shape (F, p), or None
        The covariance the fit would be weighted with.
    noise_var : ndarray, shape (F, p)
        The variances (the same estimate, or the off-grid lines' one).
    floor : ndarray, shape (p,)
        :func:`ident.core.noise.resolution_variance` of each output.

    Returns
    -------
    noise : same as ``noise``, or None
        Unchanged on the outputs whose mean variance over the lines is above their floor;
        on the others the variances are raised to the floor (per line). None when no output
        is above it: the estimate then measured no noise, only the residue of noise-free
        data (round-off, residual transient), and weighting by its inverse weighted the
        channels and lines at random: the simulated SmallSat with 2-8 noise-free periods
        lost 2 of 10 modes and its NC2-Z stiffness moved from -0.001 % to +0.09 %
        (bench/RESULTS.md, Scaling). Weighting with the floor alone would not be neutral
        either (the weighted SVD whitens through ``C_Y``): with it the same data gave
        7 modes and -0.06 %.
    noise_var : ndarray, shape (F, p)
        Raised to the floor on the unresolved outputs.
    resolved : bool ndarray, shape (p,)
    """
    floor = np.asarray(floor, float)
    resolved = np.mean(noise_var, axis=0) > floor
    if resolved.all():
        return noise, noise_var, resolved
    low = ~resolved
    noise_var = np.array(noise_var, float)  # never the caller's array
    noise_var[:, low] = np.maximum(noise_var[:, low], floor[low])
    if noise is None or not resolved.any():
        return None, noise_var, resolved
    noise = np.array(noise)
    if noise.ndim == 2:
        noise[:, low] = noise_var[:, low]
    else:
        idx = np.flatnonzero(low)
        noise[:, idx, idx] = noise_var[:, idx]
    return noise, noise_var, resolved


def smooth_lines(x: np.ndarray, half_width: int) -> np.ndarray:
    """Moving average over +-``half_width`` neighbouring lines (axis 0), shortened at the ends.

    A noise spectrum estimated from ``P`` periods has ``P - 1`` degrees of freedom per line;
    averaging neighbours assumes the noise spectrum is smooth, which sensor noise is.

    Parameters
    ----------
    x : ndarray, shape (n_lines, ...)
    half_width : int

    Returns
    -------
    ndarray, same shape as ``x``
    """
    if half_width <= 0:
        return x
    k = np.arange(x.shape[0])
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:], x.dtype), x]), axis=0)
    lo = np.maximum(k - half_width, 0)
    hi = np.minimum(k + half_width + 1, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))
