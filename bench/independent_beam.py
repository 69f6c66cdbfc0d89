"""An independent beam with a Bouc-Wen lap joint: a simulator that shares no code with
``daq/sim`` nor with ``bench/independent_joint.py``.

Written from scratch to judge fnsi-lab on a structure and a joint law none of its
simulators wrote (issue 29: "say when the data cannot tell, never worse than the linear
fit, validate on another record, find the nonlinearity and its shape"). What it is:

- **structure**: a clamped-clamped aluminium Euler-Bernoulli beam (3 m, 50 x 8 mm), 18
  Hermite cubic elements with consistent mass, cut at 7/18 of the span into two segments
  joined by a **lap joint**: a linear rotational spring (2e3 N m/rad) and, on the
  transverse relative displacement ``delta = w_left - w_right``, a **Bouc-Wen**
  hysteretic force (not in fnsi-lab's element list)::

      F = alpha k0 delta + (1 - alpha) k0 z,
      dz/dt = A delta' - beta |delta'| |z|^(n-1) z - gamma delta' |z|^n

  (small amplitude: ``z = A delta``, an equivalent stiffness ``k0 (alpha + (1-alpha) A)``;
  large amplitude: the hysteretic part saturates at ``(1-alpha) k0 (A/(beta+gamma))^(1/n)``
  and the joint's tangent stiffness falls towards ``alpha k0``), plus an optional
  two-sided clearance contact (off by default);
- **damping**: modal damping of the joint-stuck beam, ``zeta(f) = 0.4 % + 1.5 %/f[Hz]``
  (0.73 % at the first mode, 4.6 Hz; 0.41 % at 120 Hz), 5 % above 400 Hz;
- **shaker**: an armature (0.2 kg, 2 kN/m suspension, 15 N s/m back-EMF) driven by the
  commanded multisine and connected by a stinger (1e6 N/m) to the beam at 0.67 m; the
  measured force is the stinger's (force drop-out at resonances, distortion in the force);
- **test**: 512 Hz, periods of 8192 samples (0.0625 Hz lines), full-grid random-phase
  multisine 3-140 Hz (about 8 modes), 9 periods from rest (the first transient), a
  different phase realisation per level; accelerations at the drive point, on both sides
  of the joint (``jointL``, ``jointR``) and at 2.33 m (``far``), in m/s^2;
- **integrator**: the stuck linear model (beam + shaker) diagonalised in complex modes
  and propagated exactly over each 8192 Hz step (input held at the step's midpoint value);
  the Bouc-Wen correction force ``(1-alpha) k0 (z - A delta)`` enters as a second input,
  evaluated by a predictor-corrector (trapezoid over the step) with ``z`` integrated
  along ``delta`` by a midpoint rule; compiled with numba (a project dependency);
- **lab**: causal FIR anti-alias filter (513 taps, cut-off 205 Hz at 8192 Hz) and
  decimation 8192 -> 512 Hz (the same delay on every channel), white sensor noise 50 dB
  below each channel's RMS at each level (``--snr-db``; amplifiers ranged per level), DC
  offsets on every channel (2 % of its RMS at the middle level).

Run::

    python bench/independent_beam.py --out beam              # 6 levels, ~2 s each
    python bench/independent_beam.py --out beam --check      # locked joint: FRF vs exact

Each level is ``DIR/beam-rmsX.npz`` (docs/ident.md, "INPUT formats": ``u``, ``y``,
``fs``, ``N``, ``channels``, ``input_channels``, ``quantity``, ``transient_samples``) and
``DIR/beam-rmsX.truth.json`` (modes with the joint stuck, slipping and removed, the Bouc-Wen
parameters, the joint's small-amplitude stiffness, the run's joint motion and hysteresis
energy). Also ``DIR/beam-linear.yaml`` (an IDENT.yaml the docs would have a user write).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal
from numba import njit

OVERSAMPLE = 16
FS_HZ = 512.0
SAMPLES_PER_PERIOD = 8192
PERIODS = 9
BAND_HZ = (3.0, 140.0)
ANTI_ALIAS_TAPS = 513
CHANNELS = ("drive", "jointL", "jointR", "far")
INPUT_CHANNEL = "F-drive"


@dataclass
class BeamParameters:
    """Geometry and material of the beam (SI units)."""

    length_m: float = 3.0
    n_elements: int = 18
    joint_element: int = 7          # the joint sits at node joint_element (x = 7/18 L)
    width_m: float = 0.05
    thickness_m: float = 0.008
    youngs_pa: float = 70e9
    density_kg_m3: float = 2700.0
    k_rotation_nm_rad: float = 2.0e3
    drive_node: int = 4             # global node numbers (0 .. n_elements)
    far_node: int = 14


@dataclass
class BoucWenJoint:
    """Bouc-Wen lap joint on ``delta = w_left - w_right`` (m, N)."""

    k0_n_m: float = 2.0e4
    alpha: float = 0.3
    A: float = 1.0
    beta_per_mn: float = 0.0      # set from yield_m in __post_init__ when 0
    gamma_per_mn: float = 0.0
    n: float = 1.5
    yield_m: float = 40e-6        # (A / (beta + gamma))^(1/n)
    beta_share: float = 0.7       # beta / (beta + gamma)
    clearance_m: float = 0.0      # two-sided contact (0: none)
    k_contact_n_m: float = 0.0
    locked: bool = False          # True: z = A delta (a linear joint of k0)

    def __post_init__(self) -> None:
        if self.beta_per_mn == 0.0 and self.gamma_per_mn == 0.0:
            total = self.A / self.yield_m ** self.n
            self.beta_per_mn = self.beta_share * total
            self.gamma_per_mn = (1.0 - self.beta_share) * total

    @property
    def small_amplitude_stiffness_n_m(self) -> float:
        return self.k0_n_m * (self.alpha + (1.0 - self.alpha) * self.A)

    @property
    def saturation_force_n(self) -> float:
        return (1.0 - self.alpha) * self.k0_n_m * (self.A / (self.beta_per_mn + self.gamma_per_mn)) ** (1.0 / self.n)


@dataclass
class Shaker:
    armature_kg: float = 0.2
    suspension_n_m: float = 2.0e3
    damping_ns_m: float = 15.0
    stinger_n_m: float = 1.0e6


def modal_damping_ratio(frequency_hz: np.ndarray) -> np.ndarray:
    """Modal damping of the joint-stuck beam: 0.4 % + 1.5 %/f, 5 % above 400 Hz."""
    zeta = 0.004 + 0.015 / np.maximum(frequency_hz, 1e-3)
    return np.where(frequency_hz > 400.0, 0.05, zeta)


# ----------------------------------------------------------------------------- FE model
def _element_matrices(ei: float, rho_a: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    k = ei / h ** 3 * np.array([[12, 6 * h, -12, 6 * h], [6 * h, 4 * h * h, -6 * h, 2 * h * h],
                                [-12, -6 * h, 12, -6 * h], [6 * h, 2 * h * h, -6 * h, 4 * h * h]])
    m = rho_a * h / 420 * np.array([[156, 22 * h, 54, -13 * h], [22 * h, 4 * h * h, 13 * h, -3 * h * h],
                                    [54, 13 * h, 156, -22 * h], [-13 * h, -3 * h * h, -22 * h, 4 * h * h]])
    return k, m


@dataclass
class BeamModel:
    """Beam matrices (clamped DOFs removed) and the DOF indices the test needs."""

    stiffness_without_joint: np.ndarray   # (n_dof, n_dof): rotation spring only
    mass: np.ndarray
    joint_vector: np.ndarray              # L: delta = L @ q
    dof: dict = field(default_factory=dict)   # name -> transverse DOF index


def build_beam(p: BeamParameters) -> BeamModel:
    """Two beam segments, node ``joint_element`` duplicated (left / right of the joint)."""
    ei = p.youngs_pa * p.width_m * p.thickness_m ** 3 / 12.0
    rho_a = p.density_kg_m3 * p.width_m * p.thickness_m
    h = p.length_m / p.n_elements
    n_left = p.joint_element + 1
    n_nodes = p.n_elements + 2
    n_full = 2 * n_nodes
    k_full = np.zeros((n_full, n_full))
    m_full = np.zeros((n_full, n_full))

    def node_index(global_node: int, side: str = "") -> int:
        if global_node < p.joint_element or (global_node == p.joint_element and side == "left"):
            return global_node
        return global_node + 1

    for e in range(p.n_elements):
        a = node_index(e, "left")
        b = node_index(e + 1, "left") if e + 1 == p.joint_element else node_index(e + 1)
        if e == p.joint_element:
            a = node_index(e, "right")
        ke, me = _element_matrices(ei, rho_a, h)
        idx = [2 * a, 2 * a + 1, 2 * b, 2 * b + 1]
        k_full[np.ix_(idx, idx)] += ke
        m_full[np.ix_(idx, idx)] += me
    left, right = node_index(p.joint_element, "left"), node_index(p.joint_element, "right")
    r1, r2 = 2 * left + 1, 2 * right + 1
    k_full[r1, r1] += p.k_rotation_nm_rad
    k_full[r2, r2] += p.k_rotation_nm_rad
    k_full[r1, r2] -= p.k_rotation_nm_rad
    k_full[r2, r1] -= p.k_rotation_nm_rad
    fixed = {0, 1, n_full - 2, n_full - 1}
    free = [i for i in range(n_full) if i not in fixed]
    position = {full: i for i, full in enumerate(free)}
    joint_vector = np.zeros(len(free))
    joint_vector[position[2 * left]] = 1.0
    joint_vector[position[2 * right]] = -1.0
    dof = {"drive": position[2 * node_index(p.drive_node)],
           "jointL": position[2 * left], "jointR": position[2 * right],
           "far": position[2 * node_index(p.far_node)]}
    return BeamModel(k_full[np.ix_(free, free)], m_full[np.ix_(free, free)], joint_vector, dof)


def beam_modes(beam: BeamModel, joint_stiffness_n_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Undamped modes (Hz, mass-normalised shapes) with a linear joint spring."""
    k = beam.stiffness_without_joint + joint_stiffness_n_m * np.outer(beam.joint_vector, beam.joint_vector)
    eigenvalues, shapes = scipy.linalg.eigh(k, beam.mass)
    return np.sqrt(np.maximum(eigenvalues, 0.0)) / (2 * np.pi), shapes


