"""The experiment's drive signal, exported for a signal generator or DAQ output.

A *drive* is the multisine of an experiment (every realization, every period, at the
experiment's sample rate) scaled to the unit the amplifier input expects: newtons as
designed, or volts with ``volts_per_newton``. It is written as WAV (32-bit float or 24-bit
PCM), CSV, NPY or TDMS, next to a sidecar JSON (:class:`DriveDefinition`) that holds the
multisine definition (lines, amplitudes, phases, seed, N, scaling) and SHA-256 hashes of the
designed samples and of the written file. ``excitation.file: DRIVE.json`` in an experiment
makes the acquisition store that definition in the recording, so identification knows the
excited lines and the period (docs/hardware.md).

Layout of every format: one channel, samples first, realizations one after the other,
sample ``(r * periods + p) * N + n`` = sample ``n`` of period ``p`` of realization ``r``.
"""

from __future__ import annotations

import hashlib
import io
import json
import wave
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.multisine import ExcitationConfig, Multisine, multisine
from fnsi_lab.errors import ConfigError, DataFileError
from fnsi_lab.outputs import atomic_output, dumps

#: File formats :func:`write_drive` knows, by extension.
DRIVE_FORMATS = (".wav", ".csv", ".npy", ".tdms")
#: WAV sample encodings.
WAV_ENCODINGS = ("float32", "pcm24")
#: Version of the sidecar layout (checked when read back).
DRIVE_FORMAT_VERSION = 1
_PCM24_MAX = 2 ** 23 - 1


