"""Basis parameters from the data (ident.refine.parameter_search): clearances and exponents of
simulated structures with known values, noise-free and noisy, relative and grounded stops,
one- and two-sided, the refusals, the configuration syntax, the JSON/CLI/viewer outputs and
the SmallSat (39 channels).

Simulations: daq.sim (frequency-domain periodic steady state of the lumped chains and the
SmallSat, sampled band-limited), so the errors below are those of the identification.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from fnsi_lab.ident.core.basis import Nonlinearity, ParameterSpace
from fnsi_lab.ident.core.coefficients import nonlinear_coefficients, summarize_coefficients
from fnsi_lab.ident.config import parse_ident_config
from fnsi_lab.ident.errors import IdentConfigError, IdentError, IdentWarning, NotIdentifiableError
from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.refine.parameter_search import estimate_basis_parameters, search_spaces
from fnsi_lab.ident.core.periodic import prepare_frequency_data, with_basis

sim = pytest.importorskip("fnsi_lab.daq.sim")
from fnsi_lab.daq.multisine import excited_lines, multisine  # noqa: E402
from fnsi_lab.daq.sim.nonlinear import NonlinearElement  # noqa: E402

FS, N = 1024.0, 8192
BAND = (3, 150)
GAPS = (4e-4, 5e-4)            # lumped_model('trilinear') defaults, m
CONTACT = (2.0e4, 1.5e4)       # N/m


def _simulate(model, periods=3, seed=1):
    ms = multisine(N, FS, (5, 60), 20.0, n_periods=periods, seed=seed)
    u = np.asarray(ms.signal).reshape(-1, 1)
    y = sim.simulate(model, u, FS, periodic=N).displacement
    return u, y


def _data(model, u, y, basis, transient=1):
    return prepare_frequency_data(u=u, y=y, sample_rate_hz=FS, samples_per_period=N, basis=(),
                                  motion_for=basis, band_hz=BAND, transient_periods=transient,
                                  output_names=model.measured_names, input_names=model.input_names,
                                  excited_lines=excited_lines(N, FS, (5, 60)))


def _coefficients(data, basis, order=6, driving_point="X3"):
    d = with_basis(data, basis)
    dec = fnsi.subspace_decomposition(d, max_order=12)
    model = fnsi.model_at_order(dec, d, order)
    return summarize_coefficients(nonlinear_coefficients(model, d, list(basis),
                                                         driving_point=driving_point))


def _auto(name, kind, channels, **kw):
    pars = {"trilinear": ("g_neg", "g_pos"), "bilinear": ("clearance",)}[kind]
    return Nonlinearity(name, kind, channels, unknown=tuple(ParameterSpace(p) for p in pars), **kw)


@pytest.fixture(scope="module")
def chain_stop():
    model = sim.lumped_model("trilinear")
    return model, *_simulate(model)


# ---------------------------------------------------------------------------- relative stop
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_relative_two_sided_stop_noise_free(chain_stop, sign):
    """Both gaps 'auto' over the whole recorded excursion: found to the model-error floor;
    flipping L swaps the sides (same physics)."""
    model, u, y = chain_stop
    nl = _auto("stop", "trilinear", {"X2": sign, "X3": -sign})
    data = _data(model, u, y, [nl])
    res = estimate_basis_parameters(data, [nl], order=6)
    gaps = res.basis[0].clearances if sign > 0 else res.basis[0].clearances[::-1]
    # measured 5e-5 relative (the floor of the band-limited basis evaluation)
    assert np.allclose(gaps, GAPS, rtol=1e-3)
    for est in res.estimates:
        assert 0 < est.std < 1e-3 * est.value       # curvature-based, tiny without noise
        # the scan starts at 2 % of the excursion (~0.1 mm) and ends at 98 % (~4.5 mm)
        assert est.unknown.interval[0] < 0.3 * est.value and est.unknown.interval[1] > 8 * est.value
        assert est.profile_objective.min() == pytest.approx(res.objective, rel=1e-6)
        assert est.margin > 1e3
        assert est.motion_noise_std < 1e-6 * est.value   # noise-free periods: no warning
    assert not res.warnings
    coefs = _coefficients(data, res.basis, driving_point="X3")
    truth = CONTACT if sign > 0 else CONTACT[::-1]
    # known gaps give -0.01 %; within 0.1 % here (the targets: 2 % gaps, 0.5 % coefficients)
    for c, t in zip(coefs, truth):
        assert c.mean_real == pytest.approx(t, rel=1e-3)


def test_parallel_candidates_change_nothing(chain_stop):
    """Candidates evaluated on two threads give the same estimate, profile and fit count as
    one thread (each candidate is a pure function of the data)."""
    model, u, y = chain_stop
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    data = _data(model, u, y, [nl])
    one = estimate_basis_parameters(data, [nl], order=6, workers=1)
    two = estimate_basis_parameters(data, [nl], order=6, workers=2)
    assert one.basis[0].clearances == two.basis[0].clearances
    assert one.n_evaluations == two.n_evaluations
    for a, b in zip(one.estimates, two.estimates):
        assert np.array_equal(a.profile_objective, b.profile_objective) and a.std == b.std


def test_search_order_from_the_information_criterion(chain_stop):
    """Without an order the robust pipeline searched at order 30: on the 3-DOF chain (order
    6) the spare states made the model error rough: 2 steady periods ended at an edge of
    the interval (refused), 16 at gaps +49 % / +19 % (noise-free). The criterion at the
    coarse scan's estimate picks the order instead."""
    import fnsi_lab

    model, u, y = chain_stop
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    data = _data(model, u, y, [nl])
    with pytest.raises(NotIdentifiableError):   # at order 30 alone: ends at the interval's edge
        estimate_basis_parameters(data, [nl], order=30)
    res = estimate_basis_parameters(data, [nl], order=30, select_order=True)
    assert 6 <= res.order <= 8                                     # measured 6
    assert np.allclose(res.basis[0].clearances, GAPS, rtol=5e-4)   # measured 0.006 %
    # the pipeline does so when neither the call nor the configuration gives an order
    cfg = {"band_hz": list(BAND), "transient_periods": 1,
           "inputs": [{"name": model.input_names[0], "driving_point": "X3"}],
           "nonlinearities": [{"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
                               "clearances": "auto"}]}
    src = {"u": u, "y": y, "fs": FS, "N": N, "channels": list(model.measured_names),
           "input_channels": list(model.input_names)}
    out = fnsi_lab.identify(src, cfg, orders="2:30").to_json()
    assert out["parameter_search"]["order"] == res.order
    assert np.allclose(out["nonlinearities"][0]["clearances"], GAPS, rtol=5e-4)


