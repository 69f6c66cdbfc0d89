"""Fault injection: damaged bytes, cut files, killed writers, a full disk, bad paths, busy ports.

Every probe must end in one of two ways: the data come back bit for bit, or a one-line
error names the problem and the fix with the exit status of docs/cli.md (0 success, 1 the
work failed, 2 usage or input error, 130 interrupted). Never a traceback, never silently
different numbers. The recordings are real MCAP files written by the Recorder or by the
`fnsi-lab` command in a subprocess.
"""

from __future__ import annotations

import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.opcode import Opcode

from fnsi_lab.cli import main
from fnsi_lab.daq.recording import RecordingError, open_recording, recover, topics

#: Tiny simulated experiment (3-DOF chain, cubic spring): 1 s periods, fast to simulate.
EXPERIMENT = textwrap.dedent("""\
    name: fault-probe
    sample_rate_hz: 1000
    output: probe.mcap
    block_size: 100
    source:
      kind: simulated
      options: {{model: lumped, lumped: {{variant: cubic}}, oversample: 4, verify: false}}
    excitation:
      kind: multisine
      band_hz: [5, 50]
      rms: 5.0
      samples_per_period: 1000
      periods: {periods}
      transient_periods: 1
      realizations: 1
      seed: 0
      phases: random
    """)


def _experiment(tmp_path: Path, periods: int = 4) -> Path:
    path = tmp_path / f"exp{periods}.yaml"
    path.write_text(EXPERIMENT.format(periods=periods))
    return path


