"""The identified state-space model: poles, continuous time, transfer functions and FRFs
(docs/method.md §1.5, §2.1-2.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.frequency_data import FrequencyData

#: Readings of the discrete-time model (see :func:`ident.core.periodic.prepare_frequency_data`).
TIME_BASES: tuple[str, ...] = ("band-limited", "zoh", "bilinear")


@dataclass(frozen=True, eq=False)
class Poles:
    """Eigenvalues of a model, one entry per eigenvalue of ``A`` (docs/method.md §2.1).

    Attributes
    ----------
    eigenvalues : complex ndarray, shape (n,)
        Continuous-time eigenvalues ``lambda = fs log(mu)`` (rad/s).
    discrete_eigenvalues : complex ndarray, shape (n,)
        ``mu``, eigenvalues of ``A_d``.
    natural_frequency_hz : ndarray, shape (n,)
        ``|lambda| / (2 pi)``.
    damping_ratio : ndarray, shape (n,)
        ``-Re(lambda) / |lambda|``.
    stable : bool ndarray, shape (n,)
        ``|mu| < 1``.
    nyquist : bool ndarray, shape (n,)
        ``mu`` on (or numerically at) the negative real axis: no continuous-time meaning.
    real : bool ndarray, shape (n,)
        Real ``mu > 0`` (not a mode).
    mode_shapes : complex ndarray, shape (p, n)
        ``psi = C phi`` (output mode shapes, unit 2-norm, largest entry real positive).
    """

    eigenvalues: np.ndarray
    discrete_eigenvalues: np.ndarray
    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stable: np.ndarray
    nyquist: np.ndarray
    real: np.ndarray
    mode_shapes: np.ndarray

    @property
    def is_mode(self) -> np.ndarray:
        """One entry per conjugate pair: ``Im lambda > 0`` and not at Nyquist, shape (n,)."""
        return (self.eigenvalues.imag > 0) & ~self.nyquist & ~self.real

    @property
    def damped_frequency_hz(self) -> np.ndarray:
        """``Im(lambda) / (2 pi)``, shape (n,)."""
        return self.eigenvalues.imag / (2 * np.pi)

    def modes(self) -> dict[str, np.ndarray]:
        """Modes (``is_mode``) sorted by frequency: frequency_hz, damping_ratio, stable, shape."""
        idx = np.flatnonzero(self.is_mode)
        idx = idx[np.argsort(self.natural_frequency_hz[idx])]
        return {"index": idx, "frequency_hz": self.natural_frequency_hz[idx],
                "damping_ratio": self.damping_ratio[idx], "stable": self.stable[idx],
                "mode_shapes": self.mode_shapes[:, idx]}


@dataclass(frozen=True, eq=False)
class StateSpaceModel:
    """Identified linear model of the extended input ``e = [p; h]`` (docs/method.md §1.1).

    ``B`` and ``D`` are in physical basis units (the ``sigma`` scaling is undone).

    Attributes
    ----------
    order : int
        ``n``.
    a_d, b_d, c_d, d_d : ndarray
        Discrete-time matrices, shapes (n, n), (n, m_e), (p, n), (p, m_e).
    a_c, b_c, c_c, d_c : ndarray
        Continuous-time matrices per ``time_base``: impulse-invariant reading of band-limited
        data (:func:`band_limited_to_continuous`), exact ZOH inverse (docs/method.md §1.5) or exact
        bilinear inverse (docs/method.md §1.6).
    sample_rate_hz : float
    n_inputs : int
        ``m`` (forces); the other ``m_e - m`` columns are basis functions.
    time_base : {'band-limited', 'zoh', 'bilinear'}
        How the DT model maps to CT (see :func:`ident.core.periodic.prepare_frequency_data`).
    bilinear_period_s : float or None
        ``T`` of the bilinear map.
    input_names : tuple of str
        Extended-input names, length ``m_e``.
    output_names : tuple of str
        Length ``p``.
    poles : Poles
    """

    order: int
    a_d: np.ndarray
    b_d: np.ndarray
    c_d: np.ndarray
    d_d: np.ndarray
    a_c: np.ndarray
    b_c: np.ndarray
    c_c: np.ndarray
    d_c: np.ndarray
    sample_rate_hz: float
    n_inputs: int
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    poles: Poles
    time_base: str = "zoh"
    bilinear_period_s: float | None = None

    @property
    def stable(self) -> bool:
        """All ``|mu| < 1``."""
        return bool(np.all(self.poles.stable))

    def frf(self, frequencies_hz: np.ndarray) -> np.ndarray:
        """Extended FRF, see :func:`frf`."""
        return frf(self, frequencies_hz)

    def underlying_linear_frf(self, frequencies_hz: np.ndarray) -> np.ndarray:
        """Underlying linear FRF, see :func:`underlying_linear_frf`."""
        return underlying_linear_frf(self, frequencies_hz)

    def steady_state_output(self, data: FrequencyData) -> np.ndarray:
        """Periodic steady-state output, see :func:`steady_state_output`."""
        return steady_state_output(self, data)


# ---------------------------------------------------------------------------- helpers

#: Eigenvector matrices with a larger condition number use the direct (solve) fallback.
_MODAL_COND_LIMIT = 1e8


def eigen_decomposition(a: np.ndarray):
    """``(mu, Phi, ok)``: eigen-decomposition of ``a`` and whether ``Phi`` is well conditioned."""
    if a.shape[0] == 0:
        return np.zeros(0, complex), np.zeros((0, 0), complex), True
    mu, phi = np.linalg.eig(a)
    with np.errstate(all="ignore"):
        cond = np.linalg.cond(phi)
    return mu, phi, bool(np.isfinite(cond) and cond < _MODAL_COND_LIMIT)


def apply_model(a, b, c, d, s, E, *, modal=None) -> np.ndarray:
    """``[C (s_k I - A)^{-1} B + D] E_k`` for every line, shape (F, p); O(F n (m_e + p))."""
    mu, phi, ok = modal if modal is not None else eigen_decomposition(a)
    n = a.shape[0]
    if n == 0:
        return E @ d.T
    if ok:
        bh = np.linalg.solve(phi, b)  # (n, m_e)
        X = (E @ bh.T) / (s[:, None] - mu[None, :])  # (F, n)
        return X @ (c @ phi).T + E @ d.T
    rhs = (E @ b.T)[:, :, None]  # (F, n, 1)
    X = np.linalg.solve(s[:, None, None] * np.eye(n)[None] - a, rhs)[:, :, 0]
    return X @ c.T + E @ d.T


def transfer(a, b, c, d, s, *, modal=None) -> np.ndarray:
    """``C (s I - A)^{-1} B + D`` at complex points ``s``, shape (F, p, m_e)."""
    s = np.asarray(s, complex).reshape(-1)
    n = a.shape[0]
    if n == 0:
        return np.broadcast_to(d, (s.size,) + d.shape).astype(complex)
    mu, phi, ok = modal if modal is not None else eigen_decomposition(a)
    if ok:
        ch = c @ phi
        bh = np.linalg.solve(phi, b)
        w = 1.0 / (s[:, None] - mu[None, :])
        m_e = bh.shape[1]
        X = (w[:, :, None] * bh[None]).transpose(1, 0, 2).reshape(n, -1)  # (n, F m_e)
        H = (ch @ X).reshape(c.shape[0], s.size, m_e).transpose(1, 0, 2)  # one GEMM
        return H + d[None]
    X = np.linalg.solve(s[:, None, None] * np.eye(n)[None] - a, np.broadcast_to(b, (s.size,) + b.shape))
    return c[None] @ X + d[None]


# ---------------------------------------------------------------------------- CT, poles
def discrete_to_continuous(a_d: np.ndarray, b_d: np.ndarray, sample_rate_hz: float, *,
                           _modal_dt=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact inverse of zero-order hold, pole by pole (docs/method.md §1.5).

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    b_d : ndarray, shape (n, m_e)
    sample_rate_hz : float

    Returns
    -------
    a_c : ndarray, shape (n, n)
        ``fs logm(A_d)`` (rad/s).
    b_c : ndarray, shape (n, m_e)
        ``A_c (A_d - I)^{-1} B_d``.

    Notes
    -----
    ``A_d = Phi diag(mu) Phi^{-1}``; ``lambda_i = fs log(mu_i)`` (principal branch) and
    ``b_c,i = lambda_i / (mu_i - 1) b_d,i`` (the factor tends to ``fs`` as ``mu_i -> 1``).
    Inverts ``A_d = expm(A_c / fs)``, ``B_d = (A_d - I) A_c^{-1} B_c`` exactly. A negative
    real ``mu`` (Nyquist artefact) has no real logarithm: the real part is kept and the pole is
    flagged in :class:`Poles`. Ill-conditioned eigenvectors fall back to ``logm`` of the
    augmented matrix ``[[A_d, B_d], [0, I]]`` (as pyvib).
    """
    fs = float(sample_rate_hz)
    a_d = np.asarray(a_d, float)
    b_d = np.asarray(b_d, float)
    n = a_d.shape[0]
    if n == 0:
        return a_d.copy(), b_d.copy()
    mu, phi, ok = _modal_dt if _modal_dt is not None else eigen_decomposition(a_d)
    if ok:
        lam = fs * np.log(mu.astype(complex))
        dm = mu - 1.0
        small = np.abs(dm) < 1e-12
        fac = np.where(small, fs, lam / np.where(small, 1.0, dm))
        phi_inv = np.linalg.inv(phi)
        a_c = ((phi * lam) @ phi_inv).real
        b_c = ((phi * fac) @ (phi_inv @ b_d)).real
        return a_c, b_c
    m_e = b_d.shape[1]
    aug = np.zeros((n + m_e, n + m_e))
    aug[:n, :n], aug[:n, n:], aug[n:, n:] = a_d, b_d, np.eye(m_e)
    lg = np.real(sla.logm(aug)) * fs
    return lg[:n, :n], lg[:n, n:]


