"""A discrete-time state-space model in modal coordinates, as parameters to refine.

``G(z) = sum_r [gamma_r beta_r^T / (z - mu_r) + conj] + sum_q c_q b_q^T / (z - nu_q) + D``

with complex poles ``mu_r`` (one of each conjugate pair, ``Im mu_r > 0``), real poles
``nu_q``, input rows ``beta_r`` (complex) and ``b_q`` (real), output columns ``gamma_r``
(complex) and ``c_q`` (real). It is the same model as ``A, B, C, D`` with ``A`` diagonalised
(:meth:`ModalModel.from_matrices`, :meth:`ModalModel.matrices`), written so that every
output row is *linear* in its own parameters ``[Re gamma, Im gamma, c, d]`` given the poles,
the input rows and the extended input (:meth:`ModalModel.regressor`). :mod:`ident.refine.output_error`
refines it.

Shapes follow :mod:`ident`: lines first, ``(F, p, m_e)`` transfer functions.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fnsi_lab.ident.errors import IdentError

__all__ = ["ModalModel", "LowFrequency", "pole_kernel"]

#: Eigenvector matrices beyond this condition number have no usable modal form.
_MODAL_COND_LIMIT = 1e8


@dataclass(frozen=True)
class LowFrequency:
    """Lines where the model is read less its Taylor terms at ``z = 1`` (zero frequency).

    A velocity (acceleration) frequency response vanishes at zero frequency like ``j w``
    (``(j w)^2``); a fitted model's does not exactly, and read under the processed band as a
    displacement, ``G / (j w)^t``, its static terms blow up. On these lines the model is
    read as ``G(z) - G(1)`` (``t = 1``) or ``G(z) - G(1) - j w (dz/d(j w)) G'(1)``
    (``t = 2``), the physical behaviour near zero frequency.

    Attributes
    ----------
    mask : bool ndarray, shape (F,)
    jw : complex ndarray, shape (F,)
        ``j w_k`` (rad/s) of every line.
    rate : float
        ``dz / d(j w)`` at ``w = 0`` (s): ``1/fs`` for ``z = exp(j w / fs)``, ``T`` for the
        bilinear map.
    order : int
        ``t``, the Taylor terms removed.
    """

    mask: np.ndarray
    jw: np.ndarray
    rate: float
    order: int

    def tiled(self, times: int) -> "LowFrequency":
        """The same for ``times`` stacked repetitions of the lines (realisations)."""
        return replace(self, mask=np.tile(self.mask, times), jw=np.tile(self.jw, times))


def pole_kernel(z: np.ndarray, mu: np.ndarray, low: LowFrequency | None = None):
    """``1 / (z_k - mu_r)`` and its derivative in ``mu_r``, shapes (F, n) each.

    On the lines of ``low``, less the Taylor terms at ``z = 1``:
    ``- 1/(1 - mu) + j w rate / (1 - mu)^2`` (the second for ``order >= 2``).
    """
    z, mu = np.asarray(z), np.asarray(mu)
    k = 1.0 / (z[:, None] - mu[None])
    dk = k ** 2
    if low is not None and mu.size and np.any(low.mask):
        m = low.mask
        a = 1.0 / (1.0 - mu)
        k[m] -= a[None]
        dk[m] -= (a ** 2)[None]
        if low.order >= 2:
            w = (low.jw[m] * low.rate)[:, None]
            k[m] += w * (a ** 2)[None]
            dk[m] += 2.0 * w * (a ** 3)[None]
    return k, dk


@dataclass(frozen=True)
class ModalModel:
    """Modal parameters of a DT state-space model (see the module docstring).

    Attributes
    ----------
    poles : complex ndarray, shape (nc,)
        ``mu_r``, ``Im > 0``.
    real_poles : ndarray, shape (nr,)
    b_pair : complex ndarray, shape (nc, m_e)
    b_real : ndarray, shape (nr, m_e)
    c_pair : complex ndarray, shape (p, nc)
    c_real : ndarray, shape (p, nr)
    d : ndarray, shape (p, m_e)
    """

    poles: np.ndarray
    real_poles: np.ndarray
    b_pair: np.ndarray
    b_real: np.ndarray
    c_pair: np.ndarray
    c_real: np.ndarray
    d: np.ndarray

    @property
    def n_pairs(self) -> int:
        return int(self.poles.size)

    @property
    def n_real(self) -> int:
        return int(self.real_poles.size)

    @property
    def order(self) -> int:
        return 2 * self.n_pairs + self.n_real

    @classmethod
    def from_matrices(cls, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                      d: np.ndarray) -> "ModalModel":
        """Diagonalise ``A``.

        Raises
        ------
        IdentError
            ``A`` has no well-conditioned eigenvector basis (repeated poles).
        """
        a, b, c, d = (np.asarray(x, float) for x in (a, b, c, d))
        mu, phi = np.linalg.eig(a)
        tol = 1e-10 * np.maximum(np.abs(mu), 1e-300)
        upper = np.flatnonzero(mu.imag > tol)
        real = np.flatnonzero(np.abs(mu.imag) <= tol)
        if 2 * upper.size + real.size != mu.size:
            raise IdentError("the model's poles do not come in conjugate pairs")
        vecs = [phi[:, upper], phi[:, upper].conj(), phi[:, real].real]
        basis = np.concatenate(vecs, axis=1)
        with np.errstate(all="ignore"):
            cond = np.linalg.cond(basis)
        if not np.isfinite(cond) or cond > _MODAL_COND_LIMIT:
            raise IdentError("the model's state matrix has no well-conditioned modal form "
                             f"(eigenvector condition number {cond:.2g})")
        b_modal = np.linalg.solve(basis, b.astype(complex))
        c_modal = c @ basis
        nc = upper.size
        return cls(poles=mu[upper], real_poles=mu[real].real,
                   b_pair=b_modal[:nc], b_real=b_modal[2 * nc:].real,
                   c_pair=c_modal[:, :nc], c_real=c_modal[:, 2 * nc:].real, d=d.copy())

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Real block-diagonal ``(A, B, C, D)``: a ``2 x 2`` block per pair, then real poles.

        A pair's real states ``x1 + j x2`` follow ``x+``:
        ``A = [[Re mu, -Im mu], [Im mu, Re mu]]``, ``B = [Re beta; Im beta]``,
        ``C = [2 Re gamma, -2 Im gamma]``.
        """
        nc, nr = self.n_pairs, self.n_real
        n = 2 * nc + nr
        p, me = self.d.shape
        a = np.zeros((n, n))
        b = np.zeros((n, me))
        c = np.zeros((p, n))
        for r in range(nc):
            i = 2 * r
            m = self.poles[r]
            a[i:i + 2, i:i + 2] = [[m.real, -m.imag], [m.imag, m.real]]
            b[i], b[i + 1] = self.b_pair[r].real, self.b_pair[r].imag
            c[:, i], c[:, i + 1] = 2 * self.c_pair[:, r].real, -2 * self.c_pair[:, r].imag
        a[2 * nc:, 2 * nc:] = np.diag(self.real_poles)
        b[2 * nc:] = self.b_real
        c[:, 2 * nc:] = self.c_real
        return a, b, c, self.d.copy()

    def transfer(self, z: np.ndarray, low: LowFrequency | None = None) -> np.ndarray:
        """``G(z)``, shape (F, p, m_e) (on ``low``'s lines less its Taylor terms at 1)."""
        z = np.asarray(z)
        rp, _ = pole_kernel(z, self.poles, low)
        rm, _ = pole_kernel(z, self.poles.conj(), low)
        rr, _ = pole_kernel(z, self.real_poles, low)
        direct = np.broadcast_to(self.d[None], (z.size,) + self.d.shape).copy()
        if low is not None:
            direct[low.mask] = 0.0   # D is part of G(1)
        G = _residue_sum(rp, self.c_pair, self.b_pair)
        G += _residue_sum(rm, self.c_pair.conj(), self.b_pair.conj())
        G += _residue_sum(rr, self.c_real, self.b_real)
        G += direct
        return G

    def without(self, pairs: np.ndarray, real: np.ndarray) -> "ModalModel":
        """The model less the pairs and real poles where the masks are True."""
        kp, kr = ~np.asarray(pairs, bool), ~np.asarray(real, bool)
        return replace(self, poles=self.poles[kp], b_pair=self.b_pair[kp],
                       c_pair=self.c_pair[:, kp], real_poles=self.real_poles[kr],
                       b_real=self.b_real[kr], c_real=self.c_real[:, kr])

    def row_parameters(self, d_free: bool = True) -> np.ndarray:
        """Each output row's own parameters ``[Re gamma, Im gamma, c, d]``, shape (p, n_own)."""
        parts = [self.c_pair.real, self.c_pair.imag, self.c_real] + ([self.d] if d_free else [])
        return np.concatenate(parts, axis=1)

    def with_rows(self, theta: np.ndarray, d_free: bool = True) -> "ModalModel":
        """The model with every row's own parameters replaced by ``theta`` (p, n_own)."""
        nc, nr = self.n_pairs, self.n_real
        c_pair = theta[:, :nc] + 1j * theta[:, nc:2 * nc]
        c_real = theta[:, 2 * nc:2 * nc + nr]
        d = theta[:, 2 * nc + nr:] if d_free else self.d
        return replace(self, c_pair=c_pair, c_real=c_real, d=np.array(d, float))

    def regressor(self, z: np.ndarray, E: np.ndarray, d_free: bool = True,
                  low: LowFrequency | None = None) -> np.ndarray:
        """Per line, the row-independent factors of the output, shape (F, n_own) complex.

        ``Y_hat[k, o] = regressor[k] @ row_parameters()[o]``; the columns are
        ``xi+ + xi-``, ``j (xi+ - xi-)``, ``zeta`` and (``d_free``) ``E``, with
        ``xi+_r = beta_r^T E_k / (z_k - mu_r)``, ``xi-_r = conj(beta_r)^T E_k / (z_k - conj mu_r)``
        and ``zeta_q = b_q^T E_k / (z_k - nu_q)`` (the kernels of :func:`pole_kernel`).
        """
        xp, xm, zeta = self.modal_inputs(z, E, low)
        parts = [xp + xm, 1j * (xp - xm), zeta]
        if d_free:
            direct = E.astype(complex)
            if low is not None:
                direct[low.mask] = 0.0
            parts.append(direct)
        return np.concatenate(parts, axis=1)

    def modal_inputs(self, z: np.ndarray, E: np.ndarray, low: LowFrequency | None = None):
        """``(xi+, xi-, zeta)``: shapes (F, nc), (F, nc), (F, nr)."""
        xp = (E @ self.b_pair.T) * pole_kernel(z, self.poles, low)[0]
        xm = (E @ self.b_pair.conj().T) * pole_kernel(z, self.poles.conj(), low)[0]
        zeta = (E @ self.b_real.T) * pole_kernel(z, self.real_poles, low)[0]
        return xp, xm, zeta


def _residue_sum(kernel: np.ndarray, c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_r kernel[k, r] c[p, r] b[r, a]``, shape (F, p, m_e): one matrix product with the
    residues ``c[:, r] b[r]`` laid out as rows (a plain einsum over the four indices ran 7x
    slower on the 39-channel SmallSat's balance)."""
    F, n = kernel.shape
    p, a = c.shape[0], b.shape[1]
    if n == 0:
        return np.zeros((F, p, a), complex if np.iscomplexobj(kernel) else float)
    residues = (c.T[:, :, None] * b[:, None, :]).reshape(n, p * a)
    return (kernel @ residues).reshape(F, p, a)