def _cli(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """Run `fnsi-lab` in a subprocess (exit status, stdout, stderr)."""
    return subprocess.run([sys.executable, "-m", "fnsi_lab", *args], capture_output=True,
                          text=True, timeout=timeout, **kw)


def _one_line_error(stderr: str) -> str:
    """The error line; fails the test on a traceback or a multi-line error."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, stderr
    return errors[0]


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """``(opcode, start, end)`` of every top-level record after the leading magic."""
    out, pos = [], 8
    while pos + 9 <= len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((opcode, pos, pos + 9 + length))
        pos += 9 + length
    return out


def _blocks(path: Path, **kw) -> list[tuple[int, int, bytes]]:
    with open_recording(path, **kw) as rec:
        return [(b.realization, b.first_sample, b.data.tobytes()) for b in rec.iter_blocks()]


def _everything(path: Path) -> tuple:
    """Blocks, metadata and attachments: what a damaged byte must not change silently."""
    with open_recording(path) as rec:
        return (_blocks(path), rec.metadata, rec.attachments(), rec.channels, rec.sample_rate_hz)


@pytest.fixture
def multi_chunk(write_recording):
    """A finished recording with ~20 chunks, metadata, two attachments and events."""
    path, blocks = write_recording(n_periods=8, chunk_size=2_000, noise=1e-3,
                                   attachments=[("experiment.yaml", "application/yaml", b"a: 1\n"),
                                                ("truth.bin", "application/octet-stream",
                                                 bytes(range(256)) * 8)])
    return path, blocks


# ---------------------------------------------------------------------------- bit flips
def test_a_flipped_bit_in_any_record_is_caught_or_harmless(multi_chunk, tmp_path):
    path, blocks = multi_chunk
    clean = path.read_bytes()
    reference = _everything(path)
    records = _records(clean)
    kinds = {op for op, _, _ in records}
    # every record type the writer produces is probed
    assert {Opcode.HEADER, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.CHUNK,
            Opcode.MESSAGE_INDEX, Opcode.DATA_END, Opcode.SCHEMA, Opcode.CHANNEL,
            Opcode.STATISTICS, Opcode.CHUNK_INDEX, Opcode.METADATA_INDEX,
            Opcode.ATTACHMENT_INDEX, Opcode.SUMMARY_OFFSET, Opcode.FOOTER} <= kinds
    rng = np.random.default_rng(12)
    outcome: dict[str, set[str]] = {}
    broken = tmp_path / "flipped.mcap"
    probed = set()
    for opcode, start, end in records:
        if (opcode, start) in probed or (opcode == Opcode.CHUNK and len(probed) > 40):
            continue
        probed.add((opcode, start))
        for where, offset in (("start", start + 9), ("middle", (start + end) // 2),
                              ("end", end - 1), ("random", int(rng.integers(start, end)))):
            data = bytearray(clean)
            data[offset] ^= 1 << int(rng.integers(8))
            broken.write_bytes(bytes(data))
            name = Opcode(opcode).name
            try:
                got = _everything(broken)
            except RecordingError as exc:
                text = str(exc)
                assert "\n" not in text and "fnsi-lab recover" in text, text
                outcome.setdefault(name, {}).setdefault(where, set()).add("detected")
                continue
            # not detected: then nothing the reader returns may differ
            assert got == reference, f"silent change after a flip in {name} at byte {offset}"
            outcome.setdefault(name, {}).setdefault(where, set()).add("harmless")
    # the payload of a data-bearing record is always checked (a chunk's time-range header
    # fields are not read: a flip there changes nothing, which the assert above verified)
    for name in ("CHUNK", "METADATA", "ATTACHMENT", "SCHEMA", "CHANNEL", "CHUNK_INDEX",
                 "STATISTICS"):
        assert outcome[name]["middle"] == {"detected"}, (name, outcome[name])
    PROBE_OUTCOMES.update(outcome)


#: record type -> position -> outcomes of the bit-flip probe (bench/RESULTS.md table)
PROBE_OUTCOMES: dict[str, dict[str, set[str]]] = {}


def test_info_and_ident_report_a_damaged_chunk_with_the_recover_hint(multi_chunk, capsys):
    path, _ = multi_chunk
    data = bytearray(path.read_bytes())
    chunks = [(s, e) for op, s, e in _records(bytes(data)) if op == Opcode.CHUNK]
    s, e = chunks[len(chunks) // 2]
    data[(s + e) // 2] ^= 0x04
    path.write_bytes(bytes(data))
    assert main(["info", str(path)]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert f"damaged chunk {len(chunks) // 2 + 1} of {len(chunks)}" in line
    assert f"fnsi-lab recover {path}" in line
    # the documented escape hatch reads it as it is: garbage may then fail to decode, still
    # on one line
    status = main(["info", str(path), "--no-crc-check"])
    err = capsys.readouterr().err
    assert status == 0 or status == 2 and "Traceback" not in err and "fnsi-lab recover" in err


def test_recover_keeps_every_intact_chunk_around_a_damaged_one(multi_chunk, tmp_path, capsys):
    path, blocks = multi_chunk
    data = bytearray(path.read_bytes())
    chunks = [(s, e) for op, s, e in _records(bytes(data)) if op == Opcode.CHUNK]
    assert len(chunks) >= 10
    s, e = chunks[len(chunks) // 2]
    data[s + 40:s + 48] = b"\xff" * 8  # 8 bytes inside the chunk header / data
    path.write_bytes(bytes(data))
    out = tmp_path / "fixed.mcap"
    assert main(["recover", str(path), str(out)]) == 0
    text = capsys.readouterr().out
    assert "skipped 1 damaged record(s)" in text and f"bytes {s}-{e}" in text
    got = _blocks(out)
    total_s = sum(b.n_samples for b in blocks) / 1000.0
    kept_s = sum(len(d) // (4 * len(blocks[0].channels)) for _, _, d in got) / 1000.0
    assert kept_s >= 0.8 * total_s  # target: one damaged chunk in the middle keeps >= 80 %
    original = {(b.realization, b.first_sample): b.data.tobytes() for b in blocks}
    assert all(original[(r, f)] == d for r, f, d in got)  # bit for bit
    # only the damaged chunk is lost: one run of consecutive blocks
    missing = sorted(f for r, f in set(original) - {(r, f) for r, f, _ in got})
    step = blocks[0].n_samples
    assert missing and missing == list(range(missing[0], missing[0] + step * len(missing), step))


# ---------------------------------------------------------------------------- truncation
def test_truncation_at_every_chunk_boundary(multi_chunk, tmp_path, capsys):
    path, blocks = multi_chunk
    clean = path.read_bytes()
    records = _records(clean)
    ends = [e for op, _, e in records if op == Opcode.CHUNK]
    broken, out = tmp_path / "cut.mcap", tmp_path / "cut.recovered.mcap"
    expected_so_far = 0
    originals = [b.data.tobytes() for b in blocks]
    for i, end in enumerate(ends):
        for cut in (end - 1, end):
            broken.write_bytes(clean[:cut])
            assert main(["info", str(broken)]) == 2
            assert "fnsi-lab recover" in _one_line_error(capsys.readouterr().err)
            status = main(["recover", str(broken), str(out), "--force"])
            captured = capsys.readouterr()
            if cut == end - 1 and i == 0:  # no chunk complete: nothing to keep, nothing written
                assert status == 1 and "no intact sample block" in captured.err
                continue
            assert status == 0, captured.err
            got = [d for _, _, d in _blocks(out)]
            assert got == originals[:len(got)]  # a prefix, bit for bit
            if cut == end:
                assert len(got) > expected_so_far
                expected_so_far = len(got)
            else:
                assert len(got) == expected_so_far  # the cut chunk is dropped whole
    assert expected_so_far == len(blocks)


# ---------------------------------------------------------------------------- killed writer
def _reference_blocks(tmp_path: Path, config: Path) -> list[bytes]:
    ref = tmp_path / "reference.mcap"
    r = _cli("acquire", "--config", str(config), "--out", str(ref), "--quiet", "--no-info")
    assert r.returncode == 0, r.stderr
    return [d for _, _, d in _blocks(ref)]


def test_kill_9_at_random_instants_during_a_realtime_recording(tmp_path):
    config = _experiment(tmp_path, periods=12)  # 12 s of signal
    reference = _reference_blocks(tmp_path, config)
    rng = np.random.default_rng(5)
    for k, delay in enumerate(rng.uniform(1.0, 4.0, size=2)):
        path = tmp_path / f"killed{k}.mcap"
        proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "acquire", "--config",
                                 str(config), "--out", str(path), "--realtime", "--quiet",
                                 "--no-info"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # wait for the first chunk of samples on disk, then kill at a random instant
        t_data = None
        deadline = time.monotonic() + 60
        while t_data is None and time.monotonic() < deadline and proc.poll() is None:
            if path.exists() and path.stat().st_size > 40_000:
                t_data = time.monotonic()
            time.sleep(0.02)
        assert t_data is not None, "no sample reached the disk"
        time.sleep(delay)
        elapsed = time.monotonic() - t_data
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        with pytest.raises(RecordingError, match="fnsi-lab recover"):
            open_recording(path)
        out = tmp_path / f"killed{k}.recovered.mcap"
        report = recover(path, out)
        got = [d for _, _, d in _blocks(out)]
        # the same numbers as an unpaced run of the same seeds, from the first block on
        assert got == reference[:len(got)]
        # paced at 1x with a 0.25 s flush: what was due before the kill is kept, less
        # one flush interval and one block (0.1 s); 0.5 s allows for a loaded machine
        assert report.seconds_recovered >= elapsed - 0.5, (report.seconds_recovered, elapsed)


def test_sigterm_finishes_the_file_and_exits_130(tmp_path):
    config = _experiment(tmp_path, periods=12)
    path = tmp_path / "term.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "acquire", "--config",
                             str(config), "--out", str(path), "--realtime", "--quiet",
                             "--no-info"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 60
    while not (path.exists() and path.stat().st_size > 40_000) and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    with open_recording(path) as rec:  # finished cleanly: no recover needed
        assert rec.n_blocks >= 5


# ---------------------------------------------------------------------------- full disk
def _limit_file_size(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # write() then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_full_disk_is_one_line_exit_1_and_the_recording_stays_recoverable(tmp_path):
    config = _experiment(tmp_path, periods=20)  # ~20 chunks of one second
    reference = _reference_blocks(tmp_path, config)
    path = tmp_path / "full.mcap"
    r = _cli("acquire", "--config", str(config), "--out", str(path), "--quiet", "--no-info",
             preexec_fn=_limit_file_size(60_000))
    assert r.returncode == 1, r.stderr
    line = _one_line_error(r.stderr)
    assert str(path) in line and "fnsi-lab recover" in line
    report = recover(path, tmp_path / "full.recovered.mcap")
    got = [d for _, _, d in _blocks(tmp_path / "full.recovered.mcap")]
    assert report.seconds_recovered >= 1.0 and got == reference[:len(got)]


# ---------------------------------------------------------------------------- paths, overwrite
def test_outputs_are_never_overwritten_without_force(tmp_path, write_recording, capsys):
    config = _experiment(tmp_path)
    src, _ = write_recording()
    precious = tmp_path / "precious.txt"
    precious.write_text("lab notes")
    for argv in (["acquire", "--config", str(config), "--out", str(precious), "--quiet"],
                 ["recover", str(src), str(precious)],
                 ["run", "--config", str(config), "--out", str(precious), "--quiet"],
                 ["replay", str(src), "--rrd", str(precious), "--method", "frf", "--quiet"]):
        assert main(argv) == 2, argv
        assert "--force" in _one_line_error(capsys.readouterr().err)
        assert precious.read_text() == "lab notes"
    assert main(["acquire", "--config", str(config), "--out", "", "--quiet"]) == 2
    assert "--out is empty" in _one_line_error(capsys.readouterr().err)


def test_unwritable_paths_are_one_line_errors(tmp_path, write_recording, capsys):
    config = _experiment(tmp_path)
    src, _ = write_recording()
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    for argv in (["acquire", "--config", str(config), "--out", str(a_file / "x.mcap"), "--quiet"],
                 ["acquire", "--config", str(config), "--out", str(tmp_path / "no" / "x.mcap")],
                 ["recover", str(src), str(a_file / "x.mcap")],
                 ["replay", str(src), "--rrd", str(a_file / "x.rrd"), "--method", "frf",
                  "--quiet"],
                 ["acquire", "--config", str(config), "--out", str(tmp_path)]):
        assert main(argv) == 2, argv
        _one_line_error(capsys.readouterr().err)


# ---------------------------------------------------------------------------- ports
def test_busy_and_impossible_ports(write_recording, capsys):
    src, _ = write_recording()
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["replay", str(src), "--serve-web", "--web-port", str(port),
                     "--method", "frf", "--quiet"]) == 2
        line = _one_line_error(capsys.readouterr().err)
        assert f"--web-port {port}" in line and "in use" in line
    with pytest.raises(SystemExit) as exc:  # argparse: usage error
        main(["replay", str(src), "--serve-web", "--web-port", "99999"])
    assert exc.value.code == 2
    assert "outside 1..65535" in capsys.readouterr().err


def test_serve_web_listens_on_localhost_only(write_recording, tmp_path):
    src, _ = write_recording()
    ports = []
    for _ in range(2):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            ports.append(s.getsockname()[1])
    proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "replay", str(src),
                             "--serve-web", "--web-port", str(ports[0]), "--grpc-port",
                             str(ports[1]), "--method", "frf", "--quiet", "--web-wait", "20",
                             "--rrd", str(tmp_path / "x.rrd")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        listening = ""
        while time.monotonic() < deadline and proc.poll() is None:
            listening = subprocess.run(["ss", "-ltn"], capture_output=True, text=True).stdout
            if f":{ports[0]} " in listening and f":{ports[1]} " in listening:
                break
            time.sleep(0.2)
        lines = [ln for ln in listening.splitlines() if f":{ports[0]} " in ln or f":{ports[1]} " in ln]
        assert len(lines) == 2, listening
        assert all("127.0.0.1:" in ln for ln in lines), lines
    finally:
        proc.terminate()  # SIGTERM: handled like Ctrl-C, the server goes with the command
        proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        listening = subprocess.run(["ss", "-ltn"], capture_output=True, text=True).stdout
        if f":{ports[0]} " not in listening and f":{ports[1]} " not in listening:
            break
        time.sleep(0.2)
    assert f":{ports[1]} " not in listening, "the web viewer server outlived the command"


# ---------------------------------------------------------------------------- exit codes
def test_usage_errors_exit_2(tmp_path, capsys):
    config = _experiment(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["run", "--config", str(config), "--queue-blocks", "0"])
    assert exc.value.code == 2 and "drop every block" in capsys.readouterr().err


def test_run_with_an_ident_config_for_other_channels_stops_before_acquiring(tmp_path, capsys):
    config = _experiment(tmp_path)
    ident = tmp_path / "ident.yaml"
    ident.write_text(textwrap.dedent("""\
        band_hz: [5, 50]
        outputs: [X2, X9]
        """))
    out = tmp_path / "never.mcap"
    assert main(["run", "--config", str(config), "--ident", str(ident), "--out", str(out),
                 "--quiet"]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert "'X9'" in line and "X1" in line and str(ident) in line
    assert not out.exists()  # refused before any acquisition


def test_run_whose_identification_fails_exits_1_with_the_reason(tmp_path, capsys):
    config = _experiment(tmp_path)
    ident = tmp_path / "ident.yaml"
    ident.write_text("band_hz: [100, 200]\n")  # the multisine excites 5-50 Hz only
    assert main(["run", "--config", str(config), "--ident", str(ident), "--out",
                 str(tmp_path / "s.mcap"), "--rrd", str(tmp_path / "s.rrd"), "--orders", "2:4",
                 "--quiet"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "identification failed" in line and "no excited line" in line
    with open_recording(tmp_path / "s.mcap") as rec:  # the recording itself is complete
        assert rec.n_blocks == 40


def test_ident_whose_band_holds_no_excited_line_exits_1(tmp_path, capsys):
    """The identification itself refuses (ident.pipeline), at a fixed order and automatic
    alike, so `ident` and `run` agree: exit 1 (the work failed), one line naming both bands."""
    config = _experiment(tmp_path)
    rec = tmp_path / "r.mcap"
    assert main(["acquire", "--config", str(config), "--out", str(rec), "--quiet"]) == 0
    ident = tmp_path / "ident.yaml"
    ident.write_text("band_hz: [100, 200]\n")  # the multisine excites 5-50 Hz only
    capsys.readouterr()
    for how in (["--auto", "--orders", "2:4"], ["--order", "4"]):
        out = tmp_path / f"r{len(how)}.json"
        assert main(["ident", str(rec), "--config", str(ident), *how, "--json", str(out)]) == 1
        line = _one_line_error(capsys.readouterr().err)
        assert "no excited line in the processed band 100-200 Hz; the excitation's" in line
        assert not out.exists()


#: A failed identification as `fnsi-lab ident --json` writes it (lumped recording, ident band
#: 100-200 Hz, information criterion over the processed band): poles fitted to lines the
#: multisine (5-50 Hz) never drove, no excited line, an empty FRF.
FAILED_RESULT = {
    "method": "auto", "order": 2, "input": "l.mcap", "outputs": ["X1", "X2", "X3"],
    "inputs": ["F-X3"], "band_hz": [100.0, 200.0], "n_lines": 820, "n_excited_lines": 0,
    "selected_order": 2, "mdi_order": 2, "mdi_norm": "h2", "threshold": 23.9, "final": "full",
    "modes": [], "coefficients": [], "coefficient_spectra": None, "criterion": "mdl",
    "poles": [{"frequency_hz": 100.65, "damping_ratio": 5.5e-4, "stable": True,
               "physical": False}],
    "stabilisation": [{"order": 2, "poles": [{"frequency_hz": 100.65, "damping_ratio": 5.5e-4,
                                              "class": "new", "unstable": False,
                                              "mac": None}]}],
    "information_criterion": [{"order": 2, "value": 0.9988, "stable": True},
                              {"order": 3, "value": None, "stable": False}],
    "mdi": [{"frequency_hz": 100.65, "damping_ratio": 5.5e-4, "mdi_h2": 23.9, "in_band": True,
             "stabilisation": "new", "physical": False}],
    "frf": {"frequency_hz": [], "outputs": ["X1", "X2", "X3"], "inputs": ["F-X3"],
            "underlying_linear": {"re": [], "im": []}, "measured": {"re": [], "im": []},
            "model": {"re": [], "im": []}},
}


def test_run_cli_whose_identification_fails_exits_1_without_traceback(tmp_path):
    """The real command on the lumped experiment (daq/data/lumped.yaml) with an ident band
    that holds no excited line. With the information criterion over the processed band the
    pipeline itself does not object (as on the 39-output SmallSat, where the HTML report then
    crashed on the empty FRF): the service refuses the result. Exit 1, one line naming both
    bands, no traceback; the HTML report is skipped with one line saying so."""
    ident = tmp_path / "band.yaml"
    ident.write_text("band_hz: [100, 200]\nauto: {ic_band: processed}\n")
    out = tmp_path / "l.mcap"
    r = _cli("run", "--config", str(Path(__file__).parents[1] / "daq" / "data" / "lumped.yaml"),
             "--ident", str(ident), "--out", str(out), "--orders", "2:6", "--quiet")
    assert r.returncode == 1, r.stderr
    line = _one_line_error(r.stderr)
    assert line.startswith("fnsi-lab run: error: identification failed: "), line
    assert "no excited line in the processed band 100-200 Hz" in line and "5.127-49.8 Hz" in line
    html = out.with_suffix(".html")
    assert not html.exists() and f"no HTML report: no identification to report ({html} not " \
        "written)" in r.stderr
    with open_recording(out) as rec:  # the recording itself is complete
        assert rec.n_blocks == 328


def test_report_of_a_failed_identification_is_written_and_exits_1(tmp_path):
    """`fnsi-lab report` on the JSON of an identification without an excited line: the page
    is written with what exists and opens with the failure; exit 1, one line, no traceback."""
    import json

    result = tmp_path / "failed.json"
    result.write_text(json.dumps(FAILED_RESULT))
    out = tmp_path / "failed.html"
    r = _cli("report", str(result), "--out", str(out))
    assert r.returncode == 1, r.stderr
    line = _one_line_error(r.stderr)
    assert "identification failed: no excited line in the processed band 100-200 Hz" in line
    assert f"{out} was written and says so" in line
    page = out.read_text()
    assert "Identification failed:" in page and "fig-stabilisation" in page
    assert "Frequency response" in page and "not available in this result" in page


def test_npz_with_a_non_numeric_sample_rate(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    np.savez(bad, u=np.zeros((1000, 1)), y=np.zeros((1000, 2)), fs=np.array("fast"), N=100)
    assert main(["ident", str(bad), "--config", "lumped-cubic", "--order", "4"]) == 2
    assert "fs" in _one_line_error(capsys.readouterr().err)


def test_ident_band_above_nyquist_is_refused(tmp_path, write_recording, capsys):
    src, _ = write_recording()  # 1 kHz: Nyquist 500 Hz
    ident = tmp_path / "ident.yaml"
    ident.write_text("band_hz: [5, 800]\n")
    assert main(["ident", str(src), "--config", str(ident), "--order", "4"]) == 2
    assert "Nyquist" in _one_line_error(capsys.readouterr().err)


def test_selected_order_at_the_end_of_the_sweep_is_flagged(tmp_path, capsys):
    """A 3-DOF chain needs order 6: a 2..4 sweep ends before the criterion's minimum."""
    config = _experiment(tmp_path)
    rec = tmp_path / "chain.mcap"
    assert main(["acquire", "--config", str(config), "--out", str(rec), "--quiet",
                 "--no-info"]) == 0
    out = tmp_path / "r.json"
    assert main(["ident", str(rec), "--config", "lumped-cubic", "--auto", "--orders", "2:4",
                 "--json", str(out), "--quiet"]) == 0
    import json
    result = json.loads(out.read_text())
    assert result["order"] == 4
    assert any("last of the sweep 2..4" in w for w in result["warnings"])
    # a sweep that contains the minimum says nothing of the kind
    assert main(["ident", str(rec), "--config", "lumped-cubic", "--auto", "--orders", "2:12",
                 "--json", str(out), "--force", "--quiet"]) == 0
    result = json.loads(out.read_text())
    assert result["order"] < 12 and not any("last of the sweep" in w for w in result["warnings"])


def test_recover_survives_a_damaged_header_record(multi_chunk, tmp_path):
    """The MCAP header's length field itself destroyed: every record after it is still found
    (metadata and attachments by their CRCs, chunks by theirs)."""
    path, blocks = multi_chunk
    with open_recording(path) as rec:
        metadata, attachments = rec.metadata, rec.attachments()
    data = bytearray(path.read_bytes())
    (opcode, start, end), *_ = _records(bytes(data))
    assert opcode == Opcode.HEADER
    data[start + 1:start + 9] = b"\xff" * 8  # its record length
    path.write_bytes(bytes(data))
    report = recover(path, tmp_path / "out.mcap")
    got = [d for _, _, d in _blocks(tmp_path / "out.mcap")]
    assert got == [b.data.tobytes() for b in blocks]  # every chunk after it, bit for bit
    assert report.damaged and report.damaged[0][0] == start
    with open_recording(tmp_path / "out.mcap") as rec:
        assert rec.attachments() == attachments
        assert {k: v for k, v in rec.metadata.items() if k != "recovery"} == metadata
