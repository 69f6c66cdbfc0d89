"""An aircraft-like ground vibration test: a wing with a payload on a bolted joint.

Development data like a real aircraft GVT (SI units: m, N, kg, s). Built to look like the
test that identification meets in the lab, not like an ideal simulation:

Structure (:func:`aircraft_model`)
    A full-span wing (Euler-Bernoulli beam, 10 elements, bending + torsion at every node,
    section centre of mass 0.25 m aft of the elastic axis), a fuselage mass at mid-span on
    soft landing-gear springs (rigid-body modes below 1 Hz), two engines on pylons, a tail
    mass on the fuselage, and a **payload** (300 kg, heave + pitch) under the right wing at
    half span, attached by a **bolted joint** acting on the vertical relative displacement
    ``delta = q_wing - q_payload`` (channels ``wing`` and ``payload``). Modal damping
    0.4-0.7 %. With the joint stuck, 9 modes lie in 2-15 Hz (3.1 ... 14.1 Hz) and one at
    15.2 Hz; the payload mode (6.1 Hz) carries most of the joint's strain energy.
Joint (:class:`JointParameters`)
    a linear pylon stiffness ``k_linear`` in parallel with
    - a **Jenkins friction element** (hysteretic: stiffness ``k_stick`` in series with a
      Coulomb slider of force ``F_s``; stuck at low level, micro/macro-slip at high level);
      the slider's preload relaxes with the accumulated slip ``S`` (bolt settling,
      ``F_s = F_s0 (r + (1 - r) exp(-S / S0))``), so that at high levels consecutive
      periods differ by several percent while low levels stay stationary;
    - a **clearance**: contact stiffness ``k_contact`` once ``|delta|`` exceeds the gap.
    The linear part of :attr:`AircraftModel.structure` holds ``k_linear + k_stick`` (the
    stuck joint: the small-amplitude limit); the kernel adds ``f_jenkins - k_stick delta``
    and the contact force.
Shaker (force measured)
    An armature (3 kg, suspension 1 kN/m, back-EMF damping 40 N s/m) driven by the
    commanded force, coupled to the wing's left side by a stinger (2 MN/m) whose force the
    load cell measures: the measured force drops at the resonances and carries the
    structure's nonlinear distortion, as on a real shaker.
Acquisition (:func:`aircraft_record`)
    Accelerometers at the driving point (``drive``), on the wing next to the joint
    (``wing``) and on the payload (``payload``); 400 Hz after a linear-phase anti-alias
    FIR (integration at ``oversample * 400`` Hz); sensor noise (white, absolute: 60 ug
    RMS accelerometers, 0.02 N load cell), slow baseline drift of the accelerometers,
    DC offsets; the test starts from rest, so the first period is transient.

Integration (:func:`simulate_aircraft`): exact propagation of the complex modes of the
stuck linear model over each internal step (input and joint force held at their midpoint
estimate: Heun predictor-corrector), the Jenkins state updated once per step by return
mapping (no regularisation). numba-compiled; one level (9 periods of 8192 samples at 16x
oversampling, 1.2 M steps) takes about a second.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.linalg as sla
from numba import njit

from fnsi_lab.daq.sim.model import StructuralModel

__all__ = ["JointParameters", "AircraftModel", "AircraftRun", "AircraftRecord",
           "aircraft_model", "simulate_aircraft", "aircraft_record", "LEVELS_N_RMS",
           "command_gain", "period_differences", "LabNoise"]

#: Force levels of the reference campaign (measured force, N RMS).
LEVELS_N_RMS: tuple[float, ...] = (12.0, 26.0, 40.0, 55.0, 69.0, 84.0, 98.0)

#: Channel names: measured force, then the three accelerometers.
FORCE_CHANNEL = "F-shaker"
ACCEL_CHANNELS = ("drive", "wing", "payload")


@dataclass(frozen=True)
class JointParameters:
    """The bolted wing-to-payload joint (acts on ``delta = q_wing - q_payload``, m).

    Attributes
    ----------
    k_linear : float
        Always-active pylon stiffness, N/m.
    k_stick : float
        Jenkins element stiffness (in series with the slider), N/m.
    slip_force_n : float
        Initial slider force F_s0, N.
    settle_slip_m : float
        Accumulated slip S0 over which the preload relaxes, m.
    settle_residual : float
        r: fraction of F_s0 left after long slipping.
    clearance_m : (float, float)
        (g_neg, g_pos): free play before contact below / above, m.
    k_contact : float
        Contact stiffness beyond the clearance, N/m.
    """

    k_linear: float = 1.0e5
    k_stick: float = 1.0e6
    slip_force_n: float = 60.0
    settle_slip_m: float = 0.3
    settle_residual: float = 0.5
    clearance_m: tuple[float, float] = (3.45e-4, 3.0e-4)
    k_contact: float = 1.5e6

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (SI units in the key names)."""
        return {"k_linear_n_per_m": self.k_linear, "k_stick_n_per_m": self.k_stick,
                "slip_force_n": self.slip_force_n, "settle_slip_m": self.settle_slip_m,
                "settle_residual": self.settle_residual,
                "clearance_m": list(self.clearance_m), "k_contact_n_per_m": self.k_contact}


