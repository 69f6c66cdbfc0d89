"""The output-error refinement (ident.refine.output_error, ident.refine.harmonic_balance, ident.refine.modal).

FNSI reads the basis functions on the measured motion; with noisy outputs that motion's
noise sits in the regressors. The refinement fits the model's own periodic steady state,
whose basis functions read the motion the model predicts (docs/ident.md, "The output-error
refinement"). Simulations: daq.sim's frequency-domain periodic steady state of the 3-DOF
chain with a relative two-sided stop, sampled band-limited; 1 % white noise on every output
(of its RMS), 16 periods averaged, as in bench/bench_parameter_search.py.
"""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.core.basis import ParameterSpace
from fnsi_lab.ident.cli import _print_refinement
from fnsi_lab.ident.core.coefficients import nonlinear_coefficients, summarize_coefficients
from fnsi_lab.ident.config import load_ident_config, packaged_config, parse_ident_config
from fnsi_lab.ident.errors import IdentConfigError, IdentError
from fnsi_lab.ident.refine.harmonic_balance import BalanceState, HarmonicBalance
from fnsi_lab.ident.refine.modal import ModalModel
from fnsi_lab.ident.refine.output_error import omitted_mode_evidence, refine_output_error
from fnsi_lab.ident.refine.output_error_problem import OutputErrorProblem
from fnsi_lab.ident.core.periodic import with_basis

sim = pytest.importorskip("fnsi_lab.daq.sim")
from fnsi_lab.daq.multisine import multisine  # noqa: E402

FS, N = 1024.0, 8192
GAPS = np.array([4e-4, 5e-4])           # lumped_model('trilinear'), m
CONTACT = np.array([2.0e4, 1.5e4])      # N/m


def _chain(quantity="displacement", noise=0.01, periods=16, seed=0):
    """The 3-DOF chain's steady state, ``periods`` periods with white output noise."""
    model = sim.lumped_model("trilinear")
    u = np.asarray(multisine(N, FS, (5, 60), 20.0, n_periods=3, seed=1).signal).reshape(-1, 1)
    out = sim.simulate(model, u, FS, periodic=N, quantities=("displacement", quantity))
    y = np.tile(getattr(out, quantity)[-N:], (periods, 1))
    u = np.tile(u[-N:], (periods, 1))
    y = y + np.random.default_rng(seed).standard_normal(y.shape) * np.std(y, axis=0) * noise
    rel = out.displacement[-N:, 1] - out.displacement[-N:, 2]
    src = {"u": u, "y": y, "fs": FS, "N": N, "channels": list(model.measured_names),
           "quantity": quantity, "input_channels": list(model.input_names)}
    return src, float(np.mean(rel))


def _config(quantity="displacement", gaps="known", refine="auto"):
    cfg = replace(load_ident_config(packaged_config("lumped-stop")), transient_periods=0,
                  output_quantity=quantity, refine=refine)
    if gaps == "auto":
        cfg = replace(cfg, nonlinearities=tuple(
            replace(nl, unknown=(ParameterSpace("g_neg"), ParameterSpace("g_pos")))
            for nl in cfg.nonlinearities))
    return cfg


def _errors(result, gaps=GAPS):
    j = result.to_json()
    coef = np.array([c["value"] for c in j["coefficients"]]) / CONTACT - 1
    clear = np.array(j["nonlinearities"][0]["clearances"]) / gaps - 1
    return coef, clear, j


@pytest.fixture(scope="module")
def fnsi_chain():
    """FNSI's order-6 model of the noisy chain, with its data and basis (no refinement)."""
    src, _ = _chain()
    res = fnsi_lab.identify(src, _config(refine="none"), order=6)
    return res.session.data, res.session.config.nonlinearities, res.model


