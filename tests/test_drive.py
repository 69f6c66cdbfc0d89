"""fnsi-lab excitation: exported drives read back with third-party readers (scipy, npTDMS)."""

from __future__ import annotations

import hashlib
import json
import wave
from pathlib import Path

import numpy as np
import pytest
from nptdms import TdmsFile
from scipy.io import wavfile

from fnsi_lab.cli import main
from fnsi_lab.daq.config import load_experiment, parse_experiment
from fnsi_lab.daq.drive import (design_drive, load_drive_definition, off_line_power_db,
                                read_drive)
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.acquisition import record_experiment
from fnsi_lab.daq.recording.reader import read_periodic
from fnsi_lab.errors import ConfigError
import test_can_source as can_t
from test_can_source import channel, no_adapter_leaks  # noqa: F401  (fixtures)

K = 0.01  # V/N


def smallsat_drive() -> np.ndarray:
    """The default experiment's force (what the simulator feeds the model), in volts."""
    ex = load_experiment(None).excitation
    ms = multisine(ex.samples_per_period, 1000.0, ex.band_hz, ex.rms, n_periods=ex.periods,
                   n_realizations=ex.realizations, seed=ex.seed, phases=ex.phases)
    return ms.signal.reshape(-1) * K, ms.excited_lines


def assert_periodic_and_clean(x: np.ndarray, n: int, lines: np.ndarray) -> None:
    periods = x.reshape(-1, n)
    assert np.all(periods == periods[0])                  # periodic to the last bit
    assert off_line_power_db(x, n, lines) < -120.0        # target: < -120 dB off the lines


def export(tmp_path: Path, name: str, *extra: str) -> tuple[Path, dict]:
    out = tmp_path / name
    assert main(["excitation", "--out", str(out), "--volts-per-newton", str(K), "--quiet",
                 *extra]) == 0
    return out, json.loads(out.with_suffix(".json").read_text())


def test_wav_float32_reads_back_as_designed(tmp_path: Path) -> None:
    designed, lines = smallsat_drive()
    out, side = export(tmp_path, "drive.wav")
    rate, raw = wavfile.read(out)
    assert rate == 1000 and raw.dtype == np.float32 and raw.shape == designed.shape
    full_scale = side["file"]["full_scale"]
    assert full_scale == pytest.approx(np.max(np.abs(designed)), rel=1e-15)
    volts = raw.astype(np.float64) * full_scale
    # float32 keeps 24 bits of mantissa: 2**-24 of full scale at worst
    assert np.max(np.abs(volts - designed)) <= 2.0 ** -24 * full_scale
    assert np.max(np.abs(raw)) == 1.0
    assert_periodic_and_clean(volts, 8192, lines)
    assert side["file"]["encoding"] == "float32" and side["scaling"]["unit"] == "V"
    assert side["file"]["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()


def test_wav_pcm24_reads_back_within_one_code(tmp_path: Path) -> None:
    designed, lines = smallsat_drive()
    out, side = export(tmp_path, "drive24.wav", "--wav-encoding", "pcm24", "--full-scale", "5")
    with wave.open(str(out)) as w:
        assert (w.getsampwidth(), w.getnchannels(), w.getframerate()) == (3, 1, 1000)
    rate, raw = wavfile.read(out)  # scipy: 24-bit left-aligned in int32
    codes = raw.astype(np.int64) >> 8
    volts = codes / (2 ** 23 - 1) * side["file"]["full_scale"]
    assert side["file"]["full_scale"] == 5.0
    assert np.max(np.abs(volts - designed)) <= 0.5 * 5.0 / (2 ** 23 - 1) * (1 + 1e-9)
    assert_periodic_and_clean(volts, 8192, lines)
    np.testing.assert_array_equal(read_drive(out), volts)  # our reader agrees with scipy


def test_tdms_csv_npy_read_back_exactly(tmp_path: Path) -> None:
    designed, lines = smallsat_drive()
    out, side = export(tmp_path, "drive.tdms")
    tdms = TdmsFile.read(out)
    channel = tdms["drive"]["drive"]
    np.testing.assert_array_equal(channel[:], designed)  # float64: bit for bit
    assert channel.properties["wf_increment"] == pytest.approx(1e-3)
    assert channel.properties["unit_string"] == "V"
    assert_periodic_and_clean(channel[:], 8192, lines)
    for name in ("as_text.csv", "as_array.npy"):  # one sidecar per stem
        out, _ = export(tmp_path, name)
        np.testing.assert_array_equal(read_drive(out), designed)


def test_sidecar_definition_and_periods_option(tmp_path: Path) -> None:
    out, side = export(tmp_path, "loop.npy", "--periods", "2")
    x = np.load(out)
    assert x.shape == (2 * 8192,)
    assert side["periods"] == 2 and side["samples_per_period"] == 8192
    assert side["multisine"]["seed"] == 0 and side["scaling"]["volts_per_newton"] == K
    lines = np.array(side["excited_lines"])
    # the stated lines, amplitudes and phases rebuild the file (a generator could do it)
    n = np.arange(8192)
    rebuilt = np.zeros(8192)
    for k, a, phi in zip(lines, side["amplitudes"], side["phases_rad"][0]):
        rebuilt += a * np.cos(2 * np.pi * k * n / 8192 + phi)
    np.testing.assert_allclose(rebuilt, x[:8192], atol=1e-12 * np.max(np.abs(x)))
    assert side["scaling"]["rms"] == pytest.approx(np.sqrt(np.mean(x ** 2)), rel=1e-12)
    definition = load_drive_definition(out.with_suffix(".json"))
    assert definition.signal_sha256 == side["signal_sha256"]


def test_edited_sidecar_refused(tmp_path: Path) -> None:
    out, side = export(tmp_path, "d.npy")
    side["phases_rad"][0][3] += 0.1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(side))
    with pytest.raises(ConfigError, match="do not reproduce"):
        load_drive_definition(bad)


