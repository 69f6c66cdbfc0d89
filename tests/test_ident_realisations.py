"""Stacked realisations in the subspace step: each line's columns folded exactly (issue 11, 13)."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.ident.core import fnsi, models, subspace


def _hankel_gram(z, E, Y, i=4):
    xi = z[None, :] ** np.arange(i)[:, None]
    X = np.hstack([E, Y])
    M = (xi[:, None, :] * X.T[None]).reshape(i * X.shape[1], -1)
    return (M @ M.conj().T).real


def _stacked(R, F_u=50, m_e=2, p=1, seed=0):
    rng = np.random.default_rng(seed)
    lines = np.tile(np.arange(10, 10 + F_u), R)
    z = np.exp(2j * np.pi * lines / 512)
    E = rng.standard_normal((R * F_u, m_e)) + 1j * rng.standard_normal((R * F_u, m_e))
    Y = rng.standard_normal((R * F_u, p)) + 1j * rng.standard_normal((R * F_u, p))
    return z, lines, E, Y


def test_folding_keeps_the_gram_matrix_of_the_block_hankel_data():
    z, lines, E, Y = _stacked(R=10)
    zq, Eq, Yq = fnsi.merge_repeated_lines(z, lines, E, Y)
    assert zq.size == 50 * 3                       # q = m_e + p columns per line instead of R
    G, Gq = _hankel_gram(z, E, Y), _hankel_gram(zq, Eq, Yq)
    # the same matrix to round-off (sums of 10 products of O(1) numbers)
    assert np.max(np.abs(G - Gq)) <= 1e-12 * np.max(np.abs(G))


def test_no_folding_when_it_would_not_shrink_or_lines_repeat_unevenly():
    z, lines, E, Y = _stacked(R=3)                 # R = q: nothing to gain
    assert fnsi.merge_repeated_lines(z, lines, E, Y)[0] is z
    z, lines, E, Y = _stacked(R=10)
    keep = np.ones(z.size, bool)
    keep[3] = False                                # one line one realisation short
    assert fnsi.merge_repeated_lines(z[keep], lines[keep], E[keep], Y[keep])[0].size == keep.sum()


def _no_folding(monkeypatch):
    """The reference path: the QR and the model error over every stacked realisation."""
    from fnsi_lab.ident.core import fast_bd
    monkeypatch.setattr(subspace, "fold_repeated_lines", lambda z, lines, E, Y: None)
    monkeypatch.setattr(fast_bd, "line_fold", lambda data: None)


def test_identification_of_folded_realisations_matches_the_unfolded_one(monkeypatch):
    """Lab Duffing, 8 one-period realisations stacked: the same answer either way.

    The two paths differ only by round-off in an ill-conditioned projection (the block rows
    of the extended input are close to collinear): measured 0.01 % on the coefficient with
    10 realisations of 8192 samples (bench/RESULTS.md, Real data), far below its 0.3 %
    spread across realisations.
    """
    import fnsi_lab
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.lab import LabRealism, duffing_model, lab_experiment
    fs, N = 610.35, 2048
    ms = multisine(N, fs, (0.3, 200.0), 0.03, n_realizations=8, seed=2, grid="odd")
    rec = lab_experiment(duffing_model(5.33e-6, 2.2e-4, 0.98, 3.9), ms,
                         LabRealism(snr_db=60, input_snr_db=60), seed=2)
    cfg = {"band_hz": [0.3, 200.0], "inputs": [{"name": "u0", "driving_point": "y0"}],
           "nonlinearities": [{"name": "k3", "kind": "polynomial", "channels": {"y0": 1},
                               "exponent": 3}]}
    src = {"u": rec.u, "y": rec.y, "fs": fs, "N": N}
    folded = fnsi_lab.identify(src, cfg, order=2)
    _no_folding(monkeypatch)
    plain = fnsi_lab.identify(src, cfg, order=2)
    assert folded.coefficients[0]["value"] == pytest.approx(plain.coefficients[0]["value"],
                                                            rel=5e-4)
    assert folded.modes[0]["frequency_hz"] == pytest.approx(plain.modes[0]["frequency_hz"],
                                                            rel=1e-5)


def _hankel_qr_residual(z, E, Y, i):
    """``L22 L22^T`` by the exact QR of the block Hankel data (the reference)."""
    import scipy.linalg as sla
    r = np.arange(i)
    xi = z[None, :] ** r[:, None]
    Ei = (xi[:, None, :] * E.T[None]).reshape(i * E.shape[1], -1)
    Yi = (xi[:, None, :] * Y.T[None]).reshape(i * Y.shape[1], -1)
    M = np.block([[Ei.real, Ei.imag], [Yi.real, Yi.imag]])
    R = sla.qr(M.T, mode="r")[0][:M.shape[0]]
    L22 = R[i * E.shape[1]:, i * E.shape[1]:].T
    return L22 @ L22.T


def test_projected_gram_equals_the_qr_residual_and_refuses_an_unresolved_floor():
    z, lines, E, Y = _stacked(R=4, F_u=100, m_e=2, p=3, seed=1)
    reference = _hankel_qr_residual(z, E, Y, 6)
    S = subspace._projected_residual_gram(z, E, Y, lines, 6, check_order=10)
    assert S is not None          # random outputs: a noise floor far above round-off
    assert np.max(np.abs(S - reference)) <= 1e-12 * np.max(np.abs(reference))
    # outputs exactly explained by the inputs (noise-free, no dynamics beyond them): the
    # residual is round-off, which the projected form cannot resolve -> None (exact QR)
    Y_exact = E @ np.array([[1.0, 2.0, -1.0], [0.5, -1.0, 3.0]])
    assert subspace._projected_residual_gram(z, E, Y_exact, lines, 6, check_order=10) is None


def test_auto_method_takes_the_projected_form_only_on_noisy_data(monkeypatch):
    """Above the cheap-QR cost, noisy data go through the projected form with the QR's
    singular values; noise-free data keep the QR."""
    rng = np.random.default_rng(2)
    R, F_u, N = 8, 300, 2048
    lines = np.tile(np.arange(20, 20 + F_u), R)
    z = np.exp(2j * np.pi * lines / N)
    E = rng.standard_normal((lines.size, 1)) + 1j * rng.standard_normal((lines.size, 1))
    pole = 0.98 * np.exp(2j * np.pi * 100 / N)
    H = 1.0 / ((z - pole) * (z - pole.conj()))
    clean = np.stack([H, z * H, H / z], axis=1) * E
    monkeypatch.setattr(subspace, "_QR_CHEAP_FLOPS", 0.0)      # always past the cheap QR
    for noise, expected in ((1e-3, "projected"), (0.0, "qr")):
        Y = clean + noise * (rng.standard_normal(clean.shape)
                             + 1j * rng.standard_normal(clean.shape))
        data = _frequency_data(z, lines, E, Y, N)
        dec = fnsi.subspace_decomposition(data, max_order=6, block_rows=8, weighted=False)
        assert expected in dec.timings_s
        if expected == "projected":
            ref = fnsi.subspace_decomposition(data, max_order=6, block_rows=8,
                                              weighted=False, method="qr")
            # the projected form's round-off on an eigenvalue is about eps trace(Y_i Y_i^T),
            # accepted only at most 1e-6 of the floor: singular values within 5e-7 relative
            np.testing.assert_allclose(dec.singular_values[:7], ref.singular_values[:7],
                                       rtol=1e-6)


def _frequency_data(z, lines, E, Y, N):
    return fnsi.FrequencyData(lines=lines, frequencies_hz=lines / N, z=z, Y=Y, E=E,
                              input_scale=np.ones(E.shape[1]), noise_cov=None,
                              n_inputs=E.shape[1], sample_rate_hz=1.0, samples_per_period=N,
                              output_names=("a", "b", "c"), input_names=("u",),
                              excited=np.ones(lines.size, bool))


def _modal_realisations(R, *, F_u=120, m_e=2, p=4, mismatch=1e-9, noise=0.0, seed=0, N=512):
    """``R`` stacked realisations of a 4-state DT system with ``m_e`` inputs and ``p`` outputs.

    ``Y_k = G(z_k) E_k`` exactly, plus a model mismatch (``mismatch``) and noise (``noise``),
    both complex white, relative to the output RMS: noise-free realisations are of rank
    ``m_e`` per line, the mismatch sets the singular values beyond the order (7e-10 of the
    first), far below the Gram form's ``sqrt(eps)`` resolution.
    """
    rng = np.random.default_rng(seed)
    lines = np.tile(np.arange(20, 20 + F_u), R)
    z = np.exp(2j * np.pi * lines / N)
    mu = np.array([0.97 * np.exp(2j * np.pi * 40 / N), 0.95 * np.exp(2j * np.pi * 90 / N)])
    mu = np.concatenate([mu, mu.conj()])
    psi = rng.standard_normal((p, 2)) + 1j * rng.standard_normal((p, 2))
    L = rng.standard_normal((2, m_e)) + 1j * rng.standard_normal((2, m_e))
    E = rng.standard_normal((lines.size, m_e)) + 1j * rng.standard_normal((lines.size, m_e))
    Y = (((E @ np.vstack([L, L.conj()]).T) / (z[:, None] - mu)) @ np.hstack([psi, psi.conj()]).T
         + E @ rng.standard_normal((p, m_e)).T)
    Y = Y + (mismatch + noise) * np.sqrt(np.mean(np.abs(Y) ** 2)) * (
        rng.standard_normal(Y.shape) + 1j * rng.standard_normal(Y.shape))
    data = fnsi.FrequencyData(
        lines=lines, frequencies_hz=lines / N, z=z, Y=Y, E=E, input_scale=np.ones(m_e),
        noise_cov=None, n_inputs=1, sample_rate_hz=1.0, samples_per_period=N,
        output_names=tuple(f"y{c}" for c in range(p)), input_names=("u",),
        basis_names=tuple(f"h{c}" for c in range(m_e - 1)), excited=np.ones(lines.size, bool),
        n_realizations=R)
    return data, mu


@pytest.mark.parametrize("R, mismatch, noise", [(8, 1e-9, 0.0), (3, 0.0, 0.0), (8, 0.0, 1e-3)])
def test_fold_keeps_the_block_hankel_gram(R, mismatch, noise):
    """QR rows plus the lag sums of the small components: the Gram matrix of every
    realisation, whether lines are rank-deficient (noise-free, R > m_e) or not (noisy)."""
    data, _ = _modal_realisations(R, mismatch=mismatch, noise=noise)
    fold = fnsi.fold_repeated_lines(data.z, data.lines, data.E, data.Y)
    i, m_e = 4, data.n_extended_inputs
    G = _hankel_gram(data.z, data.E, data.Y, i)
    Gq = _hankel_gram(fold.z, fold.E, fold.Y, i)
    if fold.small_gram is not None:
        Gq = Gq + subspace._lag_sum_hankel_gram(fold.z_unique, fold.small_gram, i, m_e)
    # sums of a few hundred products of O(1) numbers: round-off, 1e-13 of the largest entry
    assert np.max(np.abs(G - Gq)) <= 1e-13 * np.max(np.abs(G))
    if noise:                       # every component carries noise: all of them are QR rows
        assert fold.small_gram is None and fold.deficient_share == 0.0
        assert fold.z.size == 120 * min(R, m_e + data.n_outputs)   # min(R, q) per line
    else:                           # rank m_e per line: m_e QR rows, the rest as lag sums
        assert fold.deficient_share == 1.0 and fold.z.size == 120 * min(R, m_e)


def test_folded_decomposition_resolves_what_the_unfolded_qr_resolves(monkeypatch):
    """Noise-free realisations with a 7e-10 model mismatch: 2 of 8 components per line stay
    QR rows, and the singular values and poles are the exact QR's over every realisation.

    Both are backward stable with errors about ``eps ||M||``: measured 2e-16 of ``S[0]`` on
    every singular value (1.5e-8 relative on the 7e-10 tail) and 1e-15 on the poles; bounds
    1e-14 and 1e-12. The Gram form misses that tail by 5-30x (``sqrt(eps)`` resolution),
    which is why the fold does not use it on the large components.
    """
    data, mu = _modal_realisations(8, mismatch=1e-9)
    folded = fnsi.subspace_decomposition(data, max_order=8, block_rows=6, method="qr")
    fold = fnsi.fold_repeated_lines(data.z, data.lines, data.E, data.Y)
    assert fold.z.size == 120 * 2 and fold.small_gram is not None     # m_e = 2 rows per line
    gram = fnsi.subspace_decomposition(data, max_order=8, block_rows=6, method="gram")
    _no_folding(monkeypatch)
    exact = fnsi.subspace_decomposition(data, max_order=8, block_rows=6, method="qr")
    s_f, s_e = folded.singular_values, exact.singular_values
    assert s_e[4] / s_e[0] < 1e-9                                  # the tail is the mismatch
    assert np.max(np.abs(s_f - s_e)) <= 1e-14 * s_e[0]
    assert np.max(np.abs(gram.singular_values[4:10] / s_e[4:10] - 1)) > 1.0
    poles = [np.sort_complex(np.linalg.eigvals(fnsi.model_at_order(d, data, 4).a_d))
             for d in (folded, exact)]
    assert np.max(np.abs(poles[0] - poles[1])) <= 1e-12
    assert max(np.min(np.abs(poles[0] - m)) for m in mu) <= 1e-9


def test_unrepeated_lines_take_the_plain_qr_unchanged():
    """One realisation: no fold, and the QR block equals the reference formulation's."""
    data, _ = _modal_realisations(1, mismatch=1e-6)
    assert fnsi.fold_repeated_lines(data.z, data.lines, data.E, data.Y) is None
    L22 = subspace._qr_residual_block(data.z, data.E, data.Y, 6)
    ref = _hankel_qr_residual(data.z, data.E, data.Y, 6)
    assert np.allclose(L22 @ L22.T, ref, rtol=0, atol=1e-13 * np.max(np.abs(ref)))


