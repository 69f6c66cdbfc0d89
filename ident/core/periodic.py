"""Periodic records -> frequency-domain data for FNSI (docs/method.md §1.2, §2.5).

Steps (docs/method.md §1.2): drop transient periods; average the time signals over periods (per
realization); evaluate the basis functions on the averaged response (after frequency-domain
integration for velocity/acceleration outputs, §2.5); scale each basis column to the force
RMS; DFT; keep the lines of the processed band (DC and Nyquist excluded, non-excited lines
kept); per-line noise covariance of the averaged output spectrum when ``P >= 2``. Several
realizations are handled by stacking their lines.

:func:`prepare_frequency_data` runs the steps; each lives with its job:
:mod:`ident.core.frequency_data` (the containers, :func:`data_report`),
:mod:`ident.core.averaging` (periods, steady state, the output noise),
:mod:`ident.core.processed_lines` (band, excited lines, mains hum, ``z``),
:mod:`ident.core.motion` (integration, offsets, the motion the basis reads) and
:mod:`ident.core.extended_input` (the basis evaluated on it, :func:`with_basis`). Their
public names are importable from here too, as before the split.
"""

from __future__ import annotations

from typing import Any, Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.averaging import (FULL_COV_MAX_BYTES, as_periodic, cut_realizations,
                                          floor_noise, output_noise, smooth_lines,
                                          steady_state_error)
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.extended_input import basis_spectra, with_basis
from fnsi_lab.ident.core.frequency_data import (OUTPUT_QUANTITIES, BasisMotion, FrequencyData,
                                               OutputQuantity, TimeBase, data_report)
from fnsi_lab.ident.core.motion import (as_displacement_outputs, basis_motion,
                                       integrate_periodic, interpolate_periodic, noise_gain,
                                       offsets_report)
from fnsi_lab.ident.core.noise import resolution_variance
from fnsi_lab.ident.core.processed_lines import (band_lines, drop_mains_lines,
                                                excitation_grid, line_map)
from fnsi_lab.ident.core.steady import select_steady_periods
from fnsi_lab.ident.errors import IdentError

