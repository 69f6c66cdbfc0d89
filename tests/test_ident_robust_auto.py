"""The robust pipeline on exact frequency-domain data of a known linear extended-input model.

Data: a 3-DOF chain (6 states, modes 10-40 Hz) driven by one force and one "basis" column;
``Y(k) = G_d(z_k) E(k)`` exactly (ZOH model), plus seeded output noise. The pipeline must
find the order, keep the three physical modes and remove the spurious poles of a higher
order. Seconds, not minutes: the sweep is short and the lines are few.
"""

import json

import numpy as np
import pytest
import scipy.linalg as sla

from fnsi_lab.ident.robust import auto
from fnsi_lab.ident.core import fnsi, state_space
from fnsi_lab.ident.core.fast_bd import model_error
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import IdentError

FS = 256.0
N = 1024


def _chain():
    M = np.diag([1.0, 1.0, 1.0])
    K = np.array([[3e4, -1e4, 0], [-1e4, 2e4, -1e4], [0, -1e4, 1e4]])
    C = 2e-4 * K + np.array([[5.0, -5.0, 0], [-5.0, 5.0, 0], [0, 0, 0]])
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-Mi @ K, -Mi @ C]])
    Tp = np.array([[0.0], [0.0], [1.0]])
    L = np.array([[1.0], [-1.0], [0.0]])
    c_true = 2.0
    B = np.vstack([np.zeros((3, 2)), Mi @ np.hstack([Tp, -c_true * L])])
    Cc = np.hstack([np.eye(3), np.zeros((3, 3))])
    return A, B, Cc


def make_data(noise=1e-3, seed=0, f_band=(2.0, 80.0), f_exc=(2.0, 50.0)):
    rng = np.random.default_rng(seed)
    A, B, C = _chain()
    Ad = sla.expm(A / FS)
    Bd = (Ad - np.eye(6)) @ np.linalg.solve(A, B)
    lines = np.arange(int(f_band[0] * N / FS), int(f_band[1] * N / FS) + 1)
    f = lines * FS / N
    z = np.exp(2j * np.pi * lines / N)
    exc = (f >= f_exc[0]) & (f <= f_exc[1])
    E = np.zeros((lines.size, 2), complex)
    E[exc, 0] = np.exp(2j * np.pi * rng.random(exc.sum()))
    E[:, 1] = 0.3 * (rng.standard_normal(lines.size) + 1j * rng.standard_normal(lines.size))
    G = np.array([C @ np.linalg.solve(zk * np.eye(6) - Ad, Bd) for zk in z])
    Y = np.einsum("kpm,km->kp", G, E)
    scale = np.sqrt(np.mean(np.abs(Y) ** 2))
    Y = Y + noise * scale * (rng.standard_normal(Y.shape) + 1j * rng.standard_normal(Y.shape)) / np.sqrt(2)
    data = FrequencyData(lines=lines, frequencies_hz=f, z=z, Y=Y, E=E, input_scale=np.ones(2),
                         noise_cov=None, n_inputs=1, sample_rate_hz=FS, samples_per_period=N,
                         output_names=("x1", "x2", "x3"), input_names=("p",), excited=exc,
                         basis_names=("h",), band_hz=f_band, time_base="zoh")
    lam = np.linalg.eigvals(A)
    lam = lam[lam.imag > 0]
    return data, np.sort(np.abs(lam) / (2 * np.pi)), np.sort(-lam.real / np.abs(lam))


@pytest.fixture(scope="module")
def noisy():
    return make_data()


def test_fast_model_error_matches_core_steady_state(noisy):
    data, _, _ = noisy
    dec = fnsi.subspace_decomposition(data, max_order=12)
    m = fnsi.model_at_order(dec, data, 8)
    mask = data.excited
    v_fast = model_error(m, data, mask)
    Yss = fnsi.steady_state_output(m, data)
    v_ref = np.sum(np.abs(data.Y[mask] - Yss[mask]) ** 2) / np.sum(np.abs(data.Y[mask]) ** 2)
    # same algebra in a different order: rounding only
    assert v_fast == pytest.approx(v_ref, rel=1e-9)


