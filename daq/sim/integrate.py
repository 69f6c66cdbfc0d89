"""Time integration of a structure with localized nonlinearities (:func:`simulate`).

Method (why it is fast and accurate)
------------------------------------
The nonlinear forces act on a few relative coordinates ``delta_a = L_a^T q``. The
response is split as ``x = x_lin + w``:

1. ``x_lin``, the linear response to the input force. For a periodic force
   (``periodic=N``) it is the exact periodic steady state, ``H(j w_k) F_k`` line by line,
   evaluated at any time by trigonometric (FFT) interpolation, which is exact for a
   periodic band-limited signal such as a multisine. Otherwise the force is upsampled with
   a zero-phase polyphase FIR and treated like the nonlinear forces below.
2. ``w``, the response to the nonlinear element forces ``f_a`` (plus the initial
   condition that makes the total start at rest), propagated in complex modal
   coordinates with the exact discretisation of each mode for an input that is linear
   between internal steps (first-order hold, FOH):
   ``z_{k+1} = e^{lambda h} z_k + h phi_12(lambda h) b f_k + h phi_2(lambda h) b f_{k+1}``.
   Only the relative coordinates of the elements are evaluated at each internal step; the
   implicit dependence of ``f_{k+1}`` on ``delta_{k+1}`` (through the FOH feedthrough) is
   resolved by Newton's method on the few element forces, so stiff stops do not need a
   tiny step. A step is converged when every element force agrees with its evaluation to
   ``tol`` (relative) or to the round-off of its argument (``|dF/dx|`` times a few ulps of
   ``x``; near a gap the relative test alone would ask for more digits than
   ``x - g`` has). The loop is a numba kernel (``cache=True``).
3. The recorded channels are computed afterwards in the frequency domain from the stored
   FOH forces: ``Y(w) = C (j w - Lambda)^-1 (B F_foh(w) + z_0)`` on a zero-padded grid
   long enough for every mode to decay (linear convolution, no wrap-around), multiplied
   by the anti-alias filter and inverse transformed directly at the output rate. This is
   the exact low-passed response of the same FOH trajectory the kernel integrated, at
   the cost of a few FFTs instead of an output update at every internal step.

Anti-alias filter: gain exactly 1 up to ``passband * fs`` (default 0.4 fs), raised-cosine
roll-off to 0 at fs/2 (smooth in frequency, so its impulse response decays fast and the
start of the record does not ring into the steady-state periods).

Errors come only from the FOH assumption on the nonlinear force (second order in the
internal step ``h``; kinks at contact onsets) and from the padding (decay to < 1e-12).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Callable, Literal, Sequence

import warnings

import numpy as np
import scipy.linalg as sla
from numba import njit

from fnsi_lab import plain
from fnsi_lab.daq.sim.model import StructuralModel
from fnsi_lab.daq.sim.nonlinear import BASIS_COULOMB, BASIS_NEG, BASIS_POLY, BASIS_POS, element_tables
from fnsi_lab.errors import ConfigError, FnsiLabError

Quantity = Literal["displacement", "velocity", "acceleration"]


class IntegrationError(FnsiLabError, ArithmeticError):
    """The time integration diverged (a stop far too stiff for the internal rate)."""


@dataclass(frozen=True)
class SimulationResult:
    """Output of :func:`simulate`.

    Attributes
    ----------
    displacement, velocity, acceleration : ndarray, shape (n_samples, n_out) or None
        Anti-alias-filtered responses at the output rate, model units (length, /s, /s^2);
        ``None`` when not requested.
    dofs : ndarray of int, shape (n_out,)
        DOF index of each column.
    sample_rate_hz, internal_rate_hz : float
    element_force : ndarray, shape (n_internal + 1, n_elements)
        Scalar element forces ``sum_j c_j h_j`` at every internal step (model force unit).
    contact_fraction : dict str -> float
        Fraction of internal steps (from ``count_from``) with each stop closed.
    iterations_max : int
        Largest number of corrector (Newton) iterations taken in a step.
    unconverged_steps : int
        Steps where the corrector hit ``max_iter`` (0 expected; a warning is issued).
    """

    displacement: np.ndarray | None
    velocity: np.ndarray | None
    acceleration: np.ndarray | None
    dofs: np.ndarray
    sample_rate_hz: float
    internal_rate_hz: float
    element_force: np.ndarray
    contact_fraction: dict[str, float] = field(default_factory=dict)
    iterations_max: int = 0
    unconverged_steps: int = 0

    def get(self, quantity: Quantity) -> np.ndarray:
        """The array of one quantity (raises if it was not computed)."""
        out = getattr(self, quantity)
        if out is None:
            raise ConfigError(f"{quantity} was not requested from simulate()")
        return out


# ---------------------------------------------------------------------------- kernel
# reassociation lets LLVM vectorise the modal sums (the hot loop); results are still
# deterministic for a given machine and build
_FAST = {"reassoc", "contract", "arcp", "nsz"}
#: Corrector round-off floor: an element force is converged when its residual is within
#: tol |F| or within the force of this many ulps of its argument (x = ypred + D f is a
#: rounded sum of a few terms, so it is known to ~1-2 ulps of their magnitude; see _kernel).
_ROUNDOFF_ULPS = 8.0
_EPS = float(np.finfo(np.float64).eps)

@njit(cache=True, fastmath=_FAST, nogil=True)  # nogil: realizations run in threads
def _eval_forces(y, s, el, code, coef, gap, expo, signed, vel, v0, out):
    """Element forces ``out[a] = sum_b c_b h_b(x_a)`` (``x_a`` = disp or vel of element a)."""
    for a in range(s):
        out[a] = 0.0
    for b in range(el.shape[0]):
        a = el[b]
        x = y[s + a] if vel[b] else y[a]
        c = code[b]
        if c == BASIS_NEG:
            h = x + gap[b] if x < -gap[b] else 0.0
        elif c == BASIS_POS:
            h = x - gap[b] if x > gap[b] else 0.0
        elif c == BASIS_POLY:
            if signed[b]:
                h = abs(x) ** (expo[b] - 1.0) * x
            else:
                h = x ** expo[b]
        elif c == BASIS_COULOMB:
            h = math.tanh(x / v0[b])
        else:  # quadratic damping
            h = abs(x) * x
        out[a] += coef[b] * h


@njit(cache=True, fastmath=_FAST, nogil=True)  # nogil: realizations run in threads
def _eval_slopes(y, s, el, code, coef, gap, expo, signed, vel, v0, out):
    """Derivative of each element force with respect to its own argument, ``dF_a/dx_a``."""
    for a in range(s):
        out[a] = 0.0
    for b in range(el.shape[0]):
        a = el[b]
        x = y[s + a] if vel[b] else y[a]
        c = code[b]
        if c == BASIS_NEG:
            d = 1.0 if x < -gap[b] else 0.0
        elif c == BASIS_POS:
            d = 1.0 if x > gap[b] else 0.0
        elif c == BASIS_POLY:
            p = expo[b]
            if signed[b]:
                d = p * abs(x) ** (p - 1.0)
            else:
                d = p * x ** (p - 1.0)
        elif c == BASIS_COULOMB:
            t = math.tanh(x / v0[b])
            d = (1.0 - t * t) / v0[b]
        else:
            d = 2.0 * abs(x)
        out[a] += coef[b] * d


@njit(cache=True, fastmath=_FAST, nogil=True)  # nogil: realizations run in threads
def _kernel(edr, edi, g0r, g0i, g1r, g1i, bur, bui, u, bfr, bfi, cr, ci, yoff, rows, erow,
            zr0, zi0, dmat, el, code, coef, gap, expo, signed, vel, v0, count_from,
            fout, counts, tol, max_iter):
    """Propagate the modal state over every internal step; see the module docstring.

    Shapes: modes nm, external inputs nu, elements s, needed element outputs n_r (row
    ``rows[r]`` of the 2s outputs: disp 0..s-1, vel s..2s-1). u (n_steps + 1, nu);
    cr, ci (n_r, nm); yoff (n_off, n_r) added at step k as yoff[k % n_off];
    dmat (n_r, s); erow (s,) row of each element's own argument in ``rows``;
    fout (s, n_steps + 1) receives the element forces; counts (n_basis,).
    Returns (largest number of corrector iterations, steps that hit ``max_iter``, largest
    relative force residual left in those steps).
    """
    nm = edr.shape[0]
    nu = u.shape[1]
    s = bfr.shape[1]
    n_r = rows.shape[0]
    n_steps = fout.shape[1] - 1
    n_off = yoff.shape[0]
    zr = zr0.copy()
    zi = zi0.copy()
    bvr = np.zeros(nm)   # modal input B v_k at the current step (complex)
    bvi = np.zeros(nm)
    ypred = np.zeros(n_r)
    y = np.zeros(2 * s)
    f = np.zeros(s)
    fn = np.zeros(s)
    slope = np.zeros(s)
    delta = np.zeros(s)
    act = np.zeros(s, dtype=np.int64)
    jac = np.zeros((s, s))  # Newton matrix of the active elements (first n_act rows/cols)
    rv = np.zeros(s)
    iters_max = 0
    n_fail = 0
    worst = 0.0  # largest relative force residual |F(y) - f| / |F| of unconverged steps
    # step 0: forces from the initial state
    for r in range(n_r):
        acc = yoff[0, r]
        for m in range(nm):
            acc += cr[r, m] * zr[m] - ci[r, m] * zi[m]
        y[rows[r]] = acc
    _eval_forces(y, s, el, code, coef, gap, expo, signed, vel, v0, f)
    for a in range(s):
        if f[a] != 0.0:
            fout[a, 0] = f[a]
    for m in range(nm):
        ar = 0.0
        ai = 0.0
        for j in range(nu):
            ar += bur[m, j] * u[0, j]
            ai += bui[m, j] * u[0, j]
        for a in range(s):
            ar += bfr[m, a] * f[a]
            ai += bfi[m, a] * f[a]
        bvr[m] = ar
        bvi[m] = ai
    for k in range(n_steps):
        # predictor: exact propagation with everything known at k (vectorised loop)
        for m in range(nm):
            ar = edr[m] * zr[m] - edi[m] * zi[m] + g0r[m] * bvr[m] - g0i[m] * bvi[m]
            ai = edr[m] * zi[m] + edi[m] * zr[m] + g0r[m] * bvi[m] + g0i[m] * bvr[m]
            zr[m] = ar
            zi[m] = ai
            bvr[m] = 0.0
            bvi[m] = 0.0
        if nu > 0:  # external input at k+1 (general, non-periodic path)
            for m in range(nm):
                pr = 0.0
                pi = 0.0
                for j in range(nu):
                    pr += bur[m, j] * u[k + 1, j]
                    pi += bui[m, j] * u[k + 1, j]
                zr[m] += g1r[m] * pr - g1i[m] * pi
                zi[m] += g1r[m] * pi + g1i[m] * pr
                bvr[m] = pr
                bvi[m] = pi
        if (k & 63) == 0:
            # flush decayed modal states to zero: subnormal numbers are ~100x slower
            for m in range(nm):
                if abs(zr[m]) < 1e-200:
                    zr[m] = 0.0
                if abs(zi[m]) < 1e-200:
                    zi[m] = 0.0
        ko = (k + 1) % n_off
        for r in range(n_r):
            acc = yoff[ko, r]
            for m in range(nm):
                acc += cr[r, m] * zr[m] - ci[r, m] * zi[m]
            ypred[r] = acc
        # corrector: solve f = F(y_pred + D f) for f_{k+1}. D is the FOH feedthrough
        # (~h^2 k/m): tiny for soft elements, where two fixed-point steps converge; Newton
        # takes over after that (stiff stops; piecewise-linear ones converge once the
        # contact set is right).
        any_f = False
        for a in range(s):
            if f[a] != 0.0:
                any_f = True
        it = 0
        while True:
            for r in range(n_r):
                acc = ypred[r]
                if any_f:
                    for a in range(s):
                        acc += dmat[r, a] * f[a]
                y[rows[r]] = acc
            _eval_forces(y, s, el, code, coef, gap, expo, signed, vel, v0, fn)
            it += 1
            diff = 0.0
            scale = 0.0
            for a in range(s):
                d = abs(fn[a] - f[a])
                if d > diff:
                    diff = d
                if abs(fn[a]) > scale:
                    scale = abs(fn[a])
            if diff <= tol * scale:
                for a in range(s):
                    f[a] = fn[a]
                break
            if it >= 3:
                # Newton stage. The relative test above cannot always be met: near a gap
                # (stop about to open, |h| = |x| - g << |x|) the force is known only to the
                # round-off of its argument x = ypred + D f, |G| ulp(x), which can exceed
                # tol |F|; the iteration then flips x by one ulp for ever (measured:
                # |x + g| = 6e-5 mm at x = -1.5 mm, residual 116.73 N/mm x 1 ulp = 2.6e-14 N
                # > 1e-12 x 7.3e-3 N). Accept, element by element, a residual within
                # tol |F| + _ROUNDOFF_ULPS eps |G_a| (|ypred_a| + sum_b |D_ab f_b|): the
                # contact set is then settled and f is exact to the precision of x itself.
                _eval_slopes(y, s, el, code, coef, gap, expo, signed, vel, v0, slope)
                settled = True
                for a in range(s):
                    d = abs(fn[a] - f[a])
                    if d > tol * scale:
                        ra = erow[a]
                        mag = abs(ypred[ra])
                        for b in range(s):
                            mag += abs(dmat[ra, b] * f[b])
                        if d > tol * scale + _ROUNDOFF_ULPS * _EPS * abs(slope[a]) * mag:
                            settled = False
                            break
                if settled:
                    for a in range(s):
                        f[a] = fn[a]
                    break
            if it >= max_iter:
                # genuine non-convergence (the contact set or a stiff element keeps changing)
                n_fail += 1
                rel = diff / max(scale, 1e-300)
                if rel > worst:
                    worst = rel
                for a in range(s):
                    f[a] = fn[a]
                break
            if it < 3:
                # fixed-point step first: enough for soft elements (|G D| << 1), cheapest
                any_f = False
                for a in range(s):
                    f[a] = fn[a]
                    if f[a] != 0.0:
                        any_f = True
                continue
            # then Newton: (I - G D) delta = F(y) - f with G = diag(dF_a/dx_a) (evaluated
            # above); rows of elements with G = 0 are the identity, so only the active block
            # is solved
            n_act = 0
            for a in range(s):
                delta[a] = fn[a] - f[a]
                if slope[a] != 0.0:
                    act[n_act] = a
                    n_act += 1
            if n_act == 1:
                a = act[0]
                rhs = delta[a]
                for b in range(s):
                    if b != a and slope[b] == 0.0:
                        rhs += slope[a] * dmat[erow[a], b] * delta[b]
                delta[a] = rhs / (1.0 - slope[a] * dmat[erow[a], a])
            elif n_act > 1:
                for i in range(n_act):
                    a = act[i]
                    rhs = delta[a]
                    for b in range(s):
                        if slope[b] == 0.0:
                            rhs += slope[a] * dmat[erow[a], b] * delta[b]
                    rv[i] = rhs
                    for j in range(n_act):
                        jac[i, j] = (1.0 if i == j else 0.0) - slope[a] * dmat[erow[a], act[j]]
                # Gaussian elimination with partial pivoting on the n_act x n_act block, in
                # place (what LAPACK's dgesv does; np.linalg.solve here cost ~3 s of numba
                # compilation on the first run, for a block of a few elements)
                for c in range(n_act):
                    piv = c
                    for i in range(c + 1, n_act):
                        if abs(jac[i, c]) > abs(jac[piv, c]):
                            piv = i
                    if piv != c:
                        for j in range(n_act):
                            tmp = jac[c, j]
                            jac[c, j] = jac[piv, j]
                            jac[piv, j] = tmp
                        tmp = rv[c]
                        rv[c] = rv[piv]
                        rv[piv] = tmp
                    for i in range(c + 1, n_act):
                        fac = jac[i, c] / jac[c, c]
                        for j in range(c + 1, n_act):
                            jac[i, j] -= fac * jac[c, j]
                        rv[i] -= fac * rv[c]
                for c in range(n_act - 1, -1, -1):
                    acc = rv[c]
                    for j in range(c + 1, n_act):
                        acc -= jac[c, j] * rv[j]
                    rv[c] = acc / jac[c, c]
                for i in range(n_act):
                    delta[act[i]] = rv[i]
            any_f = False
            for a in range(s):
                f[a] += delta[a]
                if f[a] != 0.0:
                    any_f = True
        if it > iters_max:
            iters_max = it
        for a in range(s):
            if f[a] != 0.0:  # fout is zero-initialised: untouched pages cost nothing
                fa = f[a]
                fout[a, k + 1] = fa
                for m in range(nm):
                    pr = bfr[m, a] * fa
                    pi = bfi[m, a] * fa
                    zr[m] += g1r[m] * pr - g1i[m] * pi
                    zi[m] += g1r[m] * pi + g1i[m] * pr
                    bvr[m] += pr
                    bvi[m] += pi
        if k + 1 >= count_from:
            for b in range(el.shape[0]):
                a = el[b]
                x = y[s + a] if vel[b] else y[a]
                if code[b] == BASIS_NEG and x < -gap[b]:
                    counts[b] += 1
                elif code[b] == BASIS_POS and x > gap[b]:
                    counts[b] += 1
    return iters_max, n_fail, worst


# ---------------------------------------------------------------------------- helpers
def foh_coefficients(lam: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact FOH discretisation of ``z' = lambda z + b u`` over one step ``h``.

    Returns
    -------
    e, gamma0, gamma1 : complex ndarray, shape (n_modes,)
        ``z_{k+1} = e z_k + (gamma0 u_k + gamma1 u_{k+1}) b`` for ``u`` linear on the step:
        ``e = exp(mu)``, ``gamma0 = h (phi_1 - phi_2)``, ``gamma1 = h phi_2`` with
        ``mu = lambda h``, ``phi_1 = (e^mu - 1)/mu``, ``phi_2 = (e^mu - 1 - mu)/mu^2``,
        computed with the matrix exponential of ``[[mu, 1, 0], [0, 0, 1], [0, 0, 0]]``
        (no cancellation for small ``mu``).
    """
    e = np.empty(lam.size, complex)
    g0 = np.empty(lam.size, complex)
    g1 = np.empty(lam.size, complex)
    for i, mu in enumerate(np.asarray(lam) * h):
        ex = sla.expm(np.array([[mu, 1, 0], [0, 0, 1], [0, 0, 0]], dtype=complex))
        e[i], phi1, phi2 = ex[0, 0], ex[0, 1], ex[0, 2]
        g0[i] = h * (phi1 - phi2)
        g1[i] = h * phi2
    return e, g0, g1


