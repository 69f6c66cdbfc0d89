"""Many channels, many realisations: the compressed subspace step, the exact output split,
the Gram form of the subspace step, the per-line sums of stacked realisations."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi_lab.ident.core import fast_bd, fnsi, models, subspace
from fnsi_lab.ident.core.periodic import FrequencyData

FS, N = 1000.0, 2048
#: Six modes in the band (Hz, damping ratio).
MODES = [(31.0, 0.01), (47.0, 0.02), (62.0, 0.015), (80.0, 0.01), (104.0, 0.02), (130.0, 0.01)]


def dense_array(p: int, *, realisations: int = 1, snr_db: float = 60.0, seed: int = 0):
    """Exact DT frequency data of a 12-state real modal model seen by ``p`` sensors.

    One force and one extra input column (a basis function stand-in), lines 20-150 Hz,
    independent complex white noise ``snr_db`` below the output RMS on every channel.
    Returns the data and the true continuous-time poles (upper half plane).
    """
    rng = np.random.default_rng(seed)
    lam = np.array([-2 * np.pi * f * z + 2j * np.pi * f * np.sqrt(1 - z * z) for f, z in MODES])
    mu = np.exp(lam / FS)
    psi = rng.standard_normal((p, mu.size)) + 0.2j * rng.standard_normal((p, mu.size))
    L = rng.standard_normal((mu.size, 2)) + 0.1j * rng.standard_normal((mu.size, 2))
    k = np.arange(int(20 * N / FS), int(150 * N / FS) + 1)
    lines = np.tile(k, realisations)
    z = np.exp(2j * np.pi * lines / N)
    E = np.exp(2j * np.pi * rng.random((lines.size, 2)))
    X = (E @ L.T) / (z[:, None] - mu)
    Xc = (E @ L.conj().T) / (z[:, None] - mu.conj())
    Y = X @ psi.T + Xc @ psi.conj().T
    sig = np.sqrt(np.mean(np.abs(Y) ** 2)) * 10 ** (-snr_db / 20)
    Y = Y + sig * (rng.standard_normal(Y.shape) + 1j * rng.standard_normal(Y.shape)) / np.sqrt(2)
    data = FrequencyData(lines=lines, frequencies_hz=lines * FS / N, z=z, Y=Y, E=E,
                         input_scale=np.ones(2), noise_cov=None, n_inputs=1, sample_rate_hz=FS,
                         samples_per_period=N, output_names=tuple(f"y{i}" for i in range(p)),
                         input_names=("p",), excited=np.ones(lines.size, bool),
                         basis_names=("h",), band_hz=(20.0, 150.0),
                         n_realizations=realisations)
    return data, lam


def pole_errors(model, lam_true):
    """Relative distance of each true pole to the nearest identified one."""
    lam = model.poles.eigenvalues
    return np.array([np.min(np.abs(lam - t)) / abs(t) for t in lam_true])


def test_compressed_subspace_step_keeps_the_poles_and_every_channel():
    data, lam = dense_array(150)
    dec_c = fnsi.subspace_decomposition(data, max_order=20)
    dec_f = fnsi.subspace_decomposition(data, max_order=20, output_rank=None)
    # 150 channels > n_max + m_e + 8 = 30: compressed to 30 directions
    assert dec_c.output_basis.shape == (150, 30) and dec_f.output_basis is None
    assert dec_c.block_size == 30
    W = dec_c.output_basis
    assert np.allclose(W.T @ W, np.eye(30), atol=1e-12)
    for dec in (dec_c, dec_f):
        model = fnsi.model_at_order(dec, data, 12)
        assert model.c_d.shape == (150, 12)
        # 60 dB noise on 131 lines: the poles to 1e-4 (measured 1e-6 .. 2e-5 both ways)
        assert np.max(pole_errors(model, lam)) < 1e-4
        # the model explains every channel down to the noise (1e-6 relative power)
        y = fnsi.steady_state_output(model, data)
        assert np.sum(np.abs(data.Y - y) ** 2) / np.sum(np.abs(data.Y) ** 2) < 5e-6


def test_output_split_gives_the_full_least_squares_exactly():
    """B and D of the r-channel problem plus the complement's D equal the least squares on
    all p channels, solved here directly as one dense real regression (the oracle)."""
    data, _ = dense_array(60, snr_db=40.0)
    dec = fnsi.subspace_decomposition(data, max_order=10, output_rank=20)
    n = 8
    model = models.model_at_order_fast(dec, data, n)
    a, c = model.a_d, model.c_d
    F, p, me = data.n_lines, data.n_outputs, data.n_extended_inputs
    # regressor of vec(B) (n me) and vec(D) (p me), real and imaginary parts as rows
    K = c @ np.linalg.solve(data.z[:, None, None] * np.eye(n) - a, np.eye(n))  # (F, p, n)
    cols = [(K @ np.eye(n)[:, [i]])[:, :, 0, None] * data.E[:, None, [j]]
            for j in range(me) for i in range(n)]
    cols += [np.eye(p)[None, :, [i]] * data.E[:, None, [j]] for j in range(me) for i in range(p)]
    R = np.concatenate(cols, axis=2).reshape(F * p, -1)
    theta = np.linalg.lstsq(np.vstack([R.real, R.imag]),
                            np.concatenate([data.Y.reshape(-1).real, data.Y.reshape(-1).imag]),
                            rcond=None)[0]
    b_ref = theta[:n * me].reshape(me, n).T
    d_ref = theta[n * me:].reshape(me, p).T
    assert np.abs(model.b_d - b_ref).max() < 1e-7 * np.abs(b_ref).max()
    assert np.abs(model.d_d - d_ref).max() < 1e-7 * np.abs(d_ref).max()
    # the core's estimate (range(C) split inside) agrees too
    b2, d2 = fnsi.estimate_bd(a, c, data, weighted=False)
    assert np.abs(b2 - b_ref).max() < 1e-7 * np.abs(b_ref).max()
    assert np.abs(d2 - d_ref).max() < 1e-7 * np.abs(d_ref).max()
    # V(n) from the r-channel twin plus the fixed complement equals V on every channel
    mask = data.frequencies_hz < 100
    v_twin = fast_bd.model_error(model, data, mask)
    y = fast_bd.model_output(model, data, mask)
    v_full = np.sum(np.abs(data.Y[mask] - y) ** 2) / np.sum(np.abs(data.Y[mask]) ** 2)
    assert v_twin == pytest.approx(v_full, rel=1e-9)


def test_gram_form_agrees_with_the_qr():
    """The Gram form forms ``L22 L22^T`` as a Schur complement, whose cancellation costs
    digits (singular values of this 60 dB array: 1-10 % apart); the models do not notice."""
    data, lam = dense_array(20)
    qr = fnsi.subspace_decomposition(data, max_order=16, method="qr")
    gram = fnsi.subspace_decomposition(data, max_order=16, method="gram")
    k = gram.singular_values.size
    assert k == 2 * 16 + 20 and qr.singular_values.size > k
    s_q, s_g = qr.singular_values / qr.singular_values[0], gram.singular_values / gram.singular_values[0]
    assert np.max(np.abs(s_g[:12] / s_q[:12] - 1)) < 0.3
    v = []
    for dec in (qr, gram):
        model = fnsi.model_at_order(dec, data, 12)
        assert np.max(pole_errors(model, lam)) < 1e-4
        y = fnsi.steady_state_output(model, data)
        v.append(np.sum(np.abs(data.Y - y) ** 2) / np.sum(np.abs(data.Y) ** 2))
    assert v[1] == pytest.approx(v[0], rel=0.01)


def test_shared_shift_qr_gives_each_orders_least_squares():
    data, _ = dense_array(20)
    dec = fnsi.subspace_decomposition(data, max_order=30)
    p = dec.block_size
    for n in (1, 5, 12, 29, 30):
        a, c = fnsi.state_matrices(dec, n)
        G = dec.observability[:, :n]
        a_ref = np.linalg.lstsq(G[:-p], G[p:], rcond=None)[0]
        assert np.allclose(np.sort_complex(np.linalg.eigvals(a)),
                           np.sort_complex(np.linalg.eigvals(a_ref)), rtol=1e-9, atol=1e-12)
        assert np.array_equal(c, G[:p])


def test_stacked_realisations_are_summed_per_line_with_the_same_answer():
    data, lam = dense_array(10, realisations=4, snr_db=50.0)
    sums = fast_bd.line_sums(data)
    assert sums is not None and sums[0].size == data.n_lines // 4
    dec = fnsi.subspace_decomposition(data, max_order=20, method="gram")
    model = models.model_at_order_fast(dec, data, 12)
    assert np.max(pole_errors(model, lam)) < 1e-4
    a, c = model.a_d, model.c_d
    mask = data.frequencies_hz > 40
    v_sums = fast_bd.model_error(model, data, mask)
    data.__dict__["_ident_cache"]["line_sums"] = None  # force the line-by-line products
    data.__dict__["_ident_cache"]["line_fold"] = None  # and the model error over every row
    b_direct, d_direct = fast_bd.fast_estimate_bd(a, c, data)
    v_direct = fast_bd.model_error(model, data, mask)
    assert np.abs(model.b_d - b_direct).max() < 1e-8 * np.abs(b_direct).max()
    assert np.abs(model.d_d - d_direct).max() < 1e-8 * np.abs(d_direct).max()
    assert v_sums == pytest.approx(v_direct, rel=1e-8)
    # the QR over every stacked line finds the poles as well
    dec_qr = fnsi.subspace_decomposition(data, max_order=20, method="qr")
    assert np.max(pole_errors(fnsi.model_at_order(dec_qr, data, 12), lam)) < 1e-4


def test_weighted_bd_with_many_channels_eliminates_d_per_channel(monkeypatch):
    """Per-channel noise weights: D eliminated by its block-diagonal Schur complement gives
    the same B, D as the full weighted normal equations (every D unknown in them)."""
    from dataclasses import replace
    data, _ = dense_array(40, snr_db=40.0)
    rng = np.random.default_rng(3)
    var = np.abs(rng.standard_normal((data.n_lines, 40))) * 1e-6 + 1e-7  # uneven channels
    data = replace(data, noise_cov=var, n_periods=4)
    dec = fnsi.subspace_decomposition(data, max_order=10, weighted=False)
    a, c = fnsi.state_matrices(dec, 8)
    b1, d1 = fnsi.estimate_bd(a, c, data, weighted=True)          # 40 > 8 + 8: eliminated
    monkeypatch.setattr(subspace, "OUTPUT_RANK_MARGIN", 10 ** 6)     # force the full system
    b2, d2 = fnsi.estimate_bd(a, c, data, weighted=True)
    assert np.abs(b1 - b2).max() < 1e-9 * np.abs(b2).max()
    assert np.abs(d1 - d2).max() < 1e-9 * np.abs(d2).max()
    # and the weights mattered: the unweighted answer is elsewhere
    b3, _ = fnsi.estimate_bd(a, c, data, weighted=False)
    assert np.abs(b3 - b2).max() > 1e-6 * np.abs(b2).max()
