"""Periodicity and clock check: does the drive's clock match the acquisition's?

A drive played by a generator on its own clock and acquired on another has, in acquisition
samples, a period of ``N (1 + e)`` instead of N, where ``e = fs_acq / fs_drive - 1``. Cut
into N-sample periods, every channel is then delayed by ``N e`` more samples in each period
than in the previous one, so the phase of excited line k turns by ``-2 pi k e`` from period
to period (numpy DFT sign). :func:`check_clock` measures that turn on every excited line
and every channel and fits ``e`` (reported in ppm), with its standard error.

What matters for identification is not ``e`` itself but the frequency offset it gives the
highest excited line, ``k_max |e|`` DFT bins: the lines stop falling on the bins, leak into
their neighbours, and lightly damped modes are smeared. The warning threshold
:data:`MAX_LINE_OFFSET_BINS` was measured on the SmallSat (docs/hardware.md, section
"The clock check, and how much clock mismatch is too much"; ``bench/clock_mismatch.py``).

Pure numpy; shapes follow the project convention, periodic records
``(n_realizations, n_periods, n_samples, n_channels)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

#: Warn when the highest excited line is offset by more than this many DFT bins. The
#: FRF on the excited lines then changes by 0.33 * 0.005 = 0.17 % (measured), the FRF noise
#: of a test at about 48 dB SNR; on the SmallSat, noise-free identification is disturbed
#: from 5-20 ppm (0.002-0.008 bins), at 40 dB SNR from 100 ppm (docs/hardware.md).
MAX_LINE_OFFSET_BINS = 0.005
#: ... and only when the offset is this many standard errors away from zero.
MIN_SIGNIFICANCE = 5.0
#: Below this phase coherence of the fit (weighted mean resultant length of the residual
#: phases: 1 = every line turns as fitted, ~0 = random phases) the data carry no usable
#: period-to-period phase (noise only, or not periodic) and the check is not measurable.
MIN_COHERENCE = 0.5


@dataclass(frozen=True)
class ClockCheck:
    """Result of :func:`check_clock`.

    Attributes
    ----------
    offset_ppm : float
        Estimated ``(fs_acq / fs_drive - 1) * 1e6``: positive when the acquisition clock runs
        fast relative to the drive (a drive period spans more than N samples). NaN when it
        cannot be measured (fewer than two periods, no excited line, no signal).
    uncertainty_ppm : float
        Standard error of ``offset_ppm``.
    line_offset_bins : float
        ``k_max * |offset|``: frequency offset of the highest excited line, in DFT bins.
    limit_ppm : float
        The offset at which the warning starts for this experiment
        (``MAX_LINE_OFFSET_BINS / k_max``).
    warning : bool
        True when the mismatch matters for identification (and is significant).
    n_periods : int
        Periods used, summed over realizations.
    coherence : float
        Weighted mean resultant length of the residual line phases (1: every line turns
        exactly as fitted); below :data:`MIN_COHERENCE` the offset is not reported.
    """

    offset_ppm: float
    uncertainty_ppm: float
    line_offset_bins: float
    limit_ppm: float
    warning: bool
    n_periods: int
    coherence: float = float("nan")

    @property
    def message(self) -> str:
        """One line for status displays and ``fnsi-lab info``."""
        if not np.isfinite(self.offset_ppm):
            return ("clock check: not measurable (needs 2 periods, excited lines and a "
                    "coherent phase turn)")
        text = (f"clock check: drive vs acquisition {self.offset_ppm:+.2f} ± "
                f"{self.uncertainty_ppm:.2f} ppm (highest line off by "
                f"{self.line_offset_bins:.4f} bins; limit {self.limit_ppm:.1f} ppm)")
        if self.warning:
            text += (" WARNING: the drive and acquisition clocks differ enough to smear the "
                     "lines; clock the generator from the DAQ (docs/hardware.md)")
        return text

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (not measurable: null offsets)."""
        from fnsi_lab.outputs import json_safe

        return json_safe({"offset_ppm": self.offset_ppm, "uncertainty_ppm": self.uncertainty_ppm,
                "line_offset_bins": self.line_offset_bins, "limit_ppm": self.limit_ppm,
                "warning": self.warning, "n_periods": self.n_periods,
                "coherence": self.coherence, "message": self.message})


