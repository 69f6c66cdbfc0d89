"""The best linear approximation (BLA) of a periodic multisine record and the lines it is
read on (Pintelon and Schoukens, *System Identification: a frequency domain approach*, 2nd
ed., ch. 3-4): the analysed band split into excited and detection lines, the period average
with the variance of that average, and the BLA with its noise and total variances.

Pure numpy. Spectra ``(R, P, n_bins, channels)`` with ``n_bins = N // 2 + 1`` (numpy DFT
divided by N); per-line results ``(n_lines, n_outputs)``. Used by
:func:`ident.core.distortion.analyse_arrays`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.excitation import MAINS_HZ

__all__ = ["LineSets", "line_sets", "period_statistics", "best_linear_approximation"]


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
