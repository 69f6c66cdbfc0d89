"""``AircraftSource``: the aircraft-like GVT (:mod:`daq.sim.aircraft`) as an acquisition source.

Registered as source kind ``aircraft`` (:mod:`daq.registry`); ``daq/data/aircraft.yaml`` is
the packaged experiment (``fnsi-lab acquire --config aircraft --level 98``). Options::

    source:
      kind: aircraft
      options:
        oversample: 16        # internal rate = oversample * sample_rate_hz
        noise: true           # lab noise (daq.sim.aircraft.LabNoise): sensor noise, drift, offsets
        noise_seed: 1
        joint: {slip_force_n: 40, settle_slip_m: 0.4, ...}   # JointParameters overrides

``excitation.rms`` is the target RMS of the **measured** (load-cell) force; ``periods``
are simulated from rest (the first ones are transient). Channels: ``F-shaker`` (N) and the
accelerations ``drive``, ``wing``, ``payload`` (m/s^2).
"""

from __future__ import annotations

import io
from dataclasses import fields, replace
from typing import Any

import numpy as np

from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.config import ExperimentConfig
from fnsi_lab.daq.sim.aircraft import (ACCEL_CHANNELS, FORCE_CHANNEL, AircraftModel,
                                       JointParameters, LabNoise, aircraft_model,
                                       aircraft_record)
from fnsi_lab.daq.sim.source import SimOptions, SimulatedSource
from fnsi_lab.validate import Section


class AircraftSource(SimulatedSource):
    """Multisine GVT of the aircraft-like structure, one simulation per realization.

    Parameters
    ----------
    aircraft : AircraftModel
    excitation, sample_rate_hz, block_size, pace
        As :class:`~daq.sim.source.SimulatedSource`.
    oversample : int
    noise : LabNoise or None
    noise_seed : int
    """

    kind = "aircraft"

    def __init__(self, aircraft: AircraftModel, excitation: Any, sample_rate_hz: float, *,
                 block_size: int = 100, oversample: int = 16, noise: LabNoise | None = LabNoise(),
                 noise_seed: int = 1, pace: float | None = None) -> None:
        self.aircraft = aircraft
        self._oversample = int(oversample)
        self._noise = noise
        self._noise_seed = int(noise_seed)
        st = aircraft.structure
        opts = SimOptions(st, {c: "acceleration" for c in ACCEL_CHANNELS}, {}, int(noise_seed),
                          int(oversample), 0.4, False)
        super().__init__(st, excitation, sample_rate_hz, block_size=block_size, options=opts,
                         pace=pace)

    @staticmethod
    def _channel_table(model: Any, options: SimOptions) -> list[ChannelInfo]:
        return ([ChannelInfo(FORCE_CHANNEL, "force", "N", "drive", "Z")]
                + [ChannelInfo(nm, "acceleration", "m/s^2", nm, "Z") for nm in ACCEL_CHANNELS])

    @classmethod
    def from_config(cls, config: ExperimentConfig, *, pace: float | None = None) -> "AircraftSource":
        """Build from a validated experiment (``source.options`` checked here)."""
        sec = Section(config.source.options, file=config.file, prefix="source.options")
        oversample = sec.integer("oversample", 16, minimum=4, maximum=256)
        noise = LabNoise() if sec.boolean("noise", True) else None
        noise_seed = sec.integer("noise_seed", 1, minimum=0)
        jsec = sec.section("joint")
        joint = JointParameters()
        overrides: dict[str, Any] = {}
        for f in fields(JointParameters):
            if jsec.has(f.name):
                overrides[f.name] = (jsec.numbers(f.name, length=2) if f.name == "clearance_m"
                                     else jsec.number(f.name, minimum=0.0,
                                                      maximum=1.0 if f.name == "settle_residual"
                                                      else None))
        jsec.finish()
        sec.finish()
        if config.excitation is None:
            raise config.error("excitation", "the aircraft source needs an excitation",
                               fix="add an 'excitation:' multisine section")
        src = cls(aircraft_model(replace(joint, **overrides)), config.excitation,
                  config.sample_rate_hz, block_size=config.block_size, oversample=oversample,
                  noise=noise, noise_seed=noise_seed, pace=pace)
        return src

    def simulate_realization(self, r: int) -> np.ndarray:
        """Noisy channel data of realization ``r``, shape (n_samples, 4)."""
        exc = self.excitation
        rec = aircraft_record(float(exc.rms), period_command=self._ms.period(r),
                              sample_rate_hz=self._sample_rate_hz,
                              samples_per_period=exc.samples_per_period, periods=exc.periods,
                              band_hz=tuple(exc.band_hz), oversample=self._oversample,
                              joint=self.aircraft.joint, noise=self._noise,
                              noise_seed=self._noise_seed * 1000 + r)
        info = dict(rec.info)
        info["command_rms_n"] = rec.command_rms_n
        self._results[r] = info
        self._cached = (r, rec.data)
        return rec.data

    def verify_integration(self) -> None:
        """Not run for the aircraft (its accuracy is checked in tests/test_sim_aircraft.py)."""
        return None

    def _truth(self, info: dict[str, Any] | None) -> dict[str, Any]:
        ac = self.aircraft
        modes = ac.structure.modes
        info = info or {}
        return {
            "units": dict(ac.structure.units),
            "model": "aircraft",
            "modes": [{"frequency_hz": float(f), "damping_ratio": float(z)}
                      for f, z in zip(modes.frequency_hz, modes.damping_ratio)],
            "modes_note": "linear structure with the joint stuck (the small-amplitude limit); "
                          "modes_joint_slipping_hz: undamped, slider fully slipping",
            "modes_joint_slipping_hz": [float(f) for f in ac.joint_free_modes_hz()],
            "joint": {"channels": {"wing": 1.0, "payload": -1.0}, **ac.joint.to_dict(),
                      "law": "k_linear delta + Jenkins(k_stick in series with a slider of "
                             "force F_s = slip_force_n (r + (1 - r) exp(-S / settle_slip_m)), "
                             "S the accumulated slip) + k_contact beyond the clearance"},
            "nonlinearities": [],
            "run": {k: v for k, v in info.items()},
            "integration": {"method": "exact complex-modal propagation, Heun joint force, "
                                      "Jenkins return mapping; linear-phase FIR decimation",
                            "internal_rate_hz": self._oversample * self._sample_rate_hz},
        }

    def truth_attachments(self) -> list[tuple[str, str, bytes]]:
        """``truth_frf.npz``: accelerations per measured force of the stuck linear model
        (``frf`` complex (n_lines, 3, 1)), like :class:`SimulatedSource`."""
        n_per = self.excitation.samples_per_period
        f = np.arange(n_per // 2 + 1) * self._sample_rate_hz / n_per
        ac = self.aircraft
        h = ac.structure.frf(f, "acceleration", ac.measured_dofs)
        hf = ac.force_frf(f)
        with np.errstate(divide="ignore", invalid="ignore"):
            frf = h / hf[:, None, None]
        frf[0] = 0.0
        buf = io.BytesIO()
        np.savez(buf, frequency_hz=f, frf=frf, outputs=np.array(ACCEL_CHANNELS),
                 inputs=np.array([FORCE_CHANNEL]), eigenvalues=ac.structure.modes.eigenvalues)
        return [("truth_frf.npz", "application/x-npz", buf.getvalue())]
