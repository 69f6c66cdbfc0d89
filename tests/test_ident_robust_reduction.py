"""Model reduction by ordered real Schur form (docs/method.md §6)."""

import numpy as np
import pytest

from fnsi_lab.ident.robust import reduction


def _real_modal_system(rng, mus, p=3, m=2):
    """Real DT system with given eigenvalues (pairs given once, Im > 0), random basis."""
    blocks = []
    for mu in mus:
        if mu.imag == 0:
            blocks.append(np.array([[mu.real]]))
        else:
            blocks.append(np.array([[mu.real, mu.imag], [-mu.imag, mu.real]]))
    T = np.zeros((sum(b.shape[0] for b in blocks),) * 2)
    i = 0
    for b in blocks:
        k = b.shape[0]
        T[i:i + k, i:i + k] = b
        i += k
    n = T.shape[0]
    V = rng.standard_normal((n, n))
    A = V @ T @ np.linalg.inv(V)
    return A, V, T


def _dense_bd(a, c, z, Y, E):
    """Slow obvious oracle: real LS for vec(B), vec(D) from stacked Re/Im (docs/method.md §1.4)."""
    n, p, me = a.shape[0], c.shape[0], E.shape[1]
    rows, rhs = [], []
    for zk, yk, ek in zip(z, Y, E):
        K = c @ np.linalg.inv(zk * np.eye(n) - a)
        J = np.hstack([np.kron(ek[None, :], K), np.kron(ek[None, :], np.eye(p))])
        rows.append(J)
        rhs.append(yk)
    J = np.vstack(rows)
    y = np.concatenate(rhs)
    theta = np.linalg.lstsq(np.vstack([J.real, J.imag]), np.concatenate([y.real, y.imag]), rcond=None)[0]
    b = theta[:n * me].reshape(me, n).T
    d = theta[n * me:].reshape(me, p).T
    return b, d


def test_restriction_keeps_poles_and_shapes():
    rng = np.random.default_rng(4)
    mus = [0.9 * np.exp(0.3j), 0.95 * np.exp(0.8j), 0.7 * np.exp(1.5j), 0.5 + 0j, -0.8 + 0j]
    A, V, _ = _real_modal_system(rng, mus)
    C = rng.standard_normal((3, A.shape[0]))
    mu = np.linalg.eigvals(A)
    keep = np.isclose(mu, mus[1]) | np.isclose(mu, 0.5)     # one member of a pair + a real
    a_r, c_r, q = reduction.restrict_to_eigenvalues(A, C, keep)
    assert a_r.shape == (3, 3) and c_r.shape == (3, 3)
    np.testing.assert_allclose(q.T @ q, np.eye(A.shape[0]), atol=1e-12)
    got = np.sort_complex(np.linalg.eigvals(a_r))
    want = np.sort_complex(np.array([mus[1], np.conj(mus[1]), 0.5]))
    # eigenvalues of a similarity-restricted block: rounding level (cond(V) ~ 1e2)
    np.testing.assert_allclose(got, want, atol=1e-10)
    # output mode shapes preserved up to scaling: MAC = 1
    lam_r, phi_r = np.linalg.eig(a_r)
    lam, phi = np.linalg.eig(A)
    for i, l in enumerate(lam_r):
        k = np.argmin(np.abs(lam - l))
        s1, s2 = c_r @ phi_r[:, i], C @ phi[:, k]
        mac = abs(np.vdot(s1, s2)) ** 2 / (np.vdot(s1, s1).real * np.vdot(s2, s2).real)
        assert mac == pytest.approx(1.0, abs=1e-12)


def test_zero_residue_pair_removed_reproduces_frf():
    """docs/method.md §6 check: 8 states, one pair with zero input residue, reduced to 6."""
    rng = np.random.default_rng(5)
    mus = [0.95 * np.exp(0.2j), 0.9 * np.exp(0.7j), 0.92 * np.exp(1.1j), 0.8 * np.exp(2.0j)]
    A, V, T = _real_modal_system(rng, mus)
    n, p, me = 8, 3, 2
    Bm = rng.standard_normal((n, me))
    Bm[4:6] = 0.0                          # third pair not excited: zero residue
    B = V @ Bm
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((p, me))
    z = np.exp(1j * np.linspace(0.05, 3.0, 60))
    E = rng.standard_normal((60, me)) + 1j * rng.standard_normal((60, me))
    G = np.array([C @ np.linalg.solve(zk * np.eye(n) - A, B) + D for zk in z])
    Y = np.einsum("kpm,km->kp", G, E)
    mu = np.linalg.eigvals(A)
    keep = ~np.isclose(np.abs(mu - mus[2]) * np.abs(mu - np.conj(mus[2])), 0)
    a_r, c_r, _ = reduction.restrict_to_eigenvalues(A, C, keep)
    b_r, d_r = _dense_bd(a_r, c_r, z, Y, E)
    Gr = np.array([c_r @ np.linalg.solve(zk * np.eye(6) - a_r, b_r) + d_r for zk in z])
    # docs/method.md §6 quotes 4.6e-12; LS conditioning here ~1e3 -> 1e-9 relative is a safe bound
    assert np.max(np.abs(Gr - G)) / np.max(np.abs(G)) < 1e-9


def test_complete_pairs():
    mu = np.array([0.5 + 0.5j, 0.5 - 0.5j, 0.3, -0.2 + 0.1j, -0.2 - 0.1j])
    k = reduction.complete_pairs(mu, [False, True, False, True, False])
    assert k.tolist() == [True, True, False, True, True]