# ---------------------------------------------------------------------------- modal form
def test_modal_form_reproduces_the_state_space_model():
    """Diagonalised and rebuilt as real 2x2 blocks, the transfer function is the same; a real
    pole is kept as one."""
    rng = np.random.default_rng(1)
    a = np.diag([0.5, -0.3]) + 0.0
    blk = 0.9 * np.array([[np.cos(0.4), -np.sin(0.4)], [np.sin(0.4), np.cos(0.4)]])
    T = rng.standard_normal((4, 4))
    A = T @ np.block([[blk, np.zeros((2, 2))], [np.zeros((2, 2)), a]]) @ np.linalg.inv(T)
    B, C, D = rng.standard_normal((4, 3)), rng.standard_normal((5, 4)), rng.standard_normal((5, 3))
    m = ModalModel.from_matrices(A, B, C, D)
    assert m.n_pairs == 1 and m.n_real == 2
    z = np.exp(1j * np.linspace(0.1, 3.0, 7))
    ref = np.einsum("pn,kna->kpa", C, np.linalg.solve(z[:, None, None] * np.eye(4) - A, B)) + D
    assert np.abs(m.transfer(z) - ref).max() < 1e-12 * np.abs(ref).max()
    a2, b2, c2, d2 = m.matrices()
    again = ModalModel.from_matrices(a2, b2, c2, d2).transfer(z)
    assert np.abs(again - ref).max() < 1e-12 * np.abs(ref).max()
    # every output row is linear in its own parameters
    E = rng.standard_normal((7, 3)) + 1j * rng.standard_normal((7, 3))
    y = m.regressor(z, E) @ m.row_parameters().T
    assert np.abs(y - np.einsum("kpa,ka->kp", ref, E)).max() < 1e-12 * np.abs(y).max()


# ---------------------------------------------------------------------------- harmonic balance
def test_balance_of_a_noise_free_model_reproduces_the_measured_motion():
    """FNSI's model of noise-free data predicts the motion it was identified on: its own
    steady state agrees with the measurement to the model's error (noise-free FNSI gives the
    contact stiffnesses within 0.01 %; the relative motion is a difference of two larger
    motions, so its relative error is larger)."""
    src, _ = _chain(noise=0.0, periods=2)
    res = fnsi_lab.identify(src, _config(), order=6)
    data, basis, model = res.session.data, res.session.config.nonlinearities, res.model
    bal = HarmonicBalance(data, basis)
    state = bal.solve(fnsi.transfer_discrete(model, bal.z))
    err = np.linalg.norm(state.delta - bal.measured) / np.linalg.norm(bal.measured)
    assert state.residual < 1e-9
    assert err < 3e-4, err                          # measured 1.0e-4


def test_balance_linearisation_is_the_derivative(fnsi_chain):
    """``(I - T)`` of the linearisation equals the finite-difference derivative of the
    balance's residual, and its solver inverts it (the Newton steps and the refinement's
    sensitivities rest on both)."""
    data, basis, model = fnsi_chain
    bal = HarmonicBalance(data, basis)
    G = fnsi.transfer_discrete(model, bal.z)
    gain = np.einsum("ep,kpa,k->kea", bal.L_out, G, bal.to_displacement)[:, :, 1:]
    state = BalanceState(delta=bal.measured.copy(), H=np.empty(0), iterations=0,
                         residual=np.inf)
    bal.linearise(state, gain)
    x = (np.random.default_rng(0).standard_normal(bal.measured.shape)
         + 1j * np.random.default_rng(1).standard_normal(bal.measured.shape))[..., None]
    x *= np.linalg.norm(bal.measured) / np.linalg.norm(x)

    def residual(d):
        return d - np.einsum("kes,rks->rke", gain, bal.basis_spectra(d))

    eps = 1e-7
    fd = (residual(bal.measured + eps * x[..., 0])
          - residual(bal.measured - eps * x[..., 0])) / (2 * eps)
    Ax = x - np.einsum("kes,rksn->rken", gain, bal.apply_slopes(state, x))
    assert np.linalg.norm(fd - Ax[..., 0]) < 1e-6 * np.linalg.norm(fd)   # measured 7e-10
    back = bal.solve_linear(state, Ax, 1e-9)
    assert np.linalg.norm(back - x) < 1e-7 * np.linalg.norm(x)