def test_curvature_is_measured_where_the_objective_is_smooth():
    """A model error that is rough at the scale of Newton's last stencil (a simulator that
    samples the contacts without band limit) gives an indefinite Hessian there; the
    uncertainty then comes from a wider stencil, not a refusal as 'flat'."""
    from fnsi_lab.ident.refine.parameter_search import Unknown
    from fnsi_lab.ident.refine.search_newton import wider_curvature

    def objectives(points):   # curvature 2 per axis, plus roughness of 1e-9 at 1e-6 scale
        return [float((p[0] - 1) ** 2 + (p[1] - 2) ** 2 + 1e-9 * np.sin(3e6 * p[0] * p[1]))
                for p in points]

    unknowns = [Unknown(0, "stop", "g_neg", interval=(0.5, 2.0)),
                Unknown(0, "stop", "g_pos", interval=(1.0, 4.0))]
    values = np.array([1.0, 2.0])
    H = wider_curvature(objectives, values, [0, 1], unknowns, -np.eye(2))
    assert np.allclose(H, 2 * np.eye(2), atol=0.02)
    assert np.array_equal(wider_curvature(objectives, values, [0, 1], unknowns, np.eye(2)),
                          np.eye(2))      # a positive one is kept


def _noisy_chain_data(gaps, seed):
    """3-DOF chain with a relative stop of these gaps, 1 % white noise on every output, 16
    periods; the basis with both gaps auto."""
    model = sim.lumped_model("trilinear", clearances=gaps)
    u, y = _simulate(model, periods=3)
    P = 16
    u, y = np.tile(u[-N:], (P, 1)), np.tile(y[-N:], (P, 1))
    y = y + np.random.default_rng(seed).standard_normal(y.shape) * np.std(y, axis=0) * 0.01
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    return _data(model, u, y, [nl], transient=0), nl


@pytest.mark.parametrize("seed", [0, 3])
def test_relative_two_sided_stop_noisy(seed):
    """1 % white noise on every output, 16 periods averaged. The noise in the measured
    relative motion, gated by the contact, biases the plain model error's gaps upwards by
    about its own size; the noise-corrected objective (ident.refine.parameter_search.MotionNoise)
    removes that bias and leaves the scatter (docs/ident.md). Seed 3 once ended in the
    spurious low-gap region where the stop columns become a linear copy of the noisy outputs
    (fixed by the Newton trust region)."""
    data, nl = _noisy_chain_data(GAPS, seed)
    plain = estimate_basis_parameters(data, [nl], order=6, noise_correction=False)
    err_plain = np.array(plain.basis[0].clearances) / GAPS - 1
    # measured +3.0 % / +4.4 % (seed 0), +0.7 % / +2.7 % (seed 3); seeds 0-7: +0.6..+7.8 %,
    # always positive (7 periods: +7..+12 %, 31 periods: +1.3..+3.9 % over 3 seeds)
    assert np.all(err_plain > 0) and np.all(err_plain < 0.08)
    assert not any(e.noise_corrected for e in plain.estimates)
    res = estimate_basis_parameters(data, [nl], order=6)
    err = np.array(res.basis[0].clearances) / GAPS - 1
    # measured -0.6 % / -0.5 % (seed 0), +1.1 % / +0.2 % (seed 3); over seeds 0-7 the
    # corrected errors scatter around zero, -2.0..+2.6 % (one seed +4.2 %): within 3 %
    # here, and the bias of the plain objective (its mean error) at least halved
    assert np.all(np.abs(err) < 0.03)
    assert np.mean(np.abs(err)) < 0.5 * np.mean(err_plain)
    assert all(e.noise_corrected for e in res.estimates)
    noise_rel = np.array([e.motion_noise_std / e.value for e in res.estimates])
    assert np.all((noise_rel > 0.02) & (noise_rel < 0.1))    # the motion's noise: 4-5 % of the gaps
    assert len(res.warnings) == 2 and all("first-order effect was removed" in w
                                          for w in res.warnings)
    for est in res.estimates:
        assert est.std > 1e-4 * est.value        # noise shows in the uncertainty


@pytest.mark.parametrize("seed, order", [(1, 6), (5, 6), (1, None)])
def test_gaps_near_the_motion_rms_are_found_from_the_stops_open(seed, order):
    """Gaps at 0.7 / 0.9 of the relative motion's RMS (contact at the peaks only), 1 % noise,
    16 periods. From the intervals' centres the one-at-a-time scan ended in the corner of both
    gaps tiny for these seeds (a linear spring plus a sign term fits better than the scan's
    points near the truth, whose valley is narrower than a scan step) and the search refused
    (minimum on the interval's edge); the search now starts again from the stops open and
    keeps the better fit (docs/ident.md, 'Unknown basis parameters'). Without an order the
    criterion chose 4 at the intervals' centres, where the open start lost; the starts are
    now also compared at other orders and the criterion picks (6)."""
    gaps = (1.2e-3, 1.5e-3)
    data, nl = _noisy_chain_data(gaps, seed)
    notes = []
    res = estimate_basis_parameters(data, [nl], order=order or 30, select_order=order is None,
                                    progress=notes.append)
    assert any(n.startswith("restart from the stops open (better)") for n in notes)
    assert res.order == 6
    err = np.array(res.basis[0].clearances) / gaps - 1
    # measured +0.02 / -0.06 % (seed 1), -0.44 / -0.44 % (seed 5); seeds 0-7 within 0.45 %
    # (curvature std 0.07-0.09 %: the scatter is 2-5x it, docs/ident.md)
    assert np.all(np.abs(err) < 0.01)
    coefficients = [c.ls_value for c in _coefficients(data, res.basis)]
    # measured within 0.08 % here, seeds 0-7 within 0.45 %; the known gaps 0.02-0.2 %
    assert np.allclose(coefficients, CONTACT, rtol=0.005)