def test_refuses_to_overwrite_and_unknown_format(tmp_path: Path, capsys) -> None:
    out, _ = export(tmp_path, "d.csv")
    before = out.read_bytes()
    assert main(["excitation", "--out", str(out), "--quiet"]) == 2
    assert out.read_bytes() == before
    assert "--force" in capsys.readouterr().err
    assert main(["excitation", "--out", str(out), "--quiet", "--force"]) == 0
    assert main(["excitation", "--out", str(tmp_path / "d.mp3"), "--quiet"]) == 2


def test_excitation_file_reaches_the_recording_and_ident_input(tmp_path: Path) -> None:
    """A source that knows nothing of the multisine still records its lines and period."""
    from fnsi_lab.daq.registry import make_source
    from fnsi_lab.daq.sources.array_source import ArraySource
    from fnsi_lab.inputs import load_input

    # the lumped experiment's drive, exported as a lab would
    assert main(["excitation", "--config", "lumped.yaml", "--out", str(tmp_path / "d.npy"),
                 "--quiet"]) == 0
    exp = {"name": "rig", "sample_rate_hz": 1000,
           "source": {"kind": "simulated", "options": {"model": "lumped"}},
           "excitation": {"file": "d.json"}}  # relative to the experiment file
    config = parse_experiment(exp, file=str(tmp_path / "rig.yaml"))
    assert config.excitation.samples_per_period == 4096
    sim = load_experiment("lumped.yaml")
    with make_source(sim) as src:
        rows = []
        for b in src:
            if b.realization:  # one realization is enough (the next is not simulated)
                break
            rows.append(b.data)
        data = np.concatenate(rows)
        channels = src.channels
    # a "hardware" source: plain rows, no excitation of its own
    hw = ArraySource(data, channels, 1000.0, block_size=256)
    out = tmp_path / "rig.mcap"
    record_experiment(config, out, source=hw)
    rec = read_periodic(out)
    drive = load_drive_definition(tmp_path / "d.json")
    assert rec.samples_per_period == 4096
    np.testing.assert_array_equal(rec.excited_lines, drive.excited_lines)
    assert rec.excitation["drive"]["signal_sha256"] == drive.signal_sha256
    assert rec.excitation["drive"]["phases_rad"] == drive.phases_rad.tolist()
    inp = load_input(out)  # what `fnsi-lab ident` reads: period and lines without guessing
    assert inp.samples_per_period == 4096
    np.testing.assert_array_equal(inp.excited_lines, drive.excited_lines)
    assert inp.transient_periods == drive.excitation.transient_periods