def test_refinement_gradient_is_the_derivative_of_the_output_error(fnsi_chain, monkeypatch):
    """``J^T r`` of the normal equations against central differences of ``V``, for a pole,
    an input row, a row the stop reads, a free row's own parameter and both clearances. The
    sensitivities pass through the linearised balance, here solved to 1e-9 (the refinement
    itself stops at 1e-3); the cost's own balance is solved to its Newton tolerance, so a
    component is compared to 1e-3 of itself or of the gradient's norm (a component near
    zero, e.g. a pole already near its optimum, is then not judged by its own size)."""
    from fnsi_lab.ident.refine import output_error_problem
    monkeypatch.setattr(output_error_problem, "SENSITIVITY_TOLERANCE", 1e-9)
    data, basis, model = fnsi_chain
    basis = tuple(nl.with_parameters({"g_neg": 0.98 * GAPS[0], "g_pos": 1.02 * GAPS[1]})
                  for nl in basis)
    data = with_basis(data, basis)
    prob = OutputErrorProblem(data, basis,
                              ModalModel.from_matrices(model.a_d, model.b_d, model.c_d, model.d_d),
                              [(0, "g_neg"), (0, "g_pos")], 1 / np.sqrt(data.noise_var), True)
    shared, own = prob.pack(prob.start_modal, basis)
    point, _ = prob.evaluate(shared, own)
    _, g_s, _, _, g_o = prob.normal_equations(point)
    sl = prob.layout.slices()
    scale = 2 * np.linalg.norm(g_s)

    def cost(sh, ow):
        return prob.evaluate(sh, ow, start=point["state"])[1]

    for j in (0, sl["mu_im"].start, sl["beta_re"].start, sl["loop"].start,
              sl["theta"].start, sl["theta"].start + 1):
        h = 1e-6 * abs(shared[j])
        e = np.zeros_like(shared)
        e[j] = h
        fd = (cost(shared + e, own) - cost(shared - e, own)) / (2 * h)
        assert 2 * g_s[j] == pytest.approx(fd, rel=1e-3, abs=1e-3 * scale), j
    h = 1e-6 * abs(own[0, 0])
    e = np.zeros_like(own)
    e[0, 0] = h
    fd = (cost(shared, own + e) - cost(shared, own - e)) / (2 * h)
    assert 2 * g_o[0, 0] == pytest.approx(fd, rel=1e-6)


# ---------------------------------------------------------------------------- the answers
def test_refinement_removes_the_motion_noise_bias_of_known_gaps(fnsi_chain):
    """Known clearances, 1 % noise: FNSI's stiffnesses carry the regressors' noise (seeds
    0-7: up to 0.73 %); refined, within 0.22 % over the same seeds (bench/RESULTS.md), the
    misfit at the noise (1.02-1.07 noise variances; the measured lines above the band are
    the rest)."""
    data, basis, model = fnsi_chain
    fit = refine_output_error(data, basis, model)
    coef = np.array([c.value for c in summarize_coefficients(
        nonlinear_coefficients(fit.model, data, fit.basis, driving_point="X3"))])
    assert np.all(np.abs(coef / CONTACT - 1) < 0.005), coef / CONTACT - 1
    assert fit.converged and 0.9 < fit.misfit < 1.3
    assert fit.misfit_start > 10 * fit.misfit        # FNSI's own steady state: 35-580
    assert fit.model.order == model.order


@pytest.mark.parametrize("seed", [1, 6])
def test_clearances_auto_meet_the_targets_through_the_pipeline(seed):
    """Issue 15's targets on the chain whose gaps are a third of the relative motion's RMS,
    1 % noise, 16 periods (where the search alone gave gaps -2.2 / -2.4 % and +2.5 / +4.1 %,
    stiffnesses +1.7 / +2.4 % and -1.6 / -2.7 % for these seeds): every clearance within
    2 %, every stiffness within 0.5 %. Refined: within 0.36 % and 0.20 % over 8 seeds."""
    src, _ = _chain(seed=seed)
    res = fnsi_lab.identify(src, _config(gaps="auto"), order=6)
    coef, clear, j = _errors(res)
    assert np.all(np.abs(clear) < 0.02), clear
    assert np.all(np.abs(coef) < 0.005), coef
    oe = j["output_error"]
    assert oe["applied"] and oe["converged"] and oe["misfit"] < 1.3
    assert [p["parameter"] for p in oe["parameters"]] == ["g_neg", "g_pos"]
    # the standard deviations are the refinement's (0.14 %), not the search's curvature
    std = np.array(j["nonlinearities"][0]["clearance_std"]) / GAPS
    assert np.all((std > 5e-4) & (std < 5e-3))
    assert j["timings_s"]["output_error"] > 0


def test_velocity_outputs_clearances_auto():
    """Velocities, 1 % noise, 16 periods: the search's gaps were +3..+22 % off and the
    stiffnesses -2..-13 % (the integrated motion's noise); refined, within 0.1 % (3 seeds).
    Integrated outputs carry no static position: the gaps count from the mean position."""
    src, mean = _chain("velocity", seed=2)
    res = fnsi_lab.identify(src, _config("velocity", gaps="auto"), order=6)
    coef, clear, j = _errors(res, gaps=GAPS + np.array([mean, -mean]))
    assert j["output_error"]["applied"]
    assert np.all(np.abs(clear) < 0.01), clear
    assert np.all(np.abs(coef) < 0.005), coef