@pytest.mark.parametrize("gaps, seed", [((0.963e-3, 1.259e-3), 26), ((1.970e-3, 0.546e-3), 96)])
def test_gaps_without_an_order(gaps, seed):
    """No order given: the information criterion picks it, but on a wrong basis it wanders
    (4 to 30 on these chains; 6 at the true gaps). (0.963, 1.259) mm: the scan at the
    centres' order (8) went to a wrong valley that no lower end revealed and the search
    refused; it is now retried from the stops open. (1.970, 0.546) mm: both starts ended in
    the corner of tiny gaps at the first estimate's order (4); they are now also compared at
    the open stops' order (6), and the criterion's own value picks between the two
    (docs/ident.md, 'Unknown basis parameters'). Both were refused before."""
    data, nl = _noisy_chain_data(gaps, seed)
    res = estimate_basis_parameters(data, [nl], order=30, select_order=True)
    err = np.array(res.basis[0].clearances) / gaps - 1
    assert np.all(np.abs(err) < 0.01)      # measured +0.06 / -0.06 %, +0.01 / +0.42 %
    assert res.order == 6


def test_unmodelled_nonlinearity_is_flagged_by_the_noise_misfit():
    """The chain with a stop AND a cubic spring (k3 = 1e9 N/m^3, as lumped_model('cubic')),
    searched with the stop alone: the free gaps absorb the cubic (measured +168 % / +193 %,
    with smooth, convex profiles), but the model leaves 47x the output noise where a right
    basis leaves 1.2-1.5x, and a warning says so."""
    stop, cubic = sim.lumped_model("trilinear"), sim.lumped_model("cubic")
    model = replace(stop, nonlinearities=stop.nonlinearities + cubic.nonlinearities)
    u, y = _simulate(model, periods=3)
    P = 16
    u, y = np.tile(u[-N:], (P, 1)), np.tile(y[-N:], (P, 1))
    y = y + np.random.default_rng(0).standard_normal(y.shape) * np.std(y, axis=0) * 0.01
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    res = estimate_basis_parameters(_data(model, u, y, [nl], transient=0), [nl], order=6)
    assert res.noise_misfit > 20
    assert any("the basis or the order does not explain these data" in w for w in res.warnings)


def test_a_rough_minimum_is_refused():
    """The local profile must rise as the curvature says: a lucky low point of a rough model
    error (5-DOF chain seen by 2 outputs: 130-10^15 times off) is refused, a smooth minimum
    (0.6-2.3 measured) passes."""
    from fnsi_lab.ident.refine.parameter_search import ParameterEstimate, Unknown
    from fnsi_lab.ident.refine.search_refusal import MAX_ROUGHNESS, refuse_if_unclear, roughness

    std, s2 = 1e-6, 1e-8
    offsets = np.array([-3e-6, 3e-6])                          # +-3 std: a rise of 9 chi-square
    assert roughness(offsets, 9 * s2 * np.ones(2), std, s2) == pytest.approx(1.0)
    assert roughness(offsets, np.array([9 * s2, 9e5 * s2]), std, s2) == pytest.approx(1e5)
    assert roughness(offsets, np.array([9 * s2, -s2]), std, s2) == np.inf   # lower nearby
    u = Unknown(0, "stop", "g_pos", interval=(1e-5, 1e-3), reach=1.1e-3)
    nl = Nonlinearity("stop", "trilinear", {"a": 1}, clearances=(1e-4, 1e-4))

    def estimate(roughness):
        return ParameterEstimate(u, 1e-4, std, np.zeros(0), np.zeros(0), margin=1e3,
                                 roughness=roughness)

    refuse_if_unclear(estimate(2.3), nl, 0.1, 25.0)
    refuse_if_unclear(estimate(float("nan")), nl, 0.1, 25.0)      # no local point
    with pytest.raises(NotIdentifiableError, match=r"g_pos: the model error around 0.0001 is rough"):
        refuse_if_unclear(estimate(10 * MAX_ROUGHNESS), nl, 0.1, 25.0)


def test_one_period_per_realisation_says_the_gaps_are_uncorrected():
    """One period per realisation has no period spread, so the motion noise is unknown and
    the search cannot correct for it: with 1 % output noise the gaps come out far too large
    (+47 % to +71 % measured with 16 realisations), and the result says so in a warning."""
    model = sim.lumped_model("trilinear")
    us, ys = [], []
    for r in range(2):
        ms = multisine(N, FS, (5, 60), 20.0, n_periods=3, seed=10 + r)
        u = np.asarray(ms.signal).reshape(-1, 1)
        us.append(u[-N:][None])
        ys.append(sim.simulate(model, u, FS, periodic=N).displacement[-N:][None])
    u, y = np.array(us), np.array(ys)                        # (R, P = 1, N, channels)
    y = y + 0.01 * np.std(y, axis=(0, 1, 2)) * np.random.default_rng(0).standard_normal(y.shape)
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    data = prepare_frequency_data(u=u, y=y, sample_rate_hz=FS, samples_per_period=N,
                                  motion_for=[nl], band_hz=BAND, transient_periods=0,
                                  output_names=model.measured_names,
                                  input_names=model.input_names,
                                  excited_lines=excited_lines(N, FS, (5, 60)))
    res = estimate_basis_parameters(data, [nl], order=6)
    assert any("one steady period per realisation" in w for w in res.warnings)
    assert np.all(np.array(res.basis[0].clearances) > 1.1 * np.array(GAPS))


def test_one_side_known_the_other_searched_in_an_interval(chain_stop):
    model, u, y = chain_stop
    nl = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=(GAPS[0], 0.0),
                      unknown=(ParameterSpace("g_pos", interval=(3e-4, 8e-4)),))
    data = _data(model, u, y, [nl])
    res = estimate_basis_parameters(data, [nl], order=6)
    (est,) = res.estimates
    assert est.unknown.interval == (3e-4, 8e-4)
    assert est.value == pytest.approx(GAPS[1], rel=1e-3)
    assert res.basis[0].clearances[0] == GAPS[0]         # the given side untouched
    assert not res.basis[0].unknown


# ---------------------------------------------------------------------------- grounded, one-sided
def _with_element(element):
    return replace(sim.lumped_model("none"), nonlinearities=(element,))