def _line_cross_spectra(x: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Sum over realizations and consecutive periods of ``X_{p+1} conj(X_p)``, (n_lines, C)."""
    spec = np.fft.rfft(x, axis=2)[:, :, lines, :]  # (R, P, K, C)
    return np.sum(spec[:, 1:] * np.conj(spec[:, :-1]), axis=(0, 1))


def _fit_slope(theta: np.ndarray, k: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Weighted least squares of ``theta = -2 pi k e`` (through 0): (e, standard error)."""
    sw = float(np.sum(w))
    skk = float(np.sum(w * k * k))
    e = -float(np.sum(w * k * theta)) / (2 * np.pi * skk)
    resid = theta + 2 * np.pi * k * e
    n_eff = sw * sw / float(np.sum(w * w))
    var_theta = float(np.sum(w * resid ** 2)) / sw * n_eff / max(n_eff - 1.0, 1.0)
    # var(e) of a weighted fit: var_theta * sum(w^2 k^2) / (2 pi sum(w k^2))^2
    se = np.sqrt(var_theta * float(np.sum(w * w * k * k))) / (2 * np.pi * skk)
    return e, float(se)


def check_clock(periods: np.ndarray, excited_lines: Sequence[int], *,
                transient_periods: int = 0,
                max_line_offset_bins: float = MAX_LINE_OFFSET_BINS) -> ClockCheck:
    """Measure the drive/acquisition clock mismatch of a periodic record.

    Parameters
    ----------
    periods : ndarray, shape (n_realizations, n_periods, N, n_channels) or (n_periods, N, n_channels)
        Samples cut into N-sample periods (any channels: forces and responses).
    excited_lines : sequence of int
        DFT bins of one period that carry the excitation.
    transient_periods : int, optional
        Leading periods of each realization to skip (not yet in steady state).
    max_line_offset_bins : float, optional
        Warning threshold on ``k_max * |offset|``.

    Returns
    -------
    ClockCheck

    Notes
    -----
    Each channel's line cross-spectra are normalised by their total magnitude, so channels
    in different units weigh the same; each line is then weighted by its coherent
    magnitude. The phase turn is unwrapped with a first estimate from the lowest quarter of
    the lines, which keeps the fit valid up to ``|e| < 2 / k_max`` (about 5000 ppm for
    the SmallSat).
    """
    x = np.asarray(periods, dtype=np.float64)
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4:
        raise ValueError(f"periods must be (R, P, N, C) or (P, N, C), got shape {x.shape}")
    x = x[:, int(transient_periods):]
    lines = np.unique(np.asarray(excited_lines, dtype=np.int64))
    lines = lines[(lines > 0) & (lines <= x.shape[2] // 2)]
    n_used = x.shape[0] * x.shape[1]
    nan = ClockCheck(np.nan, np.nan, np.nan, np.nan, False, n_used)
    if x.shape[1] < 2 or lines.size == 0:
        return nan
    cross = _line_cross_spectra(x, lines)  # (K, C)
    norm = np.sum(np.abs(cross), axis=0)
    ok = np.isfinite(norm) & (norm > 0)
    if not np.any(ok):
        return nan
    combined = np.sum(cross[:, ok] / norm[ok], axis=1)
    w = np.abs(combined)
    if not np.sum(w) > 0:
        return nan
    k = lines.astype(np.float64)
    theta = np.angle(combined)
    # first estimate on the lowest lines (where the turn cannot wrap), then unwrap the rest
    low = k <= k[0] + 0.25 * (k[-1] - k[0]) if lines.size >= 8 else np.ones(k.size, bool)
    e0, _ = _fit_slope(theta[low], k[low], w[low])
    resid = np.angle(np.exp(1j * (theta + 2 * np.pi * k * e0)))
    de, se = _fit_slope(resid, k, w)
    e = e0 + de
    final = np.angle(np.exp(1j * (theta + 2 * np.pi * k * e)))
    coherence = float(np.abs(np.sum(w * np.exp(1j * final))) / np.sum(w))
    if coherence < MIN_COHERENCE:  # phases do not follow any turn: noise, or not periodic
        return ClockCheck(np.nan, np.nan, np.nan, np.nan, False, n_used, coherence)
    k_max = float(k[-1])
    line_offset = k_max * abs(e)
    limit_ppm = max_line_offset_bins / k_max * 1e6
    warning = bool(line_offset > max_line_offset_bins and abs(e) > MIN_SIGNIFICANCE * se)
    return ClockCheck(offset_ppm=e * 1e6, uncertainty_ppm=se * 1e6, line_offset_bins=line_offset,
                      limit_ppm=limit_ppm, warning=warning, n_periods=n_used,
                      coherence=coherence)


def check_record_clock(record: Any) -> ClockCheck:
    """:func:`check_clock` on a :class:`daq.recording.reader.PeriodicRecord` (u and y).

    The steady periods are used; when fewer than two are steady (the SmallSat default: 6
    periods, 5 transient), the last two. A decaying transient biases the estimate little:
    after 4 of the SmallSat's periods the matched-clock estimate is 4e-5 ppm (1e-4 ppm
    after 2), far below any warning limit.
    """
    x = np.concatenate([np.asarray(record.u), np.asarray(record.y)], axis=-1)
    skip = max(min(int(record.transient_periods or 0), x.shape[1] - 2), 0)
    return check_clock(x, record.excited_lines, transient_periods=skip)
