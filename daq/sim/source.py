"""``SimulatedSource``: a seeded, deterministic source that simulates a structure.

Registered as kinds ``simulated`` and ``smallsat`` (:mod:`daq.registry`). Options
(``source.options`` of the experiment YAML, validated with :class:`fnsi_lab.validate.Section`)::

    source:
      kind: smallsat            # or simulated
      options:
        model: smallsat         # smallsat | lumped | {mass: ..., stiffness: ..., ...}
        lumped: {variant: cubic}     # options of the built-in lumped chain
        quantity: displacement  # or velocity / acceleration, or {channel: quantity}
        snr_db: null            # measurement noise: one number, or {channel: dB}
        noise_seed: 1           # noise is seeded too (per realization)
        oversample: 10          # internal rate = oversample * sample_rate_hz
        passband: 0.4           # anti-alias filter flat up to passband * fs
        verify: true            # measure the integration error (2x internal rate run)
        lab:                    # optional lab disturbances of every recorded channel
          noise_colour: pink    # white (default) | pink: the snr_db noise with a 1/f spectrum
          hum_hz: 50            # mains hum at hum_hz and 3 hum_hz ...
          hum_level: 0.01       # ... amplitude as a fraction of each channel's RMS
          offset: 0.02          # DC offset, fraction of each channel's RMS
      (DAC hold, a causal anti-alias filter and one period per realisation:
      daq.sim.lab.lab_experiment)

A model given as matrices::

    model:
      dofs: [X1, X2]
      mass: [[1, 0], [0, 1]]          # model units (default SI)
      stiffness: [[2e4, -1e4], [-1e4, 1e4]]
      damping: [[2, -1], [-1, 1]]
      force_dofs: [X2]
      measured: [X1, X2]              # channel name = dof name
      units: {length: m, force: N}
      nonlinearities:
        - {name: stop, kind: trilinear, dofs: {X1: 1, X2: -1},
           coefficients: {neg: 2e4, pos: 1.5e4}, clearances: [4e-4, 5e-4]}
"""

from __future__ import annotations

import io
import queue
import threading
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.config import ExperimentConfig, ExcitationConfig
from fnsi_lab.daq.multisine import Multisine, multisine
from fnsi_lab.daq.sim.integrate import (SimulationResult, antialias_gain, load_kernel_async,
                                         simulate)
from fnsi_lab.daq.sim.model import StructuralModel
from fnsi_lab.daq.sim.nonlinear import ELEMENT_KINDS, NonlinearElement
from fnsi_lab.daq.source import Source
from fnsi_lab.errors import ConfigError
from fnsi_lab.validate import Section

RESPONSE_QUANTITIES = ("displacement", "velocity", "acceleration")
_SUFFIX = {"displacement": "", "velocity": "/s", "acceleration": "/s^2"}


@dataclass(frozen=True)
class SimOptions:
    """Validated options of a :class:`SimulatedSource` (see the module docstring)."""

    model: StructuralModel
    quantities: Mapping[str, str]
    snr_db: Mapping[str, float]
    noise_seed: int
    oversample: int
    passband: float
    verify: bool
    lab: Mapping[str, Any] | None = None


# ---------------------------------------------------------------------------- options
def _matrix(sec: Section, key: str, n: int | None) -> np.ndarray:
    raw = sec.raw(key)
    try:
        a = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        raise sec.error(key, "expected a square list of lists of numbers") from None
    if a.ndim != 2 or a.shape[0] != a.shape[1] or (n is not None and a.shape[0] != n):
        raise sec.error(key, f"expected a {n or 'n'} x {n or 'n'} matrix, got {plain.shape(a.shape)}")
    if not np.all(np.isfinite(a)):
        raise sec.error(key, "contains non-finite values")
    if not np.allclose(a, a.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(a).max())):
        raise sec.error(key, "matrix is not symmetric", fix="reciprocity needs symmetric M, C, K")
    return a