def beam_damping(beam: BeamModel, stuck_stiffness_n_m: float) -> np.ndarray:
    """Modal damping matrix of the joint-stuck beam: C = M Phi diag(2 zeta w) Phi^T M."""
    f_hz, phi = beam_modes(beam, stuck_stiffness_n_m)
    w = 2 * np.pi * f_hz
    mp = beam.mass @ phi
    return mp @ np.diag(2 * modal_damping_ratio(f_hz) * w) @ mp.T


def exact_frf(beam: BeamModel, joint: BoucWenJoint, frequency_hz: np.ndarray) -> np.ndarray:
    """Accelerance (m/s^2/N) of the stuck-joint beam from the drive force to CHANNELS.

    Returns ``(n_lines, n_channels)``.
    """
    k_stuck = joint.small_amplitude_stiffness_n_m
    k = beam.stiffness_without_joint + k_stuck * np.outer(beam.joint_vector, beam.joint_vector)
    c = beam_damping(beam, k_stuck)
    b = np.zeros(len(k))
    b[beam.dof["drive"]] = 1.0
    out = np.empty((len(frequency_hz), len(CHANNELS)), complex)
    for i, f in enumerate(frequency_hz):
        w = 2 * np.pi * f
        q = np.linalg.solve(k - w * w * beam.mass + 1j * w * c, b)
        out[i] = -w * w * q[[beam.dof[name] for name in CHANNELS]]
    return out


