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