# ---------------------------------------------------------------------------- when it runs
def test_auto_leaves_noise_free_data_to_fnsi():
    src, _ = _chain(noise=0.0, periods=2)
    res = fnsi_lab.identify(src, _config(), order=6)
    j = res.to_json()
    assert res.output_error is None and not j["output_error"]["applied"]
    assert "noise-free" in j["output_error"]["reason"]


def test_auto_leaves_a_model_that_misses_dynamics_to_fnsi():
    """At order 4 the chain's three modes do not fit: FNSI's residual is far above what the
    noise and the motion noise explain, and the refinement is not run."""
    src, _ = _chain(periods=4)
    res = fnsi_lab.identify(src, _config(), order=4)
    oe = res.to_json()["output_error"]
    assert not oe["applied"] and "misses dynamics" in oe["reason"]
    assert oe["fnsi_misfit"] > 1.5 * (1 + oe["motion_noise_share"])


def test_acceleration_outputs_are_refined():
    """Accelerations, 0.1 % noise, 16 periods, the true mean position given as the offset:
    FNSI's stiffnesses -0.004 / -0.142 %; refined -0.005 / -0.004 % (the motion under the
    band predicted with the model's static terms removed, ident.refine.modal.LowFrequency)."""
    src, mean = _chain("acceleration", noise=0.001, seed=1)
    cfg = _config("acceleration")
    cfg = replace(cfg, nonlinearities=tuple(replace(nl, offset=mean) for nl in cfg.nonlinearities))
    res = fnsi_lab.identify(src, cfg, order=6)
    coef, _, j = _errors(res)
    assert j["output_error"]["applied"] and j["output_error"]["misfit"] < 1.3
    assert np.all(np.abs(coef) < 5e-4), coef


def test_refinement_reports_its_steps_on_stderr(capsys):
    """A step can take a minute (a hysteretic joint's model): with progress on, each
    Levenberg-Marquardt step is reported with its misfit, and the line is closed when the
    fit stops short of the step limit."""
    src, _ = _chain(periods=4)
    res = fnsi_lab.identify(src, _config(), order=6, progress=True)
    err = capsys.readouterr().err
    assert res.output_error is not None, res.to_json()["output_error"]
    steps = res.output_error.iterations
    assert 0 < steps < 30
    lines = [ln for ln in err.splitlines() if ln.startswith("output-error refinement (steps)")]
    assert lines, err
    assert lines[-1].split(":")[1].split()[0] == str(steps), lines  # the last count printed
    assert "misfit " in err


def test_covariance_with_a_parameter_no_line_determines():
    """An output row's own block can be singular (a parameter with no sensitivity): the
    shared parameters' covariance is still the Schur complement's pseudo-inverse, equal to
    the covariance of the problem without that parameter (a LinAlgError after 23 minutes of
    a forced refinement of the aircraft-like GVT before)."""
    from fnsi_lab.ident.refine.output_error_fit import _shared_covariance
    rng = np.random.default_rng(0)
    J_s = rng.standard_normal((2, 40, 3))        # two output rows' lines, shared parameters
    J_o = rng.standard_normal((2, 40, 4))        # each row's own four parameters
    J_o[1, :, 3] = 0.0                           # one that no line determines
    A = np.einsum("ols,olt->st", J_s, J_s)
    N = np.einsum("oln,olm->onm", J_o, J_o)
    M = np.einsum("oln,ols->ons", J_o, J_s)
    cov = _shared_covariance(A, N, M)
    J = np.zeros((80, 3 + 4 + 3))                # the problem without that parameter
    J[:, :3] = J_s.reshape(80, 3)
    J[:40, 3:7] = J_o[0]
    J[40:, 7:] = J_o[1, :, :3]
    assert np.allclose(cov, np.linalg.inv(J.T @ J)[:3, :3], rtol=1e-9)