@dataclass(frozen=True, eq=False)
class AircraftModel:
    """The linear structure (joint stuck) plus what the kernel needs.

    Attributes
    ----------
    structure : StructuralModel
        M, C, K with the joint stuck (``k_linear + k_stick``), input = commanded shaker
        force on the armature, measured DOFs ``drive``, ``wing``, ``payload``.
    joint : JointParameters
    joint_weights : ndarray, shape (n_dof,)
        L: ``delta = L @ q`` (+1 wing, -1 payload).
    armature_dof, drive_dof : int
        The stinger connects them; measured force = ``k_stinger (q_arm - q_drive)``.
    k_stinger : float
        N/m.
    """

    structure: StructuralModel
    joint: JointParameters
    joint_weights: np.ndarray
    armature_dof: int
    drive_dof: int
    k_stinger: float

    @property
    def measured_dofs(self) -> np.ndarray:
        """DOFs of ``drive``, ``wing``, ``payload``, shape (3,)."""
        return self.structure.measured_dofs

    def force_frf(self, frequency_hz: np.ndarray) -> np.ndarray:
        """Measured (load cell) force per commanded force of the stuck linear model,
        complex, shape (n_freq,)."""
        dofs = np.array([self.armature_dof, self.drive_dof])
        h = self.structure.frf(frequency_hz, "displacement", dofs)[:, :, 0]
        return self.k_stinger * (h[:, 0] - h[:, 1])

    def joint_free_modes_hz(self) -> np.ndarray:
        """Undamped natural frequencies with the slider fully slipping (k_stick removed)."""
        lw = self.joint_weights
        k = self.structure.stiffness - self.joint.k_stick * np.outer(lw, lw)
        w2 = sla.eigh(k, self.structure.mass, eigvals_only=True)
        return np.sqrt(np.abs(w2)) / (2 * np.pi)


# ---------------------------------------------------------------------------- model
def _wing(nodes: np.ndarray, ei: tuple[float, float], gj: tuple[float, float],
          mu: tuple[float, float], ip: tuple[float, float], e: float,
          n_dof: int) -> tuple[np.ndarray, np.ndarray]:
    """Beam FE (bending w, slope, torsion per node; lumped mass), linear taper root->tip."""
    k = np.zeros((n_dof, n_dof))
    m = np.zeros((n_dof, n_dof))
    half = abs(nodes[-1])
    for i in range(nodes.size - 1):
        le = nodes[i + 1] - nodes[i]
        xm = abs(0.5 * (nodes[i] + nodes[i + 1])) / half
        eil = ei[0] + (ei[1] - ei[0]) * xm
        gjl = gj[0] + (gj[1] - gj[0]) * xm
        mul = mu[0] + (mu[1] - mu[0]) * xm
        ipl = ip[0] + (ip[1] - ip[0]) * xm
        kb = eil / le ** 3 * np.array([[12, 6 * le, -12, 6 * le],
                                      [6 * le, 4 * le ** 2, -6 * le, 2 * le ** 2],
                                      [-12, -6 * le, 12, -6 * le],
                                      [6 * le, 2 * le ** 2, -6 * le, 4 * le ** 2]])
        idx = [3 * i, 3 * i + 1, 3 * i + 3, 3 * i + 4]
        k[np.ix_(idx, idx)] += kb
        it = [3 * i + 2, 3 * i + 5]
        k[np.ix_(it, it)] += gjl / le * np.array([[1.0, -1.0], [-1.0, 1.0]])
        for j in (i, i + 1):
            mm = mul * le / 2
            m[3 * j, 3 * j] += mm
            m[3 * j + 1, 3 * j + 1] += mul * le ** 3 / 210
            m[3 * j + 2, 3 * j + 2] += ipl * le / 2 + mm * e * e
            m[3 * j, 3 * j + 2] += mm * e
            m[3 * j + 2, 3 * j] += mm * e
    return m, k


