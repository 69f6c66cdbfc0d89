"""``fnsi-lab validate``: an identified model simulated on a record it was not fitted to.

Real subprocess CLI runs on real files (npz records of a simulated one-mode Duffing
oscillator, an MCAP recording of the aircraft-like GVT), the API, the JSON layout, the
model's round trip through the result JSON, and one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

FS, N = 500.0, 4096
M, F0, ZETA, K3 = 1.0, 20.0, 0.02, 5.0e9
DUFFING_CONFIG = """\
band_hz: [5, 60]
output_quantity: displacement
compare_linear: true          # the linear fit of the same data in the result, validated too
nonlinearities:
  - name: k3
    kind: polynomial
    exponent: 3
    channels: {y0: 1}
"""


def _duffing():
    from fnsi_lab.daq.sim.lab import duffing_model

    k = M * (2 * np.pi * F0) ** 2
    return duffing_model(M, 2 * ZETA * np.sqrt(k * M), k, K3)


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "fnsi_lab", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def duffing_files(tmp_path_factory):
    """Two levels of a Duffing oscillator (20 Hz, 2 % damping, k3 = 5e9 N/m^3: the cubic
    force is 5 % / 16 % of the linear one at the RMS displacement), 4 periods each after a
    transient, 60 dB output noise, different multisine phases; identified at the low level
    by the real CLI."""
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.lab import LabRealism, lab_experiment

    folder = tmp_path_factory.mktemp("duffing")
    model = _duffing()
    for name, rms, seed in (("low", 2.0, 1), ("high", 3.5, 2)):
        rec = lab_experiment(model, multisine(N, FS, (5.0, 60.0), rms, seed=seed),
                             LabRealism(snr_db=60, periods=4, transient_periods=2), seed=seed)
        np.savez(folder / f"{name}.npz", u=rec.u, y=rec.y, fs=FS, N=N)
    (folder / "duffing.yaml").write_text(DUFFING_CONFIG)
    proc = _cli(["ident", "low.npz", "--config", "duffing.yaml", "--auto", "--json", "low.json",
                 "--quiet"], folder)
    assert proc.returncode == 0, proc.stderr
    return folder


def test_nonlinear_model_beats_linear_by_25_db_on_another_level(duffing_files):
    """Identified at 2 N, validated at 3.5 N RMS (other phases): the nonlinear model's error
    is at least 25 dB below the underlying linear model's (issue 29's target; the lab's
    published figure on its electronic Duffing is about 33 dB). Measured: -43.6 dB against
    +3.4 dB. The JSON carries the documented keys and the SVG figure is written."""
    proc = _cli(["validate", "low.json", "high.npz", "--json", "val.json", "--svg", "val.svg"],
                duffing_files)
    assert proc.returncode == 0, proc.stderr
    assert "harmonic balance" in proc.stdout and "dB" in proc.stdout
    val = json.loads((duffing_files / "val.json").read_text())
    (row,) = val["outputs"]
    assert {"name", "output_rms", "error_rms", "error_db", "linear_error_rms",
            "linear_error_db"} <= set(row)
    assert row["name"] == "y0" and val["method"] == "harmonic balance" and val["converged"]
    assert row["linear_error_db"] - row["error_db"] >= 25.0, row
    assert row["error_db"] < -30.0           # the model is close to the truth (k3 to 0.02 %)
    assert row["error_db"] == pytest.approx(20 * np.log10(row["error_rms"] / row["output_rms"]))
    # the linear model identified on the same data (nonlinear_vs_linear) does no better
    # than the underlying linear one on a hardening oscillator at another level
    assert row["linear_fit_error_db"] - row["error_db"] >= 25.0, row
    figure = (duffing_files / "val.svg").read_text()
    assert "<svg" in figure and figure.rstrip().endswith("</svg>")
    # an existing output is refused without --force
    again = _cli(["validate", "low.json", "high.npz", "--json", "val.json"], duffing_files)
    assert again.returncode == 2 and "exists" in again.stderr


def test_time_integration_of_a_record_without_period(duffing_files):
    """A random (non-periodic) force, a record that gives no period: time integration from
    rest. The identified model's error is 25 dB below the linear one's as well (measured
    -42.8 dB against -1.0 dB on 8000 samples); the true model itself, stepped the same way,
    is 49 dB below, so the integration error (Heun at 8x) is not what is measured."""
    from fnsi_lab.daq.sim.integrate import simulate

    rng = np.random.default_rng(5)
    n = 4000
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1 / FS)
    spec[(f < 5) | (f > 60)] = 0
    u = np.fft.irfft(spec, n)
    u *= 1.5 / u.std()
    y = simulate(_duffing(), u[:, None], FS, oversample=10,
                 quantities=("displacement",)).displacement[:, 0]
    np.savez(duffing_files / "random.npz", u=u, y=y, fs=FS)
    proc = _cli(["validate", "low.json", "random.npz", "--json", "val-random.json"],
                duffing_files)
    assert proc.returncode == 0, proc.stderr
    val = json.loads((duffing_files / "val-random.json").read_text())
    assert val["method"] == "time integration"
    (row,) = val["outputs"]
    assert row["linear_error_db"] - row["error_db"] >= 25.0, row


def test_api_equals_cli_and_model_round_trip(duffing_files):
    """fnsi_lab.validate_model is the CLI's entry point (same numbers); the result JSON
    rebuilds the identified model exactly (its steady-state output on the data)."""
    import fnsi_lab
    from fnsi_lab.ident.core.model_json import basis_from_json, model_from_json

    v = fnsi_lab.validate_model(duffing_files / "low.json", duffing_files / "high.npz")
    cli = json.loads((duffing_files / "val.json").read_text())
    assert v.outputs[0]["error_rms"] == pytest.approx(cli["outputs"][0]["error_rms"], rel=1e-9)

    ident = fnsi_lab.identify(str(duffing_files / "low.npz"),
                              config=str(duffing_files / "duffing.yaml"))
    res = json.loads(json.dumps(ident.to_json()))
    model = model_from_json(res)
    assert np.allclose(model.steady_state_output(ident.data),
                       ident.model.steady_state_output(ident.data), rtol=1e-12, atol=0)
    (nl,) = basis_from_json(res["nonlinearities"])
    assert nl.kind == "polynomial" and nl.exponent == 3 and nl.channels == {"y0": 1.0}


def test_linear_answer_with_a_basis(duffing_files, tmp_path):
    """A result whose answer fell back to a linear model (its state space has only the
    force columns) while its basis is listed: validated as the linear model it is, the
    nonlinear error equal to the linear one, and a note says so."""
    res = json.loads((duffing_files / "low.json").read_text())
    ss = res["state_space"]
    ss["b"] = [row[:1] for row in ss["b"]]
    ss["d"] = [row[:1] for row in ss["d"]]
    ss["input_names"] = ss["input_names"][:1]
    (tmp_path / "linear.json").write_text(json.dumps(res))
    proc = _cli(["validate", "linear.json", str(duffing_files / "high.npz"), "--json", "v.json"],
                tmp_path)
    assert proc.returncode == 0, proc.stderr
    val = json.loads((tmp_path / "v.json").read_text())
    (row,) = val["outputs"]
    assert row["error_rms"] == row["linear_error_rms"]
    assert any("linear model" in w for w in val["warnings"])


def test_unsupported_terms_validate_the_linear_fit(duffing_files, tmp_path):
    """When the nested test decided the nonlinear terms are not supported
    (nonlinear_vs_linear.decision 'linear'), the answer is the linear fit: both columns give
    its error, and a note says so."""
    res = json.loads((duffing_files / "low.json").read_text())
    assert res["nonlinear_vs_linear"]["decision"] == "nonlinear"   # k3 is supported here
    res["nonlinear_vs_linear"]["decision"] = "linear"               # as if it were not
    (tmp_path / "unsupported.json").write_text(json.dumps(res))
    proc = _cli(["validate", "unsupported.json", str(duffing_files / "high.npz"), "--json",
                 "v.json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    val = json.loads((tmp_path / "v.json").read_text())
    (row,) = val["outputs"]
    assert row["error_rms"] == row["linear_error_rms"] == row["linear_fit_error_rms"]
    assert any("were not kept" in w and "nonlinear_vs_linear" in w for w in val["warnings"])
    assert not any("['" in w for w in val["warnings"])   # the terms named, not a list repr
    # --model nonlinear: the rejected nonlinear model all the same (here a good one)
    proc = _cli(["validate", "unsupported.json", str(duffing_files / "high.npz"), "--model",
                 "nonlinear", "--json", "vn.json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((tmp_path / "vn.json").read_text())["outputs"]
    assert row["linear_fit_error_db"] - row["error_db"] >= 25.0, row


def test_bad_inputs_give_one_line(duffing_files, tmp_path):
    """A result without a model, a record without the model's channels, a missing file:
    exit 2 with one line naming the file and the fix."""
    res = json.loads((duffing_files / "low.json").read_text())
    res.pop("state_space")
    (tmp_path / "old.json").write_text(json.dumps(res))
    proc = _cli(["validate", "old.json", str(duffing_files / "high.npz")], tmp_path)
    assert proc.returncode == 2
    assert "state_space" in proc.stderr and "ident --json again" in proc.stderr
    assert len([ln for ln in proc.stderr.splitlines() if "error" in ln]) == 1
    d = np.load(duffing_files / "high.npz")
    np.savez(tmp_path / "other.npz", u=d["u"], y=d["y"], fs=d["fs"], N=d["N"],
             channels=np.array(["x"]))
    proc = _cli(["validate", str(duffing_files / "low.json"), "other.npz"], tmp_path)
    assert proc.returncode == 2 and "y0" in proc.stderr, proc.stderr
    proc = _cli(["validate", str(duffing_files / "low.json"), "nothere.mcap"], tmp_path)
    assert proc.returncode == 2 and "nothere.mcap" in proc.stderr


def test_aircraft_recording(tmp_path):
    """The aircraft-like GVT as MCAP: a linear model identified at 98 N RMS validated on
    the 84 N recording (units from the channel table). The linear fit at 98 N predicts the
    84 N record better than nothing (error below the output) but far from its noise: the
    joint's friction changes the dynamics with level."""
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(root / "bench" / "aircraft.py"), "--out", "gvt",
                           "--levels", "84", "98"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr
    proc = _cli(["ident", "gvt/aircraft-rms98.mcap", "--config", "gvt/aircraft-linear.yaml",
                 "--auto", "--json", "lin98.json", "--quiet"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = _cli(["validate", "lin98.json", "gvt/aircraft-rms84.mcap", "--json", "v.json"],
                tmp_path)
    assert proc.returncode == 0, proc.stderr
    val = json.loads((tmp_path / "v.json").read_text())
    assert [r["name"] for r in val["outputs"]] == ["drive", "wing", "payload"]
    assert all(r["unit"] == "m/s^2" and r["error_rms"] is None for r in val["outputs"])
    assert all(-30.0 < r["linear_error_db"] < 0.0 for r in val["outputs"]), val["outputs"]


def test_real_silverbox_other_periods(tmp_path):
    """Real data (the Silverbox circuit, bench/data/silverbox-schroeder): identified on
    periods 0-5 of the record (the first transient), validated on periods 6-10 by the real
    CLI. Measured: -28.3 dB against -0.6 dB for the underlying linear model (the benchmark's
    own cross-level figure is about 33 dB); 20 dB is asserted, 8 dB of margin for the
    record's 0.5 % period-to-period noise. Time integration of the same record agrees
    within 1 dB (it is not told the record is periodic)."""
    src = Path(__file__).resolve().parents[1] / "bench" / "data" / "silverbox-schroeder"
    d = np.load(src / "schroeder.npz")
    n = int(d["N"])
    np.savez(tmp_path / "a.npz", u=d["u"][:6 * n], y=d["y"][:6 * n], fs=d["fs"], N=n,
             channels=d["channels"])
    np.savez(tmp_path / "b.npz", u=d["u"][6 * n:], y=d["y"][6 * n:], fs=d["fs"], N=n,
             channels=d["channels"])
    proc = _cli(["ident", "a.npz", "--config", str(src / "schroeder.yaml"), "--auto", "--json",
                 "a.json", "--quiet"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = _cli(["validate", "a.json", "b.npz", "--transient-periods", "0", "--json", "v.json"],
                tmp_path)
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((tmp_path / "v.json").read_text())["outputs"]
    assert row["linear_error_db"] - row["error_db"] >= 20.0, row
    assert json.loads((tmp_path / "v.json").read_text())["n_periods"] == 5
    proc = _cli(["validate", "a.json", "b.npz", "--method", "time", "--json", "t.json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    (t,) = json.loads((tmp_path / "t.json").read_text())["outputs"]
    assert abs(t["error_db"] - row["error_db"]) < 1.0, (t, row)


# ---------------------------------------------------------------- refusals and their messages
SILVERBOX = Path(__file__).resolve().parents[1] / "bench" / "data" / "silverbox-schroeder"


def _one_error_line(proc: subprocess.CompletedProcess, *names: str) -> str:
    """Exit 2, no traceback, one stderr line naming every one of ``names``."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert all(n in lines[0] for n in names), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def silverbox_jsons(tmp_path_factory):
    """The real Silverbox record's JSON files of four commands, written by the real CLI:
    ident (sb.json), analyse (an.json), locate (loc.json), validate (val.json)."""
    folder = tmp_path_factory.mktemp("silverbox-json")
    rec, cfg = str(SILVERBOX / "schroeder.npz"), str(SILVERBOX / "schroeder.yaml")
    for args in (["ident", rec, "--config", cfg, "--auto", "--json", "sb.json"],
                 ["analyse", rec, "--config", cfg, "--json", "an.json"],
                 ["locate", rec, "--config", cfg, "--json", "loc.json"],
                 ["validate", "sb.json", rec, "--json", "val.json"]):
        proc = _cli([*args, "--quiet"], folder)
        assert proc.returncode == 0, (args, proc.stderr)
    return folder


def test_record_given_as_the_result_gives_one_line(silverbox_jsons):
    """The arguments swapped (RESULT is the binary record): one line naming it, exit 2."""
    rec = str(SILVERBOX / "schroeder.npz")
    proc = _cli(["validate", rec, "sb.json"], silverbox_jsons)
    line = _one_error_line(proc, "schroeder.npz", "not a JSON result")
    assert "RESULT.json RECORD" in line


@pytest.mark.parametrize("name, writer", [("an.json", "fnsi-lab analyse --json"),
                                          ("loc.json", "fnsi-lab locate --json"),
                                          ("val.json", "fnsi-lab validate --json")])
def test_another_commands_json_is_refused_by_validate_and_report(silverbox_jsons, name,
                                                                 writer):
    """validate and report read only an ident result: another command's JSON is named as
    such (one line, exit 2) and nothing is written (report used to write an empty page
    from a locate or validate JSON with exit 0)."""
    folder = silverbox_jsons
    rec = str(SILVERBOX / "schroeder.npz")
    proc = _cli(["validate", name, rec, "--json", "out.json", "--svg", "out.svg"], folder)
    line = _one_error_line(proc, name, writer, "not an `fnsi-lab ident --json` result")
    assert "state_space" not in line
    proc = _cli(["report", name, "--out", "out.html", "--quiet"], folder)
    _one_error_line(proc, name, writer)
    assert not any((folder / f).exists() for f in ("out.json", "out.svg", "out.html"))
    # the API refuses the same JSON given as a dict
    import fnsi_lab
    from fnsi_lab.errors import FnsiLabError

    with pytest.raises(FnsiLabError, match=writer):
        fnsi_lab.validate_model(json.loads((folder / name).read_text()),
                                SILVERBOX / "schroeder.npz")


def test_one_path_for_two_outputs_is_refused_before_any_work(silverbox_jsons):
    """--json X --svg X would keep only the figure: refused (one line naming both options),
    with --force too, and an existing X is left as it was. analyse's --json/--report says
    it is the other output, not an input."""
    folder = silverbox_jsons
    rec = str(SILVERBOX / "schroeder.npz")
    proc = _cli(["validate", "sb.json", rec, "--json", "both", "--svg", "both"], folder)
    _one_error_line(proc, "--svg both", "the --json output")
    assert not (folder / "both").exists()
    (folder / "both").write_text("keep me")
    proc = _cli(["validate", "sb.json", rec, "--json", "both", "--svg", "both", "--force"],
                folder)
    _one_error_line(proc, "--svg both", "the --json output")
    assert (folder / "both").read_text() == "keep me"
    proc = _cli(["analyse", rec, "--json", "an2", "--report", "an2"], folder)
    line = _one_error_line(proc, "--report an2", "the --json output")
    assert "input" not in line and not (folder / "an2").exists()


def test_negative_transient_periods_is_refused_plainly(silverbox_jsons):
    proc = _cli(["validate", "sb.json", str(SILVERBOX / "schroeder.npz"),
                 "--transient-periods", "-1", "--json", "neg.json"], silverbox_jsons)
    line = _one_error_line(proc, "--transient-periods", "-1", "negative")
    assert "leaves no period" not in line and not (silverbox_jsons / "neg.json").exists()


def test_the_warning_gives_the_reason_the_answer_is_linear(duffing_files, tmp_path):
    """An answer that is the linear fit because its simulation was worse (F-test passed):
    the warning quotes the result's own statement, not "not supported by the data"."""
    res = json.loads((duffing_files / "low.json").read_text())
    statement = ("the nonlinear terms lower the noise-weighted residual (1.73x lower than the "
                 "linear fit's, F-test p = 1.1e-162) but the nonlinear model, simulated on its "
                 "own record, predicts y0 worse than the linear fit (-9.2 dB against -11.6 dB)")
    res["nonlinear_vs_linear"].update(decision="linear", simulation_rejected=True,
                                      statement=statement)
    (tmp_path / "rejected.json").write_text(json.dumps(res))
    proc = _cli(["validate", "rejected.json", str(duffing_files / "high.npz")], tmp_path)
    assert proc.returncode == 0, proc.stderr
    warning = [ln for ln in proc.stdout.splitlines() if "warning" in ln and "k3" in ln]
    assert len(warning) == 1 and statement in warning[0], proc.stdout
    assert "not supported by the data" not in proc.stdout


@pytest.fixture(scope="module")
def gvt_stop_model(tmp_path_factory):
    """The aircraft-like GVT campaign's 12-98 N records (bench/aircraft.py, one multisine
    realisation per level) and the Jenkins + stop model identified at 98 N (--auto): it
    keeps both elements (its own record and the F-test support them, and each element has
    a determined coefficient, docs/ident.md). At 84 N the stop's stiffnesses are not
    identifiable and the stop is left out."""
    folder = tmp_path_factory.mktemp("gvt-stop")
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(root / "bench" / "aircraft.py"), "--out", "gvt",
                           "--levels", "12", "26", "40", "55", "69", "84", "98"], cwd=folder,
                          capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr
    proc = _cli(["ident", "gvt/aircraft-rms98.mcap", "--config", "gvt/aircraft-jenkins-stop.yaml",
                 "--auto", "--json", "js98.json", "--quiet"], folder)
    assert proc.returncode == 0, proc.stderr
    res = json.loads((folder / "js98.json").read_text())
    assert [nl["name"] for nl in res["nonlinearities"]] == ["joint", "gap"]
    assert res["nonlinear_vs_linear"]["decision"] == "nonlinear"
    return folder


def test_a_stop_that_never_closes_is_simulated(gvt_stop_model):
    """Validated at 40 N, where one side of the 98 N model's stop never closes (its basis
    column is zero on the measured motion): no contact force is a prediction, not an
    error. The model is simulated and a note says so. Measured: -7.3 / -7.8 / -6.3 dB
    against the linear fit's -2.0 / -1.0 / -2.3 dB (it used to refuse); 1 dB better on
    every output is asserted (the smallest measured margin is 4.0 dB)."""
    folder = gvt_stop_model
    proc = _cli(["validate", "js98.json", "gvt/aircraft-rms40.mcap", "--json", "v40.json"],
                folder)
    assert proc.returncode == 0, proc.stderr
    val = json.loads((folder / "v40.json").read_text())
    assert val["converged"] and val["nonlinearities"] == ["joint", "gap"]
    assert any("basis functions 'gap:neg' are identically zero" in w for w in val["warnings"])
    assert not any("['" in w for w in val["warnings"])   # names, not a list repr
    for row in val["outputs"]:
        assert row["error_db"] < row["linear_fit_error_db"] - 1.0, row


def test_channel_mismatch_names_the_record_once(gvt_stop_model, silverbox_jsons):
    """The Silverbox model (y0, u0) on a GVT recording: one line, the path given once."""
    rec = str(gvt_stop_model / "gvt" / "aircraft-rms69.mcap")
    proc = _cli(["validate", "sb.json", rec, "--quiet"], silverbox_jsons)
    line = _one_error_line(proc, rec, "y0")
    assert line.count("aircraft-rms69.mcap") == 1, line