def _rig_yaml(channel: str, excitation: str) -> str:
    """An experiment on python-can's virtual bus (the CAN adapter of tests/test_can_source.py)."""
    signals = "".join(f"      {ch}: {sig}\n" for ch, sig in can_t.SIGNALS.items())
    chans = "".join(f"  - {{name: {c['name']}, quantity: {c['quantity']}, unit: {c['unit']}}}\n"
                    for c in can_t.CHANNELS)
    return (f"name: can-rig\nsample_rate_hz: {can_t.FS:g}\nblock_size: 100\n"
            f"source:\n  kind: can\n  options:\n    interface: virtual\n"
            f"    channel: {channel}\n    bitrate: 1000000\n    dbc: lab.dbc\n"
            f"    counter: Counter\n    rate_window_s: 0.2\n    signals:\n{signals}"
            f"{excitation}channels:\n{chans}")


def test_excitation_file_reaches_a_can_recording_made_by_the_cli(tmp_path: Path, channel: str,
                                                                  capsys) -> None:
    """The lab session of docs/hardware.md on a real adapter: ``fnsi-lab excitation`` exports
    the drive, ``fnsi-lab acquire`` records a CAN source (python-can's virtual bus) with
    ``excitation: {file: drive.json}`` until Ctrl-C, and the recording's metadata and
    ``fnsi-lab info`` carry the definition (lines, N, hash)."""
    import shutil
    import signal
    import threading
    import time

    shutil.copy(can_t.DBC, tmp_path / "lab.dbc")
    n_per, periods = 200, 5  # the frames' multisine has a 200-sample period (signals_for)
    (tmp_path / "rig.yaml").write_text(_rig_yaml(channel, (
        f"excitation:\n  kind: multisine\n  band_hz: [5, 200]\n  rms: 50.0\n"
        f"  samples_per_period: {n_per}\n  periods: {periods}\n  transient_periods: 1\n"
        f"  realizations: 1\n  seed: 3\n")))
    assert main(["excitation", "--config", str(tmp_path / "rig.yaml"),
                 "--out", str(tmp_path / "drive.npy"), "--quiet"]) == 0
    drive = load_drive_definition(tmp_path / "drive.json")
    (tmp_path / "session.yaml").write_text(_rig_yaml(channel, "excitation: {file: drive.json}\n"))

    n = n_per * periods
    frames, expected = can_t.build_frames(n)
    default = signal.getsignal(signal.SIGINT)
    failure: list[str] = []

    def operator() -> None:
        """Starts the shaker once the acquisition listens, then presses Ctrl-C."""
        deadline = time.monotonic() + 30
        while signal.getsignal(signal.SIGINT) is default:  # acquire installs its handler
            if time.monotonic() > deadline:               # after opening the bus
                failure.append("acquire never started")
                return
            time.sleep(0.01)
        with can_t.Sender(channel, frames):
            pass
        time.sleep(1.5)  # let the last blocks reach the recorder
        if signal.getsignal(signal.SIGINT) is not default:
            signal.raise_signal(signal.SIGINT)

    thread = threading.Thread(target=operator)
    thread.start()
    out = tmp_path / "run.mcap"
    try:
        code = main(["acquire", "--config", str(tmp_path / "session.yaml"), "--out", str(out),
                     "--quiet", "--no-info"])
    finally:
        thread.join(timeout=60)
    assert not failure and code == 130  # interrupted, the file finished cleanly
    assert "interrupted" in capsys.readouterr().err

    from fnsi_lab.daq.recording.reader import open_recording
    with open_recording(out) as rec:
        data = rec.read_samples()
        meta = rec.metadata["excitation"]
        source_kind = rec.metadata["source"]["kind"]
    assert source_kind == "can"
    np.testing.assert_array_equal(data, expected[:data.shape[0]].astype(np.float32))
    assert data.shape[0] == n
    assert meta["samples_per_period"] == n_per and meta["transient_periods"] == 1
    assert meta["excited_lines"] == drive.excited_lines.tolist()
    assert meta["drive"]["signal_sha256"] == drive.signal_sha256
    assert meta["drive"]["file"]["sha256"] == drive.file["sha256"]
    assert meta["drive"]["excited_lines"] == drive.excited_lines.tolist()
    rec = read_periodic(out)  # what ident reads: N and lines without a guess
    assert rec.samples_per_period == n_per and rec.n_periods == periods
    np.testing.assert_array_equal(rec.excited_lines, drive.excited_lines)

    assert main(["info", str(out)]) == 0
    info = capsys.readouterr().out
    assert (f"drive: drive.npy, {drive.excited_lines.size} lines, unit N, sha256 "
            f"{drive.signal_sha256[:12]}...") in info
    assert "clock check: drive vs acquisition" in info