@pytest.mark.parametrize("side", ["pos", "neg"])
def test_grounded_one_sided_stop(side):
    """A bilinear stop from X1 to the ground: gap at 60 % of the excursion towards it."""
    lin = sim.lumped_model("none")
    _, y_lin = _simulate(lin)
    reach = float(np.max(y_lin[-N:, 0] if side == "pos" else -y_lin[-N:, 0]))
    gap = 0.6 * reach
    el = NonlinearElement("X1-stop", "bilinear", np.array([1.0, 0.0, 0.0]), {side: 3.0e4},
                          clearances=(gap,))
    model = _with_element(el)
    u, y = _simulate(model)
    nl = Nonlinearity("X1-stop", "bilinear", {"X1": 1.0}, side=side,
                      unknown=(ParameterSpace("clearance"),))
    data = _data(model, u, y, [nl])
    res = estimate_basis_parameters(data, [nl], order=6)
    (est,) = res.estimates
    assert est.value == pytest.approx(gap, rel=2e-3)   # measured within 1e-4
    (c,) = _coefficients(data, res.basis, driving_point="X3")
    assert c.mean_real == pytest.approx(3.0e4, rel=5e-3)


def test_relative_one_sided_stop():
    el = NonlinearElement("gap", "bilinear", np.array([0.0, 1.0, -1.0]), {"neg": 2.0e4},
                          clearances=(6e-4,))
    model = _with_element(el)
    u, y = _simulate(model)
    nl = Nonlinearity("gap", "bilinear", {"X2": 1.0, "X3": -1.0}, side="neg",
                      unknown=(ParameterSpace("clearance", interval=(1e-4, 2e-3)),))
    res = estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)
    assert res.basis[0].clearance == pytest.approx(6e-4, rel=2e-3)


# ---------------------------------------------------------------------------- exponents
@pytest.fixture(scope="module")
def chain_cubic():
    model = sim.lumped_model("cubic")
    return model, *_simulate(model)


def test_exponent_auto_picks_the_cubic(chain_cubic):
    model, u, y = chain_cubic
    nl = Nonlinearity("knl", "polynomial", {"X2": 1, "X3": -1},
                      unknown=(ParameterSpace("exponent"),))
    res = estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)
    (est,) = res.estimates
    assert est.value == 3.0
    assert np.isnan(est.std) and est.margin > 1e3      # the runner-up fits far worse
    assert list(est.profile_values) == [2.0, 3.0, 4.0, 5.0, 6.0, 7.0]


def test_signed_exponent_is_continuous(chain_cubic):
    """|x|^(e-1) x with e free: the cubic spring (odd) is e = 3 exactly."""
    model, u, y = chain_cubic
    nl = Nonlinearity("knl", "polynomial", {"X2": 1, "X3": -1}, signed=True,
                      unknown=(ParameterSpace("exponent", interval=(2.0, 4.5)),))
    res = estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)
    assert res.basis[0].exponent == pytest.approx(3.0, abs=5e-3)


# ---------------------------------------------------------------------------- refusals
def test_stop_never_in_contact_is_refused(chain_stop):
    model, u, y = chain_stop
    nl = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=(GAPS[0], 0.0),
                      unknown=(ParameterSpace("g_pos", interval=(0.02, 0.05)),))
    with pytest.raises(NotIdentifiableError, match=r"g_pos.*never in contact"):
        estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)


def test_a_stop_the_structure_does_not_have_is_refused():
    """Linear chain, a stop searched over the whole excursion: nothing to find."""
    model = sim.lumped_model("none")
    u, y = _simulate(model)
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    with pytest.raises(NotIdentifiableError, match="cannot tell"):
        estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)


def test_true_gap_outside_the_interval_is_refused(chain_stop):
    model, u, y = chain_stop
    nl = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=(GAPS[0], 0.0),
                      unknown=(ParameterSpace("g_pos", interval=(6e-4, 9e-4)),))
    with pytest.raises(NotIdentifiableError, match="edge of the search interval"):
        estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=6)
    # without an order the refusal also names the order (the criterion wanders while the
    # basis is wrong)
    with pytest.raises(NotIdentifiableError, match="give the structure's model order"):
        estimate_basis_parameters(_data(model, u, y, [nl]), [nl], order=30, select_order=True)


def test_unresolved_elements_cannot_be_evaluated():
    nl = _auto("stop", "trilinear", {"a": 1})
    with pytest.raises(IdentError, match="not estimated yet"):
        nl.evaluate(np.zeros(4))
    done = nl.with_parameters({"g_neg": 1.0, "g_pos": 2.0})
    assert done.evaluate(np.array([3.0])).tolist() == [[0.0, 1.0]]


def test_search_spaces_from_the_motion(chain_stop):
    model, u, y = chain_stop
    nl = _auto("stop", "trilinear", {"X2": 1, "X3": -1})
    (neg, pos) = search_spaces(_data(model, u, y, [nl]), [nl])
    d = y[-N:, 1] - y[-N:, 2]
    # reach from the band-limited interpolation: at least the sampled extreme
    assert pos.reach >= d.max() and pos.reach == pytest.approx(d.max(), rel=0.02)
    assert neg.reach >= -d.min() and neg.reach == pytest.approx(-d.min(), rel=0.02)
    assert pos.interval == pytest.approx((0.02 * pos.reach, 0.98 * pos.reach))


# ---------------------------------------------------------------------------- configuration
def _cfg(**nl):
    base = {"name": "s", "kind": "trilinear", "channels": {"a": 1}}
    return parse_ident_config({"band_hz": [1, 2], "nonlinearities": [dict(base, **nl)]},
                              file="x.yaml").nonlinearities[0]


def test_config_syntax():
    assert [s.parameter for s in _cfg(clearances="auto").unknown] == ["g_neg", "g_pos"]
    nl = _cfg(clearances=[[1.0, 2.0], "auto"])
    assert nl.unknown[0].interval == (1.0, 2.0) and nl.unknown[1].interval is None
    nl = _cfg(clearances=[1.5, "auto"])
    assert nl.clearances[0] == 1.5 and [s.parameter for s in nl.unknown] == ["g_pos"]
    nl = _cfg(kind="bilinear", clearance=[0.5, 1.0], side="neg")
    assert nl.unknown[0].interval == (0.5, 1.0)
    nl = _cfg(kind="polynomial", exponent="auto")
    assert nl.unknown[0].candidates is None
    assert _cfg(kind="polynomial", exponent=[2, 3, 5]).unknown[0].candidates == (2.0, 3.0, 5.0)
    assert not _cfg(clearances=[1.5, 1.3]).unknown
    nl = _cfg(clearances=[1.5, 1.3], offset="auto")
    assert [s.parameter for s in nl.unknown] == ["offset"] and nl.unknown[0].interval is None
    assert _cfg(clearances=[1.5, 1.3], offset=[-0.5, 0.2]).unknown[0].interval == (-0.5, 0.2)
    assert _cfg(clearances=[1.5, 1.3], offset=-0.1).offset == -0.1


