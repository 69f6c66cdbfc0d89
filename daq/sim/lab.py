"""Lab realism for simulated multisine tests: what a real acquisition adds to the structure.

A simulation sampled at the output rate is cleaner than any lab record. This module turns a
:class:`~fnsi_lab.daq.sim.model.StructuralModel` and a multisine into records with the
defects identification meets on real data, each optional (:class:`LabRealism`):

- **DAC hold**: the generator holds each drive sample for one sample period (zero-order
  hold), so the structure sees a staircase (sinc droop, half-sample delay, images above fs);
- **anti-alias filter**: a causal analog Butterworth filter on every measured channel
  (force included, as on a real front end) before sampling; what it lets through above
  fs/2 aliases;
- **coloured sensor noise** (white or pink, at a given SNR per channel, input too);
- **mains hum** at 50/60 Hz and odd harmonics, not synchronised with the sampling (it leaks);
- **DC offsets** on every channel;
- **one period per realisation** after a transient (the usual layout of lab multisine
  tests), accelerometers (``quantity='acceleration'``).

The simulation itself runs at ``hold_factor * fs`` (:func:`~fnsi_lab.daq.sim.integrate.simulate`,
periodic steady state), so the hold, the filter and the aliasing act on a signal that
carries the nonlinear harmonics above fs/2. Pure numpy/scipy; shapes follow the project:
records ``(n_realizations, n_periods, n_samples, n_channels)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal as ssig

from fnsi_lab.daq.multisine import Multisine
from fnsi_lab.daq.sim.integrate import simulate
from fnsi_lab.daq.sim.model import StructuralModel
from fnsi_lab.daq.sim.nonlinear import NonlinearElement
from fnsi_lab.errors import ConfigError

__all__ = ["LabRealism", "LabRecord", "duffing_model", "lab_experiment", "add_disturbances"]


@dataclass(frozen=True)
class LabRealism:
    """Which lab defects to add (all off by default: an ideal band-limited acquisition).

    Attributes
    ----------
    dac_hold : bool
        Drive held between samples (zero-order hold DAC).
    antialias_order : int or None
        Order of the causal Butterworth anti-alias filter on every channel; None: an ideal
        one (nothing at or above fs/2 is sampled).
    antialias_cutoff : float
        Its -3 dB frequency as a fraction of fs.
    snr_db : float or None
        Output noise, dB below each output's RMS.
    input_snr_db : float or None
        Noise on the measured drive, dB below its RMS.
    noise_colour : {'white', 'pink'}
        Pink: power spectral density falling as 1/f (sensor 1/f noise).
    hum_hz : float or None
        Mains frequency (50 or 60 Hz); hum at it and its 3rd harmonic.
    hum_level : float
        Hum amplitude of the fundamental, fraction of each channel's RMS (the 3rd harmonic
        has a third of it).
    offset : float
        DC offset added to every channel, fraction of its RMS.
    quantity : {'displacement', 'velocity', 'acceleration'}
        What the response sensors measure.
    transient_periods : int
        Periods simulated and dropped before the recorded one(s).
    periods : int
        Recorded periods per realisation (1: the usual lab layout).
    hold_factor : int
        Simulation rate / fs (the hold and the filter act at this rate).
    """

    dac_hold: bool = False
    antialias_order: int | None = None
    antialias_cutoff: float = 0.4
    snr_db: float | None = None
    input_snr_db: float | None = None
    noise_colour: str = "white"
    hum_hz: float | None = None
    hum_level: float = 0.0
    offset: float = 0.0
    quantity: str = "displacement"
    transient_periods: int = 1
    periods: int = 1
    hold_factor: int = 8


@dataclass(frozen=True, eq=False)
class LabRecord:
    """A simulated lab record.

    Attributes
    ----------
    u : ndarray, shape (R, P, N, m)
        Measured drive (after hold, filter, noise, hum, offset).
    y : ndarray, shape (R, P, N, p)
        Measured responses.
    sample_rate_hz : float
    samples_per_period : int
    excited_lines : ndarray of int
        DFT bins of one period that the multisine excites.
    output_names, input_names : tuple of str
    truth : dict
        ``{element name: coefficients}`` of the simulated model.
    """

    u: np.ndarray
    y: np.ndarray
    sample_rate_hz: float
    samples_per_period: int
    excited_lines: np.ndarray
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    truth: dict


def duffing_model(mass: float, damping: float, stiffness: float, k3: float, *,
                  name: str = "y0", input_name: str = "u0") -> StructuralModel:
    """One-DOF Duffing oscillator ``m y'' + c y' + k y + k3 y^3 = u`` (one channel ``name``)."""
    el = NonlinearElement("k3", "polynomial", np.ones(1), {"k": float(k3)}, exponent=3)
    return StructuralModel(mass=np.array([[mass]]), damping=np.array([[damping]]),
                           stiffness=np.array([[stiffness]]), dof_names=(name,),
                           force_matrix=np.ones((1, 1)), input_names=(input_name,),
                           measured={name: 0}, nonlinearities=(el,), name="duffing",
                           description="one-DOF Duffing oscillator")


