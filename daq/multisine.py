"""Periodic multisine excitation: flat amplitude on the DFT lines of one period in a band.

Pure numpy. Axis order: ``(n_realizations, n_samples)`` for the time signal, samples of
consecutive periods concatenated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError


@dataclass(frozen=True)
class Multisine:
    """A generated multisine.

    Attributes
    ----------
    signal : ndarray, shape (n_realizations, n_periods * samples_per_period)
        Force time series, each realization ``n_periods`` identical periods long.
    excited_lines : ndarray of int, shape (n_excited,)
        DFT bin indices k (frequency ``k * sample_rate_hz / samples_per_period``) that carry
        energy, the same for every realization.
    phases_rad : ndarray, shape (n_realizations, n_excited)
        Phase of each excited line.
    sample_rate_hz, samples_per_period, n_periods, rms, band_hz, seed
        The definition, as requested.
    """

    signal: np.ndarray
    excited_lines: np.ndarray
    phases_rad: np.ndarray
    sample_rate_hz: float
    samples_per_period: int
    n_periods: int
    rms: float
    band_hz: tuple[float, float]
    seed: int | None

    @property
    def n_realizations(self) -> int:
        """Number of realizations R."""
        return int(self.signal.shape[0])

    @property
    def excited_frequencies_hz(self) -> np.ndarray:
        """Frequencies of the excited lines."""
        return self.excited_lines * self.sample_rate_hz / self.samples_per_period

    def period(self, realization: int = 0) -> np.ndarray:
        """One period of one realization, shape (samples_per_period,)."""
        return self.signal[realization, : self.samples_per_period]

    @property
    def line_amplitude(self) -> float:
        """Cosine amplitude of every excited line: ``rms * sqrt(2 / n_excited)``."""
        return self.rms * float(np.sqrt(2.0 / self.excited_lines.size))

    def at(self, positions: np.ndarray, realization: int = 0, chunk: int = 4096) -> np.ndarray:
        """Evaluate the multisine between its samples.

        Parameters
        ----------
        positions : ndarray, shape (n,)
            Fractional sample indices (``t * sample_rate_hz``).
        realization : int
        chunk : int
            Positions evaluated at once (memory: ``chunk * n_excited`` values).

        Returns
        -------
        ndarray, shape (n,)
            ``sum_k a cos(2 pi k t / N + phi_k)``; equals :attr:`signal` at integer
            positions (to rounding).
        """
        n = self.samples_per_period
        lines = self.excited_lines.astype(np.float64)
        phase = self.phases_rad[realization]
        pos = np.asarray(positions, dtype=np.float64)
        out = np.empty(pos.size)
        for start in range(0, pos.size, chunk):
            t = np.mod(pos[start:start + chunk], n)  # small cosine arguments stay accurate
            out[start:start + chunk] = self.line_amplitude * np.cos(
                2 * np.pi * np.outer(t, lines) / n + phase).sum(axis=1)
        return out


def excited_lines(samples_per_period: int, sample_rate_hz: float,
                  band_hz: tuple[float, float]) -> np.ndarray:
    """DFT bins k with ``f1 <= k fs / N <= f2``, DC and Nyquist excluded.

    Returns
    -------
    ndarray of int, shape (n_excited,)
    """
    n = int(samples_per_period)
    k = np.arange(1, (n - 1) // 2 + 1)  # strictly below Nyquist
    f = k * sample_rate_hz / n
    tol = 1e-9 * sample_rate_hz / n  # band edges given on a line must count as inside
    return k[(f >= band_hz[0] - tol) & (f <= band_hz[1] + tol)]


def random_odd_lines(band_lines: np.ndarray, detection_block: int = 4,
                     seed: int | None = 0) -> np.ndarray:
    """The excited lines of a random-odd multisine.

    Parameters
    ----------
    band_lines : int ndarray, shape (n,)
        DFT bins of the band (:func:`excited_lines`).
    detection_block : int
        The odd bins are cut into consecutive blocks of this many (>= 2); one bin of every
        complete block is left out, chosen at random (an incomplete last block is kept
        whole). Two detection lines are never neighbours: the excited grid then has no gap
        wider than two odd steps, which the line detection from a measured drive
        (:func:`ident.core.excitation.detect_excited_lines`) bridges.
    seed : int or None
        The choice is drawn from ``default_rng([seed, 1])`` (None: unpredictable), a stream
        of its own (the phase draw of ``seed`` is not shifted by it).

    Returns
    -------
    int ndarray
        Excited bins, increasing: odd, without the detection lines.
    """
    block = int(detection_block)
    if block < 2:
        raise ConfigError(f"detection_block must be >= 2 odd lines, got {detection_block}")
    odd = np.asarray(band_lines, int)
    odd = odd[odd % 2 == 1]
    n_blocks = odd.size // block
    rng = np.random.default_rng(None if seed is None else [int(seed), 1])
    choice = rng.integers(0, block, size=n_blocks)
    for b in range(1, n_blocks):  # never two detection lines side by side
        if choice[b] == 0 and choice[b - 1] == block - 1:
            choice[b] = 1 + rng.integers(0, block - 1)
    left_out = np.arange(n_blocks) * block + choice
    keep = np.ones(odd.size, bool)
    keep[left_out] = False
    return odd[keep]


def multisine(samples_per_period: int, sample_rate_hz: float, band_hz: tuple[float, float],
              rms: float, *, n_periods: int = 1, n_realizations: int = 1,
              seed: int | None = 0,
              phases: Literal["random", "schroeder"] = "random",
              grid: Literal["full", "odd", "random-odd"] = "full",
              detection_block: int = 4) -> Multisine:
    """Generate a periodic multisine with a flat amplitude spectrum in ``band_hz``.

    Parameters
    ----------
    samples_per_period : int
        N, samples per period.
    sample_rate_hz : float
        Sampling rate fs.
    band_hz : (float, float)
        Excited band [f1, f2]; every DFT line of one period inside it is excited.
    rms : float
        Exact RMS of the signal (unit of the force).
    n_periods : int, optional
        P, identical periods per realization.
    n_realizations : int, optional
        R, independent phase draws (Schroeder phases give identical realizations).
    seed : int or None, optional
        Seed of ``numpy.random.default_rng``: the same seed gives the same signal.
    phases : {'random', 'schroeder'}, optional
        Uniform random phases in [0, 2 pi), or Schroeder's low-crest-factor law
        ``phi_k = -pi k (k - 1) / K``.
    grid : {'full', 'odd', 'random-odd'}, optional
        Excite every line of the band, or only the odd ones (an odd multisine: the even
        lines then show noise and even-order distortion, the lab's usual design), or a
        random-odd multisine (:func:`random_odd_lines`): the odd lines of the band less one
        chosen at random in every block of ``detection_block`` consecutive odd lines. The
        odd lines left out (odd detection lines) then show the odd-order distortion, the even
        lines the even-order one (the fast method of :mod:`ident.core.distortion`).
    detection_block : int, optional
        Odd lines per block of a random-odd grid, one of which is left out (4: a quarter of
        the odd lines are detection lines, Pintelon and Schoukens' usual choice).

    Returns
    -------
    Multisine

    Raises
    ------
    ValueError
        If no line falls in the band or a size is not positive.

    Notes
    -----
    One period is built in the frequency domain, ``X(k) = A exp(j phi_k)`` on the excited
    lines and 0 elsewhere, and transformed with ``numpy.fft.irfft``; the amplitude A is
    then set so that the RMS is exact. Because every frequency is a multiple of
    ``fs / N``, the signal is exactly N-periodic.

    Examples
    --------
    >>> ms = multisine(8192, 1000.0, (5.0, 50.0), 100.0, n_periods=6, seed=1)
    >>> ms.signal.shape, round(float(ms.signal[0].std()), 6)
    ((1, 49152), 100.0)
    """
    n = int(samples_per_period)
    if n < 4 or n_periods < 1 or n_realizations < 1:
        raise ConfigError("samples_per_period >= 4, n_periods >= 1 and n_realizations >= 1 are required")
    if not rms > 0:
        raise ConfigError(f"rms must be > 0, got {rms}")
    if phases not in ("random", "schroeder"):
        raise ConfigError(f"phases must be 'random' or 'schroeder', got {phases!r}")
    if grid not in ("full", "odd", "random-odd"):
        raise ConfigError(f"grid must be 'full', 'odd' or 'random-odd', got {grid!r}")
    lines = excited_lines(n, sample_rate_hz, band_hz)
    if grid == "odd":
        lines = lines[lines % 2 == 1]
    elif grid == "random-odd":
        lines = random_odd_lines(lines, detection_block, seed)
    if lines.size == 0:
        raise ConfigError(f"no DFT line of an {n}-sample period at {sample_rate_hz:g} Hz lies in "
                          f"{plain.band_hz(band_hz)}")
    rng = np.random.default_rng(seed)
    n_lines = lines.size
    if phases == "random":
        phase = rng.uniform(0.0, 2 * np.pi, size=(n_realizations, n_lines))
    else:
        idx = np.arange(1, n_lines + 1)
        phase = np.broadcast_to(-np.pi * idx * (idx - 1) / n_lines, (n_realizations, n_lines)).copy()
    spectrum = np.zeros((n_realizations, n // 2 + 1), dtype=complex)
    spectrum[:, lines] = np.exp(1j * phase)
    one_period = np.fft.irfft(spectrum, n=n, axis=1)
    # Parseval: every excited line of unit amplitude contributes 2/N^2 to the mean square.
    unit_rms = np.sqrt(2.0 * n_lines) / n
    one_period *= rms / unit_rms
    signal = np.tile(one_period, (1, n_periods))
    return Multisine(signal=signal, excited_lines=lines, phases_rad=phase,
                     sample_rate_hz=float(sample_rate_hz), samples_per_period=n,
                     n_periods=int(n_periods), rms=float(rms),
                     band_hz=(float(band_hz[0]), float(band_hz[1])), seed=seed)


@dataclass(frozen=True)
class ExcitationConfig:
    """A periodic multisine (see :func:`daq.multisine.multisine`).

    Attributes
    ----------
    band_hz : (float, float)
        Excited band [f1, f2] in Hz; every DFT line of one period inside it is excited.
    rms : float
        RMS of the force, in the unit of the force channel.
    samples_per_period : int
        N, samples per period.
    periods : int
        P, periods per realization, transient ones included.
    transient_periods : int
        Leading periods that identification drops.
    realizations : int
        R, independent random-phase realizations.
    seed : int or None
        Seed of the phases (reproducible runs).
    phases : {'random', 'schroeder'}
        Phase law.
    grid : {'full', 'odd', 'random-odd'}
        Lines of the band that are excited (:func:`daq.multisine.multisine`): all, the odd
        ones, or the odd ones less one at random per ``detection_block`` (detection lines
        for ``fnsi-lab analyse``, docs/discovery.md).
    detection_block : int
        Odd lines per block of a random-odd grid (one left out per block).
    levels : tuple of float
        Force levels (RMS, unit of the force channel) of a level sweep: ``acquire`` then
        records one file per level with the same phases (empty: one run at ``rms``).
    drive : daq.drive.DriveDefinition or None
        Set by ``excitation: {file: DRIVE.json}``: the exported drive this excitation
        came from; its lines, phases and scaling are stored in the recording.
    """

    band_hz: tuple[float, float]
    rms: float
    samples_per_period: int
    periods: int = 1
    transient_periods: int = 0
    realizations: int = 1
    seed: int | None = 0
    phases: Literal["random", "schroeder"] = "random"
    grid: Literal["full", "odd", "random-odd"] = "full"
    detection_block: int = 4
    kind: Literal["multisine"] = "multisine"
    levels: tuple[float, ...] = ()
    drive: Any = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        out = {"kind": self.kind, "band_hz": list(self.band_hz), "rms": self.rms,
               "samples_per_period": self.samples_per_period, "periods": self.periods,
               "transient_periods": self.transient_periods,
               "realizations": self.realizations, "seed": self.seed, "phases": self.phases}
        if self.grid != "full":
            out["grid"] = self.grid
            if self.grid == "random-odd":
                out["detection_block"] = self.detection_block
        if self.levels:
            out["levels"] = list(self.levels)
        if self.drive is not None:
            out.update(self.drive.recording_metadata())
        return out
