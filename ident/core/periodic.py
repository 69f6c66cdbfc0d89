"""Periodic records -> frequency-domain data for FNSI (docs/method.md §1.2, §2.5).

Steps (docs/method.md §1.2): drop transient periods; average the time signals over periods (per
realization); evaluate the basis functions on the averaged response (after frequency-domain
integration for velocity/acceleration outputs, §2.5); scale each basis column to the force
RMS; DFT; keep the lines of the processed band (DC and Nyquist excluded, non-excited lines
kept); per-line noise covariance of the averaged output spectrum when ``P >= 2``. Several
realizations are handled by stacking their lines.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Literal, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity, coefficient_names, evaluate_basis
from fnsi_lab.ident.errors import IdentError, IdentWarning
from fnsi_lab.ident.core.excitation import ExcitationGrid, best_grid, detect_excited_lines
from fnsi_lab.ident.core.steady import select_steady_periods
from fnsi_lab.ident.core.noise import (mains_contaminated_lines, mains_outlier_lines,
                                  noise_from_nonexcited, noise_lines,
                                  resolution_variance)

OutputQuantity = Literal["displacement", "velocity", "acceleration"]
#: How the DT model is read at the lines (FrequencyData.time_base; ident.core.fnsi.TIME_BASES).
TimeBase = Literal["band-limited", "zoh", "bilinear"]
OUTPUT_QUANTITIES: tuple[OutputQuantity, ...] = ("displacement", "velocity", "acceleration")
#: Above this size the noise covariance keeps only its diagonal when ``P - 1 < 2 p`` (then
#: the weighting uses the variances anyway, ident.core.weights.inverse_covariance).
_FULL_COV_MAX_BYTES = 256 * 2 ** 20


@dataclass(frozen=True, eq=False)
class BasisMotion:
    """The averaged motion the basis functions read, one period per realization.

    Attributes
    ----------
    displacement : ndarray, shape (R, N_fine, c)
        ``q`` of the channels read by the basis (output units integrated to displacement),
        on the band-limited interpolation with ``basis_oversample`` points per sample.
    velocity : ndarray, shape (R, N_fine, c) or None
        ``q'``, when a velocity-dependent element reads these channels.
    channels : tuple of str
        The ``c`` channel names.
    lines : int ndarray, shape (F0,)
        DFT bins of the processed band (per realization).
    force_rms : float
        RMS of the averaged forces (N): basis columns are scaled to it.
    noise_cov : ndarray, shape (c, c) or None
        Per-sample covariance of the noise left in the averaged displacement (from the
        period-to-period spread; displacement outputs with ``P >= 2`` only).
    noise_spectrum : complex ndarray, shape (N // 2 + 1, c, c) or None
        Cross-spectrum of that noise on every DFT line of one period (numpy DFT divided by
        ``N``, of the average; realizations pooled, smoothed over +-8 lines). Same condition.
    noise_output_cross : complex ndarray, shape (F0, c, p) or None
        ``E[n_q(k) n_y(k)^H]`` on the processed lines: the same noise seen in the averaged
        motion and in the averaged outputs ``Y`` (they are the same records).
    line_noise : complex ndarray, shape (N // 2 + 1, c, c) or None
        The motion's noise cross-spectrum for any output quantity (``P >= 2``): for
        velocities and accelerations the outputs' spread integrated like the motion
        (divided by ``w^2`` or ``w^4``; DC left at 0). ``noise_spectrum`` itself for
        displacements. The output-error refinement judges the measured motion outside the
        processed band by it (:mod:`ident.refine.harmonic_balance`).

    The two spectra let :mod:`ident.refine.parameter_search` remove what the noise in the motion
    adds to the model error of a candidate clearance (docs/ident.md, "Unknown basis
    parameters").
    """

    displacement: np.ndarray
    velocity: np.ndarray | None
    channels: tuple[str, ...]
    lines: np.ndarray
    force_rms: float
    noise_cov: np.ndarray | None = None
    noise_spectrum: np.ndarray | None = None
    noise_output_cross: np.ndarray | None = None
    line_noise: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class FrequencyData:
    """Frequency-domain data of one identification problem (docs/method.md §1.2).

    Attributes
    ----------
    lines : int ndarray, shape (F,)
        DFT bin ``k`` of each line (repeats when realizations are stacked).
    frequencies_hz : ndarray, shape (F,)
        ``k fs / N`` (Hz).
    z : complex ndarray, shape (F,)
        ``z_k = exp(j 2 pi k / N)``.
    Y : complex ndarray, shape (F, p)
        Averaged output spectrum (output units, numpy DFT divided by ``N``).
    E : complex ndarray, shape (F, m_e)
        Scaled extended-input spectrum ``[P; sigma_1 H_1; ...]`` (N).
    input_scale : ndarray, shape (m_e,)
        ``sigma``: 1 for the forces, ``sigma_a = rms(p)/rms(h_a)`` for basis columns, so the
        physical spectrum is ``E / input_scale``.
    noise_cov : complex ndarray, shape (F, p, p), real ndarray, shape (F, p), or None
        Covariance of ``Y`` (of the average) per line; None when ``P < 2`` or when the
        period-to-period spread of every output is below the record resolution
        (``noise_resolved``: noise-free data, weighting by it would be weighting by
        round-off); the variances of the outputs below it are raised to it. Only the
        variances ``(F, p)`` when the full matrices would exceed ``_FULL_COV_MAX_BYTES`` and
        the periods are too few for the weighting to invert them (``P - 1 < 2 p``): 312
        channels would otherwise hold 3 GB.
    n_inputs : int
        Number of forces ``m``.
    sample_rate_hz : float
    samples_per_period : int
        ``N``.
    output_names, input_names : tuple of str
        Length ``p`` and ``m``.
    excited : bool ndarray, shape (F,)
        Lines where the force has energy.
    basis_names : tuple of str
        Names of the ``s = m_e - m`` basis columns.
    output_quantity : {'displacement', 'velocity', 'acceleration'}
    n_periods : int
        Periods averaged (after dropping transients).
    n_realizations : int
    band_hz : (float, float)
        Processed band.
    steady_state_error : float
        Largest relative period-to-period RMS difference of the kept output periods (0 if one
        period).
    time_base : {'band-limited', 'zoh', 'bilinear'}
        ``'band-limited'`` and ``'zoh'``: ``z_k = exp(j 2 pi k / N)`` (FNSI); the CT reading
        of the DT model assumes band-limited (anti-alias filtered) samples
        (:func:`ident.core.fnsi.band_limited_to_continuous`) or an input held between samples
        (exact ZOH inverse, docs/method.md §1.5). ``'bilinear'``: ``z_k = exp(j 2 atan(w_k T / 2))``
        (docs/method.md §1.6; ``G_c(j w_k) = G_d(z_k)`` exactly, no sampling assumption).
    bilinear_period_s : float or None
        ``T`` of the bilinear map (s).
    motion : BasisMotion or None
        The averaged motion the basis functions are evaluated on (kept so that
        :func:`with_basis` can rebuild ``E`` for other basis parameters without the time data).
    noise_source : {'periods', 'non-excited lines', 'none'}
        Where ``noise_var`` comes from: the period-to-period spread (``P >= 2``), the
        off-grid lines of a sparse multisine (:mod:`ident.core.noise`, one period), or nowhere.
    noise_var : ndarray, shape (F, p) or None
        Noise variance of ``Y`` per line and output, whatever its source (the detection
        test and the report use it; ``noise_cov`` is what the weighting uses). Outputs
        whose estimate is below the record resolution hold that resolution
        (:func:`floor_noise`).
    noise_resolved : bool ndarray, shape (p,) or None
        Outputs whose noise estimate stands above the resolution of a 24-bit record
        (:func:`ident.core.noise.resolution_variance`); None without an estimate. When none
        does, the data are noise-free for the fit: ``noise_cov`` is None (no weighting).
    excitation : dict or None
        How the excited lines were obtained (:meth:`ident.core.excitation.ExcitationGrid.to_dict`).
    offsets : dict or None
        DC of every channel and what was done with it (:func:`offsets_report`).
    periods : dict or None
        Which periods were averaged and why, the drift per period
        (:meth:`ident.core.steady.PeriodSelection.to_dict`).
    """

    lines: np.ndarray
    frequencies_hz: np.ndarray
    z: np.ndarray
    Y: np.ndarray
    E: np.ndarray
    input_scale: np.ndarray
    noise_cov: np.ndarray | None
    n_inputs: int
    sample_rate_hz: float
    samples_per_period: int
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    excited: np.ndarray
    basis_names: tuple[str, ...] = ()
    output_quantity: OutputQuantity = "displacement"
    n_periods: int = 1
    n_realizations: int = 1
    band_hz: tuple[float, float] = (0.0, np.inf)
    steady_state_error: float = 0.0
    time_base: TimeBase = "band-limited"
    bilinear_period_s: float | None = None
    motion: "BasisMotion | None" = None
    noise_source: str = "none"
    noise_var: np.ndarray | None = None
    noise_resolved: np.ndarray | None = None
    excitation: dict | None = None
    offsets: dict | None = None
    periods: dict | None = None

    @property
    def n_lines(self) -> int:
        """``F``."""
        return int(self.lines.size)

    @property
    def n_outputs(self) -> int:
        """``p``."""
        return int(self.Y.shape[1])

    @property
    def n_extended_inputs(self) -> int:
        """``m_e = m + s``."""
        return int(self.E.shape[1])

    @property
    def extended_input_names(self) -> tuple[str, ...]:
        """Forces then basis columns."""
        return tuple(self.input_names) + tuple(self.basis_names)

    @property
    def E_physical(self) -> np.ndarray:
        """Unscaled extended input ``E / input_scale`` (N, then basis units), shape (F, m_e)."""
        return self.E / self.input_scale

    def subset(self, mask: np.ndarray) -> "FrequencyData":
        """The same data restricted to the lines where ``mask`` is True."""
        mask = np.asarray(mask, bool)
        from dataclasses import replace
        return replace(self, lines=self.lines[mask], frequencies_hz=self.frequencies_hz[mask],
                       z=self.z[mask], Y=self.Y[mask], E=self.E[mask],
                       noise_cov=None if self.noise_cov is None else self.noise_cov[mask],
                       noise_var=None if self.noise_var is None else self.noise_var[mask],
                       excited=self.excited[mask])


# ---------------------------------------------------------------------------- helpers
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


def interpolate_periodic(x: np.ndarray, factor: int) -> np.ndarray:
    """Band-limited interpolation of periodic signals by an integer factor (zero-padded DFT).

    Exact for a periodic signal without content at or above the original Nyquist frequency
    (anti-alias filtered data); the original Nyquist line is dropped.

    Parameters
    ----------
    x : ndarray, shape (N, n_channels)
        One period.
    factor : int
        Samples per original sample (``>= 1``).

    Returns
    -------
    ndarray, shape (N * factor, n_channels)
        ``x`` on the finer grid; ``out[::factor] == x`` up to the dropped Nyquist line.
    """
    factor = int(factor)
    if factor <= 1:
        return np.asarray(x, float)
    N = x.shape[0]
    X = np.fft.rfft(x, axis=0)
    if N % 2 == 0:
        X[-1] = 0.0
    Xu = np.zeros((N * factor // 2 + 1,) + X.shape[1:], complex)
    Xu[:X.shape[0]] = X
    return np.fft.irfft(Xu, n=N * factor, axis=0) * factor


def integrate_periodic(x: np.ndarray, sample_rate_hz: float, times: int,
                       highpass_hz: float = 0.0, lowpass_hz: float | None = None,
                       gain: np.ndarray | None = None) -> np.ndarray:
    """Integrate (``times > 0``) or differentiate (``times < 0``) periodic signals exactly.

    Frequency-domain operation on one period (docs/method.md §2.5): ``X(k) / (j w_k)**times``; DC and
    the lines below ``highpass_hz`` (and above ``lowpass_hz``) are zeroed when integrating,
    because ``1/w**2`` amplifies low-frequency noise; the Nyquist line is zeroed.

    Parameters
    ----------
    x : ndarray, shape (N, n_channels)
    sample_rate_hz : float
    times : int
        Number of integrations (negative: differentiations).
    highpass_hz, lowpass_hz : float
        Band kept when integrating (Hz).
    gain : ndarray, shape (N // 2 + 1, n_channels), optional
        Extra real gain per line and channel (:func:`noise_gain`).

    Returns
    -------
    ndarray, shape (N, n_channels)
    """
    N = x.shape[0]
    X = np.fft.rfft(x, axis=0)
    f = np.fft.rfftfreq(N, 1.0 / sample_rate_hz)
    jw = 2j * np.pi * f
    fac = np.zeros_like(jw)
    nz = f > 0
    fac[nz] = jw[nz] ** (-times)
    if times > 0:
        fac[f < highpass_hz] = 0.0
        if lowpass_hz is not None:
            fac[f > lowpass_hz] = 0.0
    elif times == 0:
        fac[:] = 1.0
    if N % 2 == 0 and times != 0:
        fac[-1] = 0.0
    G = fac[:, None] if gain is None else fac[:, None] * gain
    return np.fft.irfft(X * G, n=N, axis=0)


def as_displacement_outputs(data: "FrequencyData") -> "FrequencyData":
    """The same frequency data with velocity or acceleration outputs turned into displacements.

    ``Y_k / (j w_k)**t`` (``t`` = 1 for velocities, 2 for accelerations) on every processed
    line, noise variances divided by ``w_k**(2 t)``; forces, basis columns, ``z`` and the
    motion are kept. Exact on the lines (no DC or Nyquist line is processed). Displacement
    data are returned as they are.

    Why: the basis-parameter search compares models by their relative model error, and in
    acceleration units that error is dominated by the high lines, where a wrong clearance
    misplaces every contact harmonic: on the 39-channel SmallSat the error was flat at
    10-15 % except within +-5 % of the true gaps, and a 7-point scan missed the minimum
    (gaps -57 % / -82 %). In displacement units it falls smoothly towards the true gaps
    from anywhere in the interval (docs/ident.md, "Unknown basis parameters").
    """
    from dataclasses import replace

    times = {"displacement": 0, "velocity": 1, "acceleration": 2}[data.output_quantity]
    if times == 0:
        return data
    jw = 2j * np.pi * np.asarray(data.frequencies_hz, float)
    scale = jw ** (-times)                                         # (F,)
    power = np.abs(scale) ** 2
    cov = data.noise_cov
    if cov is not None:
        cov = cov * power.reshape((-1,) + (1,) * (cov.ndim - 1))
    var = None if data.noise_var is None else data.noise_var * power[:, None]
    return replace(data, Y=data.Y * scale[:, None], noise_cov=cov, noise_var=var,
                   output_quantity="displacement")


def noise_gain(periods: np.ndarray, min_snr: float = 4.0, half_width: int = 8) -> np.ndarray:
    """Keep-or-drop mask of the lines of a period average that stand out of the noise.

    Parameters
    ----------
    periods : ndarray, shape (P, N, n_channels)
        The kept periods of one realization (``P >= 2``).
    min_snr : float
        A line is kept when ``|X(k)|^2 > min_snr var(k)``, ``X`` the spectrum of the average
        and ``var`` the noise variance of that average from the period-to-period spread.
    half_width : int
        ``var`` is averaged over +-``half_width`` neighbouring lines (smooth noise spectrum;
        one line's estimate has only ``P - 1`` degrees of freedom).

    Returns
    -------
    ndarray, shape (N // 2 + 1, n_channels)
        1.0 (kept) or 0.0 (dropped); all ones for noise-free data.

    Notes
    -----
    Integrating a noisy acceleration twice divides each line by ``w^2``, so the noise of the
    lines below the excitation dominates the displacement the basis functions see: with
    40 dB white noise on the accelerations of the 3-DOF chains (6 periods averaged, 5 noise
    seeds) c was off by 68-87 % (median) with every line kept. A fixed high-pass removes
    that noise but also the genuine low-frequency intermodulation motion (1-8 % bias
    noise-free). Dropping the lines whose power is below 4x their noise variance gave
    1.1 % and 4.8 % (median; Wiener-type soft gains 19 %, a threshold of 10: 1.1 % and
    5.2 %, of 30: 3.9 % and 6.6 %). Velocities (one integration) did better with every line
    kept (0.5-0.7 % against 1.2-1.3 %), so :func:`prepare_frequency_data` applies the mask
    to accelerations only.
    """
    Xq = np.fft.rfft(np.asarray(periods, float), axis=1)            # (P, K, c)
    P = Xq.shape[0]
    Xm = Xq.mean(axis=0)
    var = np.sum(np.abs(Xq - Xm) ** 2, axis=0) / (P * (P - 1))     # of the mean
    return (np.abs(Xm) ** 2 >= float(min_snr) * smooth_lines(var, half_width)).astype(float)


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


# ---------------------------------------------------------------------------- main entry
def prepare_frequency_data(record: Any = None, *, u: Any = None, y: Any = None,
                           sample_rate_hz: float | None = None,
                           samples_per_period: int | None = None,
                           basis: Sequence[Nonlinearity] = (),
                           band_hz: tuple[float, float] | None = None,
                           transient_periods: int | None = None,
                           output_quantity: OutputQuantity = "displacement",
                           output_names: Sequence[str] | None = None,
                           input_names: Sequence[str] | None = None,
                           excited_lines: Sequence[int] | np.ndarray | None = None,
                           highpass_hz: float | None = None,
                           excitation_threshold: float = 1e-3,
                           steady_state_tolerance: float = 0.05,
                           steady_periods: Literal["auto", "all"] = "auto",
                           time_base: Literal["auto", "band-limited", "zoh", "bilinear"] = "auto",
                           bilinear_period_s: float | None = None,
                           basis_oversample: int = 8,
                           integration_min_snr: float | None = 4.0,
                           motion_for: Sequence[Nonlinearity] = (),
                           noise_estimate: Literal["auto", "periods", "lines", "none"] = "auto",
                           remove_offsets: bool | None = None,
                           drop_mains: bool = True) -> FrequencyData:
    """Build :class:`FrequencyData` from a periodic record or from arrays (docs/method.md §1.2).

    Parameters
    ----------
    record : object, optional
        A ``daq.recording.reader.PeriodicRecord`` (or anything with ``u``, ``y``,
        ``sample_rate_hz``, ``samples_per_period``, ``input_channels``, ``output_channels``,
        ``transient_periods``, ``excited_lines``). Explicit keywords override its fields.
    u : ndarray, shape (R, P, N, m), (P, N, m), (n_samples, m) or (n_samples,)
        Forces (N).
    y : ndarray, same leading shape, last axis p
        Outputs (``output_quantity`` units: m, m/s or m/s^2).
    sample_rate_hz : float
    samples_per_period : int, optional
        ``N``; needed to cut 1-D/2-D signals into periods.
    basis : sequence of Nonlinearity
    band_hz : (float, float)
        Processed band ``[f_min, f_max]``; DC and Nyquist are always excluded.
    transient_periods : int, optional
        Periods dropped at the start of each realization (default: the record's, else 0).
    output_quantity : {'displacement', 'velocity', 'acceleration'}
    output_names, input_names : sequence of str, optional
        Default ``y0, y1, ...`` and ``u0, ...``.
    excited_lines : sequence of int, optional
        DFT bins of the excitation (of one period); default: detected from the force
        spectrum by :func:`ident.core.excitation.detect_excited_lines` (grid, runs, mains hum).
    highpass_hz : float, optional
        Integration high-pass for velocity/acceleration outputs (docs/method.md §2.5): lines below it
        are zeroed before integrating. Default 0 (only DC removed): on noise-free simulated
        accelerations of the 3-DOF cubic chain a high-pass at ``0.5 f_min`` biased ``c`` by
        -1.5 % (it removes the low-frequency intermodulation motion the basis function
        needs), against -0.03 % without; with ``P >= 2`` the noise gate
        (``integration_min_snr``) drops the noisy lines instead. One period of accelerations
        has no spread to gate with (an :class:`IdentWarning` says so): on the 39-channel
        SmallSat (one period, 0.1 % white noise) integrating the lines under the band gave
        ``c`` +207 % / +375 %, ``highpass_hz = f_min`` -1.5 % / +0.1 %; on noise-free
        one-period chains (bench/robustness.py) ``f_min`` cost 4-6 % against 0.001-0.005 %.
    excitation_threshold : float
        Power threshold of the excited-line detection, relative to the multisine's level
        (``threshold`` of :func:`ident.core.excitation.detect_excited_lines`).
    steady_state_tolerance : float
        Warn (:class:`IdentWarning`) when the relative period-to-period RMS difference of the
        kept outputs exceeds it.
    steady_periods : {'auto', 'all'}
        ``auto`` (default): after the ``transient_periods``, leave out the leading periods
        that still differ from the settled ones (:func:`ident.core.steady.select_steady_periods`;
        on the aircraft-like GVT the second period at 12 N, whose 0.5 %-damped modes still
        ring); ``all``: average every period after them. Either way the drift per period
        and the periods used are in ``FrequencyData.periods``.
    time_base : {'auto', 'band-limited', 'zoh', 'bilinear'}
        How the discrete-time model relates to continuous time. ``'auto'`` (default):
        ``'band-limited'`` for displacement outputs, ``'bilinear'`` for velocity and
        acceleration outputs (noise-free 3-DOF chains, cubic spring and stop: velocities
        0.04-1.5 % against 0.004-0.009 % bilinear, accelerations 0.01-0.14 % against
        0.002-0.003 %; at 40 dB the two were within each other's scatter).
        ``'band-limited'``: samples of anti-alias filtered signals (any acquisition system,
        and continuous-time simulations sampled at the output rate); the model is identified
        at ``z_k = exp(j 2 pi k / N)`` and read by impulse invariance, FRFs from the DT model
        (exact on the band). ``'zoh'``: the input is held between samples (data generated by
        a ZOH-discretised model); exact ZOH inverse (docs/method.md §1.5). On band-limited data the
        ZOH reading adds a half-sample delay to every FRF (SmallSat: 8.7 % RMS over
        5-50 Hz at 1 kHz against 0.02 % band-limited). ``'bilinear'``: identification in the
        warped variable of docs/method.md §1.6 (exact CT model of CT data, no sampling assumption).
        Poles are the same for ``'band-limited'`` and ``'zoh'``.
    bilinear_period_s : float, optional
        ``T`` of the bilinear map; default ``2 / sqrt(w_min w_max)`` over the processed band,
        which maps its geometric centre to ``theta = pi / 2``.
    integration_min_snr : float or None
        Acceleration outputs with ``P >= 2`` periods: before the double integration that
        gives the basis functions their displacements, drop the lines whose power is below
        this many times their noise variance (:func:`noise_gain`); None keeps every line.
        No effect on noise-free data.
    basis_oversample : int
        Evaluate the basis functions on a band-limited (zero-padded DFT) interpolation of
        the averaged response with this many points per sample, and take their Fourier
        coefficients there (docs/method.md §8.4). A kink or a power law puts broadband content in
        ``h_a``; sampled at the acquisition rate it aliases onto the processed lines, while
        the measured response was driven by the continuous-time ``h_a``. 1 evaluates at the
        samples (the seed's way). Default 8: on the SmallSat it lowered the model-error floor
        from 2e-6 to 5e-9 and the NC2-Z coefficient error from 0.1-0.3 % to 0.01-0.08 %
        (docs/ident.md). Use 1 for data generated by a discrete-time model that applies
        ``h_a`` to the samples themselves.
    noise_estimate : {'auto', 'periods', 'lines', 'none'}
        Noise of the averaged output: ``periods`` from the period-to-period spread
        (``P >= 2``); ``lines`` from the off-grid lines of a sparse (e.g. odd) multisine
        inside its band (:mod:`ident.core.noise`, diagonal); ``auto`` (default) the first
        available of the two; ``none`` no noise model. ``noise_var`` holds it for the
        detection test and the report; ``noise_cov`` (the weighting) holds the periods'
        estimate, and the lines' estimate only with ``'lines'``: weighting by it made the
        Silverbox periods identified one by one less consistent (order 2, spread of the
        mean 2.2 % unweighted, 1.1 % weighted but shifted by -7 %; the automatic pipeline
        kept split modes beside the resonance in 2 of 10), docs/ident.md.
    remove_offsets : bool or None
        Subtract each realisation's mean of the displacement outputs before the basis
        functions read them. None (default): yes when the excitation is an odd multisine
        and every basis function is odd (odd polynomial, signed power, quadratic damping,
        Coulomb): such a system has no DC response to it, so the DC is a sensor or
        amplifier offset, which in ``y^3`` would act as a spurious ``y^2`` and stiffness
        term. Otherwise no: a full multisine gives an odd element a genuine DC response,
        and gaps count their clearances from the static position the DC holds (an offset
        above 10 % of a clearance raises a warning). The DC line is never fitted.
    drop_mains : bool
        Leave out the lines within 3 lines of a 50/60 Hz harmonic where hum stands 30x
        out of the noise of the off-grid lines, in the output or the drive
        (:func:`ident.core.noise.mains_contaminated_lines`; needs a sparse multisine, e.g. odd).
        Reported in ``excitation['mains_dropped_hz']``.

    Returns
    -------
    FrequencyData

    Raises
    ------
    IdentError
        Wrong shapes, empty band, unknown channels, too few periods.
    """
    if record is not None:
        u = record.u if u is None else u
        y = record.y if y is None else y
        sample_rate_hz = sample_rate_hz or getattr(record, "sample_rate_hz", None)
        samples_per_period = samples_per_period or getattr(record, "samples_per_period", None)
        if transient_periods is None:
            transient_periods = getattr(record, "transient_periods", 0) or 0
        if output_names is None and getattr(record, "output_channels", None) is not None:
            output_names = [getattr(c, "name", c) for c in record.output_channels]
        if input_names is None and getattr(record, "input_channels", None) is not None:
            input_names = [getattr(c, "name", c) for c in record.input_channels]
        if excited_lines is None:
            excited_lines = getattr(record, "excited_lines", None)
    if u is None or y is None:
        raise IdentError("prepare_frequency_data needs a record or both u and y")
    if not sample_rate_hz or not sample_rate_hz > 0:
        raise IdentError("sample_rate_hz must be a positive number")
    if band_hz is None:
        raise IdentError("band_hz is required (processed band [f_min, f_max] in Hz)")
    if output_quantity not in OUTPUT_QUANTITIES:
        raise IdentError(f"output_quantity {output_quantity!r} is not one of {list(OUTPUT_QUANTITIES)}")
    fs = float(sample_rate_hz)
    basis_oversample = int(basis_oversample)
    if basis_oversample < 1:
        raise IdentError(f"basis_oversample must be a positive integer, got {basis_oversample}")
    U4 = as_periodic(u, samples_per_period, "u")
    Y4 = as_periodic(y, samples_per_period, "y")
    if U4.shape[:3] != Y4.shape[:3]:
        raise IdentError(f"u and y do not match: u {U4.shape[:3]} vs y {Y4.shape[:3]} "
                         "(realizations, periods, samples)")
    R, P_tot, N, m = U4.shape
    p = Y4.shape[3]
    P_tr = int(transient_periods or 0)
    if P_tr < 0 or P_tr >= P_tot:
        raise IdentError(f"transient_periods: {P_tr} leaves no period out of {P_tot} for "
                         f"the identification (fix: give fewer transient periods, at most "
                         f"{P_tot - 1}, in the config or the import, or record more periods)")
    if steady_periods not in ("auto", "all"):
        raise IdentError(f"steady_periods {steady_periods!r} is not one of ['auto', 'all']")
    P = P_tot - P_tr
    output_names = tuple(output_names) if output_names is not None else tuple(f"y{i}" for i in range(p))
    input_names = tuple(input_names) if input_names is not None else tuple(f"u{i}" for i in range(m))
    if len(output_names) != p:
        raise IdentError(f"{len(output_names)} output names for {p} output channels")
    if len(input_names) != m:
        raise IdentError(f"{len(input_names)} input names for {m} input channels")
    f_min, f_max = (float(b) for b in band_hz)
    if not 0 <= f_min < f_max:
        raise IdentError(f"band_hz must be [f_min, f_max] with 0 <= f_min < f_max, got {band_hz}")
    k_all = np.arange(N // 2 + 1)
    f_all = k_all * fs / N
    sel = (f_all >= f_min) & (f_all <= f_max) & (k_all > 0)
    if N % 2 == 0:
        sel &= k_all < N // 2
    K = k_all[sel]
    if K.size == 0:
        raise IdentError(f"no DFT line in band {band_hz} Hz (fs={fs:g} Hz, N={N})")

    # the periods in steady state (ident.core.steady), compared on the processed band
    selection = select_steady_periods(Y4, P_tr, bins=K, select=steady_periods == "auto")
    U4, Y4 = U4[:, list(selection.used)], Y4[:, list(selection.used)]
    P = Y4.shape[1]
    # steady-state check: period-to-period difference of the kept outputs
    ss_err = 0.0
    if P >= 2:
        diff = np.sqrt(np.mean((Y4[:, 1:] - Y4[:, :-1]) ** 2, axis=(2, 3)))
        ref = np.sqrt(np.mean(Y4 ** 2, axis=(1, 2, 3)))[:, None]
        ss_err = float(np.max(diff / np.where(ref > 0, ref, 1.0)))
        if ss_err > steady_state_tolerance:
            warnings.warn(f"outputs may not be in periodic steady state: relative "
                          f"period-to-period RMS difference {ss_err:.3g} > "
                          f"{steady_state_tolerance:g} over the periods used ("
                          f"{selection.statement})", IdentWarning, stacklevel=2)

    u_avg = U4.mean(axis=1)  # (R, N, m)
    y_avg = Y4.mean(axis=1)  # (R, N, p)
    rms_p = float(np.sqrt(np.mean(u_avg ** 2)))
    if not rms_p > 0:
        raise IdentError("the force signals are zero")
    # the motion the basis functions read (docs/method.md §1.2 step 3; §2.5), kept for with_basis
    basis = tuple(basis)
    readers = basis + tuple(motion_for)
    # excited lines: given (recording metadata, user file) or detected from the drive
    if excited_lines is not None and len(excited_lines):
        given = np.unique(np.asarray(excited_lines, int))
        step, offset = best_grid(given, 0.9, 8) if given.size else (1, 0)
        grid = ExcitationGrid(lines=given, step=step, offset=offset,
                              n_candidates=int(given.size), source="given")
    else:
        pw_all = np.mean(np.sum(np.abs(np.fft.rfft(u_avg, axis=1)) ** 2, axis=2), axis=0)
        grid = detect_excited_lines(pw_all, fs, N, threshold=excitation_threshold)
    # spectra on every bin: of the averages, and of each period (hum, noise estimate)
    Y_all = np.fft.rfft(y_avg, axis=1) / N                                 # (R, bins, p)
    U_all = np.fft.rfft(u_avg, axis=1) / N                                 # (R, bins, m)
    Yq_all = (np.fft.rfft(Y4, axis=2) / N                                  # (R, P, bins, p)
              if P >= 2 and (drop_mains or noise_estimate in ("auto", "periods")) else None)
    # lines where mains hum stands out of the noise are left out of the processed set
    hum_lines: np.ndarray = np.zeros(0, int)
    hum_hz: list[float] = []
    if drop_mains:
        bins = noise_lines(grid.lines, grid.step, grid.offset, N // 2 + 1, fs, N)
        hum_lines, hum_hz = mains_contaminated_lines(Y_all, U_all, bins, grid.lines, grid.step,
                                                     grid.offset, fs, N)
        # full multisines and lines beyond the excitation: no off-grid line to look at
        spread = None
        if Yq_all is not None:   # variance of the average per line: hum drifting between periods
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
    offsets, remove = offsets_report(U4, Y4, input_names, output_names, output_quantity,
                                     readers, remove_offsets, odd_grid=grid.kind == "odd")
    motion = None
    if readers:
        used = sorted({output_names.index(c) for nl in readers for c in nl.channels
                       if c in output_names})
        need_v = any(nl.needs_velocity for nl in readers)
        hp = 0.0 if highpass_hz is None else float(highpass_hz)
        if output_quantity == "acceleration" and P < 2 and highpass_hz is None and f_min > 0:
            # no period spread to gate the lines with (below): noise under the band, times
            # 1/w^4, can swamp the motion (docs/ident.md, acceleration outputs)
            warnings.warn("one steady period of accelerations: the lines under the band are "
                          "integrated without a noise check; with noisy data set highpass_hz "
                          f"(e.g. {f_min:g}, the band's lower edge) or record more periods",
                          IdentWarning, stacklevel=2)
        q_list: list[np.ndarray] = []
        qd_list: list[np.ndarray] = []    # velocities, when a basis function reads them
        for r in range(R):
            # accelerations: lines buried in noise would dominate after double integration
            g = (noise_gain(Y4[r], integration_min_snr)
                 if output_quantity == "acceleration" and P >= 2 and integration_min_snr else None)
            if output_quantity == "displacement":
                q = y_avg[r] - y_avg[r].mean(axis=0) if remove else y_avg[r]
                qd = integrate_periodic(q, fs, -1) if need_v else None
            elif output_quantity == "velocity":
                q = integrate_periodic(y_avg[r], fs, 1, hp, gain=g)
                qd = y_avg[r] - y_avg[r].mean(axis=0) if need_v else None
            else:
                q = integrate_periodic(y_avg[r], fs, 2, hp, gain=g)
                qd = integrate_periodic(y_avg[r], fs, 1, hp, gain=g) if need_v else None
            # only the channels the basis functions read, on the band-limited interpolation
            q_list.append(interpolate_periodic(q[:, used], basis_oversample))
            if qd is not None:
                qd_list.append(interpolate_periodic(qd[:, used], basis_oversample))
        motion_noise = noise_spectrum = noise_cross = line_noise = None
        if P >= 2:
            # per-line noise of the averaged motion, from the period-to-period spread
            res = Y4 - y_avg[:, None]                               # (R, P, N, p)
            res_q = res[..., used]
            dev_q = np.fft.rfft(res_q, axis=2) / N                  # (R, P, N//2+1, c)
            scale = 1.0 / (R * P * (P - 1))
            line_noise = smooth_lines(np.einsum("rpki,rpkj->kij", dev_q, dev_q.conj()) * scale, 8)
            if output_quantity != "displacement":   # integrated like the motion
                t = {"velocity": 1, "acceleration": 2}[output_quantity]
                w = 2 * np.pi * np.arange(line_noise.shape[0]) * fs / N
                with np.errstate(divide="ignore"):
                    line_noise = line_noise / np.where(w > 0, w, np.inf)[:, None, None] ** (2 * t)
        if output_quantity == "displacement" and P >= 2:
            # per-sample noise covariance of the period average and the noise spectrum, for
            # the noise correction of the clearance search
            motion_noise = np.einsum("rpni,rpnj->ij", res_q, res_q) / (R * N * (P - 1) * P)
            dev_y = np.fft.rfft(res, axis=2)[:, :, K] / N           # (R, P, F0, p)
            noise_spectrum = line_noise
            noise_cross = smooth_lines(
                np.einsum("rpki,rpkj->kij", dev_q[:, :, K], dev_y.conj()) * scale, 8)
        motion = BasisMotion(displacement=np.stack(q_list),
                             velocity=None if not need_v else np.stack(qd_list),
                             channels=tuple(output_names[i] for i in used), lines=K,
                             force_rms=rms_p, noise_cov=motion_noise,
                             noise_spectrum=noise_spectrum, noise_output_cross=noise_cross,
                             line_noise=line_noise)
    Uf = U_all[:, K]  # (R, F0, m)
    Yf = Y_all[:, K]  # (R, F0, p)
    excited = np.tile(np.isin(K, grid.lines), R)
    noise, noise_source = None, "none"
    if noise_estimate not in ("auto", "periods", "lines", "none"):
        raise IdentError(f"noise_estimate {noise_estimate!r} is not one of "
                         "['auto', 'periods', 'lines', 'none']")
    if P >= 2 and noise_estimate in ("auto", "periods"):
        if Yq_all is None:   # computed above whenever the periods give the noise
            raise IdentError("the per-period spectra for the noise estimate are missing")
        Yq = Yq_all[:, :, K]  # (R, P, F0, p)
        dev = Yq - Yf[:, None]
        if P - 1 < 2 * p and R * K.size * p * p * 16 > _FULL_COV_MAX_BYTES:
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
    noise_resolved = None
    if noise_var is not None:  # nothing below the finest record resolves (ident.core.noise)
        floor = resolution_variance(np.max(np.abs(Y4), axis=(0, 1, 2)), N)
        noise, noise_var, noise_resolved = floor_noise(noise, noise_var, floor)
    lines = np.tile(K, R)
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
    data = FrequencyData(
        time_base=time_base, bilinear_period_s=T_bl,
        lines=lines, frequencies_hz=lines * fs / N, z=z,
        Y=Yf.reshape(-1, p), E=Uf.reshape(-1, m), input_scale=np.ones(m),
        noise_cov=noise, n_inputs=m, sample_rate_hz=fs, samples_per_period=N,
        output_names=output_names, input_names=input_names, excited=excited,
        output_quantity=output_quantity, n_periods=P, n_realizations=R,
        band_hz=(f_min, f_max), steady_state_error=ss_err, motion=motion,
        noise_source=noise_source, noise_var=noise_var, noise_resolved=noise_resolved,
        excitation=dict(grid.to_dict(fs, N), mains_dropped_hz=hum_hz,
                        n_mains_dropped_lines=int(hum_lines.size)),
        offsets=offsets, periods=selection.to_dict())
    return with_basis(data, basis) if basis else data


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


def _is_odd(nl: Nonlinearity) -> bool:
    """``h(-x) = -h(x)``: odd polynomials, signed powers, quadratic damping, Coulomb."""
    if nl.kind == "polynomial":
        e = getattr(nl, "exponent", None)
        return bool(getattr(nl, "signed", False)) or (isinstance(e, (int, float))
                                                      and float(e) % 2 == 1)
    return nl.kind in ("quadratic_damping", "coulomb")


def offsets_report(U4: np.ndarray, Y4: np.ndarray, input_names: Sequence[str],
                   output_names: Sequence[str], output_quantity: str,
                   basis: Sequence[Nonlinearity], remove: bool | None, *,
                   odd_grid: bool = False) -> tuple[dict, bool]:
    """DC offsets of the channels, and whether the basis functions read the outputs without it.

    Parameters
    ----------
    U4, Y4 : ndarray, shapes (R, P, N, m) and (R, P, N, p)
        Steady periods.
    input_names, output_names : sequence of str
    output_quantity : str
    basis : sequence of Nonlinearity
    remove : bool or None
        None: remove when the excitation is an odd multisine and every element is odd
        (see :func:`prepare_frequency_data`), else keep.
    odd_grid : bool
        The excitation is an odd multisine.

    Returns
    -------
    report : dict
        ``{"removed": bool, "channels": {name: {"mean", "relative"}}}`` (``relative``: mean
        over the RMS of the channel's fluctuation), ``"note"``.
    removed : bool

    Warns
    -----
    IdentWarning
        A gap element with a given offset reads an output whose mean exceeds 10 % of its
        smallest clearance.
    """
    gaps = [nl for nl in basis if nl.kind in ("trilinear", "bilinear")
            and "offset" not in {sp.parameter for sp in nl.unknown}]
    if remove is None:
        # an odd element driven by an odd multisine puts nothing at DC (odd + odd - odd
        # lines are odd): any DC there is a sensor or amplifier offset, which in y^3 would
        # act as a spurious y^2 and stiffness term. Full multisines give odd elements a
        # genuine DC (f1 + f2 - f3 = 0), and even elements always do: kept.
        remove = (output_quantity == "displacement" and odd_grid and bool(basis)
                  and all(_is_odd(nl) for nl in basis))
    remove = bool(remove) and output_quantity == "displacement"
    chans: dict[str, dict] = {}
    for names, X in ((input_names, U4), (output_names, Y4)):
        mean = X.mean(axis=(0, 1, 2))
        ac = np.sqrt(np.mean((X - X.mean(axis=2, keepdims=True)) ** 2, axis=(0, 1, 2)))
        for i, name in enumerate(names):
            chans[str(name)] = {"mean": float(mean[i]),
                                "relative": float(mean[i] / ac[i]) if ac[i] > 0 else None}
    note = ("the DC line is never fitted; "
            + ("each realisation's mean of the outputs was removed before the basis "
               "functions read them" if remove else
               "the basis functions read the outputs with their DC" if output_quantity ==
               "displacement" else "integrated outputs carry no DC (static position lost)"))
    if output_quantity == "displacement" and not remove:
        for nl in gaps:
            clear = [c for c in (list(getattr(nl, "clearances", ()) or ())
                                 + [getattr(nl, "clearance", None)])
                     if isinstance(c, (int, float)) and c > 0]
            for ch in nl.channels:
                off = abs(chans.get(ch, {}).get("mean", 0.0))
                if clear and off > 0.1 * min(clear):
                    warnings.warn(f"output {ch!r} has a DC offset of {off:.3g} "
                                  f"({100 * off / min(clear):.0f} % of the smallest clearance "
                                  f"of {nl.name!r}): clearances count from the static "
                                  "position; remove the sensor offset from the data, give "
                                  "the element an 'offset' or, for a trilinear stop with "
                                  "known clearances, 'offset: auto'", IdentWarning,
                                  stacklevel=3)
    if output_quantity != "displacement":
        for nl in gaps:
            if nl.kind == "trilinear" and nl.offset == 0 and not nl.unknown:
                warnings.warn(f"{nl.name!r} reads {output_quantity} outputs, integrated without "
                              "their static position: its clearances count from the mean "
                              "position during the test, which an asymmetric stop moves away "
                              "from the rest position (3-DOF chain: contact stiffness -12 %); "
                              "give 'offset: auto' to estimate it", IdentWarning, stacklevel=3)
    return {"removed": remove, "channels": chans, "note": note}, remove


def basis_spectra(basis: Sequence[Nonlinearity], motion: BasisMotion) -> tuple[np.ndarray, np.ndarray]:
    """Fourier coefficients of the basis functions on the processed lines.

    Parameters
    ----------
    basis : sequence of Nonlinearity
        Elements with every parameter known; their channels must be in ``motion.channels``.
    motion : BasisMotion

    Returns
    -------
    H : complex ndarray, shape (R * F0, s)
        Unscaled spectra (numpy DFT over the fine period divided by its length), the lines of
        each realization in turn.
    rms : ndarray, shape (s,)
        RMS of each basis function over the fine periods of every realization.
    """
    q, qd = motion.displacement, motion.velocity
    h = np.stack([evaluate_basis(basis, q[r], None if qd is None else qd[r], motion.channels)
                  for r in range(q.shape[0])])                   # (R, N_fine, s)
    rms = np.sqrt(np.mean(h ** 2, axis=(0, 1)))
    H = np.fft.rfft(h, axis=1)[:, motion.lines] / h.shape[1]
    return H.reshape(-1, h.shape[2]), rms


def with_basis(data: FrequencyData, basis: Sequence[Nonlinearity]) -> FrequencyData:
    """The same data with the extended input built for ``basis`` (forces kept).

    Parameters
    ----------
    data : FrequencyData
        Prepared by :func:`prepare_frequency_data` with a ``motion`` holding the channels of
        ``basis`` (``basis=`` or ``motion_for=`` there).
    basis : sequence of Nonlinearity

    Returns
    -------
    FrequencyData
        ``E = [P; sigma_1 H_1; ...]`` with ``sigma_a = rms(p) / rms(h_a)``.

    Raises
    ------
    IdentError
        No motion kept, a channel of ``basis`` not measured, or a basis function identically
        zero on these data.
    """
    from dataclasses import replace

    basis = tuple(basis)
    m = data.n_inputs
    if not basis:
        return replace(data, E=data.E[:, :m], input_scale=data.input_scale[:m], basis_names=())
    for nl in basis:
        nl.location_vector(data.output_names)        # ChannelError naming the outputs
    motion = data.motion
    if motion is None or not all(c in motion.channels for nl in basis for c in nl.channels):
        raise IdentError("these frequency data do not hold the motion of the basis channels "
                         "(prepare them with basis= or motion_for=)")
    if motion.velocity is None and any(nl.needs_velocity for nl in basis):
        raise IdentError("these frequency data hold no velocities for the velocity-dependent "
                         "basis functions (prepare them with basis= or motion_for=)")
    H, rms_h = basis_spectra(basis, motion)
    names = coefficient_names(basis)
    if np.any(rms_h == 0):
        dead = [n for n, v in zip(names, rms_h) if v == 0]
        raise IdentError(f"basis functions {dead} are identically zero on these data "
                         "(clearance larger than the motion, or wrong channels)")
    sigma = np.concatenate([np.ones(m), motion.force_rms / rms_h])
    E = np.concatenate([data.E[:, :m], H * sigma[m:]], axis=1)
    return replace(data, E=E, input_scale=sigma, basis_names=names)


def data_report(data: FrequencyData) -> dict:
    """What the data are made of, for the result file: noise, excitation, offsets.

    Returns
    -------
    dict
        ``noise``: ``source`` (``periods``, ``non-excited lines`` or ``none``), per output
        ``level`` (noise RMS over the excited lines relative to the output's RMS there) and
        ``snr_db``, and a ``statement``; ``excitation``: how the excited lines were found
        (:class:`ident.core.excitation.ExcitationGrid`, mains lines left out); ``offsets``: DC of
        every channel and what was done with it.
    """
    src = data.noise_source
    noise: dict[str, Any] = {"source": src}
    exc = np.asarray(data.excited, bool)
    if data.noise_var is not None and exc.any():
        sig = np.mean(np.abs(data.Y[exc]) ** 2, axis=0)
        var = np.mean(np.asarray(data.noise_var)[exc], axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.sqrt(var / sig)
        noise["outputs"] = {name: {"level": float(r), "snr_db": float(-20 * np.log10(r))
                                   if r > 0 else None}
                            for name, r in zip(data.output_names, rel)}
        noise["statement"] = (
            f"noise estimated from the {src}: median output noise "
            f"{100 * float(np.median(rel)):.3g} % of the response RMS on the excited lines"
            + ("" if src == "periods" else
               " (off-grid lines: noise, hum and even-order distortion; the unmodelled odd "
               "distortion on the excited lines is not in it)"))
        low = (None if data.noise_resolved is None
               else [n for n, ok in zip(data.output_names, data.noise_resolved) if not ok])
        if low:
            noise["below_resolution"] = low
            noise["statement"] += (
                "; no fit weighting: the spread of every output is below the resolution of a "
                "24-bit record (noise-free data, e.g. a simulation), so the levels shown are "
                "that resolution" if len(low) == len(data.output_names) else
                f"; {len(low)} of {len(data.output_names)} outputs are below the resolution "
                "of a 24-bit record and are weighted at that resolution")
    else:
        noise["outputs"] = None
        noise["statement"] = (
            "no noise estimate: one period per realisation and no non-excited line inside "
            "the excited band (a full multisine). The fit is unweighted, and the detection "
            "test judges each mode against the model's residual only, which an over-fitting "
            "model makes small; record two or more steady periods, or use an odd multisine.")
    return {"noise": noise, "excitation": data.excitation, "offsets": data.offsets,
            "periods": data.periods}


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
        raise IdentError(f"realization_starts {s} must be increasing sample indices inside the "
                         f"record of {n} samples")
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