__all__ = ["FULL_COV_MAX_BYTES", "OUTPUT_QUANTITIES", "BasisMotion", "FrequencyData",
           "OutputQuantity", "TimeBase", "as_displacement_outputs", "as_periodic",
           "basis_spectra", "cut_realizations", "data_report", "floor_noise",
           "integrate_periodic", "interpolate_periodic", "noise_gain", "offsets_report",
           "prepare_frequency_data", "smooth_lines", "with_basis"]


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
    u, y, sample_rate_hz, samples_per_period, transient_periods, output_names, input_names, \
        excited_lines = _with_record_fields(record, u, y, sample_rate_hz, samples_per_period,
                                            transient_periods, output_names, input_names,
                                            excited_lines)
    if u is None or y is None:
        raise IdentError("prepare_frequency_data needs a record or both u and y")
    if not sample_rate_hz or not sample_rate_hz > 0:
        raise IdentError("sample_rate_hz must be a positive number")
    if band_hz is None:
        raise IdentError("band_hz is required (processed band [f_min, f_max] in Hz)")
    if output_quantity not in OUTPUT_QUANTITIES:
        raise IdentError(f"output_quantity {output_quantity!r} is not one of {plain.names(OUTPUT_QUANTITIES)}")
    fs = float(sample_rate_hz)
    basis_oversample = int(basis_oversample)
    if basis_oversample < 1:
        raise IdentError(f"basis_oversample must be a positive integer, got {basis_oversample}")
    U4, Y4, P_tr, output_names, input_names = _periodic_arrays(
        u, y, samples_per_period, transient_periods, steady_periods, output_names, input_names)
    R, _, N, m = U4.shape
    p = Y4.shape[3]
    K, f_min, f_max = band_lines(band_hz, fs, N)

    # the periods in steady state (ident.core.steady), compared on the processed band
    selection = select_steady_periods(Y4, P_tr, bins=K, select=steady_periods == "auto")
    U4, Y4 = U4[:, list(selection.used)], Y4[:, list(selection.used)]
    P = Y4.shape[1]
    ss_err = steady_state_error(Y4, steady_state_tolerance, selection.statement)
    u_avg = U4.mean(axis=1)  # (R, N, m)
    y_avg = Y4.mean(axis=1)  # (R, N, p)
    rms_p = float(np.sqrt(np.mean(u_avg ** 2)))
    if not rms_p > 0:
        raise IdentError("the force signals are zero")
    # the motion the basis functions read (docs/method.md §1.2 step 3; §2.5), kept for with_basis
    basis = tuple(basis)
    readers = basis + tuple(motion_for)
    grid = excitation_grid(excited_lines, u_avg, fs, excitation_threshold)
    # spectra on every bin: of the averages, and of each period (hum, noise estimate)
    Y_all = np.fft.rfft(y_avg, axis=1) / N                                 # (R, bins, p)
    U_all = np.fft.rfft(u_avg, axis=1) / N                                 # (R, bins, m)
    Yq_all = (np.fft.rfft(Y4, axis=2) / N                                  # (R, P, bins, p)
              if P >= 2 and (drop_mains or noise_estimate in ("auto", "periods")) else None)
    # lines where mains hum stands out of the noise are left out of the processed set
    hum_lines: np.ndarray = np.zeros(0, int)
    hum_hz: list[float] = []
    if drop_mains:
        K, hum_lines, hum_hz = drop_mains_lines(Y_all, U_all, Yq_all, grid, K, fs, N)
    offsets, remove = offsets_report(U4, Y4, input_names, output_names, output_quantity,
                                     readers, remove_offsets, odd_grid=grid.kind == "odd")
    motion = None
    if readers:
        motion = basis_motion(Y4, y_avg, readers, output_names, output_quantity, fs, K, rms_p,
                              highpass_hz=highpass_hz, f_min=f_min,
                              integration_min_snr=integration_min_snr,
                              basis_oversample=basis_oversample, remove_offsets=remove)
    Uf = U_all[:, K]  # (R, F0, m)
    Yf = Y_all[:, K]  # (R, F0, p)
    excited = np.tile(np.isin(K, grid.lines), R)
    noise, noise_var, noise_source = output_noise(Yq_all, y_avg, Yf, K, grid, P, noise_estimate,
                                                  fs)
    noise_resolved = None
    if noise_var is not None:  # nothing below the finest record resolves (ident.core.noise)
        floor = resolution_variance(np.max(np.abs(Y4), axis=(0, 1, 2)), N)
        noise, noise_var, noise_resolved = floor_noise(noise, noise_var, floor)
    lines = np.tile(K, R)
    time_base_used, z, T_bl = line_map(lines, fs, N, time_base, output_quantity,
                                       bilinear_period_s)
    data = FrequencyData(
        time_base=time_base_used, bilinear_period_s=T_bl,
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


def _with_record_fields(record: Any, u: Any, y: Any, sample_rate_hz: float | None,
                        samples_per_period: int | None, transient_periods: int | None,
                        output_names: Sequence[str] | None, input_names: Sequence[str] | None,
                        excited_lines: Sequence[int] | np.ndarray | None) -> tuple[Any, ...]:
    """The keywords of :func:`prepare_frequency_data` with the record's fields where not given.

    Returns ``(u, y, sample_rate_hz, samples_per_period, transient_periods, output_names,
    input_names, excited_lines)``, unchanged without a record.
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
    return (u, y, sample_rate_hz, samples_per_period, transient_periods, output_names,
            input_names, excited_lines)


def _periodic_arrays(u: Any, y: Any, samples_per_period: int | None,
                     transient_periods: int | None, steady_periods: str,
                     output_names: Sequence[str] | None, input_names: Sequence[str] | None
                     ) -> tuple[np.ndarray, np.ndarray, int, tuple[str, ...], tuple[str, ...]]:
    """Forces and outputs as ``(R, P, N, channels)``, checked against each other and the names.

    Returns
    -------
    U4, Y4 : ndarray, shapes (R, P_tot, N, m) and (R, P_tot, N, p)
    transient_periods : int
        Checked: leaves at least one period.
    output_names, input_names : tuple of str
        Length ``p`` and ``m`` (default ``y0, ...`` and ``u0, ...``).

    Raises
    ------
    IdentError
        Shapes that do not match, no period left after the transients, an unknown
        ``steady_periods``, names that do not match the channels.
    """
    U4 = as_periodic(u, samples_per_period, "u")
    Y4 = as_periodic(y, samples_per_period, "y")
    if U4.shape[:3] != Y4.shape[:3]:
        raise IdentError(f"u and y do not match: u {U4.shape[:3]} vs y {Y4.shape[:3]} "
                         "(realizations, periods, samples)")
    P_tot, m, p = U4.shape[1], U4.shape[3], Y4.shape[3]
    P_tr = int(transient_periods or 0)
    if P_tr < 0 or P_tr >= P_tot:
        raise IdentError(f"transient_periods: {P_tr} leaves no period out of {P_tot} for "
                         f"the identification (fix: give fewer transient periods, at most "
                         f"{P_tot - 1}, in the config or the import, or record more periods)")
    if steady_periods not in ("auto", "all"):
        raise IdentError(f"steady_periods {plain.value(steady_periods)} is not one of auto, all")
    outputs = tuple(output_names) if output_names is not None else tuple(f"y{i}" for i in range(p))
    inputs = tuple(input_names) if input_names is not None else tuple(f"u{i}" for i in range(m))
    if len(outputs) != p:
        raise IdentError(f"{len(outputs)} output names for {p} output channels")
    if len(inputs) != m:
        raise IdentError(f"{len(inputs)} input names for {m} input channels")
    return U4, Y4, P_tr, outputs, inputs