def test_refine_none_keeps_fnsi_and_a_failed_refinement_says_so(monkeypatch):
    src, _ = _chain(periods=4)
    res = fnsi_lab.identify(src, _config(refine="none"), order=6)
    assert res.output_error is None and "output_error" not in res.to_json()
    ref = fnsi_lab.identify(src, _config(refine="none"), order=6)

    def fails(*args, **kwargs):
        raise IdentError("the harmonic balance of the model did not converge")
    import fnsi_lab.ident.refinement as refinement
    monkeypatch.setattr(refinement, "refine_output_error", fails)
    res = fnsi_lab.identify(src, _config(), order=6)
    j = res.to_json()
    assert res.output_error is None and not j["output_error"]["applied"]
    assert j["output_error"]["reason"].startswith("not applied: the harmonic balance")
    assert any("output-error refinement was not applied" in w for w in j["warnings"])
    assert [c["value"] for c in j["coefficients"]] == [c["value"] for c in ref.coefficients]

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")
    monkeypatch.setattr(refinement, "refine_output_error", singular)
    j = fnsi_lab.identify(src, _config(), order=6).to_json()
    assert j["output_error"]["reason"] == "not applied: a singular system: Singular matrix"
    assert [c["value"] for c in j["coefficients"]] == [c["value"] for c in ref.coefficients]


def test_refine_option_is_validated():
    with pytest.raises(IdentConfigError, match="refine"):
        parse_ident_config({"band_hz": [1, 10], "refine": "outputerror"})
    assert parse_ident_config({"band_hz": [1, 10]}).refine == "auto"


def test_refinement_needs_basis_functions(fnsi_chain):
    data, _, model = fnsi_chain
    with pytest.raises(IdentError, match="basis"):
        refine_output_error(data, (), model)


def test_a_pole_the_output_error_does_not_determine_is_dropped(fnsi_chain):
    """A spurious pair (45 Hz, small residues) added to FNSI's model wanders off in the fit
    (more than 3 of its bandwidths): it is dropped and the fit goes on with the three modes,
    to the same answer as without it."""
    from dataclasses import replace as dc_replace
    data, basis, model = fnsi_chain
    m = ModalModel.from_matrices(model.a_d, model.b_d, model.c_d, model.d_d)
    w = 2 * np.pi * 45.0
    mu = np.exp((-0.01 * w + 1j * w) / FS)
    extra = dc_replace(m, poles=np.append(m.poles, mu),
                       b_pair=np.vstack([m.b_pair, 1e-3 * m.b_pair[:1]]),
                       c_pair=np.hstack([m.c_pair, 1e-3 * m.c_pair[:, :1]]))
    a, b, c, d = extra.matrices()
    start = fnsi.make_model(a, b, c, d, sample_rate_hz=FS, n_inputs=1,
                            input_names=model.input_names, output_names=model.output_names,
                            time_base=model.time_base)
    fit = refine_output_error(data, basis, start)
    ref = refine_output_error(data, basis, model)
    assert fit.dropped_hz and abs(fit.dropped_hz[0] - 45.0) < 0.5
    assert fit.model.order == 6
    assert [f for _, f in fit.frequency_map if f is None] == [None, None]
    got = np.sort(fit.model.poles.natural_frequency_hz)
    assert np.allclose(got, np.sort(ref.model.poles.natural_frequency_hz), rtol=1e-4)


def test_omitted_mode_evidence_finds_a_mode_left_in_the_residual(fnsi_chain):
    """The score test behind the split-mode check (ident.refinement): a pole where the chain
    has no mode (45 Hz) explains what noise gives, about one noise variance per output
    (3 outputs; the mode's 14 parameters are the threshold, a Gamma(3, 1) variable exceeds
    it with probability 1e-4); the contribution of one of the fit's own modes put back into
    its residual is found whole (pole and input vector held, output vector fitted), to within
    the noise's cross term with it, about ``2 sqrt(energy)`` (3e-4 of the mode's 7e7 noise
    variances)."""
    data, basis, model = fnsi_chain
    fit = refine_output_error(data, basis, model)
    n_outputs, n_excitation = fit.model.d_d.shape
    threshold = 2 + 2 * n_excitation + 2 * n_outputs
    w = 2 * np.pi * 45.0
    assert omitted_mode_evidence(fit, np.exp((-0.02 * w + 1j * w) / FS),
                                 np.ones(n_excitation), data.z) < threshold
    m = ModalModel.from_matrices(fit.model.a_d, fit.model.b_d, fit.model.c_d, fit.model.d_d)
    r = int(np.argmin(np.abs(m.poles)))            # any mode: the first one read
    # the pair's part of G(z) E: gamma beta^T E / (z - mu) + its conjugate pole's term
    plus = fit.excitation @ m.b_pair[r] / (data.z - m.poles[r])
    minus = fit.excitation @ np.conj(m.b_pair[r]) / (data.z - np.conj(m.poles[r]))
    mode = np.outer(plus, m.c_pair[:, r]) + np.outer(minus, np.conj(m.c_pair[:, r]))
    energy = float(np.sum(np.abs(fit.residual_weights * mode) ** 2))
    missing = replace(fit, weighted_residual=fit.weighted_residual
                      + fit.residual_weights * mode)
    evidence = omitted_mode_evidence(missing, m.poles[r], 2.0 * m.b_pair[r], data.z)
    assert energy > 1e4 * threshold
    assert abs(evidence / energy - 1) < 1e-3


