"""``fnsi-lab ident`` (core path): array files, YAML config, JSON result, one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

from fnsi_lab.cli import main
from fnsi_lab.ident.config import load_ident_config, packaged_config, parse_ident_config
from fnsi_lab.ident.errors import IdentConfigError, IdentDataError
from fnsi_lab.inputs import load_input

CONFIG = """\
band_hz: [3, 150]
transient_periods: 1
output_quantity: displacement
inputs:
  - {name: F-X3, driving_point: X3}
nonlinearities:
  - name: knl
    kind: polynomial
    exponent: 3
    channels: {X2: 1, X3: -1}
    truth: 1.0e9
order: 6
max_order: 10
"""


@pytest.fixture(scope="module")
def cubic_arrays():
    sim = pytest.importorskip("fnsi_lab.daq.sim")
    from fnsi_lab.daq.multisine import multisine
    fs, N = 512.0, 4096
    model = sim.lumped_model("cubic")
    u = np.asarray(multisine(N, fs, (5, 60), 20.0, n_periods=3, seed=1).signal).reshape(-1, 1)
    y = sim.simulate(model, u, fs, periodic=N).displacement
    return dict(u=u, y=y, fs=fs, N=N, channels=np.array(model.measured_names),
                input_channels=np.array(model.input_names))


@pytest.fixture
def config_file(tmp_path):
    p = tmp_path / "ident.yaml"
    p.write_text(CONFIG)
    return p


def test_npz_to_json(tmp_path, cubic_arrays, config_file, capsys):
    data = tmp_path / "run.npz"
    np.savez(data, **cubic_arrays)
    out = tmp_path / "res.json"
    assert main(["ident", str(data), "--config", str(config_file), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["order"] == 6 and len(res["poles"]) == 3
    assert {"frequency_hz", "damping_ratio", "stable"} <= set(res["poles"][0])
    (c,) = res["coefficients"]
    assert {"name", "mean_real", "std_real", "log10_re_im", "ls_value"} <= set(c)
    # same simulation as tests/test_ident_core.py (measured +0.13 %)
    assert c["name"] == "knl" and abs(c["error_percent"]) < 0.5
    assert {"load", "prepare", "decomposition", "model", "total"} <= set(res["timings_s"])
    assert "order 6" in capsys.readouterr().out


def test_mat_file_and_order_override(tmp_path, cubic_arrays, config_file, capsys):
    data = tmp_path / "run.mat"
    arrays = dict(cubic_arrays)
    arrays["u"] = arrays["u"][:, 0]  # MATLAB column vector
    scipy.io.savemat(data, arrays)
    inp = load_input(data)
    assert inp.u.shape == (1, 3, 4096, 1) and inp.output_channels == ("X1", "X2", "X3")
    assert main(["ident", str(data), "--config", str(config_file), "--order", "8",
                 "--json", "-", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["order"] == 8


@pytest.mark.parametrize("change, message", [
    (lambda a: a.pop("fs"), "missing array 'fs'"),
    (lambda a: a.update(y=a["y"][:-5]), "same number of samples"),
    (lambda a: a.update(channels=np.array(["X1", "X2", "Z3"])), "driving_point 'X3' is not an output (outputs: X1, X2, Z3)"),
    (lambda a: a.update(N=np.array(1000)), "whole number of periods"),
    # the file says accelerations, the config displacements: read as displacements the
    # lab stop's accelerations gave stiffnesses -324 % / -399 %
    (lambda a: a.update(quantity=np.array("acceleration")),
     "the outputs are acceleration but the ident config says output_quantity: displacement"),
])
def test_bad_input_is_one_line(tmp_path, cubic_arrays, config_file, capsys, change, message):
    arrays = dict(cubic_arrays)
    change(arrays)
    data = tmp_path / "bad.npz"
    np.savez(data, **arrays)
    assert main(["ident", str(data), "--config", str(config_file), "--order", "6"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_missing_order_and_unknown_key(tmp_path, cubic_arrays, capsys):
    data = tmp_path / "run.npz"
    np.savez(data, **cubic_arrays)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(CONFIG.replace("order: 6\n", ""))
    assert main(["ident", str(data), "--config", str(cfg)]) == 2
    assert "--order" in capsys.readouterr().err
    cfg.write_text(CONFIG + "ordr: 3\n")
    assert main(["ident", str(data), "--config", str(cfg), "--order", "6"]) == 2
    err = capsys.readouterr().err
    assert "ordr: unknown key" in err and "did you mean 'order'" in err


def test_config_validation_messages():
    with pytest.raises(IdentConfigError, match=r"nonlinearities\[0\]\.clearances: expected 2 numbers"):
        parse_ident_config({"band_hz": [1, 2], "nonlinearities": [
            {"name": "s", "kind": "trilinear", "channels": {"a": 1}, "clearances": [1]}]}, file="x.yaml")
    with pytest.raises(IdentConfigError, match="not whole"):
        parse_ident_config({"band_hz": [1, 2], "nonlinearities": [
            {"name": "p", "kind": "polynomial", "channels": {"a": 1}, "exponent": 2.5}]})
    with pytest.raises(IdentConfigError, match="f_min < f_max"):
        parse_ident_config({"band_hz": [5, 2]})
    cfg = load_ident_config(packaged_config("smallsat39"))
    assert cfg.nonlinearities[0].coefficient_names == ("NC2-Z:neg", "NC2-Z:pos")
    assert cfg.driving_points == {"F-NC2W-Z": "NC2W-Z"} and not cfg.d_zero_for("displacement")
    assert load_ident_config(packaged_config("smallsat3")).outputs == ("NC2W-Z", "NC2B-Z", "WHEEL-Z")


def test_unknown_format(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("1,2\n")
    with pytest.raises(IdentDataError, match="unknown format"):
        load_input(p)


def test_mcap_recording_end_to_end(tmp_path, capsys):
    """fnsi-lab acquire (packaged lumped experiment) -> MCAP -> fnsi-lab ident."""
    pytest.importorskip("fnsi_lab.daq.recording.reader")
    rec = tmp_path / "lumped.mcap"
    assert main(["acquire", "--config", "lumped.yaml", "--out", str(rec), "--quiet", "--no-info"]) == 0
    cfg = tmp_path / "ident.yaml"
    # no transient_periods / samples_per_period: they come from the recording's metadata
    # and no truth: it comes from the simulated recording (element named like the simulator's)
    cfg.write_text(CONFIG.replace("transient_periods: 1\n", "").replace("    truth: 1.0e9\n", "")
                   .replace("name: knl", "name: X2-X3-cubic"))
    out = tmp_path / "res.json"
    assert main(["ident", str(rec), "--config", str(cfg), "--json", str(out), "--quiet"]) == 0
    res = json.loads(out.read_text())
    assert res["n_realizations"] == 2 and res["n_periods"] == 2  # lumped.yaml: 2 x (4 - 2)
    assert res["weighted"] is True  # P = 2 periods give a noise covariance
    # 5 N RMS, 1 kHz: measured -0.03 % (mean) and +0.002 % (LS)
    assert abs(res["coefficients"][0]["error_percent"]) < 0.5
