"""Simulate an identified nonlinear model on a record it was not fitted to (docs/validate.md).

The model ``G(z)`` of the extended input ``e = [p; h(delta)]`` is driven by the record's
*measured* forces and its nonlinear forces read its *own* predicted motion:

- **harmonic balance** (periodic records, :func:`balance_outputs`): the model's periodic
  steady state on every line of the record's spectrum (:func:`prediction_band`), solved by
  :class:`ident.refine.harmonic_balance.HarmonicBalance` with no measured motion anywhere (its
  background is zeroed: the motion the nonlinear forces read is the model's; the measured
  motion only starts the Newton iterations), compared on the identified band;
- **time integration** (records without a period, :func:`time_outputs`): the model's
  continuous-time realisation stepped exactly (``oversample`` steps per sample, the
  band-limited interpolation of the measured force held at each step's midpoint), the
  nonlinear forces by Heun's predictor-corrector on the model's own output (displacement
  outputs only: the basis reads the relative displacement).

Both also give the **underlying linear model**'s output (the same ``G`` without its
nonlinear columns). :func:`output_errors` turns the spectra into the figures of merit:
per output the RMS of the measured output and of the simulation errors over the processed
lines, and ``20 log10(error / output)`` in dB (negative: below the output).

Shapes: spectra ``(R, F, p)`` complex (numpy DFT over one period divided by ``N``, one-sided
lines), like :class:`ident.core.periodic.FrequencyData`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, Sequence, cast

import numpy as np

from fnsi_lab import plain
from fnsi_lab.errors import WorkFailedError
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.refine.harmonic_balance import BalanceError, HarmonicBalance
from fnsi_lab.ident.refine.modal import ModalModel
from fnsi_lab.ident.core.periodic import FrequencyData, OutputQuantity, TimeBase

__all__ = ["SimulatedOutputs", "balance_outputs", "prediction_band", "prediction_data",
           "time_outputs", "output_errors"]


@dataclass
class SimulatedOutputs:
    """Measured and simulated output spectra on the compared lines.

    Attributes
    ----------
    frequency_hz : ndarray, shape (F,)
    measured, nonlinear, linear : complex ndarray, shape (R, F, p)
        Measured output; the nonlinear model's (None when it has no basis or its balance
        did not converge); the underlying linear model's.
    method : {'harmonic balance', 'time integration'}
    info : dict
        ``iterations``, ``residual``, ``converged``, ``reason`` (balance), ``oversample``
        (time integration).
    extended_input : complex ndarray, shape (R, F, m + s), or None
        The harmonic balance's extended input on the compared lines: the measured forces
        and the nonlinear forces of the model's own motion (None without a steady state).
    z : complex ndarray, shape (F,), or None
        The compared lines' ``z`` in the model's time base (harmonic balance).
    """

    frequency_hz: np.ndarray
    measured: np.ndarray
    nonlinear: np.ndarray | None
    linear: np.ndarray
    method: str
    info: dict = field(default_factory=dict)
    extended_input: np.ndarray | None = None
    z: np.ndarray | None = None


#: Relative residual ``||delta - Lambda G e(delta)|| / ||delta||`` at which the validation's
#: balance stops: an error of 1e-6 in the motion is 120 dB below it, far under any
#: validation error worth reading (the output-error refinement, whose gradients need more,
#: asks 1e-9).
BALANCE_TOLERANCE = 1e-6

#: Where Newton does not reach ``BALANCE_TOLERANCE`` in its iterations, its best iterate is
#: taken when it is below this residual, before the model is said to have no steady state: an error
#: of 1e-4 in the motion is 80 dB below it, and changes a validation error of -60 dB (better
#: than any measured here) by under 0.1 dB. On the Bouc-Wen beam (bench/RESULTS_beam.md) a
#: Jenkins model had stopped at 4e-6 after 60 iterations and was called "no periodic steady
#: state" (its Newton steps crawled: the preconditioner read every weak line's response as
#: the mean slope, since mended, :meth:`HarmonicBalance._diagonal_block`, 5 iterations to
#: 2e-11 now); at 1e-4 it predicts the record 8-10 dB better than the linear fit. The
#: fallback stays for models whose Newton steps still crawl. Models that reach 1e-6 keep
#: their numbers.
BALANCE_TOLERANCE_SLOW = 1e-4


def balance_outputs(model: StateSpaceModel, basis: Sequence[Nonlinearity],
                    data: FrequencyData, band_hz: tuple[float, float]) -> SimulatedOutputs:
    """Periodic steady state of the model and of its underlying linear part on ``data``.

    Parameters
    ----------
    model : StateSpaceModel
        Extended inputs ``[p; h]``, ``B``/``D`` in physical basis units.
    basis : sequence of Nonlinearity
        The model's basis (same order as its nonlinear columns).
    data : FrequencyData
        The record's lines, prepared with the model's time base (and the motion of the
        basis channels when there is a basis), over the *whole* spectrum where the model's
        motion is to be predicted (:func:`prediction_band`): its nonlinear forces read it.
    band_hz : (float, float)
        The lines compared (the band the model was identified on).

    Returns
    -------
    SimulatedOutputs
        On the compared lines; ``nonlinear`` None with ``info['converged'] = False`` when
        the balance found no steady state.
    """
    m = data.n_inputs
    R = data.n_realizations
    F = data.lines.size // R
    f = np.asarray(data.frequencies_hz)[:F]
    keep = (f >= band_hz[0]) & (f <= band_hz[1])
    measured = np.asarray(data.Y).reshape(R, F, -1)[:, keep]
    U = np.asarray(data.E[:, :m]).reshape(R, F, m)
    modal = ModalModel.from_matrices(model.a_d, model.b_d, model.c_d, model.d_d)
    G_data = modal.transfer(np.asarray(data.z)[:F][keep])            # (F_keep, p, m_e)
    linear = np.einsum("kpi,rki->rkp", G_data[:, :, :m], U[:, keep])
    if not basis:
        return SimulatedOutputs(f[keep], measured, None, linear, "harmonic balance",
                                {"converged": True, "iterations": 0, "residual": 0.0})
    bal = HarmonicBalance(data, basis)
    bal.background = np.zeros_like(bal.background)   # the model's motion only
    G = modal.transfer(bal.z, bal.low)
    try:   # one solve: its best iterate is taken at BALANCE_TOLERANCE_SLOW
        state = bal.solve(G, tolerance=BALANCE_TOLERANCE, max_iterations=60,
                          acceptable=BALANCE_TOLERANCE_SLOW)
    except BalanceError as exc:
        return SimulatedOutputs(f[keep], measured, None, linear, "harmonic balance",
                                {"converged": False, "reason": str(exc),
                                 "predicted_lines": int(bal.F0)})
    tolerance = (BALANCE_TOLERANCE if state.residual < BALANCE_TOLERANCE
                 else BALANCE_TOLERANCE_SLOW)
    H = state.H[:, bal.data_index][:, keep]                          # (R, F_keep, s)
    nonlinear = linear + np.einsum("kps,rks->rkp", G_data[:, :, m:], H)
    extended = np.concatenate([U[:, keep], H], axis=2)
    info = {"converged": True, "iterations": int(state.iterations),
            "residual": float(state.residual), "tolerance": tolerance,
            "predicted_lines": int(bal.F0),
            "predicted_band_hz": [float(bal.K.min() * data.sample_rate_hz / data.samples_per_period),
                                  float(bal.K.max() * data.sample_rate_hz / data.samples_per_period)]}
    return SimulatedOutputs(f[keep], measured, nonlinear, linear, "harmonic balance", info,
                            extended_input=extended, z=np.asarray(data.z)[:F][keep])


def prediction_band(band_hz: tuple[float, float], sample_rate_hz: float,
                    samples_per_period: int, output_quantity: str) -> tuple[float, float]:
    """The lines on which the balance predicts the model's motion: every line up to the one
    below Nyquist, and from the first line for displacement outputs (velocity and
    acceleration outputs: from the band's lower edge; :class:`HarmonicBalance` predicts the
    lines under it less the model's static terms).

    Truncating the motion to the identified band is not enough: on a one-mode Duffing
    oscillator (2 % damping, 60 dB noise) its own model predicted its record 20 dB below
    the output with the band's lines only, 38 dB with every line; the intermodulation
    motion under the band and the harmonics above it, amplified at the resonance, carry
    that difference."""
    df = float(sample_rate_hz) / int(samples_per_period)
    top = float(sample_rate_hz) / 2 - df
    low = df if output_quantity == "displacement" else float(band_hz[0])
    return (low, top)


def prediction_data(inp: Any, basis: Sequence[Nonlinearity], band_hz: tuple[float, float],
                    quantity: OutputQuantity, processing: Mapping[str, Any], *,
                    transient_periods: int | None, time_base: TimeBase,
                    bilinear_period_s: float | None,
                    allow_zero_basis: bool = False) -> FrequencyData:
    """A periodic record prepared for :func:`balance_outputs`: the lines of
    :func:`prediction_band`, the basis channels' motion, and the record-to-spectrum
    settings the model was identified with (``processing``, the result's ``processing``:
    :func:`ident.core.model_json.processing_json`). The preparation's warnings are raised
    as :class:`ident.errors.IdentWarning` (the caller records or drops them).

    Parameters
    ----------
    inp : IdentInput
        The record, its channels selected as the model's.
    basis : sequence of Nonlinearity
    band_hz : (float, float)
        The band the model was identified on.
    quantity : str
        The outputs' quantity.
    processing : mapping
        ``highpass_hz``, ``steady_state_tolerance``, ``steady_periods``,
        ``basis_oversample``, ``integration_min_snr``.
    transient_periods : int or None
    time_base, bilinear_period_s
        The model's time base.
    allow_zero_basis : bool
        False (``ident``'s own check): a basis function identically zero on the record's
        measured motion is refused (:class:`ident.errors.IdentError`, from
        :func:`ident.core.extended_input.with_basis`). True (``fnsi-lab validate``): the data
        hold the basis channels' motion but no basis columns (the balance reads the
        model's own motion, never the measured one), and such a function is only an
        :class:`ident.errors.IdentWarning`: a stop that never closes on a low-level record
        predicts no contact force there, a valid prediction.
    """
    if allow_zero_basis and basis:
        data = _prepare(inp, (), band_hz, quantity, processing,
                               transient_periods=transient_periods, time_base=time_base,
                               bilinear_period_s=bilinear_period_s, motion_for=basis)
        _warn_zero_basis(data, basis)
        return data
    return _prepare(inp, basis, band_hz, quantity, processing,
                    transient_periods=transient_periods, time_base=time_base,
                    bilinear_period_s=bilinear_period_s)


def _warn_zero_basis(data: FrequencyData, basis: Sequence[Nonlinearity]) -> None:
    """An :class:`ident.errors.IdentWarning` naming the basis functions that are identically
    zero on the record's measured motion (``data.motion``)."""
    import warnings

    from fnsi_lab.ident.core.basis import coefficient_names
    from fnsi_lab.ident.core.extended_input import basis_spectra
    from fnsi_lab.ident.errors import IdentWarning

    if data.motion is None:
        return
    _, rms_h = basis_spectra(tuple(basis), data.motion)
    dead = [n for n, v in zip(coefficient_names(tuple(basis)), rms_h) if v == 0]
    if dead:
        warnings.warn(f"basis functions {plain.names(dead, quote=True)} are identically zero "
                      "on the record's measured motion (a clearance larger than the motion: no "
                      "contact there); the model's own motion is simulated all the same",
                      IdentWarning,
                      stacklevel=3)


def _prepare(inp: Any, basis: Sequence[Nonlinearity], band_hz: tuple[float, float],
             quantity: OutputQuantity, processing: Mapping[str, Any], *,
             transient_periods: int | None, time_base: TimeBase,
             bilinear_period_s: float | None,
             motion_for: Sequence[Nonlinearity] = ()) -> FrequencyData:
    """:func:`prediction_data`'s preparation (``motion_for``: channels whose motion is kept
    without basis columns)."""
    from fnsi_lab.ident.core.periodic import prepare_frequency_data

    return prepare_frequency_data(
        u=inp.u, y=inp.y, sample_rate_hz=inp.sample_rate_hz,
        samples_per_period=inp.samples_per_period, basis=basis, motion_for=motion_for,
        band_hz=prediction_band(band_hz, inp.sample_rate_hz, inp.samples_per_period, quantity),
        transient_periods=transient_periods, output_quantity=quantity,
        output_names=inp.output_channels, input_names=inp.input_channels,
        excited_lines=inp.excited_lines, highpass_hz=processing.get("highpass_hz"),
        steady_state_tolerance=float(processing.get("steady_state_tolerance", 0.05)),
        steady_periods=cast(Literal["auto", "all"], str(processing.get("steady_periods", "auto"))),
        time_base=time_base, bilinear_period_s=bilinear_period_s,
        basis_oversample=int(processing.get("basis_oversample", 8)),
        integration_min_snr=processing.get("integration_min_snr", 4.0))


def _zoh(a_c: np.ndarray, b_c: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(expm(A h), int_0^h expm(A s) ds B)``."""
    import scipy.linalg as sla

    n, k = a_c.shape[0], b_c.shape[1]
    aug = np.zeros((n + k, n + k))
    aug[:n, :n], aug[:n, n:] = a_c * h, b_c * h
    e = sla.expm(aug)
    return e[:n, :n], e[:n, n:]


def time_outputs(model: StateSpaceModel, basis: Sequence[Nonlinearity], u: np.ndarray,
                 y: np.ndarray, output_names: Sequence[str], band_hz: tuple[float, float],
                 *, oversample: int = 8) -> SimulatedOutputs:
    """Integrate the model (and its underlying linear part) from rest under a measured force.

    Parameters
    ----------
    model : StateSpaceModel
    basis : sequence of Nonlinearity
        Displacement outputs only (the basis reads the outputs' relative motion).
    u : ndarray, shape (n_samples, m)
        Measured forces.
    y : ndarray, shape (n_samples, p)
        Measured outputs (compared on the lines of ``band_hz``).
    output_names : sequence of str
    band_hz : (float, float)
    oversample : int
        Internal steps per sample.

    Returns
    -------
    SimulatedOutputs
        Spectra of the whole record (R = 1) on the lines inside ``band_hz``.
    """
    u = np.asarray(u, float).reshape(len(u), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    n, m = u.shape
    fs = float(model.sample_rate_hz)
    os_ = int(oversample)
    h = 1.0 / (fs * os_)
    a_c, b_c, c_c, d_c = model.a_c, model.b_c, model.c_c, model.d_c
    ad, bd = _zoh(a_c, b_c, h)
    # band-limited interpolation of the measured force (as an acquisition's samples mean)
    spec = np.fft.rfft(u, axis=0)
    fine = np.fft.irfft(spec, n=n * os_, axis=0) * os_
    L = (np.stack([nl.location_vector(output_names) for nl in basis])
         if basis else np.zeros((0, y.shape[1])))
    sims = {}
    for name, nl_on in (("linear", False), ("nonlinear", True)):
        if nl_on and not basis:
            continue
        sims[name] = _integrate(ad, bd, a_c, b_c, c_c, d_c, fine, m, os_,
                                list(basis) if nl_on else [], L, name, fs)
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    keep = (freqs >= band_hz[0]) & (freqs <= band_hz[1]) & (freqs > 0) & (freqs < fs / 2)

    def lines(x):
        return (np.fft.rfft(x, axis=0)[keep] / n)[None]

    return SimulatedOutputs(freqs[keep], lines(y),
                            lines(sims["nonlinear"]) if "nonlinear" in sims else None,
                            lines(sims["linear"]), "time integration",
                            {"converged": True, "oversample": os_})


def _integrate(ad, bd, a_c, b_c, c_c, d_c, fine, m, os_, basis, L, name, fs):
    """Step the CT model exactly over each internal step (input at the step's midpoint);
    the nonlinear forces by Heun's predictor-corrector (second order). A hysteretic element
    (Jenkins) carries its spring's elongation from step to step (play operator, from rest),
    updated once per step at the corrected motion. Returns the outputs at every ``os_``-th
    step, shape (n_samples, p)."""
    n_fine = fine.shape[0]
    x = np.zeros(a_c.shape[0])
    e = np.zeros(b_c.shape[1])
    out = np.empty((n_fine // os_, c_c.shape[0]))
    up = np.vstack([fine, fine[:1]])          # the force's periodic continuation

    memory = {i: [0.0, None] for i, nl in enumerate(basis) if nl.hysteretic}  # [z, delta]

    def forces(x_, e_, commit=False):
        """Basis columns at state ``x_`` (the feedthrough reads ``e_``'s forces); ``commit``
        moves the hysteretic elements' memory to this motion."""
        disp = c_c @ x_ + d_c @ e_
        vel = c_c @ (a_c @ x_ + b_c @ e_)
        delta, delta_dot = L @ disp, L @ vel
        cols = []
        for i, nl in enumerate(basis):
            if i in memory:   # play operator: z + the motion's increment, within +-slip
                z, last = memory[i]
                d = float(delta[i]) + nl.offset
                z = float(np.clip(z + d - (d if last is None else last), -nl.slip, nl.slip))
                if commit:
                    memory[i] = [z, d]
                cols.append(np.array([z]))
                continue
            cols.append(nl.evaluate(delta[i:i + 1],
                                    delta_dot[i:i + 1] if nl.needs_velocity else None)[0])
        return np.concatenate(cols) if cols else np.zeros(0)

    e[:m] = up[0]
    if basis:
        e[m:] = forces(x, e, commit=True)
    for k in range(n_fine):
        if k % os_ == 0:
            out[k // os_] = c_c @ x + d_c @ e
        mid = e.copy()
        mid[:m] = 0.5 * (up[k] + up[k + 1])
        x_new = ad @ x + bd @ mid
        if basis:
            e_next = e.copy()
            e_next[:m] = up[k + 1]
            h_pred = forces(x_new, e_next)
            mid[m:] = 0.5 * (e[m:] + h_pred)
            x_new = ad @ x + bd @ mid
            e_next[m:] = forces(x_new, e_next, commit=True)
            e = e_next
        else:
            e[:m] = up[k + 1]
        x = x_new
        if not np.all(np.isfinite(x)):
            raise WorkFailedError(f"the {name} model diverged in the time integration (an "
                                  f"unstable model, or a nonlinear term too stiff for "
                                  f"{fs * os_:g} Hz steps: raise the oversampling)")
    return out


def _rms(spec: np.ndarray) -> np.ndarray:
    """RMS per output of a signal given by its one-sided lines (R, F, p), mean over R."""
    return np.sqrt(np.mean(2.0 * np.sum(np.abs(spec) ** 2, axis=1), axis=0))


def _db(err: np.ndarray, ref: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.maximum(err, 1e-300) / np.where(ref > 0, ref, 1.0))


def output_errors(sim: SimulatedOutputs, output_names: Sequence[str],
                  linear_fit: np.ndarray | None = None) -> list[dict[str, Any]]:
    """Per output: ``name``, ``output_rms``, ``error_rms``, ``error_db``,
    ``linear_error_rms``, ``linear_error_db`` (see the module doc; ``error_*`` None when
    the nonlinear model has no simulation); with ``linear_fit`` (another linear model's
    output on the same lines, shape (R, F, p)) also ``linear_fit_error_rms``,
    ``linear_fit_error_db``."""
    y = _rms(sim.measured)
    lin = _rms(sim.measured - sim.linear)
    nl = None if sim.nonlinear is None else _rms(sim.measured - sim.nonlinear)
    lin_db = _db(lin, y)
    nl_db = None if nl is None else _db(nl, y)
    fit = None if linear_fit is None else _rms(sim.measured - linear_fit)
    out = []
    for i, name in enumerate(output_names):
        row = {"name": str(name), "output_rms": float(y[i]),
               "error_rms": None if nl is None else float(nl[i]),
               "error_db": None if nl_db is None else float(nl_db[i]),
               "linear_error_rms": float(lin[i]), "linear_error_db": float(lin_db[i])}
        if fit is not None:
            row.update(linear_fit_error_rms=float(fit[i]),
                       linear_fit_error_db=float(_db(fit, y)[i]))
        out.append(row)
    return out
