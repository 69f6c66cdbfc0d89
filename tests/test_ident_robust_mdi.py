"""MDI closed forms against quadrature / dense grids, threshold and split-mode guard rails."""

import numpy as np
import pytest
from scipy.integrate import quad

from fnsi_lab.ident.robust import mdi
from fnsi_lab.ident.errors import IdentError

BAND = (2 * np.pi * 10.0, 2 * np.pi * 100.0)   # rad/s

# (pole, description): in band, above band, heavily damped, below band, band edge
POLES = [
    (-0.5 + 2 * np.pi * 60j, "in band"),
    (-3.0 + 2 * np.pi * 150j, "above band"),
    (-0.6 * 2 * np.pi * 40 + 0.8 * 2 * np.pi * 40j, "60 % damping"),
    (-0.2 + 2 * np.pi * 4j, "below band"),
    (-0.4 + 2 * np.pi * 10j, "band edge"),
]


def _quad_band(fun, band):
    w1, w2 = band
    # many narrow peaks: give quad the pole locations as break points
    opts = dict(epsabs=0.0, epsrel=1e-12, limit=500)
    return (quad(fun, w1, w2, **opts)[0] + quad(fun, -w2, -w1, **opts)[0]) / (2 * np.pi)


def _residue(rng, p=3, m=2):
    c = rng.standard_normal(p) + 1j * rng.standard_normal(p)
    b = rng.standard_normal(m) + 1j * rng.standard_normal(m)
    return c, b


@pytest.mark.parametrize("lam,desc", POLES)
def test_frh2_single_and_pair_match_quadrature(lam, desc):
    rng = np.random.default_rng(1)
    c, b = _residue(rng)
    R = np.outer(c, b)
    r2 = np.linalg.norm(R) ** 2

    def single(w):
        return r2 / abs(1j * w - lam) ** 2

    def pair(w):
        g = R / (1j * w - lam) + R.conj() / (1j * w - np.conj(lam))
        return np.real(np.trace(g.conj().T @ g))

    ref_s = _quad_band(single, BAND)
    ref_p = _quad_band(pair, BAND)
    cross = np.conj(np.sum(c * c) * np.sum(b * b))
    # closed forms are exact; quad at rel. 1e-12 on smooth Lorentzians -> 1e-9 is generous
    assert mdi.frh2_single(r2, lam, BAND) == pytest.approx(ref_s, rel=1e-9)
    assert mdi.frh2_pair(r2, cross, lam, BAND) == pytest.approx(ref_p, rel=1e-9)
    # the general sum formula is an independent closed form: must agree with both
    lams = np.array([lam, np.conj(lam)])
    C = np.stack([c, c.conj()], axis=1)
    B = np.stack([b, b.conj()], axis=0)
    assert mdi.frh2_sum(lams, C, B, BAND) == pytest.approx(ref_p, rel=1e-9)
    assert mdi.frh2_sum(lams[:1], C[:, :1], B[:1], BAND) == pytest.approx(ref_s, rel=1e-9)


def test_real_pole_seed_equals_single():
    lam = -7.0 + 0j
    # real pole: seed Eq. 18 reading and Eq. 16-17 coincide exactly (docs/method.md §5.2); rounding only
    assert mdi.frh2_seed(2.0, lam, BAND) == pytest.approx(mdi.frh2_single(2.0, lam, BAND), rel=1e-13)


def test_seed_close_to_pair_for_light_damping_in_band():
    lam = -0.5 + 60j
    c = np.array([1.0 + 0.2j, 0.3 - 0.1j])
    b = np.array([0.7 - 0.3j])
    r2 = np.linalg.norm(np.outer(c, b)) ** 2
    cross = np.conj(np.sum(c * c) * np.sum(b * b))
    band = (10.0, 100.0)
    ratio = mdi.frh2_seed(r2, lam, band) / mdi.frh2_pair(r2, cross, lam, band)
    # docs/method.md §5.2 quotes 1.001 for this pole and band; residue phase moves it by < 1 %
    assert ratio == pytest.approx(1.0, abs=0.01)


def test_unstable_pole_gives_finite_band_integral():
    lam = 0.5 + 2 * np.pi * 60j
    ref = _quad_band(lambda w: 1.0 / abs(1j * w - lam) ** 2, BAND)
    assert mdi.frh2_single(1.0, lam, BAND) == pytest.approx(ref, rel=1e-9)


@pytest.mark.parametrize("lam,desc", POLES)
def test_hinf_against_dense_grid(lam, desc):
    rnorm = 2.5
    # unrestricted sup attained at w = Im lam exactly: evaluate there
    assert mdi.hinf_single(rnorm, lam) == pytest.approx(rnorm / abs(1j * lam.imag - lam), rel=1e-14)
    w = np.concatenate([np.linspace(*BAND, 400001), -np.linspace(*BAND, 400001)])
    grid = np.max(rnorm / np.abs(1j * w - lam))
    # grid step ~1.4e-3 rad/s; the peak is flat to second order: rel. error < (step/sigma)^2
    sigma = abs(lam.real)
    tol = max(1e-12, (np.diff(BAND)[0] / 400000 / sigma) ** 2)
    assert mdi.hinf_band(rnorm, lam, BAND) == pytest.approx(grid, rel=tol)


