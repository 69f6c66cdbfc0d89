"""An independent lab-realistic joint test: a simulator that shares no code with ``daq/sim``.

Written from scratch to judge fnsi-lab's defaults on data our own simulators did not
generate (docs/aircraft.md describes the simulator they may be tuned to). What differs:

- **structure**: a 5-DOF lumped chain (a fixture on soft springs, two frames, a bolted
  bracket-to-box joint, a box with an inner mass), modes 3.2-20 Hz with the joint stuck;
  modal damping 0.6 % + 0.03 %/Hz on the stuck structure;
- **joint law**: an **Iwan** element (10 Jenkins elements in parallel: springs of
  ``K_t / 10`` in series with sliders whose slip forces are spread uniformly over
  ``[F_min, F_max]``: micro-slip between the two) next to the bolt's linear stiffness
  ``k_bolt``, plus a **one-sided** contact (a gap on one side only). Not a single Jenkins
  element, not a two-sided stop, no regularisation;
- **shaker**: an armature (3 kg on a 3 kN/m suspension, 60 N s/m back-EMF) driven by the
  commanded multisine, a stinger of 8e5 N/m to the fixture; the measured force is the
  stinger's (force drop-out at resonances, distortion in the force);
- **test**: 500 Hz, periods of **6000** samples (not a power of two; 0.0833 Hz lines),
  random-phase full-grid multisine 2-22 Hz (own seed per level), 10 periods from rest (the
  first transient), outputs are **accelerations**;
- **integrator**: the stuck linear model discretised exactly (zero-order hold, matrix
  exponential) at 8 kHz, the Iwan sliders by return mapping each step and their force
  (and the contact's) fed back explicitly; compiled with numba (a project dependency);
- **lab**: causal linear-phase FIR anti-alias filter and decimation 8 kHz -> 500 Hz (the
  same delay on every channel), white sensor noise (accelerometers 3e-4 m/s^2, load cell
  0.01 N RMS: in-band SNR about 50-60 dB at the lowest level), DC offsets on every channel.

Run::

    python bench/independent_joint.py --out indep            # 5 levels, ~2 s each
    python bench/independent_joint.py --out indep --levels 3 40 --force
    python bench/independent_joint.py --out gvt --preset gvt   # the GVT's 400 Hz, 9 x 8192, 2-15 Hz

Writes per level ``indep-rms<L>.npz`` (the array format of docs/ident.md: ``u``, ``y``,
``fs``, ``N``, ``channels``, ``input_channels``, ``quantity``) and ``indep-rms<L>.truth.json``
(the underlying linear modes with the joint stuck and free, the joint law and the run's
slip, friction energy, contact and period-to-period differences), and the ident configs
``indep-linear.yaml``, ``indep-jenkins.yaml``, ``indep-cubic.yaml``, ``indep-coulomb.yaml``.
The levels are the commanded force RMS (N); the truth gives the measured one.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal
from numba import njit

#: Sample rate of the record (Hz), samples per period, periods (the first from rest).
SAMPLE_RATE_HZ = 500.0
SAMPLES_PER_PERIOD = 6000
N_PERIODS = 10
#: Integration steps per recorded sample (8 kHz).
OVERSAMPLE = 16
#: Excited band (Hz): every line of the grid.
BAND_HZ = (2.0, 22.0)
#: Levels (commanded force RMS, N): stuck, barely slipping, micro-slip, macro-slip at the peaks,
#: macro-slip, macro-slip + contact (see the truth's ``run.regime``).
DEFAULT_LEVELS = (3.0, 6.0, 10.0, 20.0, 35.0, 55.0)
#: Output names: structure DOF index of each accelerometer.
OUTPUTS = {"drive": 0, "bracket": 2, "box": 3}


@dataclass(frozen=True)
class TestSetup:
    """The acquisition: sample rate (Hz), samples per period, periods (the first from rest),
    excited band (Hz, every line of the grid)."""

    sample_rate_hz: float = SAMPLE_RATE_HZ
    samples_per_period: int = SAMPLES_PER_PERIOD
    n_periods: int = N_PERIODS
    band_hz: tuple = BAND_HZ


@dataclass(frozen=True)
class Structure:
    """The lumped structure, the joint and the shaker (SI units)."""

    mass_kg: tuple = (40.0, 28.0, 18.0, 22.0, 10.0)
    # springs (i, j, k): j = -1 is the ground; the joint (2, 3) is separate
    springs: tuple = ((0, -1, 2.0e4), (0, 1, 1.2e5), (1, 2, 6.0e4), (3, 4, 4.0e4),
                      (1, -1, 3.0e4), (4, -1, 5.0e3))
    joint_dofs: tuple = (2, 3)
    k_bolt_n_per_m: float = 2.5e4        # linear stiffness left when every slider slides
    k_iwan_n_per_m: float = 1.0e5        # total stiffness of the Jenkins elements (stuck)
    n_iwan: int = 10
    slip_force_min_n: float = 2.0        # slider slip forces spread uniformly over
    slip_force_max_n: float = 8.0        # [min, max] (N)
    gap_m: float = 2.8e-3                # one-sided contact: delta = q_bracket - q_box > gap
    k_contact_n_per_m: float = 2.0e5
    wear_floor: float = 0.6              # interface wear: slip forces fall to this fraction
    wear_energy_j: float = 25.0          # ... as exp(-E / wear_energy) of the dissipated E
    damping_ratio_base: float = 0.006    # modal damping of the stuck structure
    damping_ratio_per_hz: float = 0.0003
    armature_kg: float = 3.0
    armature_k_n_per_m: float = 3.0e3
    armature_c_ns_per_m: float = 60.0
    stinger_k_n_per_m: float = 8.0e5
    stinger_c_ns_per_m: float = 10.0

    def slip_forces_n(self) -> np.ndarray:
        """Slip force of each Jenkins element (N), shape (n_iwan,)."""
        return np.linspace(self.slip_force_min_n, self.slip_force_max_n, self.n_iwan)


@dataclass(frozen=True)
class Lab:
    """Sensor noise (RMS, white up to the record's Nyquist) and DC offsets."""

    accel_noise: float = 3.0e-4          # m/s^2 RMS
    force_noise: float = 1.0e-2          # N RMS
    accel_offsets: tuple = (0.021, -0.013, 0.034)   # m/s^2
    force_offset: float = 0.35           # N
    noise: bool = True


def _stiffness(st: Structure, k_joint: float) -> np.ndarray:
    """Stiffness matrix of the structure (5x5, N/m) with joint stiffness ``k_joint``."""
    n = len(st.mass_kg)
    k = np.zeros((n, n))
    for i, j, kk in (*st.springs, (*st.joint_dofs, k_joint)):
        k[i, i] += kk
        if j >= 0:
            k[j, j] += kk
            k[i, j] -= kk
            k[j, i] -= kk
    return k


def structure_matrices(st: Structure) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K (joint stuck), K (joint free: bolt only) of the structure, each (5, 5)."""
    m = np.diag(st.mass_kg)
    k_stuck = _stiffness(st, st.k_bolt_n_per_m + st.k_iwan_n_per_m)
    k_free = _stiffness(st, st.k_bolt_n_per_m)
    w2, phi = scipy.linalg.eigh(k_stuck, m)          # mass-normalised modes
    w = np.sqrt(w2)
    zeta = st.damping_ratio_base + st.damping_ratio_per_hz * w / (2 * np.pi)
    c = m @ phi @ np.diag(2 * zeta * w) @ phi.T @ m
    return m, c, k_stuck, k_free


def modes(m: np.ndarray, c: np.ndarray, k: np.ndarray) -> list[dict]:
    """Damped modes of ``M q'' + C q' + K q = f``: frequency (Hz) and damping ratio."""
    n = m.shape[0]
    minv = np.linalg.inv(m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ k, -minv @ c]])
    lam = np.linalg.eigvals(a)
    lam = lam[lam.imag > 0]
    lam = lam[np.argsort(np.abs(lam))]
    return [{"frequency_hz": float(abs(x) / (2 * np.pi)), "damping_ratio": float(-x.real / abs(x))}
            for x in lam]


