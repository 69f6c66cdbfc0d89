"""Experiment configuration (YAML) validated into typed, frozen objects.

A file looks like ``daq/data/smallsat.yaml`` (the default experiment)::

    name: smallsat-default
    sample_rate_hz: 1000
    output: smallsat.mcap
    block_size: 100
    source: {kind: smallsat, options: {}}
    excitation:
      kind: multisine
      band_hz: [5, 50]
      rms: 100.0              # in the unit of the force channel (N)
      samples_per_period: 8192
      periods: 6
      transient_periods: 5
      realizations: 1
      seed: 0
      phases: random          # or schroeder
      grid: full              # or odd, random-odd (detection lines: docs/discovery.md)
    # excitation: {file: drive.json}   # instead: an exported drive (docs/hardware.md)
    trigger: {channel: F-NC2W-Z, level: 20.0, slope: rising, pre_samples: 500}  # optional
    channels:                 # optional for simulated sources: the model's own table
      - {name: F-NC2W-Z, quantity: force, unit: N, node: NC2W, direction: Z}
      - {name: NC2W-Z, quantity: displacement, unit: m, node: NC2W, direction: Z}

Every error names the file, the dotted field and the fix; see :func:`load_experiment`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from fnsi_lab import plain
from fnsi_lab.daq.channels import QUANTITIES, ChannelInfo
from fnsi_lab.daq.multisine import ExcitationConfig
from fnsi_lab.errors import ConfigError
from fnsi_lab.validate import Section, load_yaml

#: Name of the experiment that runs when no config is given.
DEFAULT_EXPERIMENT = "smallsat.yaml"


@dataclass(frozen=True)
class SourceConfig:
    """Which adapter to use and its options (validated by the adapter itself)."""

    kind: str
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ExperimentConfig:
    """A whole experiment.

    Attributes
    ----------
    name : str
        Free text, stored in the recording.
    sample_rate_hz : float
        Acquisition rate.
    source : SourceConfig
        Adapter and its options.
    excitation : ExcitationConfig or None
        The multisine (None for sources that only listen).
    channels : tuple of ChannelInfo
        Channel table; empty means "the source's own table" (simulated models).
    output : str
        Default MCAP path.
    block_size : int
        Samples per block (and per MCAP message).
    trigger : daq.trigger.TriggerConfig or None
        Software trigger: recording starts when a channel crosses a level.
    file : str or None
        Where the config was read from (for messages).
    text : str
        The YAML text, stored as an attachment of the recording.
    """

    name: str
    sample_rate_hz: float
    source: SourceConfig
    excitation: ExcitationConfig | None = None
    channels: tuple[ChannelInfo, ...] = ()
    output: str = "recording.mcap"
    block_size: int = 100
    trigger: Any = None
    file: str | None = None
    text: str = ""

    def error(self, field_name: str, message: str, fix: str | None = None) -> ConfigError:
        """A ConfigError located in this experiment's file."""
        return ConfigError(message, file=self.file, field=field_name, fix=fix)

    def with_output(self, output: str) -> "ExperimentConfig":
        """A copy writing to another file."""
        return replace(self, output=str(output))

    def level_runs(self, folder: str | Path) -> list[tuple[float, "ExperimentConfig"]]:
        """One single-level experiment per ``excitation.levels`` entry, writing into ``folder``.

        Each run keeps every setting (phases included, so the levels differ only by a
        scale factor) and records ``<folder>/<name>-rms<level>.mcap``. Empty when the
        experiment has no level sweep.
        """
        if self.excitation is None or not self.excitation.levels:
            return []
        runs = []
        for level in self.excitation.levels:
            excitation = replace(self.excitation, rms=float(level), levels=())
            out = Path(folder) / f"{self.name}-rms{level:g}.mcap"
            runs.append((float(level), replace(self, excitation=excitation, output=str(out))))
        return runs