def _spring(k: np.ndarray, weights: dict[int, float], stiffness: float) -> None:
    lw = np.zeros(k.shape[0])
    for d, w in weights.items():
        lw[d] = w
    k += stiffness * np.outer(lw, lw)


@lru_cache(maxsize=8)
def aircraft_model(joint: JointParameters = JointParameters(), *,
                   damping_ratio: float = 0.004, damping_slope_per_hz: float = 2.0e-4,
                   suspension_damping_ratio: float = 0.03, payload_mass_kg: float = 500.0,
                   payload_pitch_inertia: float = 80.0) -> AircraftModel:
    """Build the aircraft-like structure (see the module docstring).

    Parameters
    ----------
    joint : JointParameters
    damping_ratio : float
        Modal damping of the lowest modes; mode ``i`` gets
        ``damping_ratio + damping_slope_per_hz * f_i``.
    damping_slope_per_hz : float
    suspension_damping_ratio : float
        Damping of the rigid-body modes on the landing gear (below 1.5 Hz).
    payload_mass_kg, payload_pitch_inertia : float
        Payload heave mass (kg) and pitch inertia about the joint (kg m^2).

    Returns
    -------
    AircraftModel
    """
    half_span = 14.0
    nodes = np.linspace(-half_span, half_span, 11)
    nn = nodes.size
    wing_dofs = 3 * nn
    i_pay, i_pitch, i_eng_l, i_eng_r, i_tail, i_arm = range(wing_dofs, wing_dofs + 6)
    n = wing_dofs + 6
    m, k = _wing(nodes, ei=(1.0e8, 1.5e7), gj=(1.0e7, 2.2e6), mu=(180.0, 60.0),
                 ip=(60.0, 15.0), e=0.25, n_dof=n)
    centre = nn // 2
    node = {x: int(np.argmin(np.abs(nodes - x))) for x in (-0.7 * half_span, -0.35 * half_span,
                                                          0.35 * half_span, 0.5 * half_span,
                                                          -3.0, 3.0)}
    # fuselage on its landing gear, pitch restraint
    m[3 * centre, 3 * centre] += 3000.0
    m[3 * centre + 2, 3 * centre + 2] += 2.0e4
    for x in (-3.0, 3.0):
        k[3 * node[x], 3 * node[x]] += 1.2e5
    k[3 * centre + 2, 3 * centre + 2] += 2.0e6
    # engines 1.5 m ahead of the elastic axis, tail 10 m aft of the fuselage centre
    for dof, x in ((i_eng_l, -0.35 * half_span), (i_eng_r, 0.35 * half_span)):
        m[dof, dof] += 1200.0
        _spring(k, {dof: 1.0, 3 * node[x]: -1.0, 3 * node[x] + 2: -1.5}, 3.0e6)
    m[i_tail, i_tail] += 500.0
    _spring(k, {i_tail: 1.0, 3 * centre: -1.0, 3 * centre + 2: 10.0}, 6.0e5)
    # payload under the right wing: heave at the joint, pitch (bolted joint stuck)
    jp = node[0.5 * half_span]
    m[i_pay, i_pay] += payload_mass_kg
    m[i_pitch, i_pitch] += payload_pitch_inertia
    _spring(k, {3 * jp: 1.0, i_pay: -1.0}, joint.k_linear + joint.k_stick)
    _spring(k, {3 * jp + 2: 1.0, i_pitch: -1.0}, 2.0e5)
    # modal damping of the structure (shaker excluded), then the shaker
    keep = np.arange(n - 1)
    w2, phi = sla.eigh(k[np.ix_(keep, keep)], m[np.ix_(keep, keep)])
    wn = np.sqrt(np.abs(w2))
    zeta = damping_ratio + damping_slope_per_hz * wn / (2 * np.pi)
    zeta[wn < 2 * np.pi * 1.5] = suspension_damping_ratio   # tyres / bungees: rigid modes
    mphi = m[np.ix_(keep, keep)] @ phi
    c = np.zeros((n, n))
    c[np.ix_(keep, keep)] = mphi @ np.diag(2 * zeta * wn) @ mphi.T
    js = node[-0.7 * half_span]
    k_stinger = 2.0e6
    m[i_arm, i_arm] += 3.0
    k[i_arm, i_arm] += 1.0e3
    c[i_arm, i_arm] += 40.0
    _spring(k, {i_arm: 1.0, 3 * js: -1.0}, k_stinger)
    names = tuple(f"N{j}{s}" for j in range(nn) for s in ("w", "rot", "tor")) + (
        "payload", "payload-pitch", "engine-L", "engine-R", "tail", "armature")
    t = np.zeros((n, 1))
    t[i_arm, 0] = 1.0
    lw = np.zeros(n)
    lw[3 * jp], lw[i_pay] = 1.0, -1.0
    structure = StructuralModel(
        mass=m, damping=c, stiffness=k, dof_names=names, force_matrix=t,
        input_names=("command",), measured={"drive": 3 * js, "wing": 3 * jp, "payload": i_pay},
        units={"length": "m", "force": "N", "time": "s", "mass": "kg"}, name="aircraft",
        node_direction={names[3 * js]: ("drive", "Z"), names[3 * jp]: ("wing", "Z"),
                        "payload": ("payload", "Z")},
        description="aircraft-like GVT: wing, engines, tail, payload on a bolted joint "
                    "(friction + clearance), shaker under the left wing")
    return AircraftModel(structure=structure, joint=joint, joint_weights=lw, armature_dof=i_arm,
                         drive_dof=3 * js, k_stinger=k_stinger)