def model_from_mapping(data: Any, *, file: str | None = None,
                       prefix: str = "source.options.model") -> StructuralModel:
    """Build a :class:`StructuralModel` from its YAML mapping (see the module docstring)."""
    sec = Section(data, file=file, prefix=prefix)
    dofs_raw = sec.items("dofs")
    if not dofs_raw or not all(isinstance(d, str) for d in dofs_raw) or len(set(dofs_raw)) != len(dofs_raw):
        raise sec.error("dofs", "expected a list of unique DOF names")
    dofs = tuple(dofs_raw)
    n = len(dofs)
    index = {d: i for i, d in enumerate(dofs)}

    def dof_index(key: str, name: Any) -> int:
        if name not in index:
            raise sec.error(key, f"unknown DOF {name!r}", fix=f"use one of {plain.names(dofs)}")
        return index[name]

    mass = _matrix(sec, "mass", n)
    stiffness = _matrix(sec, "stiffness", n)
    damping = _matrix(sec, "damping", n) if sec.has("damping") and sec.data["damping"] is not None \
        else np.zeros((n, n))
    force_dofs = sec.items("force_dofs")
    t = np.zeros((n, len(force_dofs)))
    for j, d in enumerate(force_dofs):
        t[dof_index("force_dofs", d), j] = 1.0
    measured_raw = sec.raw("measured", list(dofs))
    if isinstance(measured_raw, Mapping):
        measured = {str(ch): dof_index("measured", d) for ch, d in measured_raw.items()}
    elif isinstance(measured_raw, list):
        measured = {str(d): dof_index("measured", d) for d in measured_raw}
    else:
        raise sec.error("measured", "expected a list of DOF names or a {channel: dof} mapping")
    units_raw = sec.raw("units", {})
    if not isinstance(units_raw, Mapping):
        raise sec.error("units", "expected a mapping such as {length: m, force: N}")
    units = {"length": "m", "force": "N", "time": "s", "mass": "kg"}
    units.update({str(k): str(v) for k, v in units_raw.items()})
    elements = []
    for i, item in enumerate(sec.items("nonlinearities", [])):
        es = Section(item, file=file, prefix=f"{prefix}.nonlinearities[{i}]")
        name = es.string("name")
        kind = es.string("kind", choices=ELEMENT_KINDS)
        wmap = es.raw("dofs")
        if not isinstance(wmap, Mapping) or not wmap:
            raise es.error("dofs", "expected a mapping {dof: weight}, e.g. {X1: 1, X2: -1}")
        w = np.zeros(n)
        for d, val in wmap.items():
            if d not in index:
                raise es.error("dofs", f"unknown DOF {d!r}", fix=f"use one of {plain.names(dofs)}")
            if isinstance(val, bool) or not isinstance(val, (int, float)):
                raise es.error("dofs", f"weight of {d!r} must be a number, got {plain.value(val)}")
            w[index[d]] = float(val)
        coefs = es.raw("coefficients")
        if not isinstance(coefs, Mapping) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in coefs.values()):
            raise es.error("coefficients", "expected a mapping of numbers, e.g. {k: 1e9}")
        kwargs: dict[str, Any] = {}
        if es.has("clearances"):
            kwargs["clearances"] = es.numbers("clearances")
        if es.has("exponent"):
            kwargs["exponent"] = es.number("exponent", positive=True)
        if es.has("signed"):
            kwargs["signed"] = es.boolean("signed")
        if es.has("argument"):
            kwargs["argument"] = es.string("argument", choices=("displacement", "velocity"))
        if es.has("regularization"):
            kwargs["regularization"] = es.number("regularization", positive=True)
        es.finish()
        try:
            elements.append(NonlinearElement(name, kind, w, dict(coefs), **kwargs))  # type: ignore[arg-type]
        except ConfigError as exc:
            raise ConfigError(exc.reason, file=file, field=f"{prefix}.nonlinearities[{i}]",
                              fix=exc.fix) from None
    name = sec.string("name", "yaml-model")
    sec.finish()
    try:
        return StructuralModel(mass, damping, stiffness, dofs, t,
                               tuple(f"F-{d}" for d in force_dofs), measured, tuple(elements),
                               units, name, {d: (d, "") for d in dofs},
                               f"{n}-DOF model from the experiment file")
    except ConfigError as exc:
        raise ConfigError(exc.reason, file=file, field=prefix, fix=exc.fix) from None