@pytest.mark.parametrize("time_base", ["zoh", "band-limited"])
def test_modal_form_matches_the_ct_and_dt_models(noisy, time_base):
    from dataclasses import replace
    data, _, _ = noisy
    data = replace(data, time_base=time_base)
    dec = fnsi.subspace_decomposition(data, max_order=12)
    m = fnsi.model_at_order(dec, data, 6)
    mu, lam, ch, bh, ch_d, bh_d = auto.modal_form(m)
    np.testing.assert_allclose(np.exp(lam / FS), mu, rtol=1e-12)
    w = 2 * np.pi * np.array([7.0, 23.0, 41.0])
    H = np.array([(ch / (1j * wk - lam)) @ bh for wk in w]) + m.d_c
    H_ct = state_space.transfer(m.a_c, m.b_c, m.c_c, m.d_c, 1j * w)
    z = np.exp(1j * w / FS)
    G = np.array([(ch_d / (zk - mu)) @ bh_d for zk in z]) + m.d_d
    # the same algebra in modal and in state coordinates: rounding only (measured ~1e-14)
    np.testing.assert_allclose(H, H_ct, rtol=1e-8, atol=1e-12 * np.abs(H_ct).max())
    np.testing.assert_allclose(G, fnsi.transfer_discrete(m, z), rtol=1e-8,
                               atol=1e-12 * np.abs(G).max())
    if time_base == "zoh":   # the exact ZOH inverse: frf is the CT model
        np.testing.assert_allclose(fnsi.frf(m, w / (2 * np.pi)), H_ct, rtol=1e-10)
    else:                    # band-limited samples: frf is the DT transfer on the unit circle
        np.testing.assert_allclose(fnsi.frf(m, w / (2 * np.pi)), G, rtol=1e-10)


def test_pipeline_selects_order_keeps_physical_modes(noisy):
    data, f_true, z_true = noisy
    # 'stabilised': poles out of band that only fit noise go too, so the reduced model is
    # the true 6-state one (the default 'keep' leaves every stable out-of-band pole)
    res = auto.identify_auto(data, {"out_of_band": "stabilised"}, orders=range(2, 21),
                             reduce_at=16)
    # 3 outputs -> IC over the excited band; noise 1e-3: V floor ~1e-6, true order 6
    assert res.selected_order == 6
    assert res.information_criterion.band == "excited"
    md = res.modal_dominancy
    kept = np.sort(md.frequency_hz[res.physical])
    # the 3 physical modes are kept, nothing else (noise 1e-3 -> frequency error << 0.5 %)
    assert kept.size == 3
    np.testing.assert_allclose(kept, f_true, rtol=5e-3)
    assert res.separation_ratio > 10
    assert res.confidence["level"] in ("clear", "moderate")
    assert res.reduced is not None and res.reduced.order == 6
    rm = res.reduced.poles.modes()
    np.testing.assert_allclose(np.sort(rm["frequency_hz"]), f_true, rtol=5e-3)
    np.testing.assert_allclose(np.sort(rm["damping_ratio"]), z_true, rtol=0.05)
    d = json.loads(res.to_json())
    for key in ("information_criterion", "selected_order", "stabilisation", "mdi",
                "separation_ratio", "confidence", "reduced"):
        assert key in d
    assert {"frequency_hz", "damping_ratio", "mdi_h2", "mdi_hinf", "physical"} <= set(d["mdi"][0])


def test_reduction_does_not_degrade_fit(noisy):
    data, _, _ = noisy
    res = auto.identify_auto(data, orders=range(2, 21), reduce_at=16)
    from fnsi_lab.ident.robust.order_selection import relative_model_error
    v_full = relative_model_error(data.Y, fnsi.steady_state_output(res.full_model, data))
    v_red = relative_model_error(data.Y, fnsi.steady_state_output(res.reduced, data))
    v_sel = relative_model_error(data.Y, fnsi.steady_state_output(res.model, data))
    # the reduced model fits like the true-order model (within noise-level differences)
    assert v_red < 1.5 * v_sel
    assert v_full <= v_red * 1.0001