def _full_system(st: Structure) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous state space of armature + structure (joint stuck): A, B_e, B_g.

    State ``[q_armature, q_1..q_5, v_armature, v_1..v_5]`` (12). ``B_e``: the commanded
    electromagnetic force on the armature; ``B_g``: the joint's correction force ``g`` (+ on
    the bracket, - on the box).
    """
    m5, c5, k5, _ = structure_matrices(st)
    n = 6
    m = np.zeros((n, n))
    c = np.zeros((n, n))
    k = np.zeros((n, n))
    m[0, 0] = st.armature_kg
    m[1:, 1:] = m5
    c[1:, 1:] = c5
    k[1:, 1:] = k5
    k[0, 0] += st.armature_k_n_per_m
    c[0, 0] += st.armature_c_ns_per_m
    for mat, val in ((k, st.stinger_k_n_per_m), (c, st.stinger_c_ns_per_m)):
        mat[0, 0] += val
        mat[1, 1] += val
        mat[0, 1] -= val
        mat[1, 0] -= val
    minv = np.linalg.inv(m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ k, -minv @ c]])
    b_e = np.zeros(2 * n)
    b_e[n:] = minv[:, 0]
    ja, jb = (1 + d for d in st.joint_dofs)
    b_g = np.zeros(2 * n)
    b_g[n:] = minv[:, ja] - minv[:, jb]
    return a, b_e, b_g


def _zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of ``x' = A x + B w``."""
    n, q = b.shape
    aug = np.zeros((n + q, n + q))
    aug[:n, :n] = a
    aug[:n, n:] = b
    e = scipy.linalg.expm(aug * dt)
    return e[:n, :n], e[:n, n:]


