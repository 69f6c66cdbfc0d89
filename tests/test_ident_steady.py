"""Periods not in steady state (ident.core.steady): measured, chosen, reported."""

from __future__ import annotations

import numpy as np

import fnsi_lab
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sim import lumped_model, simulate
from fnsi_lab.daq.sim.model import modal_decomposition
from fnsi_lab.ident.core.steady import select_steady_periods

FS, N = 256.0, 1024


def ringing_periods(P=8, decay=0.4, noise=1e-3, seed=0):
    """(1, P, N, 2): one steady period repeated, plus a transient decaying by ``decay`` per
    period and white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    steady = np.stack([np.sin(2 * np.pi * 10 * t) + 0.3 * np.sin(2 * np.pi * 23 * t),
                       np.cos(2 * np.pi * 17 * t)], axis=1)
    ring = np.stack([np.sin(2 * np.pi * 12.3 * t)] * 2, axis=1)
    y = np.stack([steady + (decay ** j if decay else 0.0) * ring + noise * rng.standard_normal(steady.shape)
                  for j in range(P)])
    return y[None]


def test_leading_transient_periods_are_left_out():
    sel = select_steady_periods(ringing_periods(decay=0.4))
    # the ringing is 1 / 0.4 / 0.16 / 0.064 / 0.026 / 0.010 of the steady RMS (~0.8): periods
    # above 1 % off the settled ones go, at most half of the record
    assert sel.dropped == (0, 1, 2, 3)
    assert sel.used == (4, 5, 6, 7)
    assert sel.deviation[0] > 0.5 and sel.floor < 0.02
    assert sel.drift.shape == (7,) and sel.drift[0] > sel.drift[-1]
    d = sel.to_dict()
    assert d["used"] == [5, 6, 7, 8] and d["dropped"] == [1, 2, 3, 4]
    assert "left out as not steady" in d["statement"]


def test_noise_or_steady_data_keep_every_period():
    # noise alone (1 %) and a transient already gone: nothing dropped, numbers unchanged
    for y in (ringing_periods(decay=0.0, noise=1e-2), ringing_periods(decay=1e-4)):
        sel = select_steady_periods(y, 1)
        assert sel.dropped == () and sel.used == tuple(range(1, 8))
    # a difference that does not decay (stick-slip): kept, and said
    y = ringing_periods(decay=0.0, noise=0.05)
    sel = select_steady_periods(y)
    assert sel.dropped == () and "no decay" in sel.statement
    assert select_steady_periods(ringing_periods(), select=False).dropped == ()


def test_identification_uses_the_steady_periods_and_says_so():
    """A lightly damped chain recorded from rest: the leading periods still ring. Averaged
    with them the damping ratios came out +3 % to +22 % (the free decay is taken for
    response); with them left out within 0.5 % of the truth (1e-3 output noise)."""
    ms = multisine(N, FS, (3, 60), 5.0, n_periods=8, seed=3)
    u = ms.signal[0][:, None]
    model = lumped_model("none", mass_damping=0.3, stiffness_damping=2e-5, dashpot=0.5)
    truth = modal_decomposition(model)
    y = simulate(model, u, FS, quantities=("displacement",)).displacement
    y = y + 1e-3 * y.std(axis=0) * np.random.default_rng(0).standard_normal(y.shape)
    arrays = {"u": u, "y": y, "fs": FS, "N": N, "channels": np.array(["X1", "X2", "X3"]),
              "input_channels": np.array(["F"])}
    errors = {}
    for choice in ("auto", "all"):
        r = fnsi_lab.identify(arrays, {"band_hz": [3, 60], "steady_periods": choice}, order=6)
        zeta = np.array([m["damping_ratio"] for m in r.modes])
        assert zeta.size == 3
        errors[choice] = np.max(np.abs(zeta / truth.damping_ratio - 1))
        doc = r.to_json()
        assert doc["periods"]["used"][-1] == 8
    assert doc["periods"]["used"] == list(range(1, 9))          # 'all'
    assert errors["auto"] < 0.01 < errors["all"]