def parse_options(config: ExperimentConfig) -> SimOptions:
    """Validate ``config.source.options`` into :class:`SimOptions`.

    Raises
    ------
    ConfigError
        Naming the file, ``source.options.<field>`` and the fix.
    """
    file = config.file
    sec = Section(config.source.options, file=file, prefix="source.options")
    default_model = "smallsat" if config.source.kind == "smallsat" else "lumped"
    model_raw = sec.raw("model", default_model)
    lumped_opts = sec.section("lumped")
    smallsat_opts = sec.section("smallsat")
    if isinstance(model_raw, Mapping):
        model = model_from_mapping(model_raw, file=file)
    elif model_raw == "lumped":
        from fnsi_lab.daq.sim.lumped import lumped_model
        kw: dict[str, Any] = {}
        kw["variant"] = lumped_opts.string("variant", "cubic",
                                           choices=("cubic", "trilinear", "duffing", "none"))
        for key in ("masses", "springs"):
            if lumped_opts.has(key):
                kw[key] = lumped_opts.numbers(key)
        for key in ("k3", "mass_damping", "stiffness_damping", "dashpot"):
            if lumped_opts.has(key):
                kw[key] = lumped_opts.number(key, nonnegative=True)
        for key in ("clearances", "contact"):
            if lumped_opts.has(key):
                kw[key] = lumped_opts.numbers(key, length=2)
        lumped_opts.finish()
        model = lumped_model(**kw)
    elif model_raw == "smallsat":
        from fnsi_lab.daq.sim.smallsat import smallsat_model
        skw: dict[str, Any] = {}
        if smallsat_opts.has("damping"):
            skw["damping"] = smallsat_opts.string("damping",
                                                  choices=("nonproportional", "proportional"))
        if smallsat_opts.has("nonlinear"):
            skw["nonlinear"] = smallsat_opts.boolean("nonlinear")
        smallsat_opts.finish()
        model = smallsat_model(**skw)
    else:
        raise sec.error("model", f"unknown model {model_raw!r}",
                        fix="use smallsat, lumped, or a mapping with mass/stiffness/damping")
    for key, used in (("lumped", model_raw == "lumped"), ("smallsat", model_raw == "smallsat")):
        if not used and sec.data.get(key):
            raise sec.error(key, f"options for the {key} model, but model is not {key}",
                            fix=f"set 'model: {key}' or remove '{key}:'")
    channels = model.measured_names
    quantities = _per_channel(sec, "quantity", channels, "displacement",
                              lambda k, v: v if v in RESPONSE_QUANTITIES else None,
                              f"one of {plain.names(RESPONSE_QUANTITIES)}")
    snr = _per_channel(sec, "snr_db", list(model.input_names) + channels, None,
                       lambda k, v: float(v) if isinstance(v, (int, float))
                       and not isinstance(v, bool) else None, "a number of dB")
    opts = SimOptions(
        model=model, quantities=quantities, snr_db={k: v for k, v in snr.items() if v is not None},
        noise_seed=sec.integer("noise_seed", 1, minimum=0),
        oversample=sec.integer("oversample", 10, minimum=1, maximum=1000),
        passband=sec.number("passband", 0.4, minimum=0.05, maximum=0.5),
        verify=sec.boolean("verify", True), lab=_lab_options(sec.section("lab")))
    sec.finish()
    return opts


def _lab_options(sec: Section) -> dict[str, Any] | None:
    """``lab:`` disturbances of the recorded channels (daq.sim.lab.add_disturbances)."""
    lab = {"noise_colour": sec.string("noise_colour", "white", choices=("white", "pink")),
           "hum_hz": sec.number("hum_hz", 0.0, minimum=0.0),
           "hum_level": sec.number("hum_level", 0.0, minimum=0.0),
           "offset": sec.number("offset", 0.0)}
    sec.finish()
    default = {"noise_colour": "white", "hum_hz": 0.0, "hum_level": 0.0, "offset": 0.0}
    return None if lab == default else lab