def test_model_error_of_folded_realisations_equals_the_sum_over_every_one(monkeypatch):
    """The model error over ``min(R, m_e)`` folded rows per line plus the fixed remainder is
    the sum over every realisation: a unitary change of the realisation axis, so only
    round-off apart (bound 1e-10 relative; the error here is 1e-6 of the output energy)."""
    from fnsi_lab.ident.core import fast_bd
    data, _ = _modal_realisations(6, noise=1e-3)
    dec = fnsi.subspace_decomposition(data, max_order=8, block_rows=6)
    mask = data.frequencies_hz > 60 / 512
    errors = []
    for fold in (True, False):
        if not fold:
            data.__dict__["_ident_cache"].clear()
            monkeypatch.setattr(fast_bd, "line_fold", lambda d: None)
        model = models.model_at_order_fast(dec, data, 4)
        errors.append(fast_bd.model_error(model, data, mask))
        if fold:
            zu, inv, Ef, Yf, const = fast_bd.line_fold(data)
            assert Ef.shape == (120, 2, 2) and np.all(const > 0)
    assert 0 < errors[0] < 1e-4
    assert errors[0] == pytest.approx(errors[1], rel=1e-10)


def test_auto_method_on_noise_free_realisations_does_not_try_the_projected_form(monkeypatch):
    """Rank-deficient lines (no noise to resolve): straight to the exact QR of the fold."""
    calls = []
    monkeypatch.setattr(subspace, "_QR_CHEAP_FLOPS", 0.0)      # always past the cheap QR
    original = subspace._projected_residual_gram
    monkeypatch.setattr(subspace, "_projected_residual_gram",
                        lambda *a, **k: calls.append(1) or original(*a, **k))
    data, _ = _modal_realisations(8, mismatch=1e-9)
    assert "qr" in fnsi.subspace_decomposition(data, max_order=8, block_rows=6).timings_s
    assert not calls
    data, _ = _modal_realisations(8, noise=1e-3)
    assert "projected" in fnsi.subspace_decomposition(data, max_order=8, block_rows=6).timings_s
    assert calls


def test_coefficients_of_stacked_realisations_evaluate_each_line_once():
    """The reciprocity formula at repeated lines: one transfer evaluation per unique line,
    the same values as evaluating every row."""
    from fnsi_lab.ident.core.basis import Nonlinearity
    from fnsi_lab.ident.core.coefficients import nonlinear_coefficients
    data, _ = _modal_realisations(3, noise=1e-3)
    model = fnsi.model_at_order(fnsi.subspace_decomposition(data, max_order=8, block_rows=6),
                                data, 4)
    nl = Nonlinearity("h0", "polynomial", {"y1": 1.0})
    stacked = nonlinear_coefficients(model, data, [nl], driving_point="y0")
    once = nonlinear_coefficients(model, None, [nl], driving_point="y0",
                                  frequencies_hz=data.frequencies_hz[:120])
    assert np.allclose(stacked.values, np.tile(once.values, (3, 1)), rtol=1e-12, atol=0)
