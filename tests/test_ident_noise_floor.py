"""Noise estimates below the record resolution are not noise (ident.core.noise.resolution_variance).

Regression: the simulated SmallSat with 2-8 noise-free steady periods was weighted by the
period-to-period spread, which there is round-off and residual transient (1e-31 to 1e-19 of
the signal power across the channels); NC2-Z moved from -0.001 % (one period) to +0.09 %
and 2 of 10 modes were lost (bench/RESULTS.md, Scaling, 'periods').
"""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.ident.core.noise import RESOLUTION_BITS, resolution_variance
from fnsi_lab.ident.core.periodic import floor_noise, prepare_frequency_data

FS, N = 256.0, 1024


def _periodic(P: int, noise: np.ndarray, seed: int = 0):
    """One force, three outputs (a filtered copy of it), P identical periods + white noise
    of std ``noise[c]`` (relative to each output's RMS) on output c."""
    rng = np.random.default_rng(seed)
    k = np.arange(5, 60)
    spec = np.zeros(N // 2 + 1, complex)
    spec[k] = np.exp(2j * np.pi * rng.random(k.size))
    u = np.fft.irfft(spec, N)
    u /= np.sqrt(np.mean(u ** 2))
    f = np.arange(N // 2 + 1) * FS / N
    H = np.stack([1.0 / (1 + 1j * f / fc) for fc in (10.0, 20.0, 40.0)], axis=1)
    y = np.fft.irfft(np.fft.rfft(u)[:, None] * H, N, axis=0)
    y = np.tile(y, (P, 1))
    y += rng.standard_normal(y.shape) * np.sqrt(np.mean(y ** 2, axis=0)) * noise
    return np.tile(u, P)[:, None], y


def _data(P, noise, **kw):
    u, y = _periodic(P, np.asarray(noise, float))
    return prepare_frequency_data(u=u, y=y, sample_rate_hz=FS, samples_per_period=N,
                                  band_hz=(1.0, 100.0), steady_state_tolerance=10.0, **kw), y


def test_resolution_variance_is_24_bit_quantisation_per_line():
    # step q = 2 peak / 2^24, white: q^2/12 per sample, / N per line of the DFT / N
    assert RESOLUTION_BITS == 24
    v = resolution_variance(np.array([1.0, 2.0]), 1000)
    q = 2.0 / 2 ** 24
    assert v == pytest.approx([q ** 2 / 12 / 1000, 4 * q ** 2 / 12 / 1000], rel=1e-12)


def test_noise_free_periods_give_no_weighting():
    # identical periods: no spread at all (a simulation's is round-off and residual
    # transient, far below a 24-bit record's resolution)
    data, y = _data(4, [0.0, 0.0, 0.0])
    assert data.noise_source == "periods" and data.n_periods == 4
    assert data.noise_cov is None                        # nothing to weight with
    assert not data.noise_resolved.any()
    floor = resolution_variance(np.max(np.abs(y), axis=0), N)
    assert np.allclose(data.noise_var, floor[None, :], rtol=1e-12)  # held at the resolution


def test_noisy_periods_are_untouched_and_a_clean_channel_is_floored(monkeypatch):
    # 80 dB below the RMS on every output: 1e3-1e4 times the floor, kept bit for bit
    import fnsi_lab.ident.core.periodic as periodic
    noisy, _ = _data(4, [1e-4, 1e-4, 1e-4])
    assert noisy.noise_resolved.all()
    with monkeypatch.context() as m:
        m.setattr(periodic, "floor_noise", lambda n, v, f: (n, v, None))
        raw, _ = _data(4, [1e-4, 1e-4, 1e-4])
    assert np.array_equal(noisy.noise_cov, raw.noise_cov)
    assert np.array_equal(noisy.noise_var, raw.noise_var)
    # one noise-free output among noisy ones: its variance is raised to the floor, the
    # others (and every cross term) keep their estimate; the weighting stays on
    mixed, y = _data(4, [1e-4, 0.0, 1e-4])
    assert mixed.noise_resolved.tolist() == [True, False, True]
    assert mixed.noise_cov is not None
    floor = resolution_variance(np.max(np.abs(y), axis=0), N)
    cov = mixed.noise_cov
    assert np.allclose(np.real(cov[:, 1, 1]), floor[1], rtol=1e-12)
    assert np.all(np.real(cov[:, 0, 0]) > 100 * floor[0])
    assert np.allclose(mixed.noise_var[:, 1], floor[1], rtol=1e-12)


def test_variances_only_are_floored_the_same_way():
    var = np.array([[1e-20, 1e-6], [2e-20, 3e-6]])            # (F, p) variances
    out, v, ok = floor_noise(var.copy(), var.copy(), np.array([1e-16, 1e-12]))
    assert ok.tolist() == [False, True]
    assert np.allclose(out[:, 0], 1e-16) and np.array_equal(out[:, 1], var[:, 1])
    out, v, ok = floor_noise(var.copy(), var.copy(), np.array([1e-16, 1e-3]))
    assert out is None and not ok.any() and np.allclose(v, [[1e-16, 1e-3], [1e-16, 1e-3]])


def test_one_period_is_unchanged():
    data, _ = _data(1, [0.0, 0.0, 0.0])
    assert data.noise_cov is None and data.noise_var is None and data.noise_resolved is None


def test_smallsat_noise_free_periods_identify_like_one_period():
    """The regression end to end: the 3-channel SmallSat (packaged smallsat3), noise-free,
    3 steady periods against 1, at the config's order 10.

    The 3-period average differs from the single period only by the residual transient
    (steady_state_error 3e-10 of the RMS) and round-off, so the coefficients must agree
    far below their 0.004-0.04 % error against the truth: measured 8e-11 relative (both
    unweighted). Weighted by that spread (before the floor) they moved by -0.14 % / -0.14 %
    (116.56 / 88.32 N/mm against 116.72 / 88.44). Tolerance 1e-6: 1e4 above the measured
    agreement, 1e3 below the regression.
    """
    import fnsi_lab
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.integrate import simulate
    from fnsi_lab.daq.sim.smallsat import smallsat_model

    model = smallsat_model(nonlinear=True)
    n, tr = 8192, 5
    u = np.asarray(multisine(n, 1000.0, (5.0, 50.0), 100.0, n_periods=tr + 3,
                             seed=1).signal[0], float)
    y = simulate(model, u[:, None], 1000.0, periodic=n, quantities=("displacement",),
                 count_from=tr * n).displacement
    names = list(model.measured)
    res, data = {}, {}
    for P in (1, 3):
        arrays = {"u": u[: (tr + P) * n, None], "y": y[: (tr + P) * n], "fs": 1000.0, "N": n,
                  "channels": names, "input_channels": ["F-NC2W-Z"]}
        ident = fnsi_lab.identify(arrays, "smallsat3", order=10)
        res[P] = {c["name"]: c for c in ident.coefficients}
        data[P] = ident.data
    for name in ("NC2-Z:neg", "NC2-Z:pos"):
        one, three = res[1][name], res[3][name]
        assert three["mean_real"] == pytest.approx(one["mean_real"], rel=1e-6)
        assert three["value"] == pytest.approx(one["value"], rel=1e-6)
        assert abs(one["error_percent"]) < 0.1    # measured -0.004 % / +0.04 %
    assert data[3].n_periods == 3 and data[3].noise_source == "periods"
    assert data[3].noise_cov is None and not data[3].noise_resolved.any()


def test_weighting_noise_on_noise_free_periods_says_why():
    import fnsi_lab
    from fnsi_lab.ident.errors import IdentError
    u, y = _periodic(3, np.zeros(3))
    arrays = {"u": u, "y": y, "fs": FS, "N": N, "channels": ["a", "b", "c"],
              "input_channels": ["f"]}
    cfg = {"band_hz": [1.0, 100.0], "weighting": "noise", "steady_state_tolerance": 10.0}
    with pytest.raises(IdentError, match="below the resolution of a 24-bit record"):
        fnsi_lab.identify(arrays, cfg, order=2)
    cfg["weighting"] = "auto"  # the same data identify, unweighted
    assert fnsi_lab.identify(arrays, cfg, order=2).data.noise_cov is None


def test_report_says_the_data_are_noise_free():
    from fnsi_lab.ident.core.periodic import data_report
    data, _ = _data(4, [0.0, 0.0, 0.0])
    rep = data_report(data)["noise"]
    assert rep["source"] == "periods" and rep["below_resolution"] == ["y0", "y1", "y2"]
    assert "no fit weighting" in rep["statement"]
    mixed, _ = _data(4, [1e-4, 0.0, 1e-4])
    assert data_report(mixed)["noise"]["below_resolution"] == ["y1"]
    noisy, _ = _data(4, [1e-4, 1e-4, 1e-4])
    assert "below_resolution" not in data_report(noisy)["noise"]
