"""The distortion tests of a periodic record: windows of lines whose power is compared with
the noise (Fisher's F law, or chi-squared against the resolution floor), on the detection
lines (fast method) and on the realisations' spread of the excited lines (robust method).
The decision rule is stated in :mod:`ident.core.distortion`.

Pure numpy/scipy; shapes as in each function's docstring.
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["detection_windows", "realisation_windows", "DEFAULT_ALPHA", "WINDOW_LINES"]

#: Family-wise false-alarm probability per record: a linear record gets a "nonlinear"
#: verdict on any output with at most this probability.
DEFAULT_ALPHA = 0.01
#: Lines (per realisation) pooled in one test window: 8 lines, 16 degrees of freedom per
#: realisation, detect a distortion at the noise level with p ~ 1e-4 while localising it.
WINDOW_LINES = 8


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