def band_limited_to_continuous(a_d, b_d, c_d, d_d, sample_rate_hz: float, *, _modal_dt=None):
    """Continuous-time reading of a DT model identified on band-limited samples.

    Parameters
    ----------
    a_d, b_d, c_d, d_d : ndarray
        Shapes (n, n), (n, m_e), (p, n), (p, m_e).
    sample_rate_hz : float

    Returns
    -------
    a_c, b_c, c_c, d_c : ndarray
        ``A_c = fs logm(A_d)`` (as the ZOH inverse: the poles are the same),
        ``B_c = fs A_d^{-1} B_d``, ``C_c = C_d``, ``D_c = D_d - C_d A_d^{-1} B_d``.

    Notes
    -----
    Anti-alias filtered (band-limited) signals are not held between samples, so the exact
    ZOH inverse reads the DT model with a half-sample delay: on the simulated SmallSat the
    ZOH-read driving-point FRF was 8.7 % (RMS) off the 1 N FRF over 5-50 Hz, its phase off
    by ``w T / 2``. For band-limited data the DT transfer function itself equals the CT FRF
    in the band, ``G_d(exp(j w T)) = H(j w)``; this CT realisation is its impulse-invariant
    counterpart: with ``G_d(z) = sum_i c_i b_i / (z - mu_i) + D_d`` and impulse invariance
    ``G_d(z) = T sum_i r_i z / (z - mu_i)``, the CT residues are ``r_i = c_i b_i / (T mu_i)``
    and the constant ``T sum_i r_i`` leaves ``D``. :func:`frf` evaluates the DT transfer
    function for this time base (exact on the data's band); these matrices give the modal
    quantities (MDI) and an exportable CT model.
    """
    fs = float(sample_rate_hz)
    a_d, b_d, c_d, d_d = (np.asarray(x, float) for x in (a_d, b_d, c_d, d_d))
    if a_d.shape[0] == 0:
        return a_d.copy(), b_d.copy(), c_d.copy(), d_d.copy()
    a_c, _ = discrete_to_continuous(a_d, b_d, fs, _modal_dt=_modal_dt)
    x = np.linalg.solve(a_d, b_d)
    return a_c, fs * x, c_d.copy(), d_d - c_d @ x