@pytest.mark.parametrize("nl, match", [
    ({"clearances": "sometimes"}, r"clearances: expected 2 numbers"),
    ({"clearances": [[2.0, 1.0], "auto"]}, r"clearances: search interval \[2, 1\]"),
    ({"clearances": [1.0, -1.0]}, r"clearances: expected a non-negative distance"),
    ({"kind": "polynomial", "exponent": [2, 3.5]}, r"exponent: candidates .* not all whole"),
    ({"kind": "polynomial", "exponent": [3]}, r"exponent: expected a list of >= 2"),
    ({"clearances": [1.0, "auto"], "offset": "auto"}, r"offset left to the data needs both"),
    ({"kind": "bilinear", "clearance": 1.0, "offset": "auto"},
     r"offset: only a trilinear .*leave the clearance to the data"),
    ({"clearances": [1.0, 1.0], "offset": [0.2, -0.2]}, r"offset: search interval"),
])
def test_config_errors_name_file_field_and_fix(nl, match):
    with pytest.raises(IdentConfigError, match=match) as err:
        _cfg(**nl)
    assert "x.yaml" in str(err.value) and "fix:" in str(err.value)


# ---------------------------------------------------------------------------- through the API / CLI
def _npz(tmp_path, model, u, y):
    path = tmp_path / "run.npz"
    np.savez(path, u=u, y=y, fs=FS, N=N, channels=np.array(model.measured_names),
             input_channels=np.array(model.input_names))
    return path


