"""Stacked realisations in the subspace step: each line's columns folded exactly (issue 11, 13)."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.ident import fnsi


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
    monkeypatch.setattr(fnsi, "merge_repeated_lines", lambda z, lines, E, Y: (z, E, Y))
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
    S = fnsi._projected_residual_gram(z, E, Y, lines, 6, check_order=10)
    assert S is not None          # random outputs: a noise floor far above round-off
    assert np.max(np.abs(S - reference)) <= 1e-12 * np.max(np.abs(reference))
    # outputs exactly explained by the inputs (noise-free, no dynamics beyond them): the
    # residual is round-off, which the projected form cannot resolve -> None (exact QR)
    Y_exact = E @ np.array([[1.0, 2.0, -1.0], [0.5, -1.0, 3.0]])
    assert fnsi._projected_residual_gram(z, E, Y_exact, lines, 6, check_order=10) is None


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
    monkeypatch.setattr(fnsi, "_QR_CHEAP_FLOPS", 0.0)      # always past the cheap QR
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