def test_two_elements_one_reading_a_velocity():
    """The stop and a quadratic damper on X1 (``c |v| v``, 200 N s^2/m^2): two elements with
    their own arguments, one of them a velocity. 1 % noise, 16 periods: FNSI's values
    +0.15 / +0.31 / +0.89 %, refined +0.24 / +0.24 / -0.01 % (misfit 1.04)."""
    from fnsi_lab.daq.sim.nonlinear import NonlinearElement
    model = sim.lumped_model("trilinear")
    damper = NonlinearElement("qd", "quadratic_damping", np.array([1.0, 0, 0]), {"c": 200.0})
    model = replace(model, nonlinearities=model.nonlinearities + (damper,))
    u = np.asarray(multisine(N, FS, (5, 60), 20.0, n_periods=3, seed=1).signal).reshape(-1, 1)
    y = np.tile(sim.simulate(model, u, FS, periodic=N).displacement[-N:], (16, 1))
    u = np.tile(u[-N:], (16, 1))
    y = y + np.random.default_rng(1).standard_normal(y.shape) * np.std(y, axis=0) * 0.01
    cfg = parse_ident_config({
        "band_hz": [3, 150], "inputs": [{"name": "F-X3", "driving_point": "X3"}],
        "nonlinearities": [
            {"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
             "clearances": [4e-4, 5e-4], "truth": [2e4, 1.5e4]},
            {"name": "qd", "kind": "quadratic_damping", "channels": {"X1": 1}, "truth": [200.0]}]})
    src = {"u": u, "y": y, "fs": FS, "N": N, "channels": list(model.measured_names),
           "input_channels": list(model.input_names)}
    j = fnsi_lab.identify(src, cfg, order=6).to_json()
    assert j["output_error"]["applied"] and j["output_error"]["misfit"] < 1.3
    errors = np.array([c["value_error_percent"] for c in j["coefficients"]])
    assert np.all(np.abs(errors) < 0.5), errors


def test_motion_under_the_band_predicted_unless_the_model_disagrees_there():
    """Displacements: the lines under the processed band are predicted by the model (their
    measured noise is read as motion otherwise: the gaps' scatter was 2.3x their standard
    deviation, 1.3x predicted). A band that starts above the chain's first mode (8.2 Hz)
    leaves that mode's resonance to the lines under it, which the model cannot predict
    (7e4 noise variances off): the measured lines are used there, and the answer holds
    (16 periods: -0.09 / -0.05 %)."""
    src, _ = _chain(periods=4)
    res = fnsi_lab.identify(src, _config(), order=6)
    oe = res.to_json()["output_error"]
    assert oe["below_band"] == "predicted" and oe["below_band_misfit"] < 4
    src, _ = _chain()
    cfg = replace(_config(refine="output-error"), band_hz=(12.0, 150.0))
    res = fnsi_lab.identify(src, cfg, order=6)
    coef, _, j = _errors(res)
    assert j["output_error"]["below_band"].startswith("measured (predicted, they were")
    assert np.all(np.abs(coef) < 0.005), coef