def _filter_and_sample(x_fine: np.ndarray, fs_fine: float, factor: int,
                       lab: LabRealism) -> np.ndarray:
    """One fine-rate period ``(N * factor, c)`` -> filtered, sampled period ``(N, c)``.

    The causal Butterworth response is applied line by line (exact periodic steady state);
    whatever it leaves above fs/2 aliases when every ``factor``-th sample is taken. Without
    a filter order the filter is ideal (lines at and above fs/2 removed).
    """
    X = np.fft.rfft(x_fine, axis=0)
    if not lab.antialias_order:     # ideal acquisition: nothing at or above fs/2 is sampled
        X[x_fine.shape[0] // (2 * factor):] = 0.0
    else:
        fs = fs_fine / factor
        b, a = ssig.butter(int(lab.antialias_order), 2 * np.pi * lab.antialias_cutoff * fs,
                           analog=True)
        w = 2 * np.pi * np.fft.rfftfreq(x_fine.shape[0], 1.0 / fs_fine)
        _, h = ssig.freqs(b, a, worN=w)
        X = X * h[:, None]
    return np.fft.irfft(X, n=x_fine.shape[0], axis=0)[::factor]


def _noise(rng: np.random.Generator, shape: tuple[int, int], colour: str) -> np.ndarray:
    """Unit-RMS noise ``(n_samples, c)``, white or pink (1/f power), zero mean."""
    e = rng.standard_normal(shape)
    if colour == "pink":
        E = np.fft.rfft(e, axis=0)
        k = np.arange(E.shape[0], dtype=float)
        k[0] = np.inf
        E /= np.sqrt(k)[:, None]
        e = np.fft.irfft(E, n=shape[0], axis=0)
    elif colour != "white":
        raise ConfigError(f"noise_colour must be 'white' or 'pink', got {colour!r}")
    e -= e.mean(axis=0)
    return e / np.sqrt(np.mean(e ** 2, axis=0))


def add_disturbances(x: np.ndarray, sample_rate_hz: float, rng: np.random.Generator, *,
                     snr_db=None, noise_colour: str = "white", hum_hz: float | None = None,
                     hum_level: float = 0.0, offset: float = 0.0, t0_s: float = 0.0
                     ) -> np.ndarray:
    """Sensor noise, mains hum and DC offsets on recorded channels.

    Parameters
    ----------
    x : ndarray, shape (n_samples, n_channels)
        Clean channels.
    sample_rate_hz : float
    rng : numpy.random.Generator
    snr_db : float, sequence of (float or None), or None
        Noise RMS ``10^(-snr/20)`` times each channel's RMS (per channel when a sequence;
        None: no noise on that channel).
    noise_colour : {'white', 'pink'}
    hum_hz, hum_level : float
        Hum at ``hum_hz`` and its 3rd harmonic (a third of it), amplitude ``hum_level``
        times each channel's RMS, random phases; the mains is not synchronised with the
        sampling (``t0_s`` shifts it).
    offset : float
        DC offset, fraction of each channel's RMS.

    Returns
    -------
    ndarray, shape (n_samples, n_channels)
    """
    x = np.array(x, float)
    n, c = x.shape
    rms = np.sqrt(np.mean(x ** 2, axis=0))
    snr = [snr_db] * c if snr_db is None or np.isscalar(snr_db) else list(snr_db)
    if any(v is not None for v in snr):
        e = _noise(rng, (n, c), noise_colour)
        for i, v in enumerate(snr):
            if v is not None:
                x[:, i] += e[:, i] * rms[i] * 10 ** (-float(v) / 20)
    if hum_hz and hum_level:
        t = np.arange(n) / float(sample_rate_hz) + t0_s
        ph = rng.uniform(0, 2 * np.pi, 2)
        hum = (np.sin(2 * np.pi * hum_hz * t + ph[0])
               + np.sin(2 * np.pi * 3 * hum_hz * t + ph[1]) / 3)
        x += hum_level * hum[:, None] * rms
    return x + offset * rms


def lab_experiment(model: StructuralModel, excitation: Multisine, lab: LabRealism = LabRealism(),
                   *, seed: int = 0, oversample: int = 4) -> LabRecord:
    """Simulate a multisine test of ``model`` as a lab would record it.

    Parameters
    ----------
    model : StructuralModel
        Driven at its first input by ``excitation``; every measured DOF is recorded.
    excitation : Multisine
        One period per realisation is used (``excitation.period(r)``).
    lab : LabRealism
    seed : int
        Seed of the noise and hum phases (realisation ``r`` uses ``[seed, r]``).
    oversample : int
        Internal integration steps per simulated sample (at ``hold_factor * fs``).

    Returns
    -------
    LabRecord
    """
    fs = float(excitation.sample_rate_hz)
    N = int(excitation.samples_per_period)
    H = max(int(lab.hold_factor), 1)
    fs_fine = fs * H
    n_per = lab.transient_periods + lab.periods
    m = model.n_inputs
    us, ys = [], []
    for r in range(excitation.n_realizations):
        drive = excitation.period(r)
        if lab.dac_hold:
            fine = np.repeat(drive, H)
        else:   # band-limited drive: trigonometric interpolation of the samples
            spec = np.fft.rfft(drive)
            fine = np.fft.irfft(spec, n=N * H) * H
        force = np.zeros((N * H * n_per, m))
        force[:, 0] = np.tile(fine, n_per)
        res = simulate(model, force, fs_fine, oversample=oversample, periodic=N * H,
                       quantities=(lab.quantity,), passband=0.45,
                       count_from=lab.transient_periods * N * H)
        resp = res.get(lab.quantity)[lab.transient_periods * N * H:]     # (P N H, p)
        u_per, y_per = [], []
        for q in range(lab.periods):
            sl = slice(q * N * H, (q + 1) * N * H)
            u_per.append(_filter_and_sample(force[sl], fs_fine, H, lab))
            y_per.append(_filter_and_sample(resp[sl], fs_fine, H, lab))
        u_r, y_r = np.stack(u_per), np.stack(y_per)                       # (P, N, c)
        rng = np.random.default_rng([seed, r])
        t0 = rng.uniform(0, 1)
        u_r = add_disturbances(u_r.reshape(-1, u_r.shape[2]), fs, rng, snr_db=lab.input_snr_db,
                               noise_colour=lab.noise_colour, hum_hz=lab.hum_hz,
                               hum_level=lab.hum_level, offset=lab.offset, t0_s=t0
                               ).reshape(u_r.shape)
        y_r = add_disturbances(y_r.reshape(-1, y_r.shape[2]), fs, rng, snr_db=lab.snr_db,
                               noise_colour=lab.noise_colour, hum_hz=lab.hum_hz,
                               hum_level=lab.hum_level, offset=lab.offset, t0_s=t0
                               ).reshape(y_r.shape)
        us.append(u_r)
        ys.append(y_r)
    truth = {el.name: dict(el.coefficients) for el in model.nonlinearities}
    return LabRecord(u=np.stack(us), y=np.stack(ys), sample_rate_hz=fs, samples_per_period=N,
                     excited_lines=np.asarray(excitation.excited_lines),
                     output_names=tuple(model.measured), input_names=tuple(model.input_names),
                     truth=truth)
