"""Order selection with the coefficient-consistency gate, MDL, the detection test, and the
basis-function interpolation, on the project's own simulators (generated in the tests)."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.ident.robust import auto
from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.robust import order_selection as osel
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.coefficients import (coefficient_spread, nonlinear_coefficients, spread_function,
                                summarize_coefficients)
from fnsi_lab.ident.robust.mdi import modal_detection
from fnsi_lab.ident.core.periodic import interpolate_periodic, prepare_frequency_data


# ---------------------------------------------------------------------------- pure functions
def test_select_order_consistent_is_argmin_over_the_gate():
    orders = [2, 4, 6, 8, 10]
    ic = np.array([1.0, 0.1, 0.05, 0.02, 0.01])
    stable = np.array([True, True, True, True, False])
    rho = np.array([0.5, 0.01, 0.004, 0.2, 0.003])
    n, gate = osel.select_order_consistent(orders, ic, stable, rho, spread_factor=3.0)
    # best rho among stable orders 0.004 -> gate 0.012: orders 4 and 6; argmin I there = 6
    assert n == 6 and gate.tolist() == [False, True, True, False, False]
    # without any usable rho it is plain argmin I over the stable orders
    n2, gate2 = osel.select_order_consistent(orders, ic, stable, np.full(5, np.nan))
    assert n2 == 8 and not gate2.any()


def test_the_gate_only_chooses_among_orders_that_explain_the_data():
    """A coefficient consistent only at an order whose model error is far above that at the
    criterion's order is the basis column standing in for missing modes (aircraft-like GVT,
    26 N, a cubic spring: order 3 against 31, V 22x, one mode of nine, "identified")."""
    orders = [3, 10, 20, 31, 40]
    v = np.array([0.55, 0.20, 0.03, 0.021, 0.02])           # relative model error V(n)
    ic = v * np.array([1.0, 1.1, 1.5, 2.0, 2.6])          # argmin I at 31
    stable = np.ones(5, bool)
    rho = np.array([0.13, 12.0, 14.0, 19.0, 30.0])        # consistent at 3 only
    n, _ = osel.select_order_consistent(orders, ic, stable, rho, spread_factor=3.0)
    assert n == 3                                         # without the model error
    n, gate = osel.select_order_consistent(orders, ic, stable, rho, spread_factor=3.0,
                                           model_error=v)
    # admissible: V <= 2 x 0.021 (orders 20, 31, 40); min rho there 14 -> gate 42: all
    # three; argmin I among them = 31, the criterion's own order
    assert n == 31 and gate.tolist() == [False, False, True, True, True]
    # an order that explains the data as well keeps the gate's choice (the SmallSat case)
    v_flat = np.array([0.03, 0.025, 0.022, 0.021, 0.02])
    n, _ = osel.select_order_consistent(orders, ic, stable, rho, spread_factor=3.0,
                                        model_error=v_flat)
    # (every order within 2x of V at 31: the gate picks 3 as before)
    assert n == 3
    # noise-free: V decades apart but all far below 1 % of the output (the 3-channel
    # SmallSat: 1e-6 to 2e-8): the gate still moves the order
    v_tiny = np.array([1e-6, 5e-7, 1e-7, 2e-8, 1e-8])
    n, _ = osel.select_order_consistent(orders, v_tiny, stable, rho, spread_factor=3.0,
                                        model_error=v_tiny)
    assert n == 3


def test_mdl_penalty_grows_with_the_parameter_count():
    v = np.full(3, 1e-6)
    n = np.array([10, 30, 60])
    i_seed = osel.information_criterion(v, n, 2000)
    i_mdl = osel.information_criterion(v, n, 2000, criterion="mdl", n_outputs=3,
                                       n_extended_inputs=3)
    # seed: 1 + n/F (0.5 % to 3 %); MDL: exp(n_theta ln(N_r)/N_r), N_r = 12000
    assert np.allclose(i_seed, 1e-6 * (1 + n / 2000))
    ntheta = n * 6 + 9
    assert np.allclose(i_mdl, 1e-6 * np.exp(ntheta * np.log(12000) / 12000))
    # from n = 10 to 60: +26 % (MDL) against +2.5 % (seed)
    assert i_mdl[2] / i_mdl[0] > 1.2 > 1.05 > i_seed[2] / i_seed[0]


def test_coefficient_spread_is_zero_for_a_real_constant_and_grows_with_departure():
    from fnsi_lab.ident.core.coefficients import CoefficientSpectra
    rng = np.random.default_rng(0)
    den = (rng.standard_normal(200) + 1j * rng.standard_normal(200))[:, None, None]
    exc = np.ones(200, bool)

    def spectra(num):
        return CoefficientSpectra(names=("c",), frequencies_hz=np.arange(200.0),
                                  values=(-num / den)[:, 0], numerator=num, denominator=den,
                                  excited=exc)
    c = 2.5e4
    assert coefficient_spread(spectra(-c * den))[0] < 1e-14
    noise = 1e-2 * c * (rng.standard_normal(den.shape) + 1j * rng.standard_normal(den.shape))
    rho = coefficient_spread(spectra(-c * den + noise * np.abs(den)))[0]
    # |den|-weighted relative RMS of a 1 % complex departure: sqrt(2) * 1e-2 * rms|den|^2/..
    assert 0.005 < rho < 0.05


def test_modal_detection_separates_a_mode_from_noise():
    fs, N = 100.0, 1000
    lines = np.arange(10, 300)
    f = lines * fs / N
    z = np.exp(2j * np.pi * lines / N)
    lam = np.array([-2 * np.pi * 12 * 0.02 + 2j * np.pi * 12, -2 * np.pi * 25 * 0.02 + 2j * np.pi * 25])
    lam = np.r_[lam, lam.conj()]
    mu = np.exp(lam / fs)
    c = np.array([[1.0, 1e-4, 1.0, 1e-4]], complex)     # the 25 Hz pair barely seen
    b = np.ones((4, 1), complex)
    E = np.ones((lines.size, 1), complex)
    Y_model = (E @ b.T / (z[:, None] - mu[None, :])) @ c.T
    rng = np.random.default_rng(1)
    noise = 1e-3 * np.abs(Y_model).max() * (rng.standard_normal(Y_model.shape)
                                           + 1j * rng.standard_normal(Y_model.shape))
    d = modal_detection(mu, c, b, E, z, Y_model + noise, Y_model, f, [(0, 2), (1, 3)],
                        np.array([12.0, 25.0]), np.array([0.02, 0.02]))
    # the 12 Hz mode stands ~1e5 sigmas out; the 25 Hz one carries 1e-8 of its energy,
    # below the noise in its band (d << 3)
    assert d[0] > 1e3 and d[1] < 3


# ---------------------------------------------------------------------------- data preparation
def test_interpolate_periodic_is_exact_for_band_limited_signals():
    N, r = 64, 8
    t = np.arange(N) / N
    x = np.c_[np.sin(2 * np.pi * 3 * t), np.cos(2 * np.pi * 7 * t + 0.3)]
    xi = interpolate_periodic(x, r)
    tf = np.arange(N * r) / (N * r)
    ref = np.c_[np.sin(2 * np.pi * 3 * tf), np.cos(2 * np.pi * 7 * tf + 0.3)]
    assert xi.shape == (N * r, 2) and np.max(np.abs(xi - ref)) < 1e-13
    assert np.max(np.abs(xi[::r] - x)) < 1e-13


def test_basis_oversampling_lowers_the_aliasing_floor_of_a_stop():
    """Relative two-sided stop of the 3-DOF chain sampled at 256 Hz: the kink's content
    aliases onto the processed lines unless h_a is evaluated between the samples."""
    sim = pytest.importorskip("fnsi_lab.daq.sim")
    from fnsi_lab.daq.multisine import excited_lines, multisine
    fs, N = 256.0, 4096
    model = sim.lumped_model("trilinear")
    u = np.asarray(multisine(N, fs, (5, 60), 12.0, n_periods=4, seed=2).signal).reshape(-1, 1)
    y = sim.simulate(model, u, fs, periodic=N, quantities=("displacement",)).displacement
    el = model.nonlinearities[0]
    nl = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=el.clearances,
                      truth=(el.coefficients["neg"], el.coefficients["pos"]))
    err, v = {}, {}
    for os_ in (1, 8):
        data = prepare_frequency_data(u=u, y=y, sample_rate_hz=fs, samples_per_period=N,
                                      basis=[nl], band_hz=(3, 120), transient_periods=2,
                                      output_names=model.measured_names,
                                      input_names=model.input_names, basis_oversample=os_,
                                      excited_lines=excited_lines(N, fs, (5, 60)))
        assert data.noise_cov is None  # noise-free periods: no weighting (ident.core.noise)
        dec = fnsi.subspace_decomposition(data, max_order=12)
        errs, vs = [], []
        for n in (6, 8, 10):
            mdl = fnsi.model_at_order(dec, data, n)
            s = summarize_coefficients(nonlinear_coefficients(mdl, data, [nl], driving_point="X3"))
            errs.append(max(abs(c.error_percent) for c in s))
            vs.append(osel.relative_model_error(data.Y, fnsi.steady_state_output(mdl, data)))
        err[os_], v[os_] = max(errs), min(vs)
    # measured (worst of orders 6, 8, 10 and of the two stops): 2.7 % at the samples, 0.17 %
    # on the 8x interpolation; model error floor 1.1e-4 against 1.4e-7 (800x). Require 5x,
    # 100x and a coefficient well inside 1 %. (Before the record-resolution floor the two
    # noise-free periods were weighted by their round-off spread: 4-20 % at the samples,
    # V 3.4e-4; one period, unweighted, gives the numbers above.)
    assert err[8] < 0.2 * err[1]
    assert v[8] < 0.01 * v[1]
    assert err[8] < 0.3


# ---------------------------------------------------------------------------- the SmallSat, 3 channels
@pytest.mark.slow
def test_three_channel_smallsat_order_selection_keeps_the_coefficients_physical():
    """The regression that motivated the gate: with 3 channels the seed's argmin I went to
    high orders where c_NC2 was -100 %. The selected order must give the paper's accuracy."""
    pytest.importorskip("fnsi_lab.daq.sim")
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.integrate import simulate
    from fnsi_lab.daq.sim.smallsat import DEFAULT_CLEARANCES, NC2Z_CONTACT, smallsat_model
    model = smallsat_model()
    fs, N = 1000.0, 8192
    u = np.asarray(multisine(N, fs, (5, 50), 100.0, n_periods=6, seed=1).signal[0], float)
    y = simulate(model, u[:, None], fs, periodic=N, quantities=("displacement",)).displacement
    names = tuple(model.measured)
    chans = ["NC2W-Z", "NC2B-Z", "WHEEL-Z"]
    y3 = y[:, [names.index(c) for c in chans]]
    nl = Nonlinearity("NC2-Z", "trilinear", {"NC2W-Z": 1, "NC2B-Z": -1},
                      clearances=tuple(DEFAULT_CLEARANCES["NC2-Z"]),
                      truth=(NC2Z_CONTACT["neg"], NC2Z_CONTACT["pos"]))
    data = prepare_frequency_data(u=u, y=y3, sample_rate_hz=fs, samples_per_period=N,
                                  basis=[nl], band_hz=(5, 250), transient_periods=5,
                                  output_names=chans, input_names=("F-NC2W-Z",))
    spread = spread_function(data, [nl], driving_point="NC2W-Z")
    res = auto.identify_auto(data, orders=range(2, 61), spread=spread)
    summ = summarize_coefficients(nonlinear_coefficients(res.final_model, data, [nl],
                                                         driving_point="NC2W-Z"))
    # the paper's errors at its best order: 0.34 % / 0.10 %; measured here ~0.02 %
    assert all(abs(c.error_percent) < 0.34 for c in summ)
    # the gate mattered: the seed's formula alone lands on an order with a large spread
    seed_vals = np.array([e["seed_value"] if e["seed_value"] is not None else np.inf
                          for e in res.information_criterion.to_list()])
    assert res.order_selection == "consistent"
    assert res.consistent[list(res.information_criterion.orders).index(res.selected_order)]
    assert np.isfinite(seed_vals).any()


