"""Stabilisation classification, MACX, information criterion (pure array functions)."""

import numpy as np
import pytest

from fnsi_lab.ident.robust import order_selection as osel
from fnsi_lab.ident.robust import stabilisation as stab
from fnsi_lab.ident.errors import IdentError


def test_macx_properties():
    rng = np.random.default_rng(0)
    psi = rng.standard_normal(6) + 1j * rng.standard_normal(6)
    # scaling, conjugation invariance, self = 1 (exact up to rounding)
    assert stab.macx(psi, psi) == pytest.approx(1.0, abs=1e-14)
    assert stab.macx(psi, (2 - 3j) * psi) == pytest.approx(1.0, abs=1e-14)
    assert stab.macx(psi, psi.conj()) == pytest.approx(1.0, abs=1e-14)
    # real shapes: MACX == MAC
    a, b = rng.standard_normal(6), rng.standard_normal(6)
    mac = (a @ b) ** 2 / ((a @ a) * (b @ b))
    assert stab.macx(a, b) == pytest.approx(mac, rel=1e-13)
    # orthogonal real shapes: 0
    assert stab.macx([1.0, 0.0], [0.0, 1.0]) == pytest.approx(0.0, abs=1e-15)


def test_classification_all_classes():
    psi_a = np.array([1.0, 0.5, 0.2])
    psi_b = np.array([0.1, -1.0, 0.7])   # MACX with psi_a well below 0.98
    orders = [2, 4, 6]
    f = [np.array([10.0]), np.array([10.05, 20.0]), np.array([10.06, 20.5, 30.0])]
    z = [np.array([0.02]), np.array([0.0205, 0.03]), np.array([0.0206, 0.03, -0.01])]
    shapes = [psi_a[:, None], np.stack([psi_a, psi_a], 1), np.stack([psi_b, psi_a, psi_a], 1)]
    d = stab.classify_stabilisation(orders, f, z, shapes, band_hz=(5, 50))
    assert d.by_order(2).classes == ("new",)
    # 10.05 vs 10: 0.5 % freq, 2.5 % damping, same shape -> stable; 20 Hz is new
    assert d.by_order(4).classes == ("stable", "new")
    # 10.06: freq+damping but shape changed -> 'damping'; 20.5 vs 20: 2.4 % -> new;
    # 30 Hz new and unstable
    o6 = d.by_order(6)
    assert o6.classes == ("damping", "new", "new")
    assert o6.unstable.tolist() == [False, False, True]
    # shape OK but damping off by 20 % -> 'mode'; damping OK alone tested above; freq only
    d2 = stab.classify_stabilisation([2, 4], [np.array([10.0]), np.array([10.0])],
                                     [np.array([0.02]), np.array([0.024])],
                                     [psi_a[:, None], psi_a[:, None]])
    assert d2.by_order(4).classes == ("mode",)
    d3 = stab.classify_stabilisation([2, 4], [np.array([10.0]), np.array([10.0])],
                                     [np.array([0.02]), np.array([0.024])],
                                     [psi_a[:, None], psi_b[:, None]])
    assert d3.by_order(4).classes == ("frequency",)
    # out-of-band poles are not reported
    d4 = stab.classify_stabilisation([2], [np.array([1.0, 10.0])], [np.array([0.1, 0.1])],
                                     [np.stack([psi_a, psi_b], 1)], band_hz=(5, 50))
    assert d4.by_order(2).frequency_hz.tolist() == [10.0]
    assert d4.to_list()[0]["poles"][0]["class"] == "new"


def test_best_mac_candidate_is_used():
    psi_a = np.array([1.0, 0.0, 0.0])
    psi_b = np.array([0.0, 1.0, 0.0])
    d = stab.classify_stabilisation([2, 4], [np.array([10.0, 10.02]), np.array([10.01])],
                                    [np.array([0.02, 0.02]), np.array([0.02])],
                                    [np.stack([psi_a, psi_b], 1), psi_b[:, None]])
    o = d.by_order(4)
    assert o.classes == ("stable",) and o.mac[0] == pytest.approx(1.0)


def test_bad_tolerance_rejected():
    with pytest.raises(IdentError, match="freq_tol"):
        stab.classify_stabilisation([2], [np.array([1.0])], [np.array([0.1])],
                                    [np.ones((1, 1))], freq_tol=-1)


def test_information_criterion_and_selection():
    orders = np.array([2, 4, 6, 8])
    v = np.array([0.5, 0.1, 0.02, 0.0199])
    stable = np.array([True, True, True, False])
    ic = osel.InformationCriterion.from_errors(orders, v, stable, n_lines=100)
    # I = V (1 + n/F): exact arithmetic
    assert ic.value[2] == pytest.approx(0.02 * 1.06, rel=1e-15)
    assert np.isinf(ic.value[3]) and ic.selected_order == 6
    assert ic.to_list()[3]["value"] is None
    aic = osel.information_criterion(0.1, 4, 100, criterion="aic", n_outputs=3, n_extended_inputs=2)
    ntheta = 4 * (2 + 3) + 3 * 2
    assert aic == pytest.approx(0.1 * (1 + ntheta / 300), rel=1e-15)
    with pytest.raises(IdentError, match="criterion"):
        osel.information_criterion(0.1, 4, 100, criterion="bic")
    with pytest.raises(IdentError, match="unstable"):
        osel.select_order(orders, v, np.zeros(4, bool))


def test_relative_model_error_and_ic_band():
    rng = np.random.default_rng(2)
    Y = rng.standard_normal((10, 2)) + 1j * rng.standard_normal((10, 2))
    assert osel.relative_model_error(Y, 0.9 * Y) == pytest.approx(0.01, rel=1e-12)
    f = np.linspace(5, 250, 50)
    exc = f <= 50
    m, r = osel.ic_line_mask(f, exc, 3)
    assert r == "excited" and m.sum() == exc.sum()
    m, r = osel.ic_line_mask(f, exc, 39)
    assert r == "processed" and m.all()
    m, r = osel.ic_line_mask(f, exc, 39, band=(10.0, 20.0))
    assert m.sum() == np.sum((f >= 10) & (f <= 20))
    with pytest.raises(IdentError, match="ic band"):
        osel.ic_line_mask(f, exc, 3, band="foo")


def test_lookback_uses_best_of_previous_orders():
    psi = np.array([1.0, 0.5, 0.2])
    f = [np.array([10.0]), np.array([12.0]), np.array([10.01])]
    z = [np.array([0.02]), np.array([0.02]), np.array([0.02])]
    sh = [psi[:, None]] * 3
    assert stab.classify_stabilisation([4, 5, 6], f, z, sh).by_order(6).classes == ("new",)
    d = stab.classify_stabilisation([4, 5, 6], f, z, sh, lookback=2)
    assert d.by_order(6).classes == ("stable",)