def antialias_gain(frequency_hz: np.ndarray, sample_rate_hz: float,
                   passband: float = 0.4) -> np.ndarray:
    """Zero-phase anti-alias filter: 1 below ``passband*fs``, raised cosine to 0 at fs/2."""
    f = np.abs(np.asarray(frequency_hz, dtype=float)) / sample_rate_hz
    g = np.ones_like(f)
    band = (f > passband) & (f < 0.5)
    g[band] = 0.5 * (1 + np.cos(np.pi * (f[band] - passband) / (0.5 - passband)))
    g[f >= 0.5] = 0.0
    return g


def _next_fast_len(n: int) -> int:
    """Smallest 5-smooth number (2^a 3^b 5^c) >= ``n``: a fast real FFT length.

    The same as ``scipy.fft.next_fast_len(n, real=True)``; numpy's FFT (the same pocketfft,
    bit for bit on these lengths) is used here because importing ``scipy.fft`` (and with it
    ``scipy.special``) costs ~0.1 s of every ``fnsi-lab acquire``.
    """
    n = max(int(n), 1)
    best = 1 << (n - 1).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            p2 = 1 << (-(-n // p35) - 1).bit_length()
            best = min(best, p2 * p35)
            p35 *= 3
        p5 *= 5
    return best


def _sinc2(f_hz: np.ndarray, h: float) -> np.ndarray:
    """Fourier transform of the FOH (triangle) interpolation kernel, divided by h."""
    return np.sinc(f_hz * h) ** 2


def _periodic_state(model: StructuralModel, force_period: np.ndarray, fs: float,
                    n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line spectra of the exact periodic linear response.

    Returns
    -------
    lines : int ndarray, shape (n_lines,)
        DFT lines (of one period) with force.
    q_spec : complex ndarray, shape (n_lines, n_dof)
        DOF displacement spectra, scaled so that ``irfft`` at ``n_out`` samples (after
        placing them on ``lines``) returns the time signal at ``n_out`` samples per period.
    w : ndarray, shape (n_lines,)
        Angular frequencies (rad/s).
    """
    p = np.asarray(force_period, dtype=float)
    n = p.shape[0]
    spec = np.fft.rfft(p, axis=0)
    if n % 2 == 0:
        spec[-1] = 0.0  # the Nyquist line of a sampled force is ambiguous: drop it
    mag = np.abs(spec).max(axis=1)
    lines = np.nonzero(mag > 1e-13 * max(mag.max(initial=0.0), 1e-300))[0]
    w = 2 * np.pi * lines * fs / n
    dyn = (model.stiffness[None] - w[:, None, None] ** 2 * model.mass[None]
           + 1j * w[:, None, None] * model.damping[None])
    rhs = (model.force_matrix[None].astype(complex) @ spec[lines][:, :, None])
    q = np.linalg.solve(dyn, rhs)[:, :, 0] * (n_out / n)
    return lines, q, w


def _spectrum_to_time(lines: np.ndarray, spec: np.ndarray, n_out: int) -> np.ndarray:
    full = np.zeros((n_out // 2 + 1, spec.shape[1]), complex)
    full[lines] = spec
    return np.fft.irfft(full, n=n_out, axis=0)


@dataclass(frozen=True)
class _Prepared:
    """Per-(model, internal step) quantities, reused across realizations."""

    h: float
    half: np.ndarray
    lam: np.ndarray
    e: np.ndarray
    g0: np.ndarray
    g1: np.ndarray
    vhalf: np.ndarray      # (2n, nm) V columns of the half set, weighted (2 or 1)
    vinv_half: np.ndarray  # (nm, 2n)
    bf: np.ndarray         # (nm, s) modal input of element forces
    bu_state: np.ndarray   # (2n, n_in) state input of external forces
    bf_state: np.ndarray   # (2n, s)
    cnl: np.ndarray        # (2s, nm) element relative disp/vel from modal coords
    need: np.ndarray       # (2s,) bool
    dmat: np.ndarray       # (2s, s) FOH feedthrough from f_{k+1}


#: Output samples simulated past the end of a periodic record (anti-alias filter support).
_MARGIN = 64


def _prepare(model: StructuralModel, h: float) -> _Prepared:
    # cached on the (immutable) model instance itself: an id()-keyed global cache would
    # hand a new model the arrays of a dead one that had the same id
    cache = model.__dict__.setdefault("_sim_prepared", {})
    hit = cache.get(h)
    if hit is not None:
        return hit
    modes = model.modes
    lam, v, vinv = modes.eigenvalues, modes.vectors, modes.inverse
    tol = 1e-9 * np.abs(lam)
    half = np.nonzero(lam.imag > tol)[0]
    real = np.nonzero(np.abs(lam.imag) <= tol)[0]
    idx = np.concatenate([half, real])
    weight = np.concatenate([np.full(half.size, 2.0), np.ones(real.size)])
    n = model.n_dof
    minv = np.linalg.inv(model.mass)
    lw = model.weights
    s = lw.shape[1]
    bu_state = np.vstack([np.zeros((n, model.n_inputs)), minv @ model.force_matrix])
    bf_state = np.vstack([np.zeros((n, s)), -minv @ lw])
    e, g0, g1 = foh_coefficients(lam[idx], h)
    e[np.abs(e) < 1e-100] = 0.0  # modes that vanish within one step: avoid subnormals
    vhalf = v[:, idx] * weight
    vinv_half = vinv[idx]
    bf = vinv_half @ bf_state
    cnl = np.vstack([lw.T @ vhalf[:n], lw.T @ vhalf[n:]]) if s else np.zeros((0, idx.size))
    need = np.zeros(2 * s, dtype=np.bool_)
    for a, el in enumerate(model.nonlinearities):
        need[s + a if el.uses_velocity else a] = True
    dmat = np.real(cnl @ (g1[:, None] * bf)) if s else np.zeros((0, 0))
    prep = _Prepared(h, idx, lam[idx], e, g0, g1, vhalf, vinv_half, bf, bu_state, bf_state,
                     cnl, need, dmat)
    if len(cache) > 8:
        cache.clear()
    cache[h] = prep
    return prep


def _element_frequency_hz(model: StructuralModel) -> float:
    """Largest local frequency of the stops/springs: sqrt(k_contact L^T M^-1 L) / 2 pi."""
    minv = np.linalg.inv(model.mass)
    best = 0.0
    for el in model.nonlinearities:
        if el.kind in ("trilinear", "bilinear"):
            k = max(abs(v) for v in el.coefficients.values())
            best = max(best, float(np.sqrt(k * el.weights @ minv @ el.weights)) / (2 * np.pi))
    return best


def _decay_samples(model: StructuralModel, rate: float, level: float = 1e-13) -> int:
    sigma = -model.modes.eigenvalues.real.max()
    return int(np.ceil(np.log(1 / level) / sigma * rate))


# ---------------------------------------------------------------------------- public
def simulate(model: StructuralModel, force: np.ndarray, sample_rate_hz: float, *,
             oversample: int = 20, periodic: int | None = None,
             dofs: Sequence[int] | np.ndarray | Literal["measured", "all"] | None = None,
             quantities: Sequence[Quantity] = ("displacement", "velocity", "acceleration"),
             passband: float = 0.4, count_from: int = 0, tol: float = 1e-12,
             max_iter: int = 50) -> SimulationResult:
    """Simulate the response of ``model`` to ``force``, starting at rest.

    Parameters
    ----------
    model : StructuralModel
    force : ndarray, shape (n_samples, n_inputs)
        Input forces sampled at ``sample_rate_hz`` (model force unit).
    sample_rate_hz : float
        Output (and force) sampling rate fs.
    oversample : int, optional
        Internal steps per output sample; internal rate = ``oversample * fs``.
    periodic : int or None, optional
        If the force is periodic with this many samples per period (``n_samples`` a
        multiple of it), its linear response is the exact periodic steady state from the
        frequency domain, and the force between samples is its trigonometric interpolant
        (exact for a multisine). Otherwise the force is upsampled with a zero-phase
        polyphase FIR (``scipy.signal.resample_poly``).
    dofs : sequence of int, or 'measured' or 'all', optional
        DOFs to return (default ``'measured'``: the model's measured DOFs, in channel
        order; ``'all'``: every DOF, internal ones included).
    quantities : sequence of {'displacement', 'velocity', 'acceleration'}
        What to compute.
    passband : float, optional
        Anti-alias filter flat up to ``passband * fs`` (see :func:`antialias_gain`).
    count_from : int, optional
        Output sample from which stop contacts are counted (the steady-state periods).
    tol, max_iter : float, int
        Corrector tolerance (relative, on element forces) and iteration cap per step. A
        residual within the round-off of the element's argument (a few ulps of it times the
        element stiffness) also counts as converged: near a gap the relative tolerance is
        below what double precision can resolve. Steps that reach ``max_iter`` are counted
        in ``unconverged_steps`` and reported by a ``RuntimeWarning``.

    Returns
    -------
    SimulationResult

    Notes
    -----
    See the module docstring for the method and its error sources.
    """
    fs = float(sample_rate_hz)
    quantities = tuple(dict.fromkeys(quantities))  # each once (the outputs accumulate per name)
    bad = sorted(set(quantities) - {"displacement", "velocity", "acceleration"})
    if bad:
        raise ConfigError(f"unknown quantities {plain.names(bad)}: use displacement, velocity, acceleration")
    p = np.asarray(force, dtype=float)
    if p.ndim == 1:
        p = p[:, None]
    if p.shape[1] != model.n_inputs:
        raise ConfigError(f"force has {p.shape[1]} columns, model has {model.n_inputs} inputs")
    n_samples = p.shape[0]
    os_ = int(oversample)
    if os_ < 1:
        raise ConfigError("oversample must be >= 1")
    h = 1.0 / (fs * os_)
    # periodic runs continue a little past the record so that the zero-phase anti-alias
    # filter sees the true continuation at the end of the last period
    margin = _MARGIN if periodic is not None else 0
    n_fine = (n_samples + margin) * os_
    n = model.n_dof
    if dofs is None or (isinstance(dofs, str) and dofs == "measured"):
        dofs_arr = model.measured_dofs
    elif isinstance(dofs, str) and dofs == "all":
        dofs_arr = np.arange(model.n_dof)
    else:
        dofs_arr = np.asarray(dofs, dtype=np.int64)
    prep = _prepare(model, h)
    nm = prep.half.size
    tabs = element_tables(model.nonlinearities)
    s = len(model.nonlinearities)

    # ---- linear part
    if periodic is not None:
        n_per = int(periodic)
        if n_samples % n_per:
            raise ConfigError(f"{n_samples} samples is not a whole number of {n_per}-sample periods")
        lines, qspec, w = _periodic_state(model, p[:n_per], fs, n_per * os_)
        lw = model.weights
        rows = np.nonzero(prep.need)[0]
        dspec = np.concatenate([qspec @ lw, (1j * w)[:, None] * (qspec @ lw)], axis=1)[:, rows]
        yoff = (_spectrum_to_time(lines, dspec, n_per * os_) if s
                else np.zeros((1, 0)))
        # state at t = 0 of the steady state: w(0) = -x_ss(0) makes the total start at rest
        # irfft at t = 0 of the one-sided lines: DC counts once, the others twice
        two = np.where(lines == 0, 1.0, 2.0)[:, None] / (n_per * os_)
        q0 = np.real((qspec * two).sum(axis=0))
        v0 = np.real(((1j * w)[:, None] * qspec * two).sum(axis=0))
        x0 = -np.concatenate([q0, v0])
        u_fine = np.zeros((n_fine + 1, 0))
        bu = np.zeros((nm, 0), complex)
    else:
        lines = qspec = w = None
        yoff = np.zeros((1, int(prep.need.sum())))
        x0 = np.zeros(2 * n)
        if os_ > 1:
            import scipy.signal as ssig  # here: importing it costs ~1 s, periodic runs skip it

            up = ssig.resample_poly(np.vstack([p, np.zeros((1, p.shape[1]))]), os_, 1, axis=0)
            u_fine = np.ascontiguousarray(up[: n_fine + 1])
        else:
            u_fine = np.vstack([p, p[-1:]])
        bu = prep.vinv_half @ prep.bu_state
    z0 = prep.vinv_half @ x0

    # ---- nonlinear loop
    fout = np.zeros((s, n_fine + 1))
    counts = np.zeros(len(tabs.names), dtype=np.int64)
    iters = n_fail = 0
    worst = 0.0
    if s:
        rows = np.nonzero(prep.need)[0].astype(np.int64)
        erow = np.array([int(np.nonzero(rows == (s + a if el.uses_velocity else a))[0][0])
                         for a, el in enumerate(model.nonlinearities)], dtype=np.int64)
        iters, n_fail, worst = _kernel(
            prep.e.real.copy(), prep.e.imag.copy(), prep.g0.real.copy(), prep.g0.imag.copy(),
            prep.g1.real.copy(), prep.g1.imag.copy(), np.ascontiguousarray(bu.real),
            np.ascontiguousarray(bu.imag), u_fine, np.ascontiguousarray(prep.bf.real),
            np.ascontiguousarray(prep.bf.imag), np.ascontiguousarray(prep.cnl.real[rows]),
            np.ascontiguousarray(prep.cnl.imag[rows]), np.ascontiguousarray(yoff), rows, erow,
            z0.real.copy(), z0.imag.copy(), np.ascontiguousarray(prep.dmat[rows]), tabs.element,
            tabs.code, tabs.coef, tabs.gap, tabs.exponent, tabs.signed, tabs.velocity, tabs.v0,
            int(count_from) * os_, fout, counts, float(tol), int(max_iter))
    if s and not np.all(np.isfinite(fout)):
        raise IntegrationError(
            f"integration diverged at {fs * os_:g} Hz internal rate: a nonlinear element is too "
            f"stiff for the step (its local frequency is ~{_element_frequency_hz(model):.3g} Hz); "
            f"raise oversample so that the internal rate exceeds ~2 pi times it")
    if n_fail:
        warnings.warn(
            f"nonlinear corrector did not converge in {n_fail} of {n_fine} steps (largest "
            f"force residual {worst:.2g} of the element force after {int(max_iter)} "
            f"iterations): the contact state or a stiff element does not settle within a step "
            f"at the {fs * os_:g} Hz internal rate; raise oversample (e.g. to {2 * os_}) "
            f"so that each step changes the element forces less, or max_iter",
            RuntimeWarning, stacklevel=2)
    n_counted = max(n_fine - int(count_from) * os_, 1)
    contact = {name: float(c) / n_counted for name, c, code in
               zip(tabs.names, counts, tabs.code) if code in (BASIS_NEG, BASIS_POS)}

    # ---- outputs in the frequency domain (exact response of the FOH trajectory)
    outputs = _outputs(model, prep, fs, os_, n_samples + margin, dofs_arr, quantities,
                       passband, fout, u_fine, periodic is not None)
    outputs = {k: v[:n_samples] for k, v in outputs.items()}
    if periodic is not None:
        # switch-on transient: free response from w(0) = -x_ss(0), sampled exactly (it is
        # not low-passed: filtering its jump at t = 0 would ring, and it has decayed long
        # before the steady-state periods)
        free = _free_response(model, prep, x0, fs, n_samples, dofs_arr, quantities)
        for qn in quantities:
            outputs[qn] += free[qn]
        n_per = int(periodic)
        gain = antialias_gain(lines * fs / n_per, fs, passband)
        for qn in quantities:
            order = {"displacement": 0, "velocity": 1, "acceleration": 2}[qn]
            spec = qspec[:, dofs_arr] * (((1j * w) ** order) * gain)[:, None] / os_
            per = _spectrum_to_time(lines, spec, n_per)
            outputs[qn] += np.tile(per, (n_samples // n_per, 1))
    return SimulationResult(
        displacement=outputs.get("displacement"), velocity=outputs.get("velocity"),
        acceleration=outputs.get("acceleration"), dofs=dofs_arr, sample_rate_hz=fs,
        internal_rate_hz=fs * os_, element_force=fout.T, contact_fraction=contact,
        iterations_max=int(iters), unconverged_steps=int(n_fail))


def _free_response(model: StructuralModel, prep: _Prepared, x0: np.ndarray, fs: float,
                   n_samples: int, dofs: np.ndarray,
                   quantities: Sequence[str]) -> dict[str, np.ndarray]:
    """Free decay from state x0 at the output samples, shape (n_samples, n_dofs) each."""
    n = model.n_dof
    z0 = prep.vinv_half @ x0
    lam = prep.lam
    decay = min(n_samples, _decay_samples(model, fs))
    t = np.arange(decay) / fs
    ez = np.exp(t[:, None] * lam[None, :]) * z0[None, :]
    out = {}
    for qn in quantities:
        if qn == "displacement":
            rows = prep.vhalf[dofs]
            zz = ez
        else:
            rows = prep.vhalf[n + dofs]
            zz = ez * lam[None, :] if qn == "acceleration" else ez
        y = np.zeros((n_samples, dofs.size))
        y[:decay] = np.real(zz @ rows.T)
        out[qn] = y
    return out


def _outputs(model: StructuralModel, prep: _Prepared, fs: float, os_: int, n_samples: int,
             dofs: np.ndarray, quantities: Sequence[str], passband: float, fout: np.ndarray,
             u_fine: np.ndarray, periodic: bool) -> dict[str, np.ndarray]:
    """Anti-aliased outputs of the modal part ``w`` at the output rate (see module doc)."""
    n = model.n_dof
    h = prep.h
    n_fine = n_samples * os_
    # inputs of the modal part: element forces (+ external forces in the general case)
    active = [a for a in range(fout.shape[0]) if fout[a].any()]
    cols = [fout[a] for a in active]
    bstate = [prep.bf_state[:, a] for a in active]
    if not periodic:
        cols += [u_fine[:, j] for j in range(u_fine.shape[1])]
        bstate += [prep.bu_state[:, j] for j in range(u_fine.shape[1])]
    pad = _decay_samples(model, fs * os_)
    n_out_total = _next_fast_len(-(-(n_fine + 1 + pad) // os_))
    length = n_out_total * os_  # internal samples of the padded window
    n_lines = n_out_total // 2 + 1
    f_hz = np.arange(n_lines) / (length * h)
    jw = 2j * np.pi * f_hz
    lam_all = model.modes.eigenvalues
    vinv = model.modes.inverse
    vecs = model.modes.vectors
    out: dict[str, np.ndarray] = {}
    if not cols:
        return {qn: np.zeros((n_samples, dofs.size)) for qn in quantities}
    # modal spectra Z(w) = B U(w) / (jw - lambda), all 2n modes, lines below fs/2; the
    # FOH input's transform is h sinc^2(f h) times the DFT of its samples
    u = np.stack(cols, axis=0)  # (n_u, n_steps + 1), FFT along contiguous rows
    u_spec = np.fft.rfft(u, n=length, axis=1)[:, :n_lines] * (h * _sinc2(f_hz, h))[None, :]
    bmod = vinv @ np.stack(bstate, axis=1)  # (2n, n_u)
    zt = (bmod @ u_spec) / (jw[None, :] - lam_all[:, None])  # (2n, n_lines)
    gain = antialias_gain(f_hz, fs, passband)
    t_len = length * h
    for qn in quantities:
        if qn == "displacement":
            spec = vecs[dofs] @ zt
        elif qn == "velocity":
            spec = vecs[n + dofs] @ zt
        elif qn == "acceleration":
            spec = (vecs[n + dofs] * lam_all[None, :]) @ zt
            spec = spec + np.stack(bstate, axis=1)[n + dofs] @ u_spec
        else:
            raise ConfigError(f"unknown quantity {qn!r}")
        spec *= gain[None, :] * (n_out_total / t_len)
        y = np.fft.irfft(spec, n=n_out_total, axis=1)
        out[qn] = np.ascontiguousarray(y[:, :n_samples].T)
    return out


# ---------------------------------------------------------------------------- reference
@njit(cache=True)
def _newmark_kernel(m_inv_eff, k, c, m, t, force, lw, h, el, code, coef, gap, expo, signed,
                    vel, v0, q_out, max_iter, tol):
    s = lw.shape[0]
    n_steps = force.shape[0]
    n = k.shape[0]
    q = np.zeros(n)
    v = np.zeros(n)
    y = np.zeros(2 * s)
    f = np.zeros(s)
    fn = np.zeros(s)
    # initial acceleration from rest: M a0 = T p0
    rhs0 = t @ force[0]
    a = np.linalg.solve(m, rhs0)
    for step in range(n_steps - 1):
        p1 = t @ force[step + 1]
        # predictor terms of the average-acceleration scheme
        qs = q + h * v + 0.25 * h * h * a
        vs = v + 0.5 * h * a
        base = p1 - k @ qs - c @ vs
        for a_ in range(s):
            f[a_] = fn[a_]
        it = 0
        while True:
            rhs = base.copy()
            for a_ in range(s):
                if f[a_] != 0.0:
                    rhs -= f[a_] * lw[a_]
            a1 = m_inv_eff @ rhs
            q1 = qs + 0.25 * h * h * a1
            v1 = vs + 0.5 * h * a1
            for a_ in range(s):
                y[a_] = lw[a_] @ q1
                y[s + a_] = lw[a_] @ v1
            _eval_forces(y, s, el, code, coef, gap, expo, signed, vel, v0, fn)
            it += 1
            diff = 0.0
            scale = 0.0
            for a_ in range(s):
                diff = max(diff, abs(fn[a_] - f[a_]))
                scale = max(scale, abs(fn[a_]))
                f[a_] = fn[a_]
            if diff <= tol * scale or it >= max_iter:
                break
        q, v, a = q1, v1, a1
        q_out[step + 1] = q
    return 0


def newmark(model: StructuralModel, force_fine: np.ndarray, internal_rate_hz: float, *,
            max_iter: int = 100, tol: float = 1e-12) -> np.ndarray:
    """Reference integrator: implicit Newmark (average acceleration), nonlinear forces solved
    by fixed-point iteration at every step, starting at rest.

    Slow and obvious (dense n_dof x n_dof algebra per step), the oracle for :func:`simulate`
    in tests and the paper's method in the benchmark (Newmark at 20 kHz).

    Parameters
    ----------
    force_fine : ndarray, shape (n_steps, n_inputs)
        Force at the internal rate.
    internal_rate_hz : float

    Returns
    -------
    ndarray, shape (n_steps, n_dof)
        Displacements at every internal step (no filtering).
    """
    h = 1.0 / internal_rate_hz
    m, c, k = model.mass, model.damping, model.stiffness
    m_eff_inv = np.linalg.inv(m + 0.5 * h * c + 0.25 * h * h * k)
    tabs = element_tables(model.nonlinearities)
    p = np.ascontiguousarray(np.asarray(force_fine, dtype=float).reshape(len(force_fine), -1))
    q_out = np.zeros((p.shape[0], model.n_dof))
    lw = np.ascontiguousarray(model.weights.T)  # (s, n_dof)
    _newmark_kernel(m_eff_inv, k, c, m, np.ascontiguousarray(model.force_matrix), p, lw, h,
                    tabs.element, tabs.code, tabs.coef, tabs.gap, tabs.exponent, tabs.signed,
                    tabs.velocity, tabs.v0, q_out, max_iter, tol)
    return q_out


def lowpass_decimate_periodic(x_fine: np.ndarray, oversample: int, sample_rate_hz: float,
                              passband: float = 0.4) -> np.ndarray:
    """Exact zero-phase low-pass + decimation of whole periods of a periodic signal.

    Parameters
    ----------
    x_fine : ndarray, shape (n_periods * N * oversample, n_channels)
    Returns
    -------
    ndarray, shape (n_periods * N, n_channels)
        FFT of the whole record, :func:`antialias_gain` at ``sample_rate_hz``, inverse
        transform at the output rate.
    """
    n_fine = x_fine.shape[0]
    n_out = n_fine // oversample
    spec = np.fft.rfft(x_fine, axis=0)[: n_out // 2 + 1]
    f = np.arange(spec.shape[0]) * sample_rate_hz / n_out
    spec *= antialias_gain(f, sample_rate_hz, passband)[:, None]
    return np.fft.irfft(spec, n=n_out, axis=0) / oversample


# ---------------------------------------------------------------------------- start-up
_LOADER: "threading.Thread | None" = None
_LOADER_LOCK = threading.Lock()
#: Called once, from the loader thread, when the kernel is not in numba's on-disk cache
#: and is about to be compiled (the command line prints a line; see :func:`on_first_compile`).
_COMPILE_NOTICE: "Callable[[], None] | None" = None
#: Compilation of the three kernels from an empty cache, measured on the 2-core machine of
#: bench/RESULTS.md (CPU seconds; the cached load takes ~0.4 s).
COMPILE_SECONDS = 3.0


def on_first_compile(notice: "Callable[[], None] | None") -> None:
    """Register what to do when the simulator is about to be compiled (first run only).

    The command line registers a line on stderr (``compiling the simulator (first run
    only)...``) so that the ~3 s of the first acquisition in a fresh environment are not
    silent; library callers are silent unless they register something. ``None`` removes it.
    """
    global _COMPILE_NOTICE
    _COMPILE_NOTICE = notice


def kernel_is_cached() -> bool:
    """True when numba's on-disk cache holds the simulator kernel for this source file.

    Reads the cache index (numba 0.5x-0.6x layout: ``__pycache__/integrate._kernel-*.nbi``,
    emptied when the source changed). Returns True when the index cannot be read through
    numba's internals (then nothing is announced rather than a false notice).
    """
    try:
        return bool(_kernel._cache._cache_file._load_index())  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001 - another numba layout: assume cached, stay silent
        return True


def load_kernel_async() -> "threading.Thread":
    """Load the compiled kernel in a background thread (once per process) and return it.

    The first call of a numba function loads its machine code from the on-disk cache and
    initialises numba's typing and target registries: ~0.4 s of CPU, nearly all of it
    holding the GIL, that would otherwise start only when the first realization reaches
    :func:`simulate`. Started as soon as a nonlinear model exists, it overlaps with what
    releases the GIL meanwhile (the model's eigenproblems, the periodic state, the truth
    FRF); a :func:`simulate` that arrives earlier waits for it on numba's compiler lock.
    Any problem is left for that :func:`simulate` call to report.
    """
    global _LOADER
    with _LOADER_LOCK:
        if _LOADER is None:
            # not a daemon: an exit during the load waits for it (~0.3 s) rather than
            # tearing the interpreter down under LLVM
            _LOADER = threading.Thread(target=_load_kernel, name="fnsi-lab-sim-load",
                                       daemon=False)
            _LOADER.start()
        return _LOADER


def _load_kernel() -> None:
    """A tiny periodic run of a 3-DOF chain with a cubic spring: the same argument types
    as every :func:`simulate` call, so the real runs find the kernel loaded."""
    from fnsi_lab.daq.sim.lumped import lumped_model

    notice = _COMPILE_NOTICE
    if notice is not None and not kernel_is_cached():
        notice()
    try:
        simulate(lumped_model("cubic"), np.array([[1.0], [0.0], [-1.0], [0.0]]), 1000.0,
                 oversample=2, periodic=4, quantities=("displacement",))
    except Exception:  # noqa: BLE001 - the real run raises it where it can be reported
        pass
