"""The frequency data of one identification problem, and what they are made of.

:class:`FrequencyData` (the processed lines: ``z``, the averaged output spectrum ``Y``, the
scaled extended input ``E``, the noise of ``Y``, how the lines and periods were chosen) and
:class:`BasisMotion` (the averaged motion the basis functions read), built by
:func:`ident.core.periodic.prepare_frequency_data` (docs/method.md §1.2);
:func:`data_report` (noise, excitation, offsets, periods: the result file's ``data`` record).
Containers only: no computation on time records here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

OutputQuantity = Literal["displacement", "velocity", "acceleration"]
#: How the DT model is read at the lines (FrequencyData.time_base; ident.core.fnsi.TIME_BASES).
TimeBase = Literal["band-limited", "zoh", "bilinear"]
OUTPUT_QUANTITIES: tuple[OutputQuantity, ...] = ("displacement", "velocity", "acceleration")


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
        variances ``(F, p)`` when the full matrices would exceed
        :data:`ident.core.averaging.FULL_COV_MAX_BYTES` and
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
        :func:`ident.core.extended_input.with_basis` can rebuild ``E`` for other basis
        parameters without the time data).
    noise_source : {'periods', 'non-excited lines', 'none'}
        Where ``noise_var`` comes from: the period-to-period spread (``P >= 2``), the
        off-grid lines of a sparse multisine (:mod:`ident.core.noise`, one period), or nowhere.
    noise_var : ndarray, shape (F, p) or None
        Noise variance of ``Y`` per line and output, whatever its source (the detection
        test and the report use it; ``noise_cov`` is what the weighting uses). Outputs
        whose estimate is below the record resolution hold that resolution
        (:func:`ident.core.averaging.floor_noise`).
    noise_resolved : bool ndarray, shape (p,) or None
        Outputs whose noise estimate stands above the resolution of a 24-bit record
        (:func:`ident.core.noise.resolution_variance`); None without an estimate. When none
        does, the data are noise-free for the fit: ``noise_cov`` is None (no weighting).
    excitation : dict or None
        How the excited lines were obtained (:meth:`ident.core.excitation.ExcitationGrid.to_dict`).
    offsets : dict or None
        DC of every channel and what was done with it (:func:`ident.core.motion.offsets_report`).
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