def compute_poles(a_d: np.ndarray, c_d: np.ndarray, sample_rate_hz: float, *,
                  time_base: str = "zoh", bilinear_period_s: float | None = None,
                  _modal_dt=None) -> Poles:
    """Poles and output mode shapes from ``A_d`` (docs/method.md §1.5, §2.1).

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
    sample_rate_hz : float

    Returns
    -------
    Poles
        ``lambda = fs log(mu)``; ``f_n = |lambda| / 2 pi``; ``zeta = -Re(lambda)/|lambda|``;
        ``psi = C phi`` (eigenvectors of ``A_c`` are those of ``A_d``).
    """
    fs = float(sample_rate_hz)
    mu, phi, _ = _modal_dt if _modal_dt is not None else eigen_decomposition(np.asarray(a_d, float))
    on_axis = np.abs(mu.imag) <= 1e-10 * np.maximum(np.abs(mu), 1e-300)
    if time_base not in TIME_BASES:
        raise IdentError(f"time_base {time_base!r} is not one of {plain.names(TIME_BASES)}")
    if time_base == "bilinear":  # lambda = (2/T) (mu - 1) / (mu + 1); mu = -1 -> infinity
        if bilinear_period_s is None:
            raise IdentError("time_base 'bilinear' needs bilinear_period_s")
        alpha = 2.0 / float(bilinear_period_s)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = alpha * (mu - 1) / (mu + 1)
        nyq = np.abs(mu + 1) < 1e-12
        lam = np.where(nyq, complex(np.inf), lam).astype(complex)
    else:
        lam = fs * np.log(mu.astype(complex)) if mu.size else np.zeros(0, complex)
        nyq = on_axis & (mu.real < 0)
    absl = np.abs(lam)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(absl > 0, -lam.real / np.where(absl > 0, absl, 1.0), 1.0)
    psi = np.asarray(c_d, float) @ phi
    nrm = np.linalg.norm(psi, axis=0)
    psi = psi / np.where(nrm > 0, nrm, 1.0)
    if psi.size:
        big = psi[np.argmax(np.abs(psi), axis=0), np.arange(psi.shape[1])]
        psi = psi * np.where(np.abs(big) > 0, np.abs(big) / np.where(big == 0, 1, big), 1.0)
    return Poles(eigenvalues=lam, discrete_eigenvalues=mu, natural_frequency_hz=absl / (2 * np.pi),
                 damping_ratio=zeta, stable=np.abs(mu) < 1.0, nyquist=nyq,
                 real=on_axis & ~nyq, mode_shapes=psi)


