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
    assert any("not supported" in w for w in val["warnings"])
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
