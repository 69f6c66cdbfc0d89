"""The processed lines: the band, the excited lines, mains hum left out, and where ``z`` sits.

:func:`band_lines` (the DFT bins of the processed band, DC and Nyquist excluded),
:func:`excitation_grid` (the excited lines: given, or detected from the drive by
:mod:`ident.core.excitation`), :func:`drop_mains_lines` (lines next to mains hum left out,
:mod:`ident.core.noise`) and :func:`line_map` (the time base and ``z_k`` of each line,
docs/method.md §1.5-1.6). Steps of :func:`ident.core.periodic.prepare_frequency_data`.
"""

from __future__ import annotations

from typing import Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.excitation import ExcitationGrid, best_grid, detect_excited_lines
from fnsi_lab.ident.core.frequency_data import TimeBase
from fnsi_lab.ident.core.noise import mains_contaminated_lines, mains_outlier_lines, noise_lines
from fnsi_lab.ident.errors import IdentError


def band_lines(band_hz: tuple[float, float], sample_rate_hz: float,
               samples_per_period: int) -> tuple[np.ndarray, float, float]:
    """DFT bins of one period inside the processed band.

    Parameters
    ----------
    band_hz : (float, float)
        ``[f_min, f_max]`` (Hz).
    sample_rate_hz : float
    samples_per_period : int
        ``N``.

    Returns
    -------
    lines : int ndarray, shape (F0,)
        Bins ``k`` with ``f_min <= k fs / N <= f_max``; DC and Nyquist excluded.
    f_min, f_max : float

    Raises
    ------
    IdentError
        A band that is not ``0 <= f_min < f_max``, or no line inside it.
    """
    fs, N = sample_rate_hz, samples_per_period
    f_min, f_max = (float(b) for b in band_hz)
    if not 0 <= f_min < f_max:
        raise IdentError(f"band_hz must be [f_min, f_max] with 0 <= f_min < f_max, got {plain.value(band_hz)}")
    k_all = np.arange(N // 2 + 1)
    f_all = k_all * fs / N
    sel = (f_all >= f_min) & (f_all <= f_max) & (k_all > 0)
    if N % 2 == 0:
        sel &= k_all < N // 2
    K = k_all[sel]
    if K.size == 0:
        raise IdentError(f"no DFT line in band {plain.band_hz(band_hz)} (fs={fs:g} Hz, N={N})")
    return K, f_min, f_max


def excitation_grid(excited_lines: Sequence[int] | np.ndarray | None, u_avg: np.ndarray,
                    sample_rate_hz: float, threshold: float) -> ExcitationGrid:
    """The excited lines: given (recording metadata, a user's file) or detected from the drive.

    Parameters
    ----------
    excited_lines : sequence of int or None
        DFT bins of one period; None or empty: detected.
    u_avg : ndarray, shape (R, N, m)
        The averaged forces.
    sample_rate_hz : float
    threshold : float
        ``threshold`` of :func:`ident.core.excitation.detect_excited_lines`.

    Returns
    -------
    ExcitationGrid
    """
    if excited_lines is not None and len(excited_lines):
        given = np.unique(np.asarray(excited_lines, int))
        step, offset = best_grid(given, 0.9, 8) if given.size else (1, 0)
        return ExcitationGrid(lines=given, step=step, offset=offset,
                              n_candidates=int(given.size), source="given")
    N = u_avg.shape[1]
    pw_all = np.mean(np.sum(np.abs(np.fft.rfft(u_avg, axis=1)) ** 2, axis=2), axis=0)
    return detect_excited_lines(pw_all, sample_rate_hz, N, threshold=threshold)


def drop_mains_lines(Y_all: np.ndarray, U_all: np.ndarray, Yq_all: np.ndarray | None,
                     grid: ExcitationGrid, lines: np.ndarray, sample_rate_hz: float,
                     samples_per_period: int) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """The processed lines without those where mains hum stands out of the noise.

    Parameters
    ----------
    Y_all, U_all : complex ndarray, shapes (R, N // 2 + 1, p) and (R, N // 2 + 1, m)
        Spectra of the averages on every bin (numpy DFT divided by ``N``).
    Yq_all : complex ndarray, shape (R, P, N // 2 + 1, p) or None
        Spectra of every period (hum drifting between periods), when ``P >= 2``.
    grid : ExcitationGrid
    lines : int ndarray, shape (F0,)
        The processed bins.
    sample_rate_hz : float
    samples_per_period : int

    Returns
    -------
    lines : int ndarray
        ``lines`` without the hum lines.
    hum_lines : int ndarray
        The bins left out (:func:`ident.core.noise.mains_contaminated_lines`, then
        :func:`ident.core.noise.mains_outlier_lines`).
    hum_hz : list of float
        The mains harmonics they belong to.

    Raises
    ------
    IdentError
        Every processed line is next to mains hum.
    """
    fs, N, K = sample_rate_hz, samples_per_period, lines
    bins = noise_lines(grid.lines, grid.step, grid.offset, N // 2 + 1, fs, N)
    hum_lines, hum_hz = mains_contaminated_lines(Y_all, U_all, bins, grid.lines, grid.step,
                                                 grid.offset, fs, N)
    # full multisines and lines beyond the excitation: no off-grid line to look at
    spread = None
    if Yq_all is not None:   # variance of the average per line: hum drifting between periods
        P = Yq_all.shape[1]
        spread = np.mean(np.sum(np.abs(Yq_all - Y_all[:, None]) ** 2, axis=1), axis=0) \
            / (P * (P - 1))
    more_lines, more_hz = mains_outlier_lines(Y_all, U_all, grid.lines, K, fs, N,
                                              spread=spread)
    hum_lines = np.union1d(hum_lines, more_lines).astype(int)
    hum_hz = sorted(set(hum_hz) | set(more_hz))
    if hum_lines.size:
        K = K[~np.isin(K, hum_lines)]
        if K.size == 0:
            raise IdentError("every processed line is next to mains hum (drop_mains: false)")
    return K, hum_lines, hum_hz


def line_map(lines: np.ndarray, sample_rate_hz: float, samples_per_period: int,
             time_base: Literal["auto", "band-limited", "zoh", "bilinear"],
             output_quantity: str, bilinear_period_s: float | None
             ) -> tuple[TimeBase, np.ndarray, float | None]:
    """How the discrete-time model is read at the lines, and ``z_k`` of each line.

    Parameters
    ----------
    lines : int ndarray, shape (F,)
        DFT bins (realisations stacked).
    sample_rate_hz : float
    samples_per_period : int
    time_base : {'auto', 'band-limited', 'zoh', 'bilinear'}
        As in :func:`ident.core.periodic.prepare_frequency_data` (``'auto'``:
        ``'band-limited'`` for displacement outputs, else ``'bilinear'``).
    output_quantity : str
    bilinear_period_s : float or None
        ``T`` of the bilinear map; default ``2 / sqrt(w_min w_max)`` over the lines.

    Returns
    -------
    time_base : {'band-limited', 'zoh', 'bilinear'}
    z : complex ndarray, shape (F,)
        ``exp(j 2 pi k / N)``, or ``exp(j 2 atan(w_k T / 2))`` for ``'bilinear'``.
    bilinear_period_s : float or None
        ``T`` (``'bilinear'`` only).

    Raises
    ------
    IdentError
        Unknown ``time_base``.
    """
    fs, N = sample_rate_hz, samples_per_period
    if time_base == "auto":
        time_base = "band-limited" if output_quantity == "displacement" else "bilinear"
    if time_base in ("band-limited", "zoh"):
        z = np.exp(2j * np.pi * lines / N)
        T_bl = None
    elif time_base == "bilinear":
        w_lines = 2 * np.pi * lines * fs / N
        T_bl = (float(bilinear_period_s) if bilinear_period_s
                else 2.0 / np.sqrt(w_lines.min() * w_lines.max()))
        z = np.exp(2j * np.arctan(w_lines * T_bl / 2))
    else:
        raise IdentError(f"time_base {time_base!r} is not one of "
                         "['band-limited', 'zoh', 'bilinear']")
    return time_base, z, T_bl