def bilinear_to_continuous(a_d, b_d, c_d, d_d, period_s: float):
    """Inverse of the bilinear (Tustin) map (docs/method.md §1.6), exact.

    ``alpha = 2/T``, ``N_d = (A_d + I)^{-1}``: ``A_c = alpha N_d (A_d - I)``,
    ``B_c = (2/sqrt T) N_d B_d``, ``C_c = (2/sqrt T) C_d N_d``, ``D_c = D_d - C_d N_d B_d``;
    then ``G_c(j w) = G_d(exp(j 2 atan(w T / 2)))``.

    Returns
    -------
    a_c, b_c, c_c, d_c : ndarray
    """
    T = float(period_s)
    n = a_d.shape[0]
    Nd = np.linalg.inv(a_d + np.eye(n))
    g = 2.0 / np.sqrt(T)
    return (2.0 / T) * Nd @ (a_d - np.eye(n)), g * Nd @ b_d, g * c_d @ Nd, d_d - c_d @ Nd @ b_d


def make_model(a_d, b_d, c_d, d_d, *, sample_rate_hz: float, n_inputs: int,
               input_names=(), output_names=(), time_base: str = "zoh",
               bilinear_period_s: float | None = None, _modal_dt=None) -> StateSpaceModel:
    """Assemble a :class:`StateSpaceModel` from DT matrices (CT by :func:`discrete_to_continuous`).

    Parameters
    ----------
    a_d, b_d, c_d, d_d : ndarray
        Shapes (n, n), (n, m_e), (p, n), (p, m_e); ``B``, ``D`` in physical basis units.
    sample_rate_hz : float
    n_inputs : int
        ``m``.
    input_names, output_names : sequence of str
        Extended-input (length ``m_e``) and output (length ``p``) names; defaults generated.

    Returns
    -------
    StateSpaceModel
    """
    a_d, b_d, c_d, d_d = (np.asarray(x, float) for x in (a_d, b_d, c_d, d_d))
    n, m_e, p = a_d.shape[0], b_d.shape[1], c_d.shape[0]
    if a_d.shape != (n, n) or b_d.shape != (n, m_e) or c_d.shape != (p, n) or d_d.shape != (p, m_e):
        raise IdentError(f"inconsistent state-space shapes A {a_d.shape}, B {b_d.shape}, "
                         f"C {c_d.shape}, D {d_d.shape}")
    modal = _modal_dt if _modal_dt is not None else eigen_decomposition(a_d)
    if time_base == "bilinear":
        if not bilinear_period_s:
            raise IdentError("time_base 'bilinear' needs bilinear_period_s")
        a_c, b_c, c_c, d_c = bilinear_to_continuous(a_d, b_d, c_d, d_d, bilinear_period_s)
    elif time_base == "zoh":
        a_c, b_c = discrete_to_continuous(a_d, b_d, sample_rate_hz, _modal_dt=modal)
        c_c, d_c = c_d.copy(), d_d.copy()
    elif time_base == "band-limited":
        a_c, b_c, c_c, d_c = band_limited_to_continuous(a_d, b_d, c_d, d_d, sample_rate_hz,
                                                        _modal_dt=modal)
    else:
        raise IdentError(f"time_base {time_base!r} is not one of {plain.names(TIME_BASES)}")
    in_names = tuple(input_names) or tuple(f"e{i}" for i in range(m_e))
    out_names = tuple(output_names) or tuple(f"y{i}" for i in range(p))
    model = StateSpaceModel(order=n, a_d=a_d, b_d=b_d, c_d=c_d, d_d=d_d, a_c=a_c, b_c=b_c,
                            c_c=c_c, d_c=d_c, sample_rate_hz=float(sample_rate_hz),
                            n_inputs=int(n_inputs), input_names=in_names, output_names=out_names,
                            poles=compute_poles(a_d, c_d, sample_rate_hz, time_base=time_base,
                                                bilinear_period_s=bilinear_period_s,
                                                _modal_dt=modal),
                            time_base=time_base, bilinear_period_s=bilinear_period_s)
    model.__dict__["_modal_dt"] = modal  # cache (the matrices are never mutated)
    return model