def test_drive_for_another_sample_rate_refused(tmp_path: Path) -> None:
    assert main(["excitation", "--out", str(tmp_path / "d.npy"), "--quiet"]) == 0
    exp = {"name": "rig", "sample_rate_hz": 2000,
           "source": {"kind": "simulated", "options": {"model": "lumped"}},
           "excitation": {"file": str(tmp_path / "d.json")}}
    with pytest.raises(ConfigError, match="made for 1000 Hz") as err:
        parse_experiment(exp, file="rig.yaml")
    assert "excitation.file" in str(err.value)


def test_lab_session_yaml_of_the_docs_loads(tmp_path: Path, monkeypatch, capsys) -> None:
    """docs/hardware.md's lab session: rig.yaml (a CAN rig with its multisine) exports the
    drive exactly as the walkthrough prints, and lab_session.yaml (drive definition +
    trigger on the same CAN source) loads with the rig's multisine."""
    import re

    from fnsi_lab.daq.registry import make_source
    from fnsi_lab.daq.sources.can_source import CanSource
    from fnsi_lab.daq.trigger import TriggeredSource

    doc = (Path(__file__).resolve().parent.parent / "docs" / "hardware.md").read_text("utf-8")

    def yaml_block(first_line: str) -> str:
        blocks = [b for b in re.findall(r"```yaml\n(.*?)```", doc, re.S)
                  if b.startswith(first_line)]
        assert len(blocks) == 1, first_line
        return blocks[0]

    monkeypatch.chdir(tmp_path)  # the walkthrough's relative file names
    Path("rig.yaml").write_text(yaml_block("# rig.yaml"), encoding="utf-8")
    Path("lab_session.yaml").write_text(yaml_block("# lab_session.yaml"), encoding="utf-8")
    rig = load_experiment("rig.yaml")
    assert rig.source.kind == "can" and rig.excitation.drive is None
    # step 1 as written: the command and the lines it prints
    sh = [b for b in re.findall(r"```sh\n(.*?)```", doc, re.S)
          if b.startswith("fnsi-lab excitation --config rig.yaml")]
    assert len(sh) == 1
    command, *shown = sh[0].strip().splitlines()
    capsys.readouterr()
    assert main(command.split()[1:]) == 0
    printed = [line.strip() for line in capsys.readouterr().out.strip().splitlines()]
    assert printed == [line.removeprefix("#").strip() for line in shown]
    config = load_experiment("lab_session.yaml")
    assert config.excitation.drive.unit == "V"
    assert config.excitation == rig.excitation  # the definition is the rig's multisine
    assert config.excitation.to_dict()["excited_lines"][0] == 41  # 5.005 Hz at N = 8192
    assert {k: v for k, v in config.source.options.items()} == dict(rig.source.options)
    src = make_source(config)
    assert isinstance(src, TriggeredSource) and isinstance(src.inner, CanSource)
    assert src.describe()["trigger"]["pre_samples"] == 1000
    src.close()