# -------------------------------------------------------------------- state space + ZOH
@dataclass
class Discrete:
    """Complex-diagonal exact discretisation of the stuck beam + shaker."""

    pole_step: np.ndarray       # exp(lambda dt), (n_states,)
    input_gain: np.ndarray      # (n_states, 2): columns u_cmd, f_corr (held over the step)
    joint_row: np.ndarray       # (n_states,): delta = Re(joint_row @ x)
    output_rows: np.ndarray     # (n_out, n_states): accelerations, then stinger force
    output_feed: np.ndarray     # (n_out, 2)


def discretise(beam: BeamModel, joint: BoucWenJoint, shaker: Shaker, dt: float) -> Discrete:
    n = len(beam.mass)
    k_stuck = joint.small_amplitude_stiffness_n_m
    # beam DOFs 0..n-1, armature n
    m = np.zeros((n + 1, n + 1))
    k = np.zeros_like(m)
    c = np.zeros_like(m)
    m[:n, :n] = beam.mass
    m[n, n] = shaker.armature_kg
    k[:n, :n] = beam.stiffness_without_joint + k_stuck * np.outer(beam.joint_vector, beam.joint_vector)
    c[:n, :n] = beam_damping(beam, k_stuck)
    d = beam.dof["drive"]
    stinger = np.zeros(n + 1)
    stinger[n], stinger[d] = 1.0, -1.0
    k += shaker.stinger_n_m * np.outer(stinger, stinger)
    k[n, n] += shaker.suspension_n_m
    c[n, n] += shaker.damping_ns_m
    inputs = np.zeros((n + 1, 2))
    inputs[n, 0] = 1.0                       # commanded force on the armature
    inputs[:n, 1] = -beam.joint_vector       # correction force: -L f
    m_inv = np.linalg.inv(m)
    a = np.block([[np.zeros((n + 1, n + 1)), np.eye(n + 1)], [-m_inv @ k, -m_inv @ c]])
    b = np.vstack([np.zeros((n + 1, 2)), m_inv @ inputs])
    eigenvalues, vectors = np.linalg.eig(a)
    inverse = np.linalg.inv(vectors)
    b_modal = inverse @ b
    step = np.exp(eigenvalues * dt)
    gain = ((step - 1.0) / eigenvalues)[:, None] * b_modal
    joint_full = np.concatenate([beam.joint_vector, [0.0], np.zeros(n + 1)])
    sensor = [beam.dof[name] for name in CHANNELS]
    acc_rows = (-m_inv @ np.hstack([k, c]))[sensor]
    acc_feed = (m_inv @ inputs)[sensor]
    force_row = np.concatenate([shaker.stinger_n_m * stinger, np.zeros(n + 1)])
    rows = np.vstack([acc_rows, force_row]) @ vectors
    feed = np.vstack([acc_feed, np.zeros((1, 2))])
    return Discrete(step, gain, joint_full @ vectors, rows, feed)


