"""Experiment YAML: typed objects on success, one clear message (file, field, fix) on failure."""

import subprocess
import sys
import textwrap

import pytest

from fnsi_lab.daq.config import load_experiment, parse_experiment
from fnsi_lab.errors import ConfigError

GOOD = """
name: bench
sample_rate_hz: 1000
output: out.mcap
source: {kind: simulated, options: {model: lumped}}
excitation:
  band_hz: [5, 50]
  rms: 10
  samples_per_period: 1024
  periods: 3
  transient_periods: 1
  realizations: 2
  seed: 7
channels:
  - {name: F, quantity: force, unit: N, node: n1, direction: Z}
  - {name: y1, quantity: acceleration, node: n1, direction: Z, sensitivity: 0.01}
"""


def _write(tmp_path, text, name="exp.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_good_config_is_typed(tmp_path):
    cfg = load_experiment(_write(tmp_path, GOOD))
    assert cfg.sample_rate_hz == 1000.0 and cfg.source.kind == "simulated"
    assert cfg.source.options == {"model": "lumped"}
    ex = cfg.excitation
    assert ex.band_hz == (5.0, 50.0) and ex.samples_per_period == 1024 and ex.periods == 3
    assert ex.transient_periods == 1 and ex.realizations == 2 and ex.seed == 7
    assert [c.name for c in cfg.channels] == ["F", "y1"]
    assert cfg.channels[1].unit == "m/s^2"  # SI default for the quantity
    assert cfg.channels[1].sensitivity == 0.01
    assert "rms: 10" in cfg.text


@pytest.mark.parametrize("change, field, words", [
    (("rms: 10", "rms: 10\n  rmss: 3"), "excitation.rmss", "did you mean 'rms'"),
    (("band_hz: [5, 50]", "band_hz: [5, 600]"), "excitation.band_hz", "Nyquist"),
    (("band_hz: [5, 50]", "band_hz: [50, 5]"), "excitation.band_hz", "increasing"),
    (("samples_per_period: 1024", "samples_per_period: 0"), "excitation.samples_per_period", ">= 1"),
    (("samples_per_period: 1024", "samples_per_period: many"), "excitation.samples_per_period", "whole number"),
    (("transient_periods: 1", "transient_periods: 3"), "excitation.transient_periods", "transient"),
    (("name: y1", "name: F"), "channels[1].name", "duplicate"),
    (("quantity: acceleration", "quantity: accel"), "channels[1].quantity", "acceleration"),
    (("kind: simulated", "kind: simulatd"), "source.kind", "simulated"),
    (("sample_rate_hz: 1000", "sample_rate_hz: -1"), "sample_rate_hz", "> 0"),
    (("output: out.mcap", "outptu: out.mcap"), "outptu", "output"),
])
def test_bad_values_name_file_field_and_fix(tmp_path, change, field, words):
    path = _write(tmp_path, GOOD.replace(*change))
    with pytest.raises(ConfigError) as info:
        load_experiment(path)
    err = info.value
    assert err.field == field
    assert str(path) in str(err)
    assert words in str(err)


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_experiment(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="not valid YAML at line"):
        load_experiment(_write(tmp_path, "a: [1, 2\nb: 3\n"))
    with pytest.raises(ConfigError, match="expected a mapping"):
        parse_experiment(["not", "a", "mapping"], file="x.yaml")
    with pytest.raises(ConfigError, match="missing required field"):
        parse_experiment({"sample_rate_hz": 100}, file="x.yaml")


def test_cli_bad_config_is_one_line_without_traceback(tmp_path):
    path = _write(tmp_path, GOOD.replace("rms: 10", "rms: -10"))
    proc = subprocess.run([sys.executable, "-m", "fnsi_lab", "acquire", "--config", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "excitation.rms" in lines[0] and "> 0" in lines[0]
    proc = subprocess.run([sys.executable, "-m", "fnsi_lab", "acquire", "--config",
                           str(tmp_path / "missing.yaml")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "file not found" in proc.stderr