def test_cli_prints_the_estimates_and_json_holds_them(tmp_path, chain_stop, capsys):
    import yaml
    from fnsi_lab.cli import main

    model, u, y = chain_stop
    cfg = {"band_hz": list(BAND), "transient_periods": 1, "order": 6, "max_order": 12,
           "inputs": [{"name": model.input_names[0], "driving_point": "X3"}],
           "nonlinearities": [{"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
                               "clearances": "auto", "truth": list(CONTACT)}]}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "r.json"
    code = main(["ident", str(_npz(tmp_path, model, u, y)), "--config", str(tmp_path / "c.yaml"),
                 "--json", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "basis parameters from the data (order 6" in text
    printed = re.search(r"stop g_pos = ([0-9.e+-]+) \+- ", text)
    assert printed and float(printed.group(1)) == pytest.approx(5e-4, rel=1e-3)
    assert "model error vs g_pos:" in text
    res = json.loads(out.read_text())
    (nl,) = res["nonlinearities"]
    assert nl["estimated"] == ["g_neg", "g_pos"]
    assert np.allclose(nl["clearances"], GAPS, rtol=1e-3)
    assert all(0 < s < 1e-6 for s in nl["clearance_std"])
    prof = nl["objective"]["g_pos"]
    assert len(prof["values"]) == len(prof["relative_model_error"]) >= 8
    assert res["parameter_search"]["order"] == 6
    assert all(abs(c["error_percent"]) < 0.1 for c in res["coefficients"])


@pytest.mark.parametrize("keep_cubic", [False, True])
def test_a_refused_search_gives_the_linear_answer_and_says_why(tmp_path, capsys, keep_cubic):
    """Issue 29: the data cannot tell a stop's gap (a linear chain: never in contact). The
    answer is not an error but the linear fit (or keeps the fully given element), with the
    refusal in one line and in the JSON (nonlinear_vs_linear.refused)."""
    import yaml
    from fnsi_lab.cli import main

    model = sim.lumped_model("none")
    u, y = _simulate(model)
    stop = {"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
            "clearances": [[0.05, 0.1], "auto"]}
    cubic = {"name": "cubic", "kind": "polynomial", "channels": {"X3": 1}, "exponent": 3}
    cfg = {"band_hz": list(BAND), "transient_periods": 1, "order": 6,
           "inputs": [{"name": model.input_names[0], "driving_point": "X3"}],
           "nonlinearities": [stop] + ([cubic] if keep_cubic else [])}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "r.json"
    code = main(["ident", str(_npz(tmp_path, model, u, y)), "--config", str(tmp_path / "c.yaml"),
                 "--json", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    res = json.loads(out.read_text())
    nvl = res["nonlinear_vs_linear"]
    (refused,) = nvl["refused"]
    assert refused["name"] == "stop" and refused["parameters"] == ["g_neg", "g_pos"]
    assert "never in contact" in refused["reason"]
    assert [nl["name"] for nl in res["nonlinearities"]] == (["cubic"] if keep_cubic else [])
    # the chain's three modes, from the linear (or linear + cubic) model of order 6
    assert len(res["modes"]) == 3
    if keep_cubic:   # the given cubic is tested as usual; the refusal is a warning
        assert nvl["test"].startswith("F-test")
        assert any("'stop' left out" in w for w in res["warnings"])
    else:
        assert nvl["decision"] == "linear" and res["coefficients"] == []
        line = next(ln for ln in text.splitlines() if ln.startswith("nonlinear vs linear:"))
        assert "never in contact" in line and "the answer is the linear fit" in line
        from fnsi_lab.viewer.report import summary_rows
        assert ("nonlinear vs linear", nvl["statement"]) in summary_rows(res)


def test_viewer_logs_the_objective(tmp_path):
    rr = pytest.importorskip("rerun")
    from fnsi_lab.viewer import paths
    from fnsi_lab.viewer.log import log_parameter_objective

    path = tmp_path / "p.rrd"
    rec = rr.RecordingStream("fnsi-lab-test")
    rec.save(str(path))
    x = np.linspace(1.0, 2.0, 9)
    log_parameter_objective(rec, [{"label": "NC2-Z.g_pos", "values": x,
                                   "objective": (x - 1.3) ** 2 + 1e-8, "estimate": 1.3,
                                   "std": 1e-4}])
    rec.flush()
    from rerun.chunk import RrdReader

    chunks = list(RrdReader(str(path)).stream().collect().stream())
    ours = [c for c in chunks if str(c.entity_path).startswith(paths.PARAMETERS)]
    assert ours, "nothing logged under " + paths.PARAMETERS
    columns = {n for c in ours for n in c.to_record_batch().schema.names}
    # the physical values travel with the curve (export), not only canvas coordinates
    assert any("relative_model_error" in n for n in columns)


def test_search_compares_integrated_outputs_as_displacements(chain_stop):
    """Acceleration data reach the search as the displacements they integrate to: the same
    spectrum on every processed line (exact for band-limited samples), noise variances
    divided by w^4, forces and motion untouched."""
    from fnsi_lab.ident.core.periodic import as_displacement_outputs

    model, u, _ = chain_stop
    ms = multisine(N, FS, (5, 60), 20.0, n_periods=3, seed=1)   # as chain_stop
    out = sim.simulate(model, np.asarray(ms.signal).reshape(-1, 1), FS, periodic=N,
                       quantities=("displacement", "acceleration"))
    basis = (_auto("stop", "trilinear", {"X2": 1, "X3": -1}),)
    disp = _data(model, u, out.displacement, basis)
    acc = prepare_frequency_data(u=u, y=out.acceleration, sample_rate_hz=FS,
                                 samples_per_period=N, motion_for=basis, band_hz=BAND,
                                 transient_periods=1, output_quantity="acceleration",
                                 output_names=model.measured_names,
                                 input_names=model.input_names,
                                 excited_lines=excited_lines(N, FS, (5, 60)))
    conv = as_displacement_outputs(acc)
    assert conv.output_quantity == "displacement" and as_displacement_outputs(disp) is disp
    # the simulator's accelerations agree with its displacements to ~1e-5 of each line
    err = np.abs(conv.Y - disp.Y) / (np.abs(disp.Y) + 1e-6 * np.abs(disp.Y).max())
    assert err.max() < 1e-3
    assert np.array_equal(conv.E, acc.E) and conv.motion is acc.motion
    w4 = (2 * np.pi * acc.frequencies_hz) ** 4
    fake = replace(acc, noise_var=np.abs(acc.Y) ** 2, noise_cov=np.abs(acc.Y) ** 2)
    conv = as_displacement_outputs(fake)
    assert np.allclose(conv.noise_var * w4[:, None], fake.noise_var)
    assert np.allclose(conv.noise_cov * w4[:, None], fake.noise_cov)


# ---------------------------------------------------------------------------- offset: auto
def _relative_mean(model, y):
    """Mean of X2 - X3 over the steady periods: the static position the stop sees."""
    names = list(model.measured_names)
    return float(np.mean(y[N:, names.index("X2")] - y[N:, names.index("X3")]))


def _offset_auto(nl):
    return replace(nl, unknown=(ParameterSpace("offset"),))


def test_offset_auto_restores_the_position_integration_loses(chain_stop):
    """Accelerations carry no static position: the chain's asymmetric stop (gaps 0.4 / 0.5 mm,
    stiffnesses 2.0 / 1.5e4 N/m) sits 0.107 mm off its rest position on average, and with the
    clearances counted from that mean the contact stiffness comes out 12 % low. With the
    clearances known, the offset is the one position that puts both contacts where the data
    have them."""
    model, u, y = chain_stop
    ms = multisine(N, FS, (5, 60), 20.0, n_periods=3, seed=1)   # as chain_stop
    acc = sim.simulate(model, np.asarray(ms.signal).reshape(-1, 1), FS, periodic=N,
                       quantities=("acceleration",)).acceleration
    known = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=GAPS)
    data = prepare_frequency_data(u=u, y=acc, sample_rate_hz=FS, samples_per_period=N,
                                  motion_for=[_offset_auto(known)], band_hz=BAND,
                                  transient_periods=1, output_quantity="acceleration",
                                  output_names=model.measured_names,
                                  input_names=model.input_names,
                                  excited_lines=excited_lines(N, FS, (5, 60)))
    truth = _relative_mean(model, y)
    assert truth == pytest.approx(1.07e-4, rel=0.01)
    c_known = np.array([c.ls_value for c in _coefficients(data, [known])])
    assert np.max(np.abs(c_known / CONTACT - 1)) > 0.05            # measured -12 %
    res = estimate_basis_parameters(data, [_offset_auto(known)], order=6)
    (est,) = res.estimates
    # measured +0.05 %, std 2e-9: noise-free data, the offset is exact but for the integration
    assert est.unknown.parameter == "offset" and est.value == pytest.approx(truth, rel=0.01)
    assert 0 < est.std < 0.01 * GAPS[0]
    assert res.basis[0].clearances == GAPS and not res.basis[0].unknown
    c = np.array([c.ls_value for c in _coefficients(data, res.basis)])
    assert np.allclose(c, CONTACT, rtol=1e-3)                      # measured 0.00 %
    assert not any("mean relative position" in w for w in res.warnings)


@pytest.mark.parametrize("seed", [0, 1])
def test_offset_auto_absorbs_a_sensor_offset(chain_stop, seed):
    """Displacement sensors with DC offsets (+-0.135 mm on X2, X3: the relative motion reads
    0.27 mm, two thirds of the smaller gap, too low), 1 % white noise, 16 periods. Given the true
    clearances and offset 0 the stiffnesses are off by -6 % / -26 %; with ``offset: auto`` the
    offset comes back within 0.3 % and the stiffnesses within 0.4 % (3 seeds); asserted within
    2 % and 1 % (the noise-free known-gap fit on these data is exact, and the chain's
    stiffnesses scatter up to 0.8 % with 1 % noise even with the true gaps: bench/RESULTS.md)."""
    model, u, y = chain_stop
    P = 16
    u, y = np.tile(u[-N:], (P, 1)), np.tile(y[-N:], (P, 1))
    sensor = np.zeros(y.shape[1])
    names = list(model.measured_names)
    sensor[names.index("X2")], sensor[names.index("X3")] = -1.35e-4, 1.35e-4
    truth = 2.7e-4                   # what cancels the sensors (the displacements hold the rest)
    y = y + sensor + np.random.default_rng(seed).standard_normal(y.shape) * np.std(y, axis=0) * 0.01
    known = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=GAPS)
    with pytest.warns(IdentWarning, match="offset: auto"):
        _data(model, u, y, [known], transient=0)
    data = _data(model, u, y, [_offset_auto(known)], transient=0)
    c_known = np.array([c.ls_value for c in _coefficients(data, [known])])
    assert np.max(np.abs(c_known / CONTACT - 1)) > 0.05
    res = estimate_basis_parameters(data, [_offset_auto(known)], order=6)
    assert res.estimates[0].value == pytest.approx(truth, rel=0.02)
    c = np.array([c.ls_value for c in _coefficients(data, res.basis)])
    assert np.allclose(c, CONTACT, rtol=0.01)


def test_cli_offset_auto_in_summary_and_json(tmp_path, chain_stop, capsys):
    import yaml
    from fnsi_lab.cli import main

    model, u, y = chain_stop
    names = list(model.measured_names)
    y = y.copy()
    y[:, names.index("X3")] += 2e-4                   # a sensor offset on X3
    cfg = {"band_hz": list(BAND), "transient_periods": 1, "order": 6, "max_order": 12,
           "inputs": [{"name": model.input_names[0], "driving_point": "X3"}],
           "nonlinearities": [{"name": "stop", "kind": "trilinear", "channels": {"X2": 1, "X3": -1},
                               "clearances": list(GAPS), "offset": "auto",
                               "truth": list(CONTACT)}]}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "r.json"
    assert main(["ident", str(_npz(tmp_path, model, u, y)), "--config", str(tmp_path / "c.yaml"),
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    printed = re.search(r"stop offset = ([0-9.e+-]+) \+- ", text)
    assert printed and float(printed.group(1)) == pytest.approx(2e-4, rel=1e-3)
    assert "model error vs offset:" in text
    (nl,) = json.loads(out.read_text())["nonlinearities"]
    assert nl["estimated"] == ["offset"] and nl["clearance_std"] == [None, None]
    assert nl["offset"] == pytest.approx(2e-4, rel=1e-3) and 0 < nl["offset_std"] < 1e-6
    assert nl["objective"]["offset"]["interval"][0] < 2e-4 < nl["objective"]["offset"]["interval"][1]
    assert all(abs(c["error_percent"]) < 0.1 for c in json.loads(out.read_text())["coefficients"])


def test_offset_refusals(chain_stop):
    model, u, y = chain_stop
    wide = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=(5e-3, 5e-3),
                        unknown=(ParameterSpace("offset"),))
    data = _data(model, u, y, [wide])
    # the relative motion spans ~8 mm: no position between gaps of 5 mm touches both stops
    with pytest.raises(NotIdentifiableError, match=r"offset: the recorded relative motion spans"):
        search_spaces(data, [wide])
    # the truth (~0.1 mm) lies outside [0.2, 0.35] mm: the minimum is at the edge
    nl = Nonlinearity("stop", "trilinear", {"X2": 1, "X3": -1}, clearances=GAPS,
                      unknown=(ParameterSpace("offset", interval=(2e-4, 3.5e-4)),))
    y0 = y - y[N:].mean(axis=0)        # remove the static position, as integration does
    with pytest.raises(NotIdentifiableError, match=r"offset: the model error is smallest at the edge"):
        estimate_basis_parameters(_data(model, u, y0, [nl]), [nl], order=6)


# ---------------------------------------------------------------------------- the SmallSat
@pytest.mark.slow
@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
def test_smallsat_39_channels_gaps_auto(quantity):
    """The paper's SmallSat, 39 channels, NC2-Z clearances 'auto' through the one entry
    point: gaps and contact stiffnesses as with the known gaps, from displacements and from
    accelerometers with 0.1 % noise and one steady period (searched in displacement units: in
    acceleration units the model error was flat except within +-5 % of the gaps and the
    scan missed them by -57 % / -82 %). One noisy period of accelerations needs the
    integration high-pass at the band's edge (a warning says so: without it the known-gap
    coefficients are +207 % / +375 %)."""
    import fnsi_lab
    from fnsi_lab.daq.sim.smallsat import DEFAULT_CLEARANCES, NC2Z_CONTACT, smallsat_model
    from fnsi_lab.ident.config import load_ident_config, packaged_config

    model = smallsat_model()
    fs, n = 1000.0, 8192
    u = np.asarray(multisine(n, fs, (5, 50), 100.0, n_periods=6, seed=1).signal[0], float)
    y = getattr(sim.simulate(model, u[:, None], fs, periodic=n, quantities=(quantity,)), quantity)
    if quantity == "acceleration":
        y = y + 1e-3 * np.std(y, axis=0) * np.random.default_rng(0).standard_normal(y.shape)
    src = {"u": u[:, None], "y": y, "fs": fs, "N": n, "channels": list(model.measured_names),
           "input_channels": ["F-NC2W-Z"], "quantity": quantity}
    cfg = replace(load_ident_config(packaged_config("smallsat39")), output_quantity=quantity,
                  highpass_hz=5.0 if quantity == "acceleration" else None)
    (nl,) = cfg.nonlinearities
    auto = replace(cfg, nonlinearities=(replace(nl, clearances=(0.0, 0.0), unknown=(
        ParameterSpace("g_neg"), ParameterSpace("g_pos"))),))
    res = fnsi_lab.identify(src, auto).to_json()
    (got,) = res["nonlinearities"]
    truth = {"NC2-Z:neg": NC2Z_CONTACT["neg"], "NC2-Z:pos": NC2Z_CONTACT["pos"]}
    if quantity == "displacement":
        # measured 1e-5 (gaps) and 0.005 % (coefficients); the targets 2 % and 0.5 %
        gap_tol, coef_tol = 1e-3, 2e-3
    else:
        # measured -0.76 / -0.28 % and -2.1 / +0.2 % (the known gaps: -1.5 / +0.1 %: the
        # basis misses the motion under the band, ident.core.periodic highpass_hz); the gaps count
        # from the mean position (integrated outputs have no DC; a note says so). The issue's
        # 2 % on the gaps; 3 % on the coefficients, against +200 % before
        gap_tol, coef_tol = 2e-2, 3e-2
        assert any("mean relative position" in w for w in res["warnings"])
    assert np.allclose(got["clearances"], DEFAULT_CLEARANCES["NC2-Z"], rtol=gap_tol)
    for c in res["coefficients"]:
        assert c["value"] == pytest.approx(truth[c["name"]], rel=coef_tol)


@pytest.mark.slow
def test_smallsat_39_channels_gaps_auto_six_noisy_periods():
    """The issue's SmallSat-like target with noise: 39 displacement channels, 1 % white noise
    on each, 6 steady periods. The motion noise is 0.33 % of the gaps (the search then does
    not correct for it); the plain model error on unweighted decompositions finds them
    (weighting every output by 1/noise made a needle of the objective: -8 % / -3 %)."""
    import fnsi_lab
    from fnsi_lab.daq.sim.smallsat import DEFAULT_CLEARANCES, NC2Z_CONTACT, smallsat_model
    from fnsi_lab.ident.config import load_ident_config, packaged_config

    model = smallsat_model()
    fs, n = 1000.0, 8192
    u = np.asarray(multisine(n, fs, (5, 50), 100.0, n_periods=11, seed=1).signal[0], float)
    y = sim.simulate(model, u[:, None], fs, periodic=n, quantities=("displacement",)).displacement
    y = y + 0.01 * np.std(y, axis=0) * np.random.default_rng(0).standard_normal(y.shape)
    src = {"u": u[:, None], "y": y, "fs": fs, "N": n, "channels": list(model.measured_names),
           "input_channels": ["F-NC2W-Z"]}
    cfg = load_ident_config(packaged_config("smallsat39"))      # 5 transient periods
    (nl,) = cfg.nonlinearities
    auto = replace(cfg, nonlinearities=(replace(nl, clearances=(0.0, 0.0), unknown=(
        ParameterSpace("g_neg"), ParameterSpace("g_pos"))),))
    res = fnsi_lab.identify(src, auto).to_json()
    (got,) = res["nonlinearities"]
    # measured over 3 noise seeds: gaps within 0.073 %, coefficients within 0.26 % (known
    # gaps: within 0.25 %); the targets, 2 % and 0.5 %
    assert np.allclose(got["clearances"], DEFAULT_CLEARANCES["NC2-Z"], rtol=2e-2)
    truth = {"NC2-Z:neg": NC2Z_CONTACT["neg"], "NC2-Z:pos": NC2Z_CONTACT["pos"]}
    for c in res["coefficients"]:
        assert c["value"] == pytest.approx(truth[c["name"]], rel=5e-3)
    assert res["parameter_search"]["n_evaluations"] < 60


def _stop_recording(tmp_path):
    """A real MCAP recording of the chain with its stop (fnsi-lab acquire), its stop's truth
    and an ident config naming that element with clearances 'auto'."""
    import yaml
    import fnsi_lab

    exp = yaml.safe_load((__import__("pathlib").Path(fnsi_lab.daq.__file__).parent / "data"
                          / "lumped.yaml").read_text())
    exp["source"]["options"]["lumped"] = {"variant": "trilinear"}
    exp["excitation"].update(band_hz=[5, 60], rms=20.0, samples_per_period=8192,
                             realizations=1, periods=3, transient_periods=1)
    exp["sample_rate_hz"] = 1024
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(exp))
    rec = tmp_path / "stop.mcap"
    fnsi_lab.acquire(str(tmp_path / "exp.yaml"), rec)
    (el,) = fnsi_lab.open_recording(rec).truth["nonlinearities"]
    cfg = {"band_hz": list(BAND), "order": 6, "max_order": 12,
           "inputs": [{"name": "F-X3", "driving_point": "X3"}],
           "nonlinearities": [{"name": el["name"], "kind": "trilinear",
                               "channels": {"X2": 1, "X3": -1}, "clearances": "auto"}]}
    return rec, el, cfg


def test_simulated_recording_truth_is_compared_never_used(tmp_path):
    """'auto' gaps are estimated from the data; the recording's truth only fills the
    coefficients' exact values and the gaps' error, and raises no 'clearances differ'
    warning."""
    import fnsi_lab

    rec, el, cfg = _stop_recording(tmp_path)
    res = fnsi_lab.identify(str(rec), cfg, order=6).to_json()
    (nl,) = res["nonlinearities"]
    assert nl["estimated"] == ["g_neg", "g_pos"]
    assert not any("differ" in w for w in res["warnings"])
    # measured -0.003 % / +0.00003 % (gaps), -0.002 % / -0.001 % (coefficients)
    assert all(abs(e) < 0.2 for e in nl["clearance_error_percent"])
    assert np.allclose(nl["clearances"], el["clearances"], rtol=2e-3)
    assert all(c["error_percent"] is not None and abs(c["error_percent"]) < 0.5
               for c in res["coefficients"])


def test_live_service_shows_the_objective_in_rerun(tmp_path):
    """The recording replayed through the live identification service with the 'auto'
    config: the last update's view carries the objective profiles, and they reach a real
    Rerun recording under /ident/parameters."""
    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from fnsi_lab.replay.service import IdentService
    from fnsi_lab.viewer.views import auto_view
    from fnsi_lab.replay.identifiers import config_identifier
    from fnsi_lab.replay.source import ReplaySource
    from fnsi_lab.viewer import paths
    from fnsi_lab.viewer.log import log_identification

    rec, el, cfg = _stop_recording(tmp_path)
    src = ReplaySource(rec)
    identify, _ = config_identifier(parse_ident_config(cfg), orders="2:12", channels=src.channels)
    svc = IdentService.for_recording_metadata(src.channels, src.sample_rate_hz, src.metadata,
                                              identify).start(src)
    svc.finish()
    src.close()
    view = auto_view(svc.updates[-1])
    profiles = view["parameters"]["profiles"]
    assert [p["label"] for p in profiles] == [f"{el['name']}.g_neg", f"{el['name']}.g_pos"]
    assert np.allclose([p["estimate"] for p in profiles], el["clearances"], rtol=2e-3)
    out = tmp_path / "live.rrd"
    stream = rr.RecordingStream("fnsi-lab-test")
    stream.save(str(out))
    log_identification(stream, view, update=svc.updates[-1].update)
    stream.flush()
    chunks = list(RrdReader(str(out)).stream().collect().stream())
    assert any(str(c.entity_path).startswith(paths.PARAMETERS) for c in chunks)