@njit(cache=True)
def _bouc_wen_step(z, d_delta, a_, beta, gamma, n):
    """z after a relative displacement increment (midpoint rule along delta)."""
    def rate(zz, dd):
        s = 1.0 if dd * zz >= 0.0 else -1.0
        return a_ - (beta * s + gamma) * abs(zz) ** n
    z_half = z + 0.5 * d_delta * rate(z, d_delta)
    return z + d_delta * rate(z_half, d_delta)


@njit(cache=True)
def _integrate(step, gain, joint_row, rows, feed, u_mid, u_at, k0, alpha, a_, beta, gamma,
               n, clearance, k_contact, locked):
    n_steps = u_mid.shape[0]
    n_states = step.shape[0]
    x = np.zeros(n_states, np.complex128)
    out = np.zeros((n_steps, rows.shape[0]))
    joint = np.zeros((n_steps, 2))        # delta, joint force
    z = 0.0
    delta = 0.0
    f_corr = 0.0
    hyst = (1.0 - alpha) * k0
    energy = 0.0
    contact_steps = 0
    gain_u = np.ascontiguousarray(gain[:, 0])
    gain_f = np.ascontiguousarray(gain[:, 1])
    g = (joint_row @ gain_f).real
    for i in range(n_steps):
        # free propagation with the commanded force; the correction force's gain on delta
        x_free = step * x + gain_u * u_mid[i]
        delta_free = (joint_row @ x_free).real
        f_new = f_corr
        delta_new = delta_free
        z_new = z
        for _ in range(3):
            f_mid = 0.5 * (f_corr + f_new)
            delta_new = delta_free + g * f_mid
            if locked:
                z_new = a_ * delta_new
            else:
                z_new = _bouc_wen_step(z, delta_new - delta, a_, beta, gamma, n)
            f_new = hyst * (z_new - a_ * delta_new)
            if clearance > 0.0:
                if delta_new > clearance:
                    f_new += k_contact * (delta_new - clearance)
                elif delta_new < -clearance:
                    f_new += k_contact * (delta_new + clearance)
        f_mid = 0.5 * (f_corr + f_new)
        x = x_free + gain_f * f_mid
        energy += hyst * 0.5 * (z + z_new) * (delta_new - delta)
        if clearance > 0.0 and abs(delta_new) > clearance:
            contact_steps += 1
        delta, z, f_corr = delta_new, z_new, f_new
        for r in range(rows.shape[0]):
            out[i, r] = (rows[r] @ x).real + feed[r, 0] * u_at[i] + feed[r, 1] * f_corr
        joint[i, 0] = delta
        joint[i, 1] = hyst * z + alpha * k0 * delta
    return out, joint, energy, contact_steps