@dataclass(frozen=True)
class DriveDefinition:
    """What the sidecar ``DRIVE.json`` holds: the multisine and its scaling.

    Attributes
    ----------
    excitation : ExcitationConfig
        The multisine as configured (band, RMS in newtons, N, periods, seed, phase law).
        ``periods`` is the number of periods in the exported file.
    sample_rate_hz : float
        Sample rate of the drive (the experiment's).
    excited_lines : ndarray of int, shape (n_lines,)
        DFT bins k of one N-sample period (frequency ``k * fs / N``).
    amplitudes : ndarray, shape (n_lines,)
        Cosine amplitude of every excited line, in the drive unit.
    phases_rad : ndarray, shape (n_realizations, n_lines)
        Cosine phase of every line and realization.
    unit : str
        ``"N"`` (force as designed) or ``"V"`` (scaled by ``volts_per_newton``).
    volts_per_newton : float or None
        Amplifier input per newton of force (None: the file holds newtons).
    signal_sha256 : str
        SHA-256 of the designed samples, float64 little-endian, shape
        ``(n_realizations, periods * N)``, in the drive unit.
    file : dict
        The written file: ``name``, ``format``, ``sha256`` of its bytes and, for WAV,
        ``encoding`` and ``full_scale`` (the drive value of digital full scale 1.0).
    """

    excitation: ExcitationConfig
    sample_rate_hz: float
    excited_lines: np.ndarray
    amplitudes: np.ndarray
    phases_rad: np.ndarray
    unit: str
    volts_per_newton: float | None
    signal_sha256: str
    file: dict[str, Any] = field(default_factory=dict)

    @property
    def scale(self) -> float:
        """Drive unit per newton (1 for a force file)."""
        return 1.0 if self.volts_per_newton is None else float(self.volts_per_newton)

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Frequencies of the excited lines, shape (n_lines,)."""
        return self.excited_lines * self.sample_rate_hz / self.excitation.samples_per_period

    def to_dict(self) -> dict[str, Any]:
        """The JSON-able sidecar content."""
        ex = self.excitation
        return {
            "format": "fnsi-lab drive", "version": DRIVE_FORMAT_VERSION,
            "sample_rate_hz": self.sample_rate_hz,
            "samples_per_period": ex.samples_per_period, "periods": ex.periods,
            "realizations": ex.realizations, "transient_periods": ex.transient_periods,
            "n_samples": ex.realizations * ex.periods * ex.samples_per_period,
            "layout": "one channel; realizations one after the other; sample "
                      "(r * periods + p) * samples_per_period + n",
            "multisine": {"band_hz": list(ex.band_hz), "rms_newton": ex.rms, "seed": ex.seed,
                          "phases": ex.phases, "grid": ex.grid,
                          "detection_block": ex.detection_block},
            "scaling": {"unit": self.unit, "volts_per_newton": self.volts_per_newton,
                        "rms": ex.rms * self.scale},
            "excited_lines": [int(k) for k in self.excited_lines],
            "frequencies_hz": [float(f) for f in self.frequencies_hz],
            "amplitudes": [float(a) for a in self.amplitudes],
            "phases_rad": [[float(p) for p in row] for row in self.phases_rad],
            "signal_sha256": self.signal_sha256,
            "file": dict(self.file),
        }

    def recording_metadata(self) -> dict[str, Any]:
        """The ``excitation`` metadata of a recording driven by this drive.

        Carries what :func:`daq.recording.reader.read_periodic` reads (``samples_per_period``,
        ``excited_lines``, ``transient_periods``) plus the whole definition under ``drive``.
        """
        return {**self.excitation.to_dict(), "excited_lines": [int(k) for k in self.excited_lines],
                "sample_rate_hz": self.sample_rate_hz, "drive": self.to_dict()}


# ---------------------------------------------------------------------------- design
def design_drive(excitation: ExcitationConfig, sample_rate_hz: float, *,
                 volts_per_newton: float | None = None,
                 periods: int | None = None) -> tuple[DriveDefinition, np.ndarray]:
    """The exact drive of an experiment and its definition.

    Parameters
    ----------
    excitation : ExcitationConfig
        The experiment's multisine (RMS in newtons).
    sample_rate_hz : float
        The experiment's sample rate.
    volts_per_newton : float, optional
        Scale to volts (the amplifier's input per newton of shaker force); None keeps newtons.
    periods : int, optional
        Periods per realization in the file (default: the experiment's).

    Returns
    -------
    definition : DriveDefinition
        ``file`` is empty until :func:`write_drive` fills it.
    signal : ndarray, shape (n_realizations, periods * N)
        The drive samples (float64), the same numbers the simulator feeds the model, times
        the scale.
    """
    if volts_per_newton is not None and not (np.isfinite(volts_per_newton) and volts_per_newton > 0):
        raise ConfigError(f"volts per newton must be a positive number, got {volts_per_newton}",
                          field="--volts-per-newton", fix="give the amplifier's volts per newton, e.g. 0.01")
    excitation = replace(excitation, drive=None)  # a drive-based experiment re-exports plainly
    if periods is not None:
        if periods < 1:
            raise ConfigError(f"periods must be >= 1, got {periods}", field="--periods")
        excitation = replace(excitation, periods=int(periods),
                             transient_periods=min(excitation.transient_periods, int(periods) - 1))
    ms = _multisine(excitation, sample_rate_hz)
    scale = 1.0 if volts_per_newton is None else float(volts_per_newton)
    signal = ms.signal * scale if scale != 1.0 else ms.signal
    n_lines = ms.excited_lines.size
    amplitude = ms.line_amplitude * scale
    definition = DriveDefinition(
        excitation=excitation, sample_rate_hz=float(sample_rate_hz),
        excited_lines=ms.excited_lines.copy(), amplitudes=np.full(n_lines, amplitude),
        phases_rad=ms.phases_rad.copy(), unit="N" if volts_per_newton is None else "V",
        volts_per_newton=None if volts_per_newton is None else float(volts_per_newton),
        signal_sha256=signal_hash(signal))
    return definition, signal


def _multisine(ex: ExcitationConfig, fs: float) -> Multisine:
    return multisine(ex.samples_per_period, fs, ex.band_hz, ex.rms, n_periods=ex.periods,
                     n_realizations=ex.realizations, seed=ex.seed, phases=ex.phases,
                     grid=ex.grid, detection_block=ex.detection_block)


def signal_hash(signal: np.ndarray) -> str:
    """SHA-256 of samples as float64 little-endian, C order (any platform gives the same)."""
    return hashlib.sha256(np.ascontiguousarray(signal, dtype="<f8").tobytes()).hexdigest()


# ---------------------------------------------------------------------------- writing
def write_drive(path: str | Path, definition: DriveDefinition, signal: np.ndarray, *,
                wav_encoding: Literal["float32", "pcm24"] = "float32",
                full_scale: float | None = None) -> DriveDefinition:
    """Write the drive file (format from the extension) and return the completed definition.

    Parameters
    ----------
    path : str or Path
        ``.wav``, ``.csv``, ``.npy`` or ``.tdms``; replaced if it exists (the caller checks
        ``--force``). Written through a temporary file, renamed when complete.
    definition : DriveDefinition
        From :func:`design_drive`.
    signal : ndarray, shape (n_realizations, n_samples_per_realization)
        From :func:`design_drive`.
    wav_encoding : {'float32', 'pcm24'}
        WAV only. Digital value = drive / ``full_scale`` in both encodings; PCM code =
        round(value * (2**23 - 1)).
    full_scale : float, optional
        WAV only: drive value (N or V) of digital full scale; default the drive's peak.

    Returns
    -------
    DriveDefinition
        ``definition`` with ``file`` = name, format, SHA-256 of the bytes (and WAV scale).
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in DRIVE_FORMATS:
        raise DataFileError(f"--out {p}: unknown drive format {ext!r} "
                            f"(fix: use one of {', '.join(DRIVE_FORMATS)})")
    flat = np.asarray(signal, dtype=np.float64).reshape(-1)
    fs = definition.sample_rate_hz
    info: dict[str, Any] = {"name": p.name, "format": ext[1:], "n_samples": int(flat.size),
                            "unit": definition.unit}
    if ext == ".wav":
        data = _wav_bytes(flat, fs, wav_encoding, full_scale, info)
    elif ext == ".csv":
        data = _csv_bytes(flat, fs, definition.unit)
    elif ext == ".npy":
        buf = io.BytesIO()
        np.save(buf, flat.astype("<f8"), allow_pickle=False)
        data = buf.getvalue()
        info["dtype"] = "float64"
    else:
        data = _tdms_bytes(flat, fs, definition)
        info["group"], info["channel"] = "drive", "drive"
    info["sha256"] = hashlib.sha256(data).hexdigest()
    with atomic_output(p, "wb") as fh:
        fh.write(data)
    return replace(definition, file=info)


def _wav_bytes(flat: np.ndarray, fs: float, encoding: str, full_scale: float | None,
               info: dict[str, Any]) -> bytes:
    if encoding not in WAV_ENCODINGS:
        raise ConfigError(f"unknown WAV encoding {encoding!r}", field="--wav-encoding",
                          fix=f"use one of {plain.names(WAV_ENCODINGS)}")
    rate = int(round(fs))
    if abs(rate - fs) > 1e-9 * fs:
        raise ConfigError(f"WAV needs a whole-number sample rate, the experiment has {fs:g} Hz",
                          field="sample_rate_hz", fix="export .csv, .npy or .tdms instead")
    peak = float(np.max(np.abs(flat)))
    scale = peak if full_scale is None else float(full_scale)
    if not scale > 0 or scale < peak:
        raise ConfigError(f"full scale {scale:g} is below the drive's peak {peak:g}",
                          field="--full-scale", fix=f"use at least {peak:g} or omit it")
    digital = flat / scale
    buf = io.BytesIO()
    if encoding == "float32":
        from scipy.io import wavfile

        wavfile.write(buf, rate, digital.astype(np.float32))
    else:
        codes = np.round(digital * _PCM24_MAX).astype("<i4")
        raw = codes.view(np.uint8).reshape(-1, 4)[:, :3].tobytes()  # little-endian low 3 bytes
        with wave.open(buf, "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(3)
            w.setframerate(rate)
            w.writeframes(raw)
    info.update({"encoding": encoding, "full_scale": scale, "sample_rate_hz": rate,
                 # 7 digits: the 24-bit mantissa/code holds no more (file.full_scale: exact)
                 "scale": (f"digital 1.0 = {scale:.7g} {info['unit']}" if encoding == "float32" else
                           f"PCM code {_PCM24_MAX} = {scale:.7g} {info['unit']} "
                           f"(value = code / {_PCM24_MAX} * {scale:.7g})")})
    return buf.getvalue()


def _csv_bytes(flat: np.ndarray, fs: float, unit: str) -> bytes:
    lines = [f"time_s,drive_{unit}"]
    t = np.arange(flat.size) / fs
    # 17 significant digits: a float64 reads back bit-exact
    lines.extend(f"{ti:.17g},{xi:.17g}" for ti, xi in zip(t, flat))
    return ("\n".join(lines) + "\n").encode()


def _tdms_bytes(flat: np.ndarray, fs: float, definition: DriveDefinition) -> bytes:
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    ex = definition.excitation
    root = RootObject(properties={"name": "fnsi-lab drive",
                                  "signal_sha256": definition.signal_sha256})
    group = GroupObject("drive", properties={"samples_per_period": ex.samples_per_period,
                                             "periods": ex.periods,
                                             "realizations": ex.realizations})
    # wf_increment / wf_start_offset: the waveform timing LabVIEW and DIAdem read
    channel = ChannelObject("drive", "drive", flat.astype(np.float64),
                            properties={"unit_string": definition.unit,
                                        "wf_increment": 1.0 / fs, "wf_start_offset": 0.0,
                                        "wf_samples": int(flat.size)})
    buf = io.BytesIO()
    with TdmsWriter(buf) as writer:
        writer.write_segment([root, group, channel])
    return buf.getvalue()


def write_sidecar(path: str | Path, definition: DriveDefinition) -> None:
    """Write ``definition`` as indented JSON (atomic)."""
    with atomic_output(path) as fh:
        fh.write(dumps(definition.to_dict(), indent=2) + "\n")


def sidecar_path(drive_path: str | Path) -> Path:
    """``DRIVE.wav`` -> ``DRIVE.json``."""
    return Path(drive_path).with_suffix(".json")


# ---------------------------------------------------------------------------- reading
def load_drive_definition(path: str | Path) -> DriveDefinition:
    """Read a sidecar ``DRIVE.json`` and check it against the multisine it describes.

    The multisine is regenerated from band, RMS, N, seed and phase law; its lines, phases and
    sample hash must equal the file's, so a hand-edited or foreign file is refused instead of
    being trusted for identification.

    Raises
    ------
    ConfigError
        Missing or unreadable file, missing field, or a definition that does not reproduce.
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError("drive definition not found", file=str(p),
                          fix="export it with 'fnsi-lab excitation --out DRIVE.wav'") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"not a readable drive definition ({exc})", file=str(p)) from None
    if not isinstance(data, dict) or data.get("format") != "fnsi-lab drive":
        raise ConfigError("not an fnsi-lab drive definition (no \"format\": \"fnsi-lab drive\")",
                          file=str(p), fix="use the .json written by 'fnsi-lab excitation'")
    try:
        ms = data["multisine"]
        sc = data["scaling"]
        ex = ExcitationConfig(band_hz=(float(ms["band_hz"][0]), float(ms["band_hz"][1])),
                              rms=float(ms["rms_newton"]),
                              samples_per_period=int(data["samples_per_period"]),
                              periods=int(data["periods"]),
                              transient_periods=int(data.get("transient_periods", 0)),
                              realizations=int(data["realizations"]), seed=ms["seed"],
                              phases=ms["phases"], grid=ms.get("grid", "full"),
                              detection_block=int(ms.get("detection_block", 4)))
        fs = float(data["sample_rate_hz"])
        vpn = sc.get("volts_per_newton")
        definition, _ = design_drive(ex, fs, volts_per_newton=None if vpn is None else float(vpn))
        lines = np.asarray(data["excited_lines"], dtype=np.int64)
        phases = np.asarray(data["phases_rad"], dtype=np.float64)
        stored_hash = str(data["signal_sha256"])
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ConfigError(f"incomplete drive definition ({type(exc).__name__}: {exc})",
                          file=str(p), fix="export it again with 'fnsi-lab excitation'") from None
    if (lines.shape != definition.excited_lines.shape or np.any(lines != definition.excited_lines)
            or phases.shape != definition.phases_rad.shape
            or np.any(phases != definition.phases_rad) or stored_hash != definition.signal_sha256):
        raise ConfigError("the lines, phases or sample hash do not reproduce from the stated "
                          "multisine (edited file, or written by another version)", file=str(p),
                          fix="export the drive again with 'fnsi-lab excitation'")
    return replace(definition, file=dict(data.get("file", {})))


def read_drive(path: str | Path, definition: DriveDefinition | None = None) -> np.ndarray:
    """Read an exported drive file back, in the drive unit, shape (n_samples,).

    WAV values are digital values times the sidecar's ``full_scale`` (``definition`` or
    ``DRIVE.json`` next to the file).
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".npy":
        return np.load(p, allow_pickle=False)
    if ext == ".csv":
        return np.loadtxt(p, delimiter=",", skiprows=1, usecols=1)
    if ext == ".tdms":
        from nptdms import TdmsFile

        return np.asarray(TdmsFile.read(p)["drive"]["drive"][:], dtype=np.float64)
    if ext == ".wav":
        from scipy.io import wavfile

        if definition is None:
            definition = load_drive_definition(sidecar_path(p))
        full_scale = float(definition.file["full_scale"])
        _, raw = wavfile.read(p)
        if raw.dtype == np.float32:
            return raw.astype(np.float64) * full_scale
        # scipy returns 24-bit PCM left-aligned in int32 (code * 256)
        return (raw.astype(np.int64) >> 8).astype(np.float64) / _PCM24_MAX * full_scale
    raise DataFileError(f"{p}: unknown drive format {ext!r} (use {', '.join(DRIVE_FORMATS)})")


def off_line_power_db(signal: np.ndarray, samples_per_period: int,
                      excited_lines: Sequence[int]) -> float:
    """Power off the excited lines relative to the total, in dB, over whole periods.

    Parameters
    ----------
    signal : ndarray, shape (n_samples,)
        A whole number of periods.
    samples_per_period : int
    excited_lines : sequence of int

    Returns
    -------
    float
        ``10 log10(P_off / P_total)`` of the one-period spectrum of every period; -inf when
        nothing is off the lines.
    """
    n = int(samples_per_period)
    x = np.asarray(signal, dtype=np.float64).reshape(-1, n)
    spec = np.abs(np.fft.rfft(x, axis=1)) ** 2
    on = np.zeros(spec.shape[1], dtype=bool)
    on[np.asarray(excited_lines, dtype=np.int64)] = True
    total = float(spec.sum())
    off = float(spec[:, ~on].sum())
    return float(10 * np.log10(off / total)) if off > 0 else float("-inf")