# ---------------------------------------------------------------------------- kernel
@njit(cache=True)
def _joint_force(delta, z, fs, k_stick, g_neg, g_pos, k_contact):
    """Jenkins + contact force deviation from the stuck linear spring; the trial slider
    state (returned, not committed)."""
    f_trial = k_stick * (delta - z)
    z_new = z
    if f_trial > fs:
        z_new = delta - fs / k_stick
        f_trial = fs
    elif f_trial < -fs:
        z_new = delta + fs / k_stick
        f_trial = -fs
    f = f_trial - k_stick * delta
    if delta > g_pos:
        f += k_contact * (delta - g_pos)
    elif delta < -g_neg:
        f += k_contact * (delta + g_neg)
    return f, z_new


@njit(cache=True)
def _aircraft_kernel(e, g, bu, bf, c_delta, c_out_state, d_out_u, d_out_f, u, k_stick,
                     fs0, s0, resid, g_neg, g_pos, k_contact, out, diag):
    n_modes = e.size
    n_steps = u.size - 1
    n_out = c_out_state.shape[0]
    eta = np.zeros(n_modes, dtype=np.complex128)
    z = 0.0
    slip = 0.0
    energy = 0.0
    n_slip = 0
    n_contact = 0
    f_k = 0.0
    for k in range(n_steps):
        u_mid = 0.5 * (u[k] + u[k + 1])
        # outputs at step k
        for o in range(n_out):
            acc = 0.0
            for i in range(n_modes):
                acc += (c_out_state[o, i] * eta[i]).real
            out[k, o] = acc + d_out_u[o] * u[k] + d_out_f[o] * f_k
        # predictor with f_k, corrector with the mean of f_k and f(eta_pred)
        delta_p = 0.0
        for i in range(n_modes):
            ep = e[i] * eta[i] + g[i] * (bu[i] * u_mid + bf[i] * f_k)
            delta_p += (c_delta[i] * ep).real
        fs = fs0 * (resid + (1.0 - resid) * np.exp(-slip / s0))
        f_p, _ = _joint_force(delta_p, z, fs, k_stick, g_neg, g_pos, k_contact)
        f_mid = 0.5 * (f_k + f_p)
        delta = 0.0
        for i in range(n_modes):
            eta[i] = e[i] * eta[i] + g[i] * (bu[i] * u_mid + bf[i] * f_mid)
            delta += (c_delta[i] * eta[i]).real
        f_k, z_new = _joint_force(delta, z, fs, k_stick, g_neg, g_pos, k_contact)
        dz = abs(z_new - z)
        if dz > 0.0:
            slip += dz
            energy += fs * dz
            n_slip += 1
        if delta > g_pos or delta < -g_neg:
            n_contact += 1
        z = z_new
    for o in range(n_out):
        acc = 0.0
        for i in range(n_modes):
            acc += (c_out_state[o, i] * eta[i]).real
        out[n_steps, o] = acc + d_out_u[o] * u[n_steps] + d_out_f[o] * f_k
    diag[0] = slip
    diag[1] = energy
    diag[2] = n_slip
    diag[3] = n_contact
    diag[4] = fs0 * (resid + (1.0 - resid) * np.exp(-slip / s0))
    return 0