# ------------------------------------------------------------------------- excitation
def multisine_period(n_samples: int, fs_hz: float, band_hz: tuple[float, float],
                     rng: np.random.Generator, shift_samples: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Unit-RMS full-grid random-phase multisine, one period (``n_samples``,) and its lines."""
    lines = np.arange(int(math.ceil(band_hz[0] * n_samples / fs_hz)),
                      int(math.floor(band_hz[1] * n_samples / fs_hz)) + 1)
    phases = rng.uniform(0, 2 * np.pi, len(lines))
    return phases, lines


def synthesize(phases: np.ndarray, lines: np.ndarray, n_samples: int, shift: float) -> np.ndarray:
    spectrum = np.zeros(n_samples // 2 + 1, complex)
    spectrum[lines] = np.exp(1j * (phases + 2 * np.pi * lines * shift / n_samples))
    x = np.fft.irfft(spectrum, n_samples)
    return x / np.sqrt(np.mean(x ** 2))


# ------------------------------------------------------------------------------- a run
def simulate(rms_n: float, seed: int, joint: BoucWenJoint, beam_p: BeamParameters | None = None,
             shaker: Shaker | None = None, noise_rms: np.ndarray | None = None,
             offsets: np.ndarray | None = None, noise_seed: int = 0) -> dict:
    """One level: returns u (n, 1), y (n, 4) at FS_HZ, and the run's joint statistics.

    ``rms_n`` is the commanded force RMS (N); ``noise_rms`` per column of [y, u] (None:
    noise-free), ``offsets`` likewise.
    """
    beam_p = beam_p or BeamParameters()
    shaker = shaker or Shaker()
    beam = build_beam(beam_p)
    fs_int = FS_HZ * OVERSAMPLE
    n_int = SAMPLES_PER_PERIOD * OVERSAMPLE
    disc = discretise(beam, joint, shaker, 1.0 / fs_int)
    rng = np.random.default_rng(seed)
    phases, lines = multisine_period(n_int, fs_int, BAND_HZ, rng)
    u_at = rms_n * np.tile(synthesize(phases, lines, n_int, 0.0), PERIODS)
    u_mid = rms_n * np.tile(synthesize(phases, lines, n_int, 0.5), PERIODS)
    out, joint_trace, energy, contact_steps = _integrate(
        disc.pole_step, disc.input_gain, disc.joint_row, disc.output_rows, disc.output_feed,
        u_mid, u_at, joint.k0_n_m, joint.alpha, joint.A, joint.beta_per_mn, joint.gamma_per_mn,
        joint.n, joint.clearance_m, joint.k_contact_n_m, joint.locked)
    taps = scipy.signal.firwin(ANTI_ALIAS_TAPS, 0.4 * FS_HZ, fs=fs_int)
    filtered = scipy.signal.lfilter(taps, 1.0, out, axis=0)
    decimated = filtered[::OVERSAMPLE]
    y_clean, u_clean = decimated[:, :4], decimated[:, 4:5]
    signals = np.hstack([y_clean, u_clean])
    if noise_rms is not None:
        noise_rng = np.random.default_rng(10_000 + noise_seed)
        signals = signals + noise_rng.standard_normal(signals.shape) * noise_rms
    if offsets is not None:
        signals = signals + offsets
    delta = joint_trace[::OVERSAMPLE, 0]
    last = delta[-SAMPLES_PER_PERIOD:]
    period_y = y_clean.reshape(PERIODS, SAMPLES_PER_PERIOD, 4)
    diffs = [float(np.max(np.sqrt(np.mean((period_y[p] - period_y[p - 1]) ** 2, axis=0))
                          / np.sqrt(np.mean(period_y[p] ** 2, axis=0)))) for p in range(1, PERIODS)]
    return {
        "u": signals[:, 4:5], "y": signals[:, :4], "y_clean": y_clean, "u_clean": u_clean,
        "delta_rms_m": float(np.sqrt(np.mean(last ** 2))),
        "delta_peak_m": float(np.max(np.abs(last))),
        "hysteresis_energy_j": float(energy),
        "contact_fraction": contact_steps / len(u_mid),
        "period_differences": diffs,
        "joint_trace": joint_trace[::OVERSAMPLE],
    }


def truth(beam_p: BeamParameters, joint: BoucWenJoint) -> dict:
    beam = build_beam(beam_p)
    in_band = lambda f: [round(float(x), 4) for x in f if BAND_HZ[0] <= x <= BAND_HZ[1] * 1.15]
    stuck_hz, _ = beam_modes(beam, joint.small_amplitude_stiffness_n_m)
    slip_hz, _ = beam_modes(beam, joint.alpha * joint.k0_n_m)
    free_hz, _ = beam_modes(beam, 0.0)
    return {
        "modes_joint_stuck_hz": in_band(stuck_hz),
        "damping_joint_stuck": [round(float(modal_damping_ratio(np.array([f]))[0]), 5) for f in in_band(stuck_hz)],
        "modes_joint_slipping_hz": in_band(slip_hz),
        "modes_joint_removed_hz": in_band(free_hz),
        "joint": {
            "law": "Bouc-Wen on delta = w(jointL) - w(jointR): F = alpha k0 delta + (1-alpha) k0 z, "
                   "dz/dt = A delta' - beta |delta'| |z|^(n-1) z - gamma delta' |z|^n",
            "channels": {"jointL": 1, "jointR": -1},
            "k0_n_m": joint.k0_n_m, "alpha": joint.alpha, "A": joint.A,
            "beta_per_m^n": joint.beta_per_mn, "gamma_per_m^n": joint.gamma_per_mn, "n": joint.n,
            "yield_displacement_m": joint.yield_m,
            "small_amplitude_stiffness_n_m": joint.small_amplitude_stiffness_n_m,
            "post_yield_stiffness_n_m": joint.alpha * joint.k0_n_m,
            "saturation_force_n": joint.saturation_force_n,
            "clearance_m": joint.clearance_m, "k_contact_n_m": joint.k_contact_n_m,
            "rotation_spring_nm_rad": beam_p.k_rotation_nm_rad,
        },
        "beam": asdict(beam_p),
        "band_hz": list(BAND_HZ), "fs_hz": FS_HZ, "samples_per_period": SAMPLES_PER_PERIOD,
        "periods": PERIODS,
    }


def check_locked_frf(seed: int = 0) -> dict:
    """Joint locked (linear): the simulated FRF against the exact FRF, noise-free."""
    joint = BoucWenJoint(locked=True)
    beam_p = BeamParameters()
    run = simulate(10.0, seed, joint, beam_p)
    u = run["u_clean"].reshape(PERIODS, SAMPLES_PER_PERIOD)[2:].mean(axis=0)
    y = run["y_clean"].reshape(PERIODS, SAMPLES_PER_PERIOD, 4)[2:].mean(axis=0)
    lines = np.arange(int(math.ceil(BAND_HZ[0] * SAMPLES_PER_PERIOD / FS_HZ)),
                      int(math.floor(BAND_HZ[1] * SAMPLES_PER_PERIOD / FS_HZ)) + 1)
    h_sim = np.fft.rfft(y, axis=0)[lines] / np.fft.rfft(u)[lines, None]
    h_exact = exact_frf(build_beam(beam_p), joint, lines * FS_HZ / SAMPLES_PER_PERIOD)
    relative = np.abs(h_sim - h_exact) / np.abs(h_exact)
    return {"max_relative_error": float(relative.max()),
            "median_relative_error": float(np.median(relative)),
            "max_error_over_peak": float((np.abs(h_sim - h_exact) / np.abs(h_exact).max(axis=0)).max())}


LINEAR_YAML = """\
# Written by bench/independent_beam.py: the IDENT.yaml a user writes for these .npz files
band_hz: [{lo}, {hi}]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {{name: F-drive, driving_point: drive}}
nonlinearities: []
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="example: python bench/independent_beam.py --out beam")
    parser.add_argument("--out", type=Path, required=False, help="output folder")
    parser.add_argument("--levels", type=float, nargs="+", default=[0.002, 0.02, 0.1, 0.3, 1.0, 3.0],
                        help="commanded force RMS per level (N)")
    parser.add_argument("--seed", type=int, default=0, help="phase seed (level i: seed + i)")
    parser.add_argument("--snr-db", type=float, default=50.0,
                        help="white sensor noise this far below each channel's RMS, per level")
    parser.add_argument("--check", action="store_true", help="locked joint: FRF vs exact, then exit")
    parser.add_argument("--force", action="store_true", help="overwrite existing files")
    args = parser.parse_args(argv)
    if args.check:
        t0 = time.perf_counter()
        print(json.dumps(check_locked_frf(args.seed), indent=1), f"({time.perf_counter() - t0:.1f} s)")
        return 0
    if args.out is None:
        parser.error("--out DIR is required (or --check)")
    args.out.mkdir(parents=True, exist_ok=True)
    beam_p, joint = BeamParameters(), BoucWenJoint()
    # DC offsets: fixed per channel, 2 % of the channel's RMS at the middle level
    middle = simulate(args.levels[len(args.levels) // 2], args.seed, joint, beam_p)
    rms_middle = np.sqrt(np.mean(np.hstack([middle["y_clean"], middle["u_clean"]]) ** 2, axis=0))
    offsets = np.random.default_rng(args.seed + 777).normal(0, 1, 5) * rms_middle * 0.02
    base_truth = truth(beam_p, joint)
    for i, level in enumerate(args.levels):
        stem = f"beam-rms{level:g}"
        path = args.out / f"{stem}.npz"
        if path.exists() and not args.force:
            print(f"{path} exists: --force to overwrite", file=sys.stderr)
            return 2
        t0 = time.perf_counter()
        clean = simulate(level, args.seed + i, joint, beam_p)
        # white sensor noise 50 dB below each channel's in-steady-state RMS (ranged per level)
        noise_rms = np.sqrt(np.mean(np.hstack([clean["y_clean"], clean["u_clean"]])[SAMPLES_PER_PERIOD:] ** 2,
                                    axis=0)) * 10 ** (-args.snr_db / 20)
        run = simulate(level, args.seed + i, joint, beam_p, noise_rms=noise_rms, offsets=offsets,
                       noise_seed=args.seed + i)
        np.savez(path, u=run["u"], y=run["y"], fs=FS_HZ, N=SAMPLES_PER_PERIOD,
                 channels=np.array(CHANNELS), input_channels=np.array([INPUT_CHANNEL]),
                 quantity="acceleration", transient_samples=SAMPLES_PER_PERIOD)
        t = dict(base_truth)
        t["run"] = {
            "commanded_force_rms_n": level,
            "measured_force_rms_n": float(np.sqrt(np.mean(run["u_clean"][SAMPLES_PER_PERIOD:] ** 2))),
            "phase_seed": args.seed + i,
            "joint_delta_rms_m": run["delta_rms_m"], "joint_delta_peak_m": run["delta_peak_m"],
            "peak_over_yield": run["delta_peak_m"] / joint.yield_m,
            "hysteresis_energy_j": run["hysteresis_energy_j"],
            "contact_fraction": run["contact_fraction"],
            "period_differences": run["period_differences"],
            "noise_rms": dict(zip(list(CHANNELS) + [INPUT_CHANNEL], noise_rms.tolist())),
            "offsets": dict(zip(list(CHANNELS) + [INPUT_CHANNEL], offsets.tolist())),
        }
        (args.out / f"{stem}.truth.json").write_text(json.dumps(t, indent=1))
        print(f"{path}: F {t['run']['measured_force_rms_n']:.3f} N RMS, delta peak "
              f"{run['delta_peak_m'] * 1e6:.1f} um ({t['run']['peak_over_yield']:.2f} x yield), "
              f"energy {run['hysteresis_energy_j']:.2e} J, last period diff "
              f"{run['period_differences'][-1] * 100:.2f} % ({time.perf_counter() - t0:.1f} s)")
    (args.out / "beam-linear.yaml").write_text(LINEAR_YAML.format(lo=BAND_HZ[0], hi=BAND_HZ[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