@njit(cache=True)
def _integrate(ad, bd, a, b, e, ja, jb, k_el, slip0, gap, k_c, wear_floor, wear_e, out_rows):  # pragma: no cover
    """Step the stuck linear model with the Iwan + contact correction fed back explicitly.

    Returns the recorded accelerations (n_steps, n_out), the stinger displacement difference
    and velocity difference (for the force), and per step the summed slider motion, the
    friction power and the contact indicator.
    """
    n_steps = e.shape[0]
    nx = ad.shape[0]
    nel = k_el.shape[0]
    x = np.zeros(nx)
    z = np.zeros(nel)
    acc = np.zeros((n_steps, out_rows.shape[0]))
    stinger = np.zeros((n_steps, 2))
    slip = np.zeros(n_steps)
    energy = np.zeros(n_steps)
    contact = np.zeros(n_steps)
    n_slipping = np.zeros(n_steps)
    nq = nx // 2
    slip_el = slip0.copy()
    e_total = 0.0
    for s in range(n_steps):
        wear = wear_floor + (1.0 - wear_floor) * np.exp(-e_total / wear_e)
        for i in range(nel):
            slip_el[i] = slip0[i] * wear
        delta = x[ja] - x[jb]
        g = 0.0
        ds = 0.0
        de = 0.0
        ns = 0
        for i in range(nel):
            f = k_el[i] * (delta - z[i])
            if f > slip_el[i]:
                znew = delta - slip_el[i] / k_el[i]
                ds += abs(znew - z[i])
                de += slip_el[i] * abs(znew - z[i])
                z[i] = znew
                ns += 1
            elif f < -slip_el[i]:
                znew = delta + slip_el[i] / k_el[i]
                ds += abs(znew - z[i])
                de += slip_el[i] * abs(znew - z[i])
                z[i] = znew
                ns += 1
            g += k_el[i] * z[i]
        if delta > gap:
            g -= k_c * (delta - gap)
            contact[s] = 1.0
        slip[s] = ds
        energy[s] = de
        e_total += de
        n_slipping[s] = ns
        w0 = e[s]
        for r in range(out_rows.shape[0]):
            row = out_rows[r]
            v = b[row, 0] * w0 + b[row, 1] * g
            for j in range(nx):
                v += a[row, j] * x[j]
            acc[s, r] = v
        stinger[s, 0] = x[0] - x[1]
        stinger[s, 1] = x[nq] - x[nq + 1]
        xn = np.zeros(nx)
        for i in range(nx):
            v = bd[i, 0] * w0 + bd[i, 1] * g
            for j in range(nx):
                v += ad[i, j] * x[j]
            xn[i] = v
        x = xn
    return acc, stinger, slip, energy, contact, n_slipping