@dataclass(frozen=True)
class AircraftRun:
    """Raw result of :func:`simulate_aircraft` at the internal rate.

    Attributes
    ----------
    outputs : ndarray, shape (n_steps, 5)
        Measured force (N), accelerations of ``drive``, ``wing``, ``payload`` (m/s^2) and
        the joint's relative displacement ``delta`` (m), at every internal step.
    slip_m : float
        Accumulated slider slip.
    friction_energy_j : float
        Energy dissipated by the slider.
    slip_fraction, contact_fraction : float
        Fraction of internal steps slipping / in contact.
    final_slip_force_n : float
        Slider force at the end (after preload relaxation).
    """

    outputs: np.ndarray
    slip_m: float
    friction_energy_j: float
    slip_fraction: float
    contact_fraction: float
    final_slip_force_n: float


def simulate_aircraft(model: AircraftModel, command_n: np.ndarray, internal_rate_hz: float,
                      *, joint: JointParameters | None = None) -> AircraftRun:
    """Integrate the aircraft from rest under a commanded shaker force.

    Parameters
    ----------
    model : AircraftModel
    command_n : ndarray, shape (n_steps,)
        Commanded force at the internal rate, N.
    internal_rate_hz : float
    joint : JointParameters, optional
        Overrides ``model.joint`` for the nonlinear part (the linear part keeps
        ``model.joint.k_linear + model.joint.k_stick``; pass the same ``k_stick``).

    Returns
    -------
    AircraftRun
    """
    jp = model.joint if joint is None else joint
    st = model.structure
    h = 1.0 / float(internal_rate_hz)
    modes = st.modes
    lam = modes.eigenvalues
    keep = lam.imag >= 0            # one of each conjugate pair (and real eigenvalues)
    weight = np.where(lam.imag > 0, 2.0, 1.0)[keep]
    vec = modes.vectors[:, keep] * weight[None, :]
    inv = modes.inverse[keep]
    lam = lam[keep]
    n = st.n_dof
    minv = np.linalg.inv(st.mass)
    b_u = np.concatenate([np.zeros(n), minv @ st.force_matrix[:, 0]])
    b_f = np.concatenate([np.zeros(n), -minv @ model.joint_weights])
    e = np.exp(lam * h)
    g = (e - 1.0) / lam
    lw = model.joint_weights
    c_delta = lw @ vec[:n]
    dofs = model.measured_dofs
    k_s = model.k_stinger
    rows = [k_s * (vec[model.armature_dof] - vec[model.drive_dof])]
    rows += [vec[n + d] * lam for d in dofs]
    rows += [c_delta]
    c_out = np.ascontiguousarray(np.stack(rows))
    d_u = np.concatenate([[0.0], b_u[n + dofs], [0.0]])
    d_f = np.concatenate([[0.0], b_f[n + dofs], [0.0]])
    u = np.ascontiguousarray(np.asarray(command_n, dtype=float).reshape(-1))
    out = np.zeros((u.size, c_out.shape[0]))
    diag = np.zeros(5)
    _aircraft_kernel(np.ascontiguousarray(e), np.ascontiguousarray(g),
                     np.ascontiguousarray(inv @ b_u), np.ascontiguousarray(inv @ b_f),
                     np.ascontiguousarray(c_delta), c_out, d_u, d_f, u, float(jp.k_stick),
                     float(jp.slip_force_n), float(jp.settle_slip_m), float(jp.settle_residual),
                     float(jp.clearance_m[0]), float(jp.clearance_m[1]), float(jp.k_contact),
                     out, diag)
    steps = max(u.size - 1, 1)
    return AircraftRun(outputs=out, slip_m=float(diag[0]), friction_energy_j=float(diag[1]),
                       slip_fraction=float(diag[2]) / steps,
                       contact_fraction=float(diag[3]) / steps, final_slip_force_n=float(diag[4]))