def _per_channel(sec: Section, key: str, channels: list[str], default: Any, check, what: str
                 ) -> dict[str, Any]:
    """A value for every channel: one global value or a {channel: value} mapping."""
    raw = sec.raw(key, default)
    if isinstance(raw, Mapping):
        out = {ch: default for ch in channels}
        for ch, v in raw.items():
            if ch not in out:
                raise sec.error(key, f"unknown channel {ch!r}", fix=f"use one of {plain.names(channels)}")
            val = check(ch, v)
            if val is None:
                raise sec.error(key, f"{ch}: expected {what}, got {plain.value(v)}")
            out[ch] = val
        return out
    if raw is None:
        return {ch: None for ch in channels}
    val = check(None, raw)
    if val is None:
        raise sec.error(key, f"expected {what} or a {{channel: value}} mapping, got {raw!r}")
    return {ch: val for ch in channels}


# ---------------------------------------------------------------------------- source
class SimulatedSource(Source):
    """Multisine experiment on a simulated structure (deterministic from the seeds).

    Parameters
    ----------
    model : StructuralModel
    excitation : ExcitationConfig
        The multisine (``rms`` in the model force unit).
    sample_rate_hz : float
    block_size : int
        Samples per block (the last block of a realization may be shorter).
    options : SimOptions, optional
        Quantities, noise, integration settings (defaults: displacement, no noise).
    channels : sequence of ChannelInfo, optional
        Subset/order of the model's channels (names must exist; force channels first).
    pace : float or None
        Wall-clock pacing (see :class:`daq.source.Source`).

    Notes
    -----
    Once started, a background thread simulates the realizations in order, one ahead of
    the reader (bounded memory); a second thread computes the truth FRF and then runs the
    integration check at twice the internal rate (``verify``) meanwhile (paced: after
    realization 0 is handed over). A nonlinear model's compiled kernel starts loading in a
    third thread when the source is built (:func:`~daq.sim.integrate.load_kernel_async`).
    A paced source streams from the moment realization 0 is computed instead of after the
    whole experiment, and an unpaced one overlaps the simulation with the recording.
    Blocks carry ``first_sample`` counted within the realization and the realization
    index. Columns: force channel(s) first (quantity ``force``), then the responses.
    """

    kind = "simulated"

    def __init__(self, model: StructuralModel, excitation: ExcitationConfig,
                 sample_rate_hz: float, *, block_size: int = 100,
                 options: SimOptions | None = None,
                 channels: tuple[ChannelInfo, ...] = (), pace: float | None = None) -> None:
        if options is None:
            options = SimOptions(model, {c: "displacement" for c in model.measured_names}, {},
                                 1, 10, 0.4, False)
        self.model = model
        self.excitation = excitation
        self.options = options
        self.block_size = int(block_size)
        table = self._channel_table(model, options)
        if channels:
            by_name = {c.name: c for c in table}
            chosen = []
            for c in channels:
                if c.name not in by_name:
                    raise ConfigError(f"channel {c.name!r} is not produced by model {model.name}",
                                      field="channels", fix=f"use names from {plain.names(by_name)}")
                base = by_name[c.name]
                if c.quantity != base.quantity and not base.is_force:
                    unit = model.units.get("length", "m") + _SUFFIX[c.quantity]
                    base = ChannelInfo(base.name, c.quantity, unit, base.node, base.direction)
                chosen.append(base)
            chosen.sort(key=lambda c: not c.is_force)
            table = chosen
        super().__init__(table, sample_rate_hz, pace=pace)
        self._ms: Multisine = multisine(
            excitation.samples_per_period, sample_rate_hz, excitation.band_hz, excitation.rms,
            n_periods=excitation.periods, n_realizations=excitation.realizations,
            seed=excitation.seed, phases=excitation.phases, grid=excitation.grid,
            detection_block=excitation.detection_block)
        self._dof_of = {ch: model.measured[ch] for ch in model.measured_names}
        self._input_index = {nm: j for j, nm in enumerate(model.input_names)}
        self._realization = 0
        self._position = 0
        self._data: np.ndarray | None = None
        self._results: dict[int, dict[str, Any]] = {}
        self._cached: tuple[int, np.ndarray] | None = None  # last simulated realization
        # background production (see Notes): realizations computed ahead of the reader
        self._ready: queue.Queue[Any] = queue.Queue(maxsize=1)
        self._producer: threading.Thread | None = None
        self._halt = threading.Event()
        self._lock_sim = threading.RLock()  # one simulation at a time (reader or producer)
        self._r0_run: SimulationResult | None = None  # realization 0's run, for verify
        self._verify_error: dict[str, float] | None = None
        self._lock_verify = threading.Lock()
        self._checker: threading.Thread | None = None
        self._check_error: BaseException | None = None
        self._first_ready = threading.Event()  # realization 0 handed to the reader
        self._frf_attachment: list[tuple[str, str, bytes]] | None = None
        if model.nonlinearities:  # the compiled kernel loads while the rest is set up
            load_kernel_async()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_config(cls, config: ExperimentConfig, *, pace: float | None = None) -> "SimulatedSource":
        """Build from a validated experiment (options checked with ``Section``)."""
        opts = parse_options(config)
        if config.excitation is None:
            raise config.error("excitation", "a simulated source needs an excitation",
                               fix="add an 'excitation:' multisine section")
        src = cls(opts.model, config.excitation, config.sample_rate_hz,
                  block_size=config.block_size, options=opts, channels=config.channels,
                  pace=pace)
        src.kind = config.source.kind  # type: ignore[misc]
        return src

    @staticmethod
    def _channel_table(model: StructuralModel, options: SimOptions) -> list[ChannelInfo]:
        length = model.units.get("length", "m")
        force = model.units.get("force", "N")
        table = []
        for j, nm in enumerate(model.input_names):
            dof = int(np.argmax(np.abs(model.force_matrix[:, j])))
            node, direction = model.node_direction.get(model.dof_names[dof], ("", ""))
            table.append(ChannelInfo(nm, "force", force, node, direction))
        for ch, dof in model.measured.items():
            q = options.quantities.get(ch, "displacement")
            node, direction = model.node_direction.get(model.dof_names[dof], ("", ""))
            table.append(ChannelInfo(ch, q, length + _SUFFIX[q], node, direction))  # type: ignore[arg-type]
        return table

    # ------------------------------------------------------------------ simulation
    @property
    def multisine(self) -> Multisine:
        """The excitation signal (all realizations)."""
        return self._ms

    def _sim_inputs(self, r: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Force (n_samples, n_inputs), response DOFs and quantities of realization ``r``."""
        force = np.zeros((self._ms.signal.shape[1], self.model.n_inputs))
        force[:, 0] = self._ms.signal[r]  # the multisine drives the first input
        resp = [c for c in self._channels if not c.is_force]
        dofs = np.array([self._dof_of[c.name] for c in resp], dtype=np.int64)
        qs = sorted({c.quantity for c in resp}, key=RESPONSE_QUANTITIES.index)
        return force, dofs, qs

    def simulate_realization(self, r: int) -> np.ndarray:
        """Noisy channel data of realization ``r``, shape (n_samples, n_channels)."""
        exc = self.excitation
        n_per = exc.samples_per_period
        force, dofs, qs = self._sim_inputs(r)
        res = simulate(self.model, force, self._sample_rate_hz, oversample=self.options.oversample,
                       periodic=n_per, dofs=dofs, quantities=qs, passband=self.options.passband,
                       count_from=exc.transient_periods * n_per)
        # the recorded force sees the same anti-alias filter as the responses (identity for
        # a multisine below passband * fs; exact per period otherwise)
        spec = np.fft.rfft(force[:n_per], axis=0)
        spec *= antialias_gain(np.arange(spec.shape[0]) * self._sample_rate_hz / n_per,
                               self._sample_rate_hz, self.options.passband)[:, None]
        rec_force = np.tile(np.fft.irfft(spec, n=n_per, axis=0), (exc.periods, 1))
        cols = []
        j = 0
        for c in self._channels:
            if c.is_force:
                cols.append(rec_force[:, self._input_index[c.name]])
            else:
                cols.append(res.get(c.quantity)[:, j])  # type: ignore[arg-type]
                j += 1
        clean = np.stack(cols, axis=1)
        info: dict[str, Any] = {"contact_fraction": res.contact_fraction,
                                "steady_state_error": steady_state_error(clean, n_per, exc.periods),
                                "iterations_max": res.iterations_max,
                                "unconverged_steps": res.unconverged_steps,
                                "internal_rate_hz": res.internal_rate_hz}
        if r == 0:
            self._r0_run = res
        self._results[r] = info
        data = self._add_noise(clean, r)
        self._cached = (r, data)
        return data

    def verify_integration(self) -> dict[str, float] | None:
        """Relative error of realization 0 against a run at twice the internal rate.

        Stored in ``run_info(0)['error_vs_double_rate']`` (None when ``verify`` is off or
        the model is linear). Simulates realization 0 first if needed.
        """
        if not (self.options.verify and self.model.nonlinearities):
            return None
        with self._lock_verify:
            if self._verify_error is None:
                # independent of realization 0's run: in the background it runs alongside it
                force, dofs, qs = self._sim_inputs(0)
                exc = self.excitation
                n_per = exc.samples_per_period
                fine = simulate(self.model, force, self._sample_rate_hz,
                                oversample=2 * self.options.oversample, periodic=n_per,
                                dofs=dofs, quantities=qs, passband=self.options.passband)
                info = self.run_info(0, verify=False)
                assert self._r0_run is not None
                self._verify_error = _relative_error(self._r0_run, fine, qs,
                                                     n_per * exc.transient_periods)
                info["error_vs_double_rate"] = self._verify_error
                self._r0_run = None
        return self._verify_error

    # ------------------------------------------------------------------ background production
    def _start(self) -> None:
        if self._producer is None:
            self._producer = threading.Thread(target=self._produce, name="fnsi-lab-sim",
                                              daemon=True)
            self._producer.start()
            # the 2x-rate check and the truth FRF on a second thread (a second core)
            self._checker = threading.Thread(target=self._check, name="fnsi-lab-sim-check",
                                             daemon=True)
            self._checker.start()

    def _check(self) -> None:
        try:
            if self._pace is not None:  # paced: the first realization has the CPU first
                while not (self._first_ready.wait(0.2) or self._halt.is_set()):
                    pass
                if self._halt.is_set():
                    return
            # the truth FRF first: its solves release the GIL while the kernel loads and
            # realization 0 runs, instead of delaying the end of the recording
            self._frf_attachment = self.truth_attachments()
            self.verify_integration()
        except BaseException as exc:  # noqa: BLE001 - re-raised by describe_at_end
            self._check_error = exc

    def _close(self) -> None:
        self._halt.set()

    def _produce(self) -> None:
        """Thread: the realizations in order (the truth FRF and the integration check run
        on the other thread, :meth:`_check`)."""
        try:
            for r in range(self._realization, self.excitation.realizations):
                with self._lock_sim:
                    cached = self._cached
                    data = (cached[1] if cached is not None and cached[0] == r
                            else self.simulate_realization(r))
                    self._cached = None
                while not self._halt.is_set():
                    try:
                        self._ready.put((r, data), timeout=0.2)
                        self._first_ready.set()
                        break
                    except queue.Full:
                        continue
                if self._halt.is_set():
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the reader, raised there
            while not self._halt.is_set():
                try:
                    self._ready.put(exc, timeout=0.2)
                    return
                except queue.Full:
                    continue

    def _add_noise(self, clean: np.ndarray, r: int) -> np.ndarray:
        rng = np.random.default_rng([self.options.noise_seed, r])
        if self.options.lab:   # coloured noise, hum, offsets (daq.sim.lab)
            from fnsi_lab.daq.sim.lab import add_disturbances
            return add_disturbances(clean, self._sample_rate_hz, rng,
                                    snr_db=[self.options.snr_db.get(c.name) for c in self._channels],
                                    **self.options.lab)
        if not self.options.snr_db:
            return clean
        out = clean.copy()
        for i, c in enumerate(self._channels):
            snr = self.options.snr_db.get(c.name)
            if snr is None:
                continue
            rms = float(np.sqrt(np.mean(clean[:, i] ** 2)))
            out[:, i] += rng.standard_normal(clean.shape[0]) * rms * 10 ** (-snr / 20)
        return out

    def _read_block(self, timeout: float | None) -> Block | None:
        exc = self.excitation
        n_total = exc.samples_per_period * exc.periods
        if self._data is None:
            try:
                item = self._ready.get(timeout=timeout)
            except queue.Empty:
                return None  # still computing: the acquisition loop asks again
            if isinstance(item, BaseException):
                raise item
            _, self._data = item
            self._position = 0
        start = self._position
        stop = min(start + self.block_size, n_total)
        # first_sample counts within the realization; the time stamp is a continuous source
        # clock over all realizations (monotonic for pacing and for the recording)
        t0_ns = int(round((self._realization * n_total + start) * 1e9 / self._sample_rate_hz))
        block = self._make_block(self._data[start:stop], start, t0_ns=t0_ns,
                                 realization=self._realization)
        self._position = stop
        if stop >= n_total:
            self._data = None
            self._realization += 1
            if self._realization >= exc.realizations:
                self._mark_finished()
        return block

    # ------------------------------------------------------------------ metadata
    def run_info(self, r: int = 0, *, verify: bool = True) -> dict[str, Any]:
        """Contact fractions, steady-state error... of realization ``r`` (simulates it if
        needed; with ``verify``, realization 0 also gets ``error_vs_double_rate``)."""
        if r not in self._results:
            with self._lock_sim:
                if r not in self._results:
                    self.simulate_realization(r)
        if r == 0 and verify:
            self.verify_integration()
        return self._results[r]

    def describe(self) -> dict[str, Any]:
        """Base dict plus ``excitation``, ``model`` and ``truth`` (simulates realization 0)."""
        return self._describe(self.truth())

    def describe_at_start(self) -> dict[str, Any]:
        """:meth:`describe` without the run-dependent truth (contact fractions, steady-state
        and integration errors), so that recording starts before any simulation;
        :meth:`describe_at_end` completes it."""
        return self._describe(self._truth(self._results.get(0)))

    def describe_at_end(self, finished: bool = True) -> tuple[dict[str, Any], list]:
        """Metadata and attachments known once the run is over: the complete ``truth`` and
        the truth FRF. ``finished=False`` (interrupted) returns what is already known."""
        if finished and self._checker is not None:
            self._checker.join()
            if self._producer is not None:
                self._producer.join()
            if self._check_error is not None:
                raise self._check_error
        elif finished:
            self.run_info(0)
        info = self._results.get(0)
        attachments = list(self._frf_attachment or [])
        if finished and not attachments:
            attachments = self.truth_attachments()
        return ({"truth": self._truth(info)} if info is not None else {}), attachments

    def _describe(self, truth: dict[str, Any]) -> dict[str, Any]:
        out = super().describe()
        exc = self.excitation.to_dict()
        exc["excited_lines"] = [int(k) for k in self._ms.excited_lines]
        exc["sample_rate_hz"] = self._sample_rate_hz
        out["excitation"] = exc
        out["model"] = {k: v for k, v in self.model.summary().items() if k != "nonlinearities"}
        out["truth"] = truth
        return out

    def truth(self) -> dict[str, Any]:
        """The exact model behind the data (JSON-able; simulates realization 0 if needed)."""
        return self._truth(self.run_info(0))

    def _truth(self, info: dict[str, Any] | None) -> dict[str, Any]:
        """The truth; the run-dependent entries are None when ``info`` is None."""
        m = self.model
        modes = m.modes
        info = info or {}
        chan_of_dof: dict[int, str] = {}
        for ch, d in m.measured.items():
            chan_of_dof.setdefault(d, ch)
        nls = []
        for el in m.nonlinearities:
            d = el.to_truth(m.dof_names)
            d["channels"] = {chan_of_dof[i]: float(w) for i, w in enumerate(el.weights)
                             if w != 0 and i in chan_of_dof}
            nls.append(d)
        units = dict(m.units)
        return {
            "units": units,
            "model": m.name,
            "modes": [{"frequency_hz": float(f), "damping_ratio": float(z)}
                      for f, z in zip(modes.frequency_hz, modes.damping_ratio)],
            "nonlinearities": nls,
            "contact_fraction": info.get("contact_fraction"),
            "contact_fraction_note": "fraction of internal steps with the stop closed, over "
                                     "the non-transient periods of realization 0",
            "steady_state_error": info.get("steady_state_error"),
            "integration": {
                "method": "exact modal propagation (FOH nonlinear forces, implicit), "
                          "frequency-domain anti-alias filter",
                "internal_rate_hz": info.get("internal_rate_hz",
                                             self.options.oversample * self._sample_rate_hz),
                "passband_hz": self.options.passband * self._sample_rate_hz,
                "error_vs_double_rate": info.get("error_vs_double_rate"),
            },
        }

    def truth_attachments(self) -> list[tuple[str, str, bytes]]:
        """Binary truth: the exact linear FRF at the recorded channels (``truth_frf.npz``).

        The npz holds ``frequency_hz`` (n_lines,), ``frf`` complex (n_lines, n_out, n_in)
        in each channel's recorded quantity and unit per input force unit, ``outputs``,
        ``inputs``, ``eigenvalues`` (rad/s, complex, all 2 n_dof).
        """
        n_per = self.excitation.samples_per_period
        f = np.arange(n_per // 2 + 1) * self._sample_rate_hz / n_per
        resp = [c for c in self._channels if not c.is_force]
        frf = np.zeros((f.size, len(resp), self.model.n_inputs), complex)
        for q in RESPONSE_QUANTITIES:
            idx = [i for i, c in enumerate(resp) if c.quantity == q]
            if idx:
                dofs = np.array([self._dof_of[resp[i].name] for i in idx])
                frf[:, idx, :] = self.model.frf(f, q, dofs)
        buf = io.BytesIO()
        # not compressed: full-precision FRF values do not compress (~7 %), and zlib would
        # cost a third of a second of the acquisition
        np.savez(buf, frequency_hz=f, frf=frf,
                            outputs=np.array([c.name for c in resp]),
                            inputs=np.array(self.model.input_names),
                            eigenvalues=self.model.modes.eigenvalues)
        return [("truth_frf.npz", "application/x-npz", buf.getvalue())]


def steady_state_error(data: np.ndarray, samples_per_period: int, periods: int) -> float | None:
    """max over channels of rms(last period - previous one) / rms(last period)."""
    if periods < 2:
        return None
    n = samples_per_period
    last = data[(periods - 1) * n: periods * n]
    prev = data[(periods - 2) * n: (periods - 1) * n]
    rms = np.sqrt(np.mean(last ** 2, axis=0))
    ok = rms > 0
    err = np.sqrt(np.mean((last - prev) ** 2, axis=0))[ok] / rms[ok]
    return float(err.max()) if err.size else 0.0


def _relative_error(a: SimulationResult, b: SimulationResult, quantities, start: int) -> dict[str, float]:
    """max over channels of rms(a - b) / rms(b), per quantity, from sample ``start``."""
    out = {}
    for q in quantities:
        x, y = a.get(q)[start:], b.get(q)[start:]
        rms = np.sqrt(np.mean(y ** 2, axis=0))
        ok = rms > 0
        out[q] = float((np.sqrt(np.mean((x - y) ** 2, axis=0))[ok] / rms[ok]).max())
    return out
