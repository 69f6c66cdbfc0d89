"""excitation.levels: one recording per force level (``fnsi-lab acquire`` level sweep)."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.cli import main
from fnsi_lab.daq.config import parse_experiment
from fnsi_lab.daq.recording.reader import open_recording
from fnsi_lab.errors import ConfigError

SWEEP = """\
name: stop-sweep
sample_rate_hz: 1000
source:
  kind: simulated
  options: {model: lumped, lumped: {variant: trilinear}, verify: false}
excitation:
  band_hz: [5, 50]
  levels: [0.5, 4.0]
  samples_per_period: 1024
  periods: 3
  transient_periods: 1
"""


def _experiment(levels):
    import yaml

    data = yaml.safe_load(SWEEP)
    data["excitation"]["levels"] = levels
    return parse_experiment(data, file="sweep.yaml")


def test_levels_parse_and_runs(tmp_path):
    config = _experiment([0.5, 4.0])
    assert config.excitation.levels == (0.5, 4.0)
    assert config.excitation.rms == 0.5  # the first level when rms is not given
    runs = config.level_runs(tmp_path)
    assert [level for level, _ in runs] == [0.5, 4.0]
    assert [run.excitation.rms for _, run in runs] == [0.5, 4.0]
    assert all(run.excitation.levels == () for _, run in runs)
    assert runs[1][1].output == str(tmp_path / "stop-sweep-rms4.mcap")
    assert parse_experiment(__import__("yaml").safe_load(SWEEP.replace("  levels: [0.5, 4.0]\n",
                                                                       "  rms: 2\n")),
                            file="x.yaml").level_runs(tmp_path) == []


@pytest.mark.parametrize("levels, field", [([1.0, -2.0], "levels"), ([1.0, 1.0], "levels"),
                                           (["a"], "levels")])
def test_bad_levels_name_the_field(levels, field):
    with pytest.raises(ConfigError) as info:
        _experiment(levels)
    assert info.value.field == f"excitation.{field}" and info.value.file == "sweep.yaml"


def test_acquire_records_one_file_per_level(tmp_path, capsys):
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SWEEP)
    folder = tmp_path / "campaign"
    assert main(["acquire", "--config", str(cfg), "--out", str(folder), "--quiet"]) == 0
    files = sorted(folder.glob("*.mcap"))
    assert [f.name for f in files] == ["stop-sweep-rms0.5.mcap", "stop-sweep-rms4.mcap"]
    forces = {}
    for f in files:
        rec = open_recording(f)
        level = rec.excitation["rms"]
        force_col = [i for i, c in enumerate(rec.channels) if c.quantity == "force"][0]
        force = rec.read_samples()[:, force_col]
        # the recorded force has the requested RMS (the multisine is scaled exactly)
        assert np.sqrt(np.mean(force ** 2)) == pytest.approx(level, rel=1e-6)
        forces[level] = force
    # same phases at every level: the signals differ by the level ratio only
    np.testing.assert_allclose(forces[4.0], forces[0.5] * 8.0, rtol=1e-9, atol=1e-12)
    # a second run refuses to overwrite the campaign, before recording anything
    mtime = files[0].stat().st_mtime_ns
    assert main(["acquire", "--config", str(cfg), "--out", str(folder), "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err
    assert files[0].stat().st_mtime_ns == mtime