def test_noisy_accelerations_integrate_only_the_lines_above_the_noise():
    """40 dB white noise on the accelerations of the cubic chain (6 periods averaged): the
    double integration for the basis function blows up the noise of the lines below the
    excitation unless those lines are dropped (ident.core.periodic.noise_gain)."""
    sim = pytest.importorskip("fnsi_lab.daq.sim")
    from fnsi_lab.daq.multisine import excited_lines, multisine
    fs, N = 512.0, 4096
    model = sim.lumped_model("cubic")
    u = np.asarray(multisine(N, fs, (5, 60), 20.0, n_periods=10, seed=1).signal).reshape(-1, 1)
    res = sim.simulate(model, u, fs, periodic=N)
    offset = float(np.mean(res.displacement[-N:, 1] - res.displacement[-N:, 2]))
    nl = Nonlinearity("knl", "polynomial", {"X2": 1, "X3": -1}, exponent=3, truth=(1e9,),
                      offset=offset)
    y = res.acceleration + (np.random.default_rng(0).standard_normal(res.acceleration.shape)
                            * np.std(res.acceleration[-N:], axis=0) * 1e-2)
    err = {}
    for snr in (4.0, None):
        data = prepare_frequency_data(u=u, y=y, sample_rate_hz=fs, samples_per_period=N,
                                      basis=[nl], band_hz=(3, 150), transient_periods=4,
                                      output_names=model.measured_names,
                                      input_names=model.input_names,
                                      output_quantity="acceleration", integration_min_snr=snr,
                                      excited_lines=excited_lines(N, fs, (5, 60)))
        r = auto.identify_auto(data, orders=range(2, 31),
                               spread=spread_function(data, [nl], driving_point="X3"))
        (s,) = summarize_coefficients(nonlinear_coefficients(r.final_model, data, [nl],
                                                             driving_point="X3"))
        err[snr] = abs(s.error_percent)
    # measured over 5 noise seeds: 1.0-4.7 % (median 2.4 %) with the mask, 80-99 % without
    assert err[4.0] < 10.0
    assert err[None] > 30.0