def _chain5_stop(noise_seed: int):
    """A 5-DOF chain (masses 1 / 0.8 / 1.2 / 1 / 0.6 kg, Rayleigh damping plus a dashpot)
    with a relative two-sided stop between DOFs 3 and 4 (gaps 0.2 / 0.3 mm, 4e4 / 3e4 N/m),
    forced at DOF 5, every DOF measured, 40 dB of white noise, 4 transient and 6 steady
    periods: the ``chain5-stop`` case of bench/robustness.py through daq.sim's periodic
    steady state."""
    from fnsi_lab.daq.sim.lumped import lumped_model
    from fnsi_lab.daq.sim.model import StructuralModel
    from fnsi_lab.daq.sim.nonlinear import NonlinearElement
    fs, n = 1000.0, 4096
    lin = lumped_model("none", masses=[1.0, 0.8, 1.2, 1.0, 0.6],
                       springs=[3e4, 2e4, 2e4, 1.5e4, 1e4], mass_damping=2.0,
                       stiffness_damping=1e-4, dashpot=3.0, dashpot_dofs=(0, 1))
    names = tuple(f"q{i}" for i in range(5))
    force = np.zeros((5, 1))
    force[4, 0] = 1.0
    stop = NonlinearElement("stop", "trilinear", np.array([0, 0, 1.0, -1.0, 0]),
                            {"neg": 4e4, "pos": 3e4}, clearances=(2e-4, 3e-4))
    model = StructuralModel(mass=lin.mass, damping=lin.damping, stiffness=lin.stiffness,
                            dof_names=names, force_matrix=force, input_names=("F",),
                            measured={q: i for i, q in enumerate(names)},
                            nonlinearities=(stop,), name="chain5-stop")
    u = np.asarray(multisine(n, fs, (5, 60), 8.0, n_periods=10, seed=3).signal[0], float)
    y = sim.simulate(model, u[:, None], fs, periodic=n, oversample=20,
                     quantities=("displacement",)).displacement
    y = y + (np.random.default_rng(noise_seed).standard_normal(y.shape)
             * np.sqrt(np.mean(y[4 * n:] ** 2, axis=0)) * 0.01)
    src = {"u": u[:, None], "y": y, "fs": fs, "N": n, "channels": list(names),
           "input_channels": ["F"]}
    cfg = parse_ident_config({
        "band_hz": [5, 200], "transient_periods": 4,
        "inputs": [{"name": "F", "driving_point": "q4"}],
        "nonlinearities": [{"name": "stop", "kind": "trilinear",
                            "channels": {"q2": 1.0, "q3": -1.0},
                            "clearances": "auto"}]})
    return src, cfg


def test_the_chain_answer_does_not_depend_on_the_blas_thread_count():
    """The robust answer on the 5-DOF chain with searched gaps (seed 11), refined, is the same
    with one and two BLAS threads: order, modes, what the refinement leaves out, and the
    values to 1e-8 (issue 27: the subspace step projected on input-lag directions set by
    round-off, and the two thread counts gave orders 12 and 10, one with a weak 16.8 Hz pole
    the refinement then left out). Physics as issue 15's targets: five modes, stiffnesses
    within 0.5 %, gaps within 2 %."""
    from fnsi_lab.blas import limit_blas_threads, restored_blas_threads
    src, cfg = _chain5_stop(noise_seed=11)
    answers = []
    with restored_blas_threads():
        for threads in (1, 2):
            limit_blas_threads(threads)
            res = fnsi_lab.identify(src, cfg, orders="2:30")
            answers.append((res, res.to_json()))
    (res, j), (_, j2) = answers
    assert j["order"] == j2["order"]
    assert (j["output_error"].get("left_out") or []) == (j2["output_error"].get("left_out") or [])
    assert [m["frequency_hz"] for m in j["modes"]] == pytest.approx(
        [m["frequency_hz"] for m in j2["modes"]], rel=1e-8)
    values = [c["value"] for c in j["coefficients"]]
    assert values == pytest.approx([c["value"] for c in j2["coefficients"]], rel=1e-8)
    oe = j["output_error"]
    assert oe["applied"] and oe["converged"] and oe["iterations"] <= 12
    assert sorted(round(f) for f in res.model.poles.natural_frequency_hz[::2]) == \
        [7, 19, 28, 34, 44]
    coef = np.array(values) / [4e4, 3e4] - 1
    clear = np.array(j["nonlinearities"][0]["clearances"]) / [2e-4, 3e-4] - 1
    assert np.all(np.abs(clear) < 0.02) and np.all(np.abs(coef) < 0.005), (clear, coef)
    summary = io.StringIO()
    _print_refinement(j, out=summary)                # what `fnsi-lab ident` prints
    assert "output-error refinement (docs/ident.md): misfit" in summary.getvalue()