def dt_modal(model: StateSpaceModel):
    m = model.__dict__.get("_modal_dt")
    if m is None:
        m = model.__dict__["_modal_dt"] = eigen_decomposition(model.a_d)
    return m


def ct_modal(model: StateSpaceModel):
    m = model.__dict__.get("_modal_ct")
    if m is None:
        m = model.__dict__["_modal_ct"] = eigen_decomposition(model.a_c)
    return m


# ---------------------------------------------------------------------------- responses
def transfer_discrete(model: StateSpaceModel, z: np.ndarray, rows=None) -> np.ndarray:
    """``G_d(z) = C (z I - A_d)^{-1} B_d + D``.

    Parameters
    ----------
    model : StateSpaceModel
    z : complex ndarray, shape (F,)
    rows : sequence of int, optional
        Only these outputs (a coefficient needs two channels of hundreds).

    Returns
    -------
    complex ndarray, shape (F, p, m_e), or (F, len(rows), m_e)
    """
    c, d = (model.c_d, model.d_d) if rows is None else (model.c_d[rows], model.d_d[rows])
    return transfer(model.a_d, model.b_d, c, d, z, modal=dt_modal(model))


def steady_state_output(model: StateSpaceModel, data: FrequencyData) -> np.ndarray:
    """Periodic steady-state output of the DT model driven by the measured extended input.

    Parameters
    ----------
    model : StateSpaceModel
    data : FrequencyData

    Returns
    -------
    complex ndarray, shape (F, p)
        ``G_d(z_k) E_phys(k)`` on the data lines (same normalization as ``data.Y``).

    Notes
    -----
    docs/method.md §3: the DFT of the unique N-periodic solution of ``x(t+1) = A x(t) + B e(t)`` is
    ``X(k) = (z_k I - A)^{-1} B E(k)``, so this equals the seed's steady-state simulation
    (Eq. 6-7) exactly; the information criterion uses it as its oracle. Unstable models still
    give the periodic solution (exclude them upstream).
    """
    return apply_model(model.a_d, model.b_d, model.c_d, model.d_d, data.z, data.E_physical,
                        modal=dt_modal(model))


def frf(model: StateSpaceModel, frequencies_hz: np.ndarray) -> np.ndarray:
    """Extended FRF ``H_E(w)`` (docs/method.md §2.2).

    Parameters
    ----------
    model : StateSpaceModel
    frequencies_hz : ndarray, shape (F,)
        Any frequencies (Hz), not only DFT lines (below Nyquist for the band-limited time
        base).

    Returns
    -------
    complex ndarray, shape (F, p, m_e)
        ``[G_p | G_1 | ... | G_s]`` in physical units (output per N, output per basis unit).

    Notes
    -----
    ``'zoh'`` and ``'bilinear'`` time bases: the CT model,
    ``C_c (j w I - A_c)^{-1} B_c + D_c``. ``'band-limited'``: the identified DT transfer
    function on the unit circle, ``G_d(exp(j w / fs))``, which equals the CT FRF of
    band-limited data (see :func:`band_limited_to_continuous`).
    """
    f = np.asarray(frequencies_hz, float).reshape(-1)
    if model.time_base == "band-limited":
        return transfer_discrete(model, np.exp(2j * np.pi * f / model.sample_rate_hz))
    w = 2 * np.pi * f
    return transfer(model.a_c, model.b_c, model.c_c, model.d_c, 1j * w, modal=ct_modal(model))


def underlying_linear_frf(model: StateSpaceModel, frequencies_hz: np.ndarray) -> np.ndarray:
    """Underlying linear FRF ``G_p`` (force columns of :func:`frf`), shape (F, p, m).

    The "synthesised underlying linear FRF" of the seed (Fig. 11), at any frequency.
    """
    return frf(model, frequencies_hz)[:, :, :model.n_inputs]