# ---------------------------------------------------------------------------- acquisition
@dataclass(frozen=True)
class LabNoise:
    """Sensor noise and drift of the acquisition (absolute levels, SI units).

    Attributes
    ----------
    accel_noise_ms2 : float
        White noise RMS of each accelerometer (60 ug ~ 6e-4 m/s^2).
    force_noise_n : float
        White noise RMS of the load cell.
    drift_ms2 : float
        RMS of each accelerometer's slow baseline wander (below ``drift_corner_hz``).
    drift_corner_hz : float
    offset_ms2, offset_n : float
        Maximum DC offset of an accelerometer / the load cell (uniform, seeded).
    """

    accel_noise_ms2: float = 6.0e-4
    force_noise_n: float = 0.02
    drift_ms2: float = 2.0e-4
    drift_corner_hz: float = 0.2
    offset_ms2: float = 2.0e-3
    offset_n: float = 0.05


@dataclass(frozen=True)
class AircraftRecord:
    """One simulated level of the aircraft GVT at the output rate.

    Attributes
    ----------
    data : ndarray, shape (n_periods * N, 4)
        Columns ``F-shaker`` (N), ``drive``, ``wing``, ``payload`` (m/s^2), noisy.
    clean : ndarray, shape (n_periods * N, 4)
        The same without noise, drift and offsets.
    delta_m : ndarray, shape (n_periods * N,)
        Joint relative displacement (truth, m).
    sample_rate_hz, samples_per_period, periods
    command_rms_n : float
        RMS of the commanded force.
    info : dict
        Slip, dissipated energy, slip/contact fractions, period-to-period differences.
    """

    data: np.ndarray
    clean: np.ndarray
    delta_m: np.ndarray
    sample_rate_hz: float
    samples_per_period: int
    periods: int
    command_rms_n: float
    info: dict = field(default_factory=dict)

    channel_names: tuple[str, ...] = (FORCE_CHANNEL,) + ACCEL_CHANNELS


def command_gain(model: AircraftModel, excited_hz: np.ndarray, amplitudes: np.ndarray) -> float:
    """Factor from commanded to measured force RMS of the stuck linear model for a
    multisine with ``amplitudes`` (any scale) at ``excited_hz``."""
    hf = model.force_frf(excited_hz)
    a = np.asarray(amplitudes, dtype=float)
    return float(np.sqrt(np.sum(np.abs(hf * a) ** 2) / np.sum(a ** 2)))


def period_differences(x: np.ndarray, samples_per_period: int, first: int = 1) -> np.ndarray:
    """rms(period p - period p-1) / rms(period p) per channel, for p > first.

    Parameters
    ----------
    x : ndarray, shape (n_periods * N, c)

    Returns
    -------
    ndarray, shape (n_periods - first - 1, c)
    """
    n = samples_per_period
    per = x.reshape(-1, n, x.shape[1])
    d = per[first + 1:] - per[first:-1]
    return np.sqrt(np.mean(d ** 2, axis=1)) / np.sqrt(np.mean(per[first + 1:] ** 2, axis=1))


