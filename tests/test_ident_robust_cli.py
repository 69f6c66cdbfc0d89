"""``fnsi-lab ident --auto`` (hooks in ident.robust.auto called by the core's ident.cli)."""

import json

import numpy as np
import pytest

from fnsi_lab.cli import main
from fnsi_lab.ident.robust import auto
from fnsi_lab.ident.errors import IdentError

YAML = """\
band_hz: [3, 150]
transient_periods: 1
output_quantity: displacement
weighting: none
inputs:
  - {name: F-X3, driving_point: X3}
nonlinearities:
  - name: knl
    kind: polynomial
    exponent: 3
    channels: {X2: 1, X3: -1}
    truth: 1.0e9
auto:
  mdi_norm: h2
  min_physical: 1
"""


@pytest.fixture(scope="module")
def lumped_npz(tmp_path_factory):
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.integrate import simulate
    from fnsi_lab.daq.sim.lumped import lumped_model
    m = lumped_model("cubic")
    ms = multisine(4096, 500.0, (3, 60), 20.0, n_periods=2, seed=1)
    r = simulate(m, ms.signal[0][:, None], 500.0, periodic=4096, quantities=("displacement",))
    d = tmp_path_factory.mktemp("auto")
    path = d / "lumped.npz"
    np.savez(path, u=ms.signal[0][:, None], y=r.displacement, fs=500.0, N=4096,
             channels=np.array(list(m.measured)), input_channels=np.array(["F-X3"]))
    (d / "ident.yaml").write_text(YAML)
    return path, d / "ident.yaml"


def test_cli_auto_writes_json(lumped_npz, tmp_path, capsys):
    npz, cfg = lumped_npz
    out = tmp_path / "out.json"
    rc = main(["ident", str(npz), "--config", str(cfg), "--auto", "--orders", "2:16",
               "--reduce-at", "14", "--json", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    for key in ("information_criterion", "selected_order", "stabilisation", "mdi",
                "separation_ratio", "confidence", "reduced", "selected_model"):
        assert key in d
    assert d["mdi_order"] == 14
    # the three lumped modes (8.2, 22.5, 30.7 Hz) are the physical ones
    phys = sorted(r["frequency_hz"] for r in d["mdi"] if r["physical"])
    np.testing.assert_allclose(phys, [8.239, 22.508, 30.744], rtol=2e-3)
    assert "confidence" in capsys.readouterr().out
    # the answer, with the single-order result's keys (docs/robust.md, JSON)
    assert d["final"] in ("reduced", "full")
    assert d["order"] == (d["reduced"]["order"] if d["final"] == "reduced" else 14)
    np.testing.assert_allclose(sorted(m["frequency_hz"] for m in d["modes"]), phys)
    assert {"frequency_hz", "damping_ratio", "stable", "physical"} <= set(d["poles"][0])
    (knl,) = d["coefficients"]
    # noise-free simulated cubic chain: measured ~0.01 %; 0.5 % leaves room for other BLAS builds
    assert knl["name"] == "knl" and abs(knl["error_percent"]) < 0.5
    assert {"ic_order", "order_selection", "coefficient_spread"} <= set(d)
    assert all(e["seed_value"] is None or e["seed_value"] > 0 for e in d["information_criterion"])


def test_cli_bad_auto_section(lumped_npz, tmp_path, capsys):
    npz, cfg = lumped_npz
    bad = tmp_path / "bad.yaml"
    bad.write_text(cfg.read_text().replace("mdi_norm: h2", "mdi_norm: l7"))
    rc = main(["ident", str(npz), "--config", str(bad), "--auto"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "auto" in err and "mdi_norm" in err


def test_parse_orders_one_syntax_everywhere():
    assert auto.parse_orders("2:60") == list(range(2, 61))
    assert auto.parse_orders("4:20:2") == list(range(4, 21, 2))
    assert auto.parse_orders("8,4,6") == [4, 6, 8] and auto.parse_orders("10") == [10]
    for bad in ("10:2", "x", "0:4", "2:4:0", ""):
        with pytest.raises(IdentError):
            auto.parse_orders(bad)