def test_modal_dominancy_from_state_space_matches_direct_residues():
    rng = np.random.default_rng(3)
    # random real stable 8-state system with 2 inputs, 3 outputs
    lam_true = np.array([-0.3 + 30j, -0.3 - 30j, -1 + 200j, -1 - 200j, -2 + 400j, -2 - 400j,
                         -50.0, -800.0])
    V = rng.standard_normal((8, 8))
    # build a real A from a real block-diagonal modal form
    blocks = np.zeros((8, 8))
    for k in range(3):
        s, w = -lam_true[2 * k].real, lam_true[2 * k].imag
        blocks[2 * k:2 * k + 2, 2 * k:2 * k + 2] = [[-s, w], [-w, -s]]
    blocks[6, 6], blocks[7, 7] = -50.0, -800.0
    A = V @ blocks @ np.linalg.inv(V)
    B = rng.standard_normal((8, 2))
    C = rng.standard_normal((3, 8))
    lam, ch, bh = mdi.modal_decomposition(A, B, C)
    md = mdi.modal_dominancy(lam, ch, bh, (1.0, 100.0))
    assert md.eigenvalues.size == 5                       # 3 pairs + 2 real poles
    assert md.is_pair.sum() == 3
    # each pair's h2 equals the general closed form over both members
    band = (2 * np.pi * 1.0, 2 * np.pi * 100.0)
    for k, mem in enumerate(md.members):
        ref = mdi.frh2_sum(lam[list(mem)], ch[:, list(mem)], bh[list(mem), :], band)
        assert md.values["h2"][k] == pytest.approx(ref, rel=1e-9)
    # eigenvector scaling invariance: rescale Phi columns
    s = rng.standard_normal(8) + 1j * rng.standard_normal(8)
    md2 = mdi.modal_dominancy(lam, ch * s, bh / s[:, None], (1.0, 100.0))
    np.testing.assert_allclose(md2.values["h2"], md.values["h2"], rtol=1e-12)


def test_input_weights_options():
    E = np.array([[1.0, 10.0], [1.0, 10.0j]])
    np.testing.assert_allclose(mdi.input_weights(E, 1, "default"), [1.0, 10.0])
    np.testing.assert_allclose(mdi.input_weights(E, 1, "force"), [1.0, 0.0])
    np.testing.assert_allclose(mdi.input_weights(E, 1, "raw"), [1.0, 1.0])
    with pytest.raises(IdentError, match="input_scaling"):
        mdi.input_weights(E, 1, "bogus")


def test_largest_gap_threshold_and_ratio():
    v = np.array([1e-1, 3e-2, 1e-2, 2e-5, 1e-5, 1e-6])
    t = mdi.largest_gap_threshold(v)
    assert t.physical.tolist() == [True, True, True, False, False, False]
    assert t.separation_ratio == pytest.approx(500.0, rel=1e-12)
    assert t.threshold == pytest.approx(np.sqrt(1e-2 * 2e-5), rel=1e-12)
    # candidates: the largest value excluded beforehand
    t2 = mdi.largest_gap_threshold(v, candidates=[False, True, True, True, True, True])
    assert not t2.physical[0] and t2.physical[1:3].all()
    # min_physical pushes the search below the 4 largest values
    t3 = mdi.largest_gap_threshold(v, min_physical=4)
    assert t3.physical.sum() == 5 and t3.separation_ratio == pytest.approx(10.0)
    t4 = mdi.largest_gap_threshold(v, top_n=2)
    assert t4.physical.sum() == 2 and t4.separation_ratio == pytest.approx(3.0)
    t5 = mdi.largest_gap_threshold(v, manual_threshold=1.5e-5)
    assert t5.physical.sum() == 4 and t5.separation_ratio == pytest.approx(2.0)
    with pytest.raises(IdentError):
        mdi.largest_gap_threshold(v, top_n=2, manual_threshold=1.0)


def test_split_mode_grouped():
    # two near-duplicate poles with large opposing residues = one weak mode split in two
    f = 2 * np.pi * 20.0
    l1 = -0.02 * f + 1j * f
    l2 = -0.02 * f * 1.001 + 1j * f * 1.0005
    big = 1e3
    lam = np.array([l1, np.conj(l1), l2, np.conj(l2), -0.03 * 300 + 300j, -0.03 * 300 - 300j])
    c = np.array([[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]], dtype=complex)
    r = 1.0
    b = np.array([[big], [big], [-big + r], [-big + r], [50.0], [50.0]], dtype=complex)
    md = mdi.modal_dominancy(lam, c, b, (1.0, 100.0))
    groups, gm = mdi.group_split_modes(md, lam, c, b)
    assert sorted(len(g) for g in groups) == [1, 2]
    g2 = [g for g in groups if len(g) == 2][0]
    # the group's joint MDI is far below the individual (spuriously large) values
    assert gm[groups.index(g2)] < 1e-3 * md.mdi[g2].min()