def aircraft_record(level_n_rms: float, *, period_command: np.ndarray | None = None,
                    sample_rate_hz: float = 400.0, samples_per_period: int = 8192,
                    periods: int = 9, band_hz: tuple[float, float] = (2.0, 15.0),
                    seed: int = 0, oversample: int = 16,
                    joint: JointParameters = JointParameters(),
                    noise: LabNoise | None = LabNoise(), noise_seed: int | None = None
                    ) -> AircraftRecord:
    """Simulate one level of the GVT (see the module docstring).

    Parameters
    ----------
    level_n_rms : float
        Target RMS of the *measured* force, N (the commanded multisine is scaled with the
        stuck linear model's load-cell FRF; at high levels the joint changes it slightly).
    period_command : ndarray, shape (samples_per_period,), optional
        One period of the drive shape (any scale); default: a full-grid random-phase
        multisine in ``band_hz`` with ``seed``.
    sample_rate_hz, samples_per_period, periods, band_hz, seed
        The test layout (defaults: the real test's 400 Hz, 9 x 8192, 2-15 Hz).
    oversample : int
        Internal steps per output sample.
    joint : JointParameters
    noise : LabNoise or None
        None: clean data.
    noise_seed : int, optional
        Default ``seed``.

    Returns
    -------
    AircraftRecord
    """
    from scipy.signal import resample_poly

    from fnsi_lab.daq.multisine import multisine

    model = aircraft_model(joint)
    n = int(samples_per_period)
    if period_command is None:
        period_command = multisine(n, sample_rate_hz, band_hz, 1.0, seed=seed).period(0)
    spec = np.fft.rfft(np.asarray(period_command, dtype=float))
    lines = np.nonzero(np.abs(spec) > 1e-9 * np.abs(spec).max())[0]
    gain = command_gain(model, lines * sample_rate_hz / n, np.abs(spec[lines]))
    rms_shape = float(np.sqrt(np.mean(np.asarray(period_command) ** 2)))
    scale = level_n_rms / (gain * rms_shape)
    os_ = int(oversample)
    fine = np.fft.irfft(spec * scale, n=n * os_) * os_          # band-limited interpolation
    command = np.concatenate([np.tile(fine, periods), fine[:1]])
    run = simulate_aircraft(model, command, sample_rate_hz * os_, joint=joint)
    # linear-phase anti-alias FIR + decimation (force and accelerations alike)
    dec = resample_poly(run.outputs[:-1], 1, os_, axis=0)
    clean = np.ascontiguousarray(dec[:, :4])
    delta = np.ascontiguousarray(run.outputs[:-1:os_, 4])
    data = clean.copy()
    if noise is not None:
        data += _lab_noise(clean.shape[0], sample_rate_hz, noise,
                           np.random.default_rng([seed if noise_seed is None else noise_seed,
                                                  int(round(level_n_rms * 1000))]))
    diffs = period_differences(clean, n)
    info = {"slip_m": run.slip_m, "friction_energy_j": run.friction_energy_j,
            "slip_fraction": run.slip_fraction, "contact_fraction": run.contact_fraction,
            "final_slip_force_n": run.final_slip_force_n,
            "force_rms_n": float(np.sqrt(np.mean(clean[n:, 0] ** 2))),
            "delta_rms_m": float(np.sqrt(np.mean(delta[n:] ** 2))),
            "period_difference_max": {nm: float(diffs[:, i].max())
                                      for i, nm in enumerate((FORCE_CHANNEL,) + ACCEL_CHANNELS)},
            "period_difference_last": {nm: float(diffs[-1, i])
                                       for i, nm in enumerate((FORCE_CHANNEL,) + ACCEL_CHANNELS)},
            "internal_rate_hz": sample_rate_hz * os_}
    return AircraftRecord(data=data, clean=clean, delta_m=delta, sample_rate_hz=sample_rate_hz,
                          samples_per_period=n, periods=int(periods),
                          command_rms_n=float(scale * rms_shape), info=info)


def _lab_noise(n_samples: int, fs: float, noise: LabNoise,
               rng: np.random.Generator) -> np.ndarray:
    """Noise + drift + offsets, shape (n_samples, 4) (force first)."""
    out = np.empty((n_samples, 4))
    out[:, 0] = noise.force_noise_n * rng.standard_normal(n_samples)
    out[:, 0] += noise.offset_n * rng.uniform(-1, 1)
    white = rng.standard_normal((n_samples, 3))
    f = np.fft.rfftfreq(n_samples, 1.0 / fs)
    wander = np.fft.rfft(rng.standard_normal((n_samples, 3)), axis=0)
    wander *= (1.0 / (1.0 + (f / noise.drift_corner_hz) ** 2))[:, None]
    wander[0] = 0.0
    drift = np.fft.irfft(wander, n=n_samples, axis=0)
    drift *= noise.drift_ms2 / np.maximum(np.sqrt(np.mean(drift ** 2, axis=0)), 1e-300)
    out[:, 1:] = (noise.accel_noise_ms2 * white + drift
                  + noise.offset_ms2 * rng.uniform(-1, 1, 3)[None, :])
    return out
