"""Generic simulator: basis functions, linear exactness, convergence, source behaviour."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fnsi_lab.daq.config import load_experiment
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.registry import make_source
from fnsi_lab.daq.sim.integrate import foh_coefficients, simulate
from fnsi_lab.daq.sim.lumped import lumped_model
from fnsi_lab.daq.sim.nonlinear import NonlinearElement
from fnsi_lab.daq.sim.source import SimulatedSource, model_from_mapping
from fnsi_lab.errors import ConfigError

FS = 1000.0
N = 2048


def _force(periods=3, rms=5.0, seed=1):
    return multisine(N, FS, (5, 50), rms, n_periods=periods, seed=seed).signal[0][:, None]


def test_basis_functions_match_docstring():
    x = np.array([-3.0, -1.0, -0.5, 0.0, 0.5, 2.0, 4.0])
    tri = NonlinearElement("t", "trilinear", [1.0, -1.0], {"neg": 2.0, "pos": 3.0},
                           clearances=(1.0, 2.0))
    h = tri.basis(x)
    np.testing.assert_array_equal(h[:, 0], [-2.0, 0, 0, 0, 0, 0, 0])    # x + g_neg if x < -g_neg
    np.testing.assert_array_equal(h[:, 1], [0, 0, 0, 0, 0, 0, 2.0])     # x - g_pos if x > g_pos
    np.testing.assert_array_equal(tri.force(x), 2.0 * h[:, 0] + 3.0 * h[:, 1])
    bil = NonlinearElement("b", "bilinear", [1.0], {"pos": 5.0}, clearances=(0.5,))
    np.testing.assert_array_equal(bil.basis(x)[:, 0], np.where(x > 0.5, x - 0.5, 0.0))
    sp = NonlinearElement("p", "polynomial", [1.0], {"k": 1.0}, exponent=2, signed=True)
    np.testing.assert_allclose(sp.basis(x)[:, 0], np.abs(x) * x)
    cub = NonlinearElement("c", "polynomial", [1.0], {"k": 1.0}, exponent=3)
    np.testing.assert_allclose(cub.basis(x)[:, 0], x ** 3)
    qd = NonlinearElement("q", "quadratic_damping", [1.0], {"c": 1.0})
    np.testing.assert_allclose(qd.basis(x, x)[:, 0], np.abs(x) * x)
    co = NonlinearElement("f", "coulomb", [1.0], {"f": 1.0}, regularization=0.1)
    np.testing.assert_allclose(co.basis(x, x)[:, 0], np.tanh(x / 0.1))


def test_element_validation_names_the_problem():
    with pytest.raises(ConfigError, match="clearance"):
        NonlinearElement("t", "trilinear", [1.0], {"neg": 1.0, "pos": 1.0}, clearances=(1.0,))
    with pytest.raises(ConfigError, match="coefficients"):
        NonlinearElement("t", "trilinear", [1.0], {"k": 1.0}, clearances=(1.0, 1.0))
    with pytest.raises(ConfigError, match="whole"):
        NonlinearElement("p", "polynomial", [1.0], {"k": 1.0}, exponent=2.5)


def test_foh_coefficients_small_and_large_mu():
    lam = np.array([-1e-6 + 1e-5j, -3.0 + 200.0j, -50.0 + 9000.0j])
    h = 1e-4
    e, g0, g1 = foh_coefficients(lam, h)
    # reference by fine quadrature of the defining integrals
    tau = np.linspace(0, h, 200001)
    for i, l in enumerate(lam):
        k = np.exp(l * (h - tau))
        np.testing.assert_allclose(g0[i], np.trapezoid(k * (1 - tau / h), tau), rtol=1e-8)
        np.testing.assert_allclose(g1[i], np.trapezoid(k * tau / h, tau), rtol=1e-8)
        np.testing.assert_allclose(e[i], np.exp(l * h), rtol=1e-14)


def test_linear_periodic_run_equals_frequency_domain_truth():
    """Linear model: after the transient, the output is H(jw) F(w) line by line.

    Tolerance 1e-6: the periodic linear part is computed exactly from the frequency
    domain; only the switch-on transient remains, decayed by exp(-sigma t) < 1e-6 after 4
    periods (asserted), plus round-off.
    """
    m = lumped_model("none")
    p = _force(periods=5)
    r = simulate(m, p, FS, oversample=4, periodic=N)
    f = np.arange(N // 2 + 1) * FS / N
    y_true = np.fft.irfft(m.frf(f)[:, :, 0] * np.fft.rfft(p[:N, 0])[:, None], n=N, axis=0)
    sigma = -m.modes.eigenvalues.real.max()
    assert np.exp(-sigma * 4 * N / FS) < 1e-6
    err = np.abs(r.displacement[4 * N:] - y_true).max() / np.abs(y_true).max()
    assert err < 1e-6


@pytest.mark.parametrize("variant", ["none", "trilinear"])
def test_general_force_path_matches_periodic_path(variant):
    """Non-periodic path (FIR upsampling + FOH, force inside the kernel) vs the exact
    periodic path, linear and with a stop.

    The polyphase FIR (scipy default Kaiser design) is flat to ~1e-4 in 5-50 Hz at 4x and
    the FOH error at 8x is ~2e-5, so 1e-3 relative bounds the difference with margin, yet
    catches a wrong scaling or a sign/one-sample shift (those give O(1) or >1e-2 errors).
    """
    m = lumped_model(variant)
    p = _force(periods=3)
    a = simulate(m, p, FS, oversample=8, periodic=N).displacement
    b = simulate(m, p, FS, oversample=8).displacement
    assert np.abs(a - b).max() / np.abs(a).max() < 1e-3


@pytest.mark.parametrize("variant", ["cubic", "trilinear", "duffing"])
def test_second_order_convergence_with_internal_rate(variant):
    """FOH on the nonlinear force is second order: halving h divides the error by ~4.

    Error measured against the 8x run; the ratio err(2x)/err(4x) must exceed 2.5 (first
    order would give 2, second 4; kinks at contact onsets lower it a little).
    """
    m = lumped_model(variant)
    p = _force(periods=2, rms=5.0)
    runs = {os_: simulate(m, p, FS, oversample=os_, periodic=N).displacement[N:]
            for os_ in (2, 4, 16)}
    ref = runs[16]
    e2 = np.abs(runs[2] - ref).max() / np.abs(ref).max()
    e4 = np.abs(runs[4] - ref).max() / np.abs(ref).max()
    assert e2 / e4 > 2.5
    assert e4 < 1e-3
    lin = simulate(m.linear(), p, FS, oversample=4, periodic=N).displacement[N:]
    # the nonlinearity must matter at this level, else the test would prove nothing
    assert np.abs(ref - lin).max() / np.abs(ref).max() > 0.05


def test_model_from_yaml_mapping_and_errors():
    data = {"dofs": ["A", "B"], "mass": [[1, 0], [0, 1]],
            "stiffness": [[2e4, -1e4], [-1e4, 1e4]], "damping": [[4, -1], [-1, 2]],
            "force_dofs": ["B"],
            "nonlinearities": [{"name": "s", "kind": "trilinear", "dofs": {"A": 1, "B": -1},
                                "coefficients": {"neg": 1e4, "pos": 1e4},
                                "clearances": [1e-4, 1e-4]}]}
    m = model_from_mapping(data, file="x.yaml")
    assert m.n_dof == 2 and m.input_names == ("F-B",)
    np.testing.assert_array_equal(m.nonlinearities[0].weights, [1.0, -1.0])
    bad = dict(data, stiffness=[[2e4, -1e4], [-2e4, 1e4]])
    with pytest.raises(ConfigError, match="symmetric") as ei:
        model_from_mapping(bad, file="x.yaml")
    assert "x.yaml" in str(ei.value) and "stiffness" in str(ei.value)
    bad = dict(data, force_dofs=["Z"])
    with pytest.raises(ConfigError, match="unknown DOF"):
        model_from_mapping(bad, file="x.yaml")


def test_lumped_source_blocks_and_reproducibility():
    cfg = load_experiment("lumped.yaml")
    exc = cfg.excitation
    with make_source(cfg) as src:
        assert isinstance(src, SimulatedSource)
        assert src.channels[0].quantity == "force"
        blocks = list(src)
    n_total = exc.samples_per_period * exc.periods
    per_real = [b for b in blocks if b.realization == 0]
    assert sum(b.n_samples for b in per_real) == n_total
    assert per_real[0].first_sample == 0 and per_real[-1].first_sample + per_real[-1].n_samples == n_total
    assert {b.realization for b in blocks} == set(range(exc.realizations))
    assert all(b.n_samples <= cfg.block_size for b in blocks)
    t0 = [b.t0_ns for b in blocks]
    assert all(b > a for a, b in zip(t0, t0[1:]))  # one continuous clock over realizations
    data = np.concatenate([b.data for b in per_real])
    # the recorded force is the multisine (the anti-alias filter is 1 below 400 Hz)
    np.testing.assert_allclose(data[:, 0], src.multisine.signal[0], rtol=0, atol=1e-12 * exc.rms)
    with make_source(cfg) as again:
        data2 = np.concatenate([b.data for b in list(again) if b.realization == 0])
    np.testing.assert_array_equal(data, data2)


def test_noise_is_seeded_and_at_the_requested_snr():
    cfg = load_experiment("lumped.yaml")
    opts = dict(cfg.source.options, snr_db={"X3": 20.0}, noise_seed=7)
    from dataclasses import replace
    cfg2 = replace(cfg, source=replace(cfg.source, options=opts))
    a = make_source(cfg).simulate_realization(0)
    b1 = make_source(cfg2).simulate_realization(0)
    b2 = make_source(cfg2).simulate_realization(0)
    np.testing.assert_array_equal(b1, b2)
    noise = b1[:, 3] - a[:, 3]
    snr = 20 * np.log10(np.sqrt(np.mean(a[:, 3] ** 2)) / np.sqrt(np.mean(noise ** 2)))
    # 16384 Gaussian samples: the rms estimate has relative std 1/sqrt(2*16384) = 0.55 %,
    # i.e. 0.05 dB; 0.3 dB is > 5 sigma
    assert abs(snr - 20.0) < 0.3
    np.testing.assert_array_equal(b1[:, :3], a[:, :3])  # other channels untouched


def test_options_are_validated_with_file_and_field():
    cfg = load_experiment("lumped.yaml")
    from dataclasses import replace
    for bad, match in (({"quantity": "jerk"}, "quantity"), ({"snr_db": {"NOPE": 3}}, "NOPE"),
                       ({"oversampel": 3}, "oversample"), ({"model": "moon"}, "model")):
        opts = dict(cfg.source.options, **bad)
        cfg2 = replace(cfg, source=replace(cfg.source, options=opts))
        with pytest.raises(ConfigError, match=match) as ei:
            make_source(cfg2)
        assert "lumped.yaml" in str(ei.value) and "source.options" in str(ei.value)


def test_velocity_and_acceleration_channels_are_derivatives():
    """Per channel quantity: velocity/acceleration equal j w / -w^2 times displacement.

    In steady state for the linear lumped model the three are exact (1e-6: see the
    linear-exactness test; derivative lines are exact too).
    """
    m = lumped_model("none")
    p = _force(periods=5)
    r = simulate(m, p, FS, oversample=4, periodic=N)
    d, v, a = (r.get(q)[4 * N:] for q in ("displacement", "velocity", "acceleration"))
    w = 2 * np.pi * np.fft.rfftfreq(N, 1 / FS)
    v_from_d = np.fft.irfft(np.fft.rfft(d, axis=0) * (1j * w)[:, None], n=N, axis=0)
    a_from_d = np.fft.irfft(np.fft.rfft(d, axis=0) * (-(w ** 2))[:, None], n=N, axis=0)
    assert np.abs(v - v_from_d).max() / np.abs(v).max() < 1e-6
    assert np.abs(a - a_from_d).max() / np.abs(a).max() < 1e-6


def test_independent_newmark_oracle_agrees():
    """An independent, obvious integrator (implicit Newmark, dense algebra) converges to
    the modal/FOH result on the trilinear chain.

    Newmark's own error is O(h^2): ~5e-5 at 20x, ~1.2e-5 at 40x (measured); the modal run
    at 32x is within 4e-6 of its limit (convergence test). 4e-5 at 40x leaves a 3x margin;
    the 20x error must be larger than the 40x one (both codes converge to the same limit).
    """
    from fnsi_lab.daq.sim.integrate import lowpass_decimate_periodic, newmark
    m = lumped_model("trilinear")
    p = _force(periods=5)
    ref = simulate(m, p, FS, oversample=32, periodic=N).displacement[-N:]
    errs = {}
    for osn in (20, 40):
        pf = np.tile(np.fft.irfft(np.fft.rfft(p[:N], axis=0), n=N * osn, axis=0) * osn, (5, 1))
        q = newmark(m, pf, FS * osn)[-N * osn:]
        d = lowpass_decimate_periodic(q, osn, FS)
        errs[osn] = np.abs(d - ref).max() / np.abs(ref).max()
    assert errs[40] < 4e-5
    assert errs[20] > 2 * errs[40]


def test_yaml_matrix_model_through_the_source(tmp_path):
    """A model written as matrices in the experiment file runs end to end; its linear part
    equals the built-in 'none' chain, so with a stop that is never reached (huge
    clearance) the data equal the linear lumped data to round-off (1e-9)."""
    import yaml
    base = lumped_model("none")
    text = {
        "name": "yaml-model", "sample_rate_hz": 1000, "block_size": 512,
        "source": {"kind": "simulated", "options": {"verify": False, "model": {
            "dofs": list(base.dof_names), "mass": base.mass.tolist(),
            "stiffness": base.stiffness.tolist(), "damping": base.damping.tolist(),
            "force_dofs": ["X3"], "units": {"length": "m", "force": "N"},
            "nonlinearities": [{"name": "gap", "kind": "trilinear", "dofs": {"X2": 1, "X3": -1},
                                "coefficients": {"neg": 1e4, "pos": 1e4},
                                "clearances": [1.0, 1.0]}]}}},
        "excitation": {"band_hz": [5, 50], "rms": 5.0, "samples_per_period": N, "periods": 5,
                       "transient_periods": 4, "seed": 3},
    }
    path = tmp_path / "exp.yaml"
    path.write_text(yaml.safe_dump(text))
    src = make_source(load_experiment(path))
    data = src.simulate_realization(0)
    assert src.channel_names == ["F-X3", "X1", "X2", "X3"]
    assert max(src.truth()["contact_fraction"].values()) == 0.0
    ref = simulate(base, data[:, :1], FS, oversample=10, periodic=N).displacement
    assert np.abs(data[:, 1:] - ref).max() / np.abs(ref).max() < 1e-9


def test_stiff_stop_newton_and_divergence_is_reported():
    """A stop 1000x stiffer than the chain (local frequency ~2.3 kHz) is still integrated at
    16 kHz (Newton corrector, converged in every step); at 4 kHz internal rate the scheme is
    out of its stability range and must raise, not return garbage."""
    from fnsi_lab.daq.sim.integrate import IntegrationError
    m = lumped_model("trilinear", contact=(1e8, 1e8))
    p = _force(periods=2)
    r = simulate(m, p, FS, oversample=16, periodic=N)
    assert r.unconverged_steps == 0 and np.all(np.isfinite(r.displacement))
    assert r.contact_fraction["X2-X3-stop.neg"] > 1e-3  # stiff stop: short contacts (0.5 %)
    with pytest.raises(IntegrationError, match="oversample"):
        simulate(m, p, FS, oversample=4, periodic=N)


def test_default_smallsat_run_has_no_corrector_warning_and_keeps_its_accuracy():
    """The default experiment (``fnsi-lab acquire``: SmallSat, 100 N RMS, 10 kHz internal
    rate, realization 0 plus the 20 kHz verification run) converges in every step.

    Old behaviour: 2 of 492160 steps hit ``max_iter`` (RuntimeWarning). Both were the last
    contact step before the NC2-Z negative stop opens (x = -1.500063 mm, gap 1.5 mm): x
    flipped by one ulp (2.2e-16 mm) between iterations for ever, a force residual of
    116.73 N/mm x 1 ulp = 2.6e-14 N, above the relative tolerance 1e-12 x |f| = 7e-15 N.
    The round-off floor of the corrector accepts it after Newton's first step; the accepted
    forces are those the old code returned after 50 iterations (outputs bit-identical).

    Accuracy: error vs the 20 kHz run measured 3.973e-4 before and after the fix
    (docs/smallsat.md: 4.0e-4). The band 3.5e-4 .. 4.2e-4 (-12 % .. +6 %) allows for a
    different machine/numba build (fastmath reassociation changes round-off only, ~1e-12
    relative) and catches any loss of accuracy at the contact transitions above 6 %.
    Iterations: 2 fixed-point steps + 1 Newton step + the check = 4 on every step (measured
    at 5-80 kHz); <= 6 leaves room for a contact-state change inside a step, the old code
    took 50 (the cap) and 5 on 12 other steps.
    """
    src = make_source(load_experiment(None))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            truth = src.truth()
        info = src.run_info(0)
    finally:
        src.close()
    assert info["unconverged_steps"] == 0
    assert info["iterations_max"] <= 6
    err = truth["integration"]["error_vs_double_rate"]["displacement"]
    assert 3.5e-4 < err < 4.2e-4


def test_corrector_converges_to_round_off_and_warns_on_genuine_failure():
    """``tol=0`` asks the corrector for more than double precision can give: the old
    relative-only test then hit ``max_iter`` (trilinear 1, cubic 1, stiff stop 74 steps);
    with the round-off floor every step converges in <= 5 iterations (measured 4) and the
    result equals the default-tolerance run to round-off (1e-12 relative asserted: the two
    runs differ only by forces accepted within a few ulps). A genuine failure (``max_iter``
    too small for the contact steps) still warns, and says what to do."""
    p = _force(periods=3)
    for m, os_ in ((lumped_model("trilinear"), 8), (lumped_model("cubic"), 8),
                   (lumped_model("trilinear", contact=(1e8, 1e8)), 16)):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            exact = simulate(m, p, FS, oversample=os_, periodic=N, tol=0.0)
        ref = simulate(m, p, FS, oversample=os_, periodic=N)
        assert exact.unconverged_steps == 0 and exact.iterations_max <= 5
        assert np.abs(exact.displacement - ref.displacement).max() < (
            1e-12 * np.abs(ref.displacement).max())
    with pytest.warns(RuntimeWarning, match=r"did not converge in \d+ of .*raise oversample"):
        r = simulate(lumped_model("trilinear"), p, FS, oversample=8, periodic=N, max_iter=2)
    assert r.unconverged_steps > 0


def test_a_quantity_asked_twice_is_computed_once():
    """``quantities`` accumulate per name: a repeated name must not double the output."""
    from fnsi_lab.daq.multisine import multisine
    model = lumped_model("none")
    u = np.asarray(multisine(256, 64.0, (2, 20), 1.0, n_periods=2, seed=0).signal[0])[:, None]
    once = simulate(model, u, 64.0, periodic=256, quantities=("displacement",))
    twice = simulate(model, u, 64.0, periodic=256, quantities=("displacement", "displacement"))
    assert np.array_equal(once.displacement, twice.displacement)
    with pytest.raises(ValueError, match="unknown quantities"):
        simulate(model, u, 64.0, periodic=256, quantities=("jerk",))


def test_fast_fft_length_equals_scipys():
    """daq.sim.integrate keeps its own 5-smooth length (scipy.fft is not imported by
    `acquire`); it must be scipy's real-FFT choice exactly, or the simulated outputs change."""
    import scipy.fft
    from fnsi_lab.daq.sim.integrate import _next_fast_len
    for n in list(range(1, 2000)) + [8192 * 6 + 1, 49153, 65537, 409601, 1_000_003]:
        assert _next_fast_len(n) == scipy.fft.next_fast_len(n, real=True), n