def test_options_validation():
    with pytest.raises(IdentError, match="mdi_norm"):
        auto.AutoOptions(mdi_norm="l1").validate()
    with pytest.raises(IdentError, match="unknown auto option"):
        auto.AutoOptions.from_dict({"bogus": 1})
    o = auto.AutoOptions.from_dict({"ic_band": [5, 50], "top_n": 3})
    assert o.ic_band == (5.0, 50.0) and o.top_n == 3


def test_confidence_levels():
    c = auto.confidence_statement(50.0, 3, {})
    assert c["level"] == "clear"
    c = auto.confidence_statement(50.0, 3, {"dropped_fully_stable": [12.0]})
    assert c["level"] == "moderate" and "12.00 Hz" in c["statement"]
    assert auto.confidence_statement(1.5, 3, {})["level"] == "ambiguous"
    assert auto.confidence_statement(4.35, 3, {})["level"] == "moderate"


@pytest.mark.parametrize("d_zero", [False, True])
def test_fast_bd_matches_core_estimate_bd(noisy, d_zero):
    data, _, _ = noisy
    dec = fnsi.subspace_decomposition(data, max_order=14)
    G = dec.observability[:, :12]
    p = data.n_outputs
    c = G[:p]
    a = np.linalg.lstsq(G[:-p], G[p:], rcond=None)[0]
    b1, d1 = auto.fast_estimate_bd(a, c, data, d_zero=d_zero)
    b2, d2 = fnsi.estimate_bd(a, c, data, d_zero=d_zero, weighted=False)
    # same LS problem, both refined twice: agreement to ~1e-10 of the largest entry (the
    # normal equations square cond ~1e3 -> 1e-10 is a generous rounding bound)
    assert np.max(np.abs(b1 - b2)) <= 1e-9 * np.max(np.abs(b2))
    assert np.max(np.abs(d1 - d2)) <= 1e-9 * max(np.max(np.abs(d2)), np.max(np.abs(b2)))


def test_fallback_when_no_spurious_pole_in_band():
    """All eligible modes genuine, MDIs within ~1 decade: the largest gap would split genuine
    modes; the fallback keeps every stabilised mode above 1e-3 of the largest MDI."""
    data, f_true, _ = make_data(noise=1e-3)
    res = auto.identify_auto(data, orders=range(2, 9), reduce_at=6)
    # at the true order there is nothing spurious in band: the gap is between genuine modes
    kept = np.sort(res.modal_dominancy.frequency_hz[res.physical])
    np.testing.assert_allclose(kept, f_true, rtol=5e-3)
    if res.separation_ratio < res.options.clear_ratio:
        assert res.confidence["fallback_stabilisation"]
    res2 = auto.identify_auto(data, {"fallback": "none"}, orders=range(2, 9), reduce_at=6)
    assert res2.physical.sum() <= res.physical.sum()


def test_weighted_data_report_weighted_models(noisy):
    """With a noise covariance the sweep uses the fast unweighted B, D, and the reported
    models (selected order, MDI order) are re-estimated with the core's weighted LS."""
    from dataclasses import replace
    data, f_true, _ = noisy
    p = data.n_outputs
    var = np.full((data.n_lines, p), 1e-3 ** 2 * np.mean(np.abs(data.Y) ** 2))
    var[:, 0] *= 4.0                                  # unequal channels: weights matter
    wdata = replace(data, noise_cov=np.einsum("ki,ij->kij", var, np.eye(p)), n_periods=4)
    res = auto.identify_auto(wdata, orders=range(2, 13), reduce_at=10)
    dec = fnsi.subspace_decomposition(wdata, max_order=12)
    assert dec.weighted
    ref = fnsi.model_at_order(dec, wdata, res.selected_order)
    # identical computation path for the reported model -> equal to rounding
    np.testing.assert_allclose(res.model.b_d, ref.b_d, rtol=1e-8, atol=1e-12 * np.abs(ref.b_d).max())
    kept = np.sort(res.modal_dominancy.frequency_hz[res.physical])
    np.testing.assert_allclose(kept, f_true, rtol=5e-3)