# ---------------------------------------------------------------------------- parsing
def _parse_excitation(sec: Section, sample_rate_hz: float) -> ExcitationConfig:
    sec.string("kind", "multisine", choices=("multisine",))
    band = sec.numbers("band_hz", length=2)
    nyquist = sample_rate_hz / 2
    if not 0 <= band[0] < band[1]:
        raise sec.error("band_hz", f"band {plain.band_hz(band)} is not increasing and >= 0",
                        fix="write [f_low, f_high] with f_low < f_high")
    if band[1] >= nyquist:
        raise sec.error("band_hz", f"upper edge {band[1]:g} Hz is at or above Nyquist "
                        f"({nyquist:g} Hz at {sample_rate_hz:g} Hz)",
                        fix="lower the band or raise sample_rate_hz")
    n = sec.integer("samples_per_period", minimum=1)
    if n < 4:
        raise sec.error("samples_per_period", f"{n} samples per period is too few", fix="use >= 4")
    resolution = sample_rate_hz / n
    first = int(-(-band[0] // resolution)) if band[0] > 0 else 1
    last = int(band[1] // resolution)
    if last < max(first, 1):
        raise sec.error("band_hz", f"no DFT line of a {n}-sample period "
                        f"({resolution:g} Hz spacing) falls inside {plain.band_hz(band)}",
                        fix="widen the band or use more samples per period")
    periods = sec.integer("periods", 1, minimum=1)
    transient = sec.integer("transient_periods", 0, minimum=0)
    if transient >= periods:
        raise sec.error("transient_periods", f"{transient} transient periods leave none of "
                        f"the {periods} periods for identification",
                        fix="use transient_periods < periods")
    seed = sec.raw("seed", 0)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise sec.error("seed", f"expected a whole number >= 0 or null, got {plain.value(seed)}")
    levels = sec.numbers("levels", None) or ()
    if any(not level > 0 for level in levels):
        raise sec.error("levels", f"every level must be an RMS > 0, got {plain.names(levels)}",
                        fix="list positive force RMS values, e.g. [10, 50, 100]")
    if len(set(levels)) != len(levels):
        raise sec.error("levels", f"repeated level in {plain.names(levels)}",
                        fix="list each force level once")
    exc = ExcitationConfig(
        band_hz=(band[0], band[1]),
        # with a level sweep, rms is the first level unless given
        rms=sec.number("rms", levels[0], positive=True) if levels else sec.number("rms", positive=True),
        samples_per_period=n,
        periods=periods,
        transient_periods=transient,
        realizations=sec.integer("realizations", 1, minimum=1),
        seed=seed,
        phases=sec.string("phases", "random", choices=("random", "schroeder")),  # type: ignore[arg-type]
        grid=sec.string("grid", "full", choices=("full", "odd", "random-odd")),  # type: ignore[arg-type]
        detection_block=sec.integer("detection_block", 4, minimum=2),
        levels=tuple(levels),
    )
    sec.finish()
    return exc


def _excitation_from_drive(sec: Section, sample_rate_hz: float,
                           file: str | None) -> ExcitationConfig:
    """``excitation: {file: DRIVE.json}``: the multisine of an exported drive."""
    from fnsi_lab.daq.drive import load_drive_definition

    name = sec.string("file")
    sec.finish()
    path = Path(name)
    if not path.is_absolute() and file:
        path = Path(file).parent / path  # relative to the experiment file
    drive = load_drive_definition(path)
    if abs(drive.sample_rate_hz - sample_rate_hz) > 1e-9 * sample_rate_hz:
        raise sec.error("file", f"the drive was made for {drive.sample_rate_hz:g} Hz, the "
                        f"experiment samples at {sample_rate_hz:g} Hz",
                        fix="export the drive with this experiment, or set sample_rate_hz "
                            f"to {drive.sample_rate_hz:g}")
    return replace(drive.excitation, drive=drive)


def _parse_channels(items: list[Any], file: str | None) -> tuple[ChannelInfo, ...]:
    channels = []
    seen: dict[str, int] = {}
    for i, item in enumerate(items):
        sec = Section(item, file=file, prefix=f"channels[{i}]")
        name = sec.string("name")
        if not name.strip():
            raise sec.error("name", "empty channel name")
        if name in seen:
            raise sec.error("name", f"duplicate channel name {name!r} (also channels[{seen[name]}])",
                            fix="give every channel a unique name")
        seen[name] = i
        quantity = sec.string("quantity", choices=QUANTITIES)
        sensitivity = sec.number("sensitivity", 1.0)
        if sensitivity == 0:
            raise sec.error("sensitivity", "must not be 0")
        channels.append(ChannelInfo(name=name, quantity=quantity,  # type: ignore[arg-type]
                                    unit=sec.string("unit", ""), node=str(sec.raw("node", "")),
                                    direction=str(sec.raw("direction", "")),
                                    sensitivity=sensitivity))
        sec.finish()
    return tuple(channels)


def parse_experiment(data: Any, *, file: str | None = None, text: str = "") -> ExperimentConfig:
    """Validate a parsed YAML mapping into an :class:`ExperimentConfig`.

    Raises
    ------
    ConfigError
        On unknown keys, wrong types or impossible values, naming file, field and fix.
    """
    top = Section(data, file=file)
    rate = top.number("sample_rate_hz", positive=True)
    src = top.section("source", required=True)
    kind = src.string("kind")
    options = src.raw("options", {})
    if not isinstance(options, Mapping):
        raise src.error("options", f"expected a mapping, got {type(options).__name__}")
    src.finish()
    excitation = None
    if top.has("excitation") and top.data["excitation"] is not None:
        exc_sec = top.section("excitation")
        if exc_sec.has("file"):
            excitation = _excitation_from_drive(exc_sec, rate, file)
        else:
            excitation = _parse_excitation(exc_sec, rate)
    trigger = None
    if top.has("trigger") and top.data["trigger"] is not None:
        from fnsi_lab.daq.trigger import parse_trigger
        trigger = parse_trigger(top.section("trigger"))
    channels = _parse_channels(top.items("channels", []), file)
    config = ExperimentConfig(
        name=top.string("name", Path(file).stem if file else "experiment"),
        sample_rate_hz=rate,
        source=SourceConfig(kind=kind, options=dict(options)),
        excitation=excitation,
        channels=channels,
        output=top.string("output", "recording.mcap"),
        block_size=top.integer("block_size", 100, minimum=1, maximum=1_000_000),
        trigger=trigger,
        file=file,
        text=text,
    )
    top.finish()
    # Fail early on an unknown source kind (message lists the known ones).
    from fnsi_lab.daq.registry import SOURCES
    if kind not in SOURCES:
        raise ConfigError(f"unknown source kind {kind!r}", file=file, field="source.kind",
                          fix=f"use one of {plain.names(sorted(SOURCES))}")
    return config


def load_experiment(path: str | Path | None = None) -> ExperimentConfig:
    """Load an experiment from YAML; ``None`` loads the packaged SmallSat experiment.

    Parameters
    ----------
    path : str or Path or None
        YAML file. ``None`` gives :data:`DEFAULT_EXPERIMENT`; a bare name of a packaged
        experiment (``lumped3.yaml``, or without the suffix: ``aircraft``) also works.
    """
    if path is None:
        path = DEFAULT_EXPERIMENT
    p = Path(path)
    if not p.exists() and p.parent == Path("."):
        for name in (p.name, p.name + ".yaml"):   # `--config aircraft` finds aircraft.yaml
            if packaged_experiment(name) is not None:
                p = packaged_experiment(name)  # type: ignore[assignment]
                break
    data, text = load_yaml(p, missing_fix="check the path, or omit --config to use the default")
    return parse_experiment(data, file=str(path), text=text)


def packaged_experiment(name: str) -> Path | None:
    """Path of an experiment shipped in ``daq/data`` (None if there is none)."""
    candidate = resources.files("fnsi_lab.daq") / "data" / name
    try:
        return Path(str(candidate)) if candidate.is_file() else None
    except (FileNotFoundError, OSError):
        return None
