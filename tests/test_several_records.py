"""Several records of one structure identified together (`fnsi-lab ident A B C`,
`fnsi_lab.identify([A, B, C])`): the records are the realisations of one input, so one model
(one underlying linear model, one coefficient) answers for every level."""

import json

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.cli import main
from fnsi_lab.errors import FnsiLabError

CONFIG = """\
band_hz: [3, 60]
transient_periods: 1
output_quantity: displacement
inputs:
  - {name: F-X3, driving_point: X3}
nonlinearities:
  - {name: knl, kind: polynomial, exponent: 3, channels: {X2: 1, X3: -1}}
"""


@pytest.fixture(scope="module")
def levels(tmp_path_factory):
    """The 3-DOF chain with its relative cubic spring (k3 = 1e9 N/m^3) at 10 and 30 N RMS,
    other multisine phases per level, 3 periods of 4096 at 500 Hz, 60 dB noise."""
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.integrate import simulate
    from fnsi_lab.daq.sim.lumped import lumped_model

    m = lumped_model("cubic")
    d = tmp_path_factory.mktemp("levels")
    for k, rms in enumerate((10.0, 30.0)):
        ms = multisine(4096, 500.0, (3, 60), rms, n_periods=3, seed=k + 1)
        y = simulate(m, ms.signal[0][:, None], 500.0, periodic=4096,
                     quantities=("displacement",)).displacement
        y = y + 1e-3 * y.std(axis=0) * np.random.default_rng(k).standard_normal(y.shape)
        np.savez(d / f"l{k}.npz", u=ms.signal[0][:, None], y=y, fs=500.0, N=4096,
                 channels=np.array(list(m.measured)), input_channels=np.array(["F-X3"]))
    short = multisine(2048, 500.0, (3, 60), 10.0, n_periods=3, seed=9)
    np.savez(d / "short.npz", u=short.signal[0][:, None], y=np.zeros((short.signal[0].size, 3)),
             fs=500.0, N=2048, channels=np.array(list(m.measured)),
             input_channels=np.array(["F-X3"]))
    (d / "cubic.yaml").write_text(CONFIG)
    return d


def test_two_levels_give_one_model(levels, tmp_path, capsys):
    """Through the command line: both records are realisations of one identification; the
    cubic coefficient comes out within 1 % of the truth (60 dB noise: measured on each
    level alone within 0.1-0.3 %), the result names both records."""
    out = tmp_path / "both.json"
    assert main(["ident", str(levels / "l0.npz"), str(levels / "l1.npz"), "--config",
                 str(levels / "cubic.yaml"), "--order", "6", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["n_realizations"] == 2
    assert doc["input"] == f"{levels / 'l0.npz'} + {levels / 'l1.npz'}"
    (c,) = doc["coefficients"]
    assert c["value"] == pytest.approx(1.0e9, rel=0.01) and c["verdict"] == "identified"


def test_records_of_another_plan_are_refused(levels):
    """Another period length: one line naming the record and the fix, before any work."""
    with pytest.raises(FnsiLabError, match=r"short.npz: 3 periods of 2048 samples"):
        fnsi_lab.identify([str(levels / "l0.npz"), str(levels / "short.npz")],
                          str(levels / "cubic.yaml"), order=6)