def multisine(rms: float, seed: int, n: int, fs: float, band_hz: tuple,
              oversample: int) -> tuple[np.ndarray, np.ndarray]:
    """One period of a random-phase full-grid multisine at ``fs * oversample``.

    Returns the period (``n * oversample`` samples, RMS ``rms``) and its excited DFT bins
    (of one period of ``n`` samples at ``fs``).
    """
    lines = np.arange(int(np.ceil(band_hz[0] * n / fs)), int(np.floor(band_hz[1] * n / fs)) + 1)
    rng = np.random.default_rng(seed)
    spec = np.zeros(n * oversample // 2 + 1, complex)
    spec[lines] = np.exp(2j * np.pi * rng.random(lines.size))
    x = np.fft.irfft(spec, n * oversample)
    return x * rms / np.sqrt(np.mean(x ** 2)), lines


def simulate(level_n_rms: float, seed: int, st: Structure = Structure(), lab: Lab = Lab(),
             setup: TestSetup = TestSetup(), noise_seed: int | None = None) -> dict:
    """Simulate one level; returns the record's arrays and the run's truth.

    Returns
    -------
    dict with ``u`` (n_samples, 1) measured force (N), ``y`` (n_samples, 3) accelerations
    (m/s^2), ``lines`` the excited bins and ``run`` (slip, friction energy, contact, period
    differences, measured force RMS, regime).
    """
    n_periods, samples_per_period = setup.n_periods, setup.samples_per_period
    dt = 1.0 / (setup.sample_rate_hz * OVERSAMPLE)
    period, lines = multisine(level_n_rms, seed, samples_per_period, setup.sample_rate_hz,
                              setup.band_hz, OVERSAMPLE)
    e = np.tile(period, n_periods)
    a, b_e, b_g = _full_system(st)
    b = np.column_stack([b_e, b_g])
    ad, bd = _zoh(a, b, dt)
    ja, jb = (1 + d for d in st.joint_dofs)
    k_el = np.full(st.n_iwan, st.k_iwan_n_per_m / st.n_iwan)
    rows = np.array([6 + 1 + OUTPUTS[k] for k in OUTPUTS], dtype=np.int64)
    acc, sting, slip, energy, contact, n_slip = _integrate(
        ad, bd, a, b, e, ja, jb, k_el, st.slip_forces_n(), st.gap_m, st.k_contact_n_per_m,
        st.wear_floor, st.wear_energy_j, rows)
    force = st.stinger_k_n_per_m * sting[:, 0] + st.stinger_c_ns_per_m * sting[:, 1]
    raw = np.column_stack([force, acc])
    # lab: causal linear-phase anti-alias FIR (pass band to 0.4 fs), decimation
    taps = scipy.signal.firwin(16 * OVERSAMPLE + 1, 0.8 / OVERSAMPLE)
    rec = scipy.signal.lfilter(taps, 1.0, raw, axis=0)[::OVERSAMPLE]
    rng = np.random.default_rng(10_000 + seed if noise_seed is None else noise_seed)
    if lab.noise:
        rec[:, 0] += lab.force_noise * rng.standard_normal(rec.shape[0]) + lab.force_offset
        rec[:, 1:] += (lab.accel_noise * rng.standard_normal((rec.shape[0], 3))
                       + np.asarray(lab.accel_offsets))
    per = rec.reshape(n_periods, samples_per_period, 4)
    step_per = slip.reshape(n_periods, -1)
    diffs = [float(np.max([np.sqrt(np.mean((per[p, :, c] - per[p - 1, :, c]) ** 2))
                           / np.sqrt(np.mean((per[p, :, c] - per[p, :, c].mean()) ** 2))
                           for c in range(1, 4)])) for p in range(1, n_periods)]
    max_slipping = int(n_slip.max())
    regime = ("stuck" if max_slipping == 0 else
              "micro-slip" if max_slipping < st.n_iwan else "macro-slip")
    if contact.any():
        regime += " + contact"
    run = {
        "commanded_force_rms_n": float(level_n_rms),
        "measured_force_rms_n": float(np.std(per[-1, :, 0])),
        "regime": regime,
        "max_elements_slipping": max_slipping,
        "slip_m_per_period": [float(x) for x in step_per.sum(axis=1)],
        "friction_energy_j": float(energy.sum()),
        "contact_fraction": float(contact.mean()),
        "period_difference_max_channel": diffs,
        "output_rms_last_period": {k: float(np.std(per[-1, :, 1 + i]))
                                   for i, k in enumerate(OUTPUTS)},
    }
    return {"u": rec[:, :1], "y": rec[:, 1:], "lines": lines, "run": run}


def truth(st: Structure = Structure(), setup: TestSetup = TestSetup()) -> dict:
    """The underlying linear structure with the joint stuck and free, and the joint law."""
    m, c, k_stuck, k_free = structure_matrices(st)
    band = [float(f) for f in setup.band_hz]
    return {
        "simulator": "bench/independent_joint.py (independent of daq/sim)",
        "modes_joint_stuck": modes(m, c, k_stuck),
        "modes_joint_free": modes(m, c, k_free),
        "band_hz": band,
        "joint": {
            "law": "k_bolt*delta + Iwan (n Jenkins elements K_t/n in series with sliders, slip "
                   "forces uniform in [F_min, F_max]) + one-sided contact k_c*max(delta-gap, 0)",
            "delta": "q_bracket - q_box (channels {bracket: 1, box: -1})",
            **{k: v for k, v in asdict(st).items() if k not in ("springs",)},
            "slip_displacement_first_m": st.slip_force_min_n * st.n_iwan / st.k_iwan_n_per_m,
            "slip_displacement_last_m": st.slip_force_max_n * st.n_iwan / st.k_iwan_n_per_m,
        },
    }


_COMMON = """\
band_hz: [LOW, HIGH]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {name: F-shaker, driving_point: drive}
max_order: 30
"""

CONFIGS = {
    "indep-linear.yaml": "nonlinearities: []\n",
    "indep-jenkins.yaml": """\
nonlinearities:
  - name: joint
    kind: jenkins
    channels: {bracket: 1, box: -1}
    slip: auto
""",
    "indep-cubic.yaml": """\
nonlinearities:
  - name: joint-cubic
    kind: polynomial
    exponent: 3
    channels: {bracket: 1, box: -1}
""",
    "indep-coulomb.yaml": """\
nonlinearities:
  - name: joint-friction
    kind: coulomb
    channels: {bracket: 1, box: -1}
    velocity_scale: 1.0e-3
""",
}


#: ``--preset gvt``: the acquisition of the aircraft GVT (400 Hz, 9 periods of 8192, 2-15
#: Hz) on this structure with 2.2x the masses (modes 2.2-13.6 Hz with the joint stuck).
PRESETS = {
    "default": (Structure(), TestSetup()),
    "gvt": (Structure(mass_kg=tuple(2.2 * m for m in Structure().mass_kg)),
            TestSetup(sample_rate_hz=400.0, samples_per_period=8192, n_periods=9,
                      band_hz=(2.0, 15.0))),
}


def write_level(out: Path, level: float, seed: int, *, force: bool = False,
                preset: str = "default") -> Path:
    """Simulate one level and write ``indep-rms<L>.npz`` and its truth JSON."""
    st, setup = PRESETS[preset]
    path = out / f"indep-rms{level:g}.npz"
    if path.exists() and not force:
        print(f"{path} exists: kept (--force replaces it)", file=sys.stderr)
        return path
    sim = simulate(level, seed, st=st, setup=setup)
    np.savez(path, u=sim["u"], y=sim["y"], fs=setup.sample_rate_hz, N=setup.samples_per_period,
             channels=np.array(list(OUTPUTS)), input_channels=np.array(["F-shaker"]),
             quantity="acceleration")
    t = truth(st, setup)
    t["run"] = {**sim["run"], "phase_seed": seed, "preset": preset}
    path.with_suffix(".truth.json").write_text(json.dumps(t, indent=2))
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="example: python bench/independent_joint.py --out indep")
    p.add_argument("--out", type=Path, required=True, help="folder for the records and configs")
    p.add_argument("--levels", type=float, nargs="+", default=list(DEFAULT_LEVELS),
                   help="commanded force RMS (N) of each level")
    p.add_argument("--phase-seed", type=int, default=100, help="seed of the first level's phases")
    p.add_argument("--preset", choices=sorted(PRESETS), default="default",
                   help="gvt: the aircraft GVT's acquisition (400 Hz, 9 x 8192, 2-15 Hz) on "
                        "this structure with 2.2x the masses")
    p.add_argument("--force", action="store_true", help="replace existing files")
    args = p.parse_args(argv)
    band = PRESETS[args.preset][1].band_hz
    args.out.mkdir(parents=True, exist_ok=True)
    for i, level in enumerate(args.levels):
        path = write_level(args.out, level, args.phase_seed + i, force=args.force,
                           preset=args.preset)
        run = json.loads(path.with_suffix(".truth.json").read_text())["run"]
        print(f"{path}: {run['regime']}, measured {run['measured_force_rms_n']:.2f} N RMS, "
              f"slip {sum(run['slip_m_per_period']):.2e} m, contact {run['contact_fraction']:.2%}, "
              f"last period difference {run['period_difference_max_channel'][-1]:.2%}",
              file=sys.stderr)
    for name, body in CONFIGS.items():
        path = args.out / name
        if not path.exists() or args.force:
            common = _COMMON.replace("LOW", f"{band[0]:g}").replace("HIGH", f"{band[1]:g}")
            path.write_text(f"# Independent joint test (bench/independent_joint.py)\n{common}{body}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
