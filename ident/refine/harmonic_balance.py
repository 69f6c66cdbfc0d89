"""The periodic steady state of an identified model whose nonlinear forces read its own motion.

FNSI evaluates the basis functions on the *measured* motion, noise included. The model's own
periodic steady state reads them on the motion the model predicts instead. For the elements
``e`` of the basis (arguments ``delta_e = L_e^T q``) the predicted relative motions on the
processed lines ``k`` (for velocity and acceleration outputs also the lines under the band,
:class:`ident.refine.modal.LowFrequency`) solve

    ``delta_e(k) = Lambda_e(k) G(z_k) [P(k); H(delta)(k)]``,  ``Lambda_e(k) = L_e^T / (j w_k)^t``

(``t`` = 0, 1, 2 for displacement, velocity and acceleration outputs), where ``H(delta)`` are
the basis spectra of the whole period: the predicted lines plus a fixed *background* on every
other line (the measured motion there, its lines below 4x their noise removed when the
period-to-period spread gives that noise). The basis functions are evaluated on the
band-limited fine grid of :mod:`ident.core.periodic` (``basis_oversample`` points per sample).

The equations are solved by damped Newton steps (switching the nonlinear forces on in steps
when that fails from the measured motion). Each step solves the linearised balance by GMRES,
preconditioned by a dense LU of the coupling between the *strong* lines (those that hold all
but ``1e-4`` of the motion's energy, the excitation's lines in practice), the weak lines
following them with their own-line response (:meth:`HarmonicBalance._diagonal_block`). The
same linearisation gives the predicted motion's sensitivity to the model's parameters
(:meth:`HarmonicBalance.solve_linear`, :meth:`HarmonicBalance.apply_slopes`), used by
:mod:`ident.refine.output_error`. docs/ident.md, "The output-error refinement", explains why.

Shapes: ``R`` realisations, ``F0`` lines per realisation, ``n_el`` elements, ``s`` basis
columns, ``m`` forces; predicted motions ``(R, F0, n_el)`` complex (numpy DFT over one
period divided by ``N``, as ``FrequencyData.Y``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.fft as sfft
import scipy.linalg as sla

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.refine.modal import LowFrequency
from fnsi_lab.ident.core.periodic import FrequencyData

__all__ = ["HarmonicBalance", "BalanceState", "BalanceError"]

#: Derivative powers of the output quantities (displacement = motion, velocity = its first
#: derivative, ...).
_QUANTITY_POWER = {"displacement": 0, "velocity": 1, "acceleration": 2}
#: The strong lines hold all but this fraction of a realisation's motion energy (3-DOF chain:
#: 548 of 1177 processed lines; the excited ones hold all but 7e-4).
_WEAK_ENERGY = 1e-4
#: At most this many real unknowns in the dense linearisation (an LU of 1200 is ~20 ms).
_MAX_STRONG_UNKNOWNS = 1200
#: GMRES iterations after which the preconditioner is renewed (5-6 with a fresh one).
_RENEW_AFTER = 10
#: The same with hysteretic elements, whose preconditioner is built column by column (about
#: 70 applications of the loop, against one per GMRES iteration): GMRES goes on longer before
#: renewing it (aircraft-like GVT, Jenkins + stop at 84 N: the balance 3.0x faster than with
#: 10, the same steady state; 80 gained 5 % more).
_RENEW_AFTER_MEMORY = 40
#: Step halvings of a Newton iteration before the balance gives up.
_MAX_HALVINGS = 8
#: Out of the processed band, background lines with less than this power over their noise
#: variance are left out (the integration gate of accelerations uses the same 4).
_BACKGROUND_MIN_SNR = 4.0


class BalanceError(IdentError):
    """The harmonic balance did not converge (the model has no steady state near the data)."""


@dataclass
class BalanceState:
    """A solved harmonic balance and its linearisation.

    Attributes
    ----------
    delta : complex ndarray, shape (R, F0, n_el)
        Predicted relative motions on the processed lines.
    H : complex ndarray, shape (R, F0, s)
        Basis spectra read on the predicted motion (physical units).
    iterations : int
    residual : float
        Final ``||F|| / ||delta||``.
    """

    delta: np.ndarray
    H: np.ndarray
    iterations: int
    residual: float
    _linear: _Linearisation | None = None               # set by HarmonicBalance.linearise
    _preconditioner: _Preconditioner | None = None      # from this or a nearby state

    @property
    def linearisation(self) -> _Linearisation:
        """The linearisation at this state (:meth:`HarmonicBalance.linearise`)."""
        if self._linear is None:
            raise BalanceError("the balance state is not linearised "
                               "(HarmonicBalance.linearise first)")
        return self._linear

    @property
    def preconditioner(self) -> _Preconditioner:
        """The strong lines' LU (:meth:`HarmonicBalance.linearise`)."""
        if self._preconditioner is None:
            raise BalanceError("the balance state has no preconditioner "
                               "(HarmonicBalance.linearise first)")
        return self._preconditioner


@dataclass(frozen=True)
class _Linearisation:
    """The balance linearised at one state: ``T = Lambda G_h C``."""

    slopes: np.ndarray               # (R, Nc, s) spectra of dh/d(argument)
    slopes_t: np.ndarray             # (R, Nc, s) the same on the convolution grid
    weak_diagonal: list[np.ndarray]  # per realisation: (F0, n_el, n_el) own-line blocks
    loop_gain: np.ndarray            # (F0, n_el, s) Lambda G_h of the linearisation
    #: hysteretic columns: {column: {n_grid: per realisation, the start of each sample's
    #: stick phase (-1 slipping)}} (ident.core.hysteresis.periodic_play_anchors)
    anchors: dict | None = None


@dataclass(frozen=True)
class _Preconditioner:
    """The strong lines' exact coupling, per realisation (reused by nearby states)."""

    strong: list[np.ndarray]                  # index arrays of the strong lines
    lu: list[tuple[np.ndarray, np.ndarray]]   # LU of the real form of (I - T) on them


class HarmonicBalance:
    """The predicted steady state of models on one set of frequency data.

    Parameters
    ----------
    data : FrequencyData
        With the motion of the basis channels (:attr:`FrequencyData.motion`).
    basis : sequence of Nonlinearity
        Every parameter known (the values at which the balance is evaluated by default).
    predict_below : bool, optional
        Predict the lines under the processed band too (default: for velocity and
        acceleration outputs, whose measured lines there carry the noise times ``1/w^t``).
        Displacements need the period-to-period noise (``motion.line_noise``) for it: the
        caller checks the prediction against the measurement there (:meth:`below_band_misfit`).
    """

    def __init__(self, data: FrequencyData, basis, *, predict_below: bool | None = None):
        motion = data.motion
        if motion is None:
            raise IdentError("the harmonic balance needs the motion of the basis channels")
        self.basis = tuple(basis)
        self.m = data.n_inputs
        self.N = int(data.samples_per_period)
        self.fs = float(data.sample_rate_hz)
        t = _QUANTITY_POWER[data.output_quantity]
        data_lines = np.asarray(motion.lines)
        # The lines under the band: measured, they hold noise that the refinement takes for
        # motion (3-DOF chain, 1 % noise, 16 periods: the gaps scattered 2.3x their standard
        # deviation, 1.3x with those lines predicted; velocities with 0.1 % noise, whose
        # noise grows as 1 / w there: misfit 79 noise variances, predicted 1.1). Velocity
        # and acceleration models are read there less their static terms
        # (:class:`ident.refine.modal.LowFrequency`): a fitted acceleration model's G / (j w)^2 blows
        # up at low frequency, and the balance diverged.
        if predict_below is None:
            predict_below = t > 0
        if predict_below and t == 0 and motion.line_noise is None:
            predict_below = False        # no noise to check the prediction against
        below = np.arange(1, data_lines.min()) if predict_below else np.zeros(0, int)
        #: (F0,) the predicted lines: the processed ones, and for integrated outputs those below
        self.K = np.union1d(below, data_lines).astype(int)
        #: positions of the processed lines among the predicted ones
        self.data_index = np.searchsorted(self.K, data_lines)
        self.F0 = self.K.size
        self.R = motion.displacement.shape[0]
        self.Nf = motion.displacement.shape[1]
        # The linearisation needs the slopes' spectrum only within twice the highest processed
        # line: on a grid of Nc > 4 k_max points the product of a slope and a perturbation is
        # exact on the processed lines (no wrap-around), 13x fewer points than the fine grid
        # on the 3-DOF chain. Slopes read on a coarser *time* grid are not exact: on a 2x grid
        # the Newton iterations converged only linearly (x0.2 per step).
        self.k_max = int(self.K.max())
        self.Nc = int(sfft.next_fast_len(4 * self.k_max + 2))
        self.n_el = len(self.basis)
        cols, vel = [], []
        for e, nl in enumerate(self.basis):
            cols.extend([e] * len(nl.coefficient_names))
            vel.extend([nl.needs_velocity] * len(nl.coefficient_names))
        self.column_element = np.asarray(cols, int)
        self.column_velocity = np.asarray(vel, bool)
        self.s = self.column_element.size
        self.L_out = np.stack([nl.location_vector(data.output_names) for nl in self.basis])
        L_mot = np.stack([nl.location_vector(motion.channels) for nl in self.basis])
        self.omega_lines = 2 * np.pi * self.K * self.fs / self.N
        #: (F0,) the displacement a line of the output quantity stands for
        self.to_displacement = 1.0 / (1j * self.omega_lines) ** t
        #: (F0,) the model's frequency variable on the predicted lines (the data's line map)
        if data.time_base == "bilinear":
            period_s = data.bilinear_period_s
            if period_s is None:
                raise IdentError("time_base 'bilinear' needs bilinear_period_s")
            self.z = np.exp(2j * np.arctan(self.omega_lines * period_s / 2))
            rate = float(period_s)                         # dz / d(j w) at 0
        else:
            self.z = np.exp(2j * np.pi * self.K / self.N)
            rate = 1.0 / self.fs
        #: (F0,) bool: the predicted lines under the band (None: none)
        low_lines = np.isin(self.K, below) if below.size else None
        self.low_lines = low_lines
        #: where the model is read less its static terms (None: nowhere)
        self.low = (LowFrequency(mask=low_lines, jw=1j * self.omega_lines,
                                 rate=rate, order=t) if low_lines is not None and t > 0
                    else None)
        # the forces: measured on the processed lines, none under the band (not excited)
        self.U = np.zeros((self.R, self.F0, self.m), complex)
        self.U[:, self.data_index] = data.E[:, :self.m].reshape(self.R, -1, self.m)
        # the measured relative motions: initial guess on K, background elsewhere
        measured = np.fft.rfft(np.einsum("rnc,ec->ren", motion.displacement, L_mot),
                               axis=2) / self.Nf                       # (R, n_el, Nf/2+1)
        self.measured = np.moveaxis(measured[:, :, self.K], 1, 2)      # (R, F0, n_el)
        background = measured.copy()
        #: (n_el, F0) the measured motion's noise variance per predicted line (None: unknown)
        self.line_variance = None
        if motion.line_noise is not None:
            var = np.einsum("ei,kij,ej->ek", L_mot, motion.line_noise, L_mot).real
            self.line_variance = var[:, self.K]
            n = var.shape[1]
            weak = np.abs(background[:, :, :n]) ** 2 < _BACKGROUND_MIN_SNR * var[None]
            weak[:, :, 0] = False            # the static position is one well-averaged line
            background[:, :, :n][weak] = 0.0
            background[:, :, n:] = 0.0
        background[:, :, self.K] = 0.0
        self.background = background
        self.background_kept = (None if motion.line_noise is None
                                else int(np.count_nonzero(np.abs(background[0]) > 0)))

    def below_band_misfit(self, state: BalanceState) -> float | None:
        """Mean ``|measured - predicted|^2 / noise variance`` over the predicted lines under
        the band (about 1 where the model describes the structure there; None without such
        lines or a noise estimate)."""
        if self.low_lines is None or not self.low_lines.any() or self.line_variance is None:
            return None
        m = self.low_lines
        diff = np.abs(self.measured[:, m] - state.delta[:, m]) ** 2          # (R, n, n_el)
        var = np.maximum(self.line_variance[:, m].T, 1e-300)[None]
        return float(np.mean(diff / var))

    # ------------------------------------------------------------------ the basis spectra
    def _signals(self, delta_r: np.ndarray, r: int, n_grid: int):
        """Time signals of the relative motions (and velocities) of realisation ``r``.

        ``delta_r`` (F0, n_el) on the predicted lines; returns ``(q, q_dot)`` each of shape
        (n_grid, n_el) on a grid of ``n_grid`` points per period (``q_dot`` None when no
        element reads a velocity)."""
        n_bins = n_grid // 2 + 1
        spec = np.zeros((self.n_el, n_bins), complex)
        nb = min(n_bins, self.background.shape[2])
        spec[:, :nb] = self.background[r, :, :nb]
        spec[:, self.K] = delta_r.T
        q = np.fft.irfft(spec * n_grid, n=n_grid, axis=1).T
        q_dot = None
        if self.column_velocity.any():
            omega = 2 * np.pi * np.arange(n_bins) * self.fs / self.N
            q_dot = np.fft.irfft(spec * (1j * omega) * n_grid, n=n_grid, axis=1).T
        return q, q_dot

    def _evaluate(self, basis, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        """Basis columns on element arguments ``q``, ``q_dot`` of shape (n, n_el)."""
        return np.concatenate([nl.evaluate(q[:, e], q_dot[:, e] if nl.needs_velocity else None)
                               for e, nl in enumerate(basis)], axis=1)

    def basis_spectra(self, delta: np.ndarray, basis=None) -> np.ndarray:
        """Basis spectra ``H`` (R, F0, s) read on the motions ``delta`` (R, F0, n_el)."""
        basis = self.basis if basis is None else tuple(basis)
        out = np.empty((self.R, self.F0, self.s), complex)
        for r in range(self.R):
            q, qd = self._signals(delta[r], r, self.Nf)
            h = self._evaluate(basis, q, qd)
            out[r] = np.fft.rfft(h, axis=0)[self.K] / self.Nf
        return out

    def _slope_spectra(self, delta: np.ndarray, basis) -> np.ndarray:
        """Spectra of ``dh_a / d(argument)`` up to ``2 k_max``, in FFT order on the
        convolution grid: shape (R, Nc, s), by :meth:`Nonlinearity.slope` (central
        differences; a hysteretic element's tangent along its cycle)."""
        out = np.zeros((self.R, self.Nc, self.s), complex)
        top = 2 * self.k_max
        for r in range(self.R):
            q, qd = self._signals(delta[r], r, self.Nf)
            cols = []
            for e, nl in enumerate(basis):
                cols.append(nl.slope(q[:, e], qd[:, e] if nl.needs_velocity else None))
            full = np.fft.fft(np.concatenate(cols, axis=1), axis=0) / self.Nf
            out[r, :top + 1] = full[:top + 1]
            out[r, self.Nc - top:] = full[self.Nf - top:]
        return out

    # ------------------------------------------------------------------ the linearisation
    def apply_slopes(self, state: BalanceState, d_delta: np.ndarray, *,
                     coarse: bool = False) -> np.ndarray:
        """``dH = C d_delta``: the basis spectra's response to motion perturbations.

        Parameters
        ----------
        d_delta : complex ndarray, shape (R, F0, n_el, n)
        coarse : bool
            Hysteretic columns on the convolution grid instead of the basis's fine grid
            (4-8x fewer points; 26 % off the exact response on the aircraft-like GVT, where
            the fine grid is 0.2 % off a finite difference): for the preconditioner only.

        Returns
        -------
        complex ndarray, shape (R, F0, s, n)
        """
        n = d_delta.shape[3]
        slopes_t = state.linearisation.slopes_t
        out = np.empty((self.R, self.F0, self.s, n), complex)
        spec = np.zeros((self.Nc // 2 + 1, n), complex)
        for r in range(self.R):
            x = {}
            for a in range(self.s):
                key = (self.column_element[a], self.column_velocity[a])
                anchors = (state.linearisation.anchors or {}).get(a)
                if anchors is not None:   # its own grid: no convolution-grid signal needed
                    grid = self.Nc if coarse else self.Nf
                    out[r, :, a, :] = self._hysteretic_response(
                        anchors[grid][r], d_delta[r, :, key[0], :], grid)
                    continue
                if key not in x:   # the argument's perturbation on the grid, once per element
                    w = 1j * self.omega_lines[:, None] if key[1] else 1.0
                    spec[self.K] = d_delta[r, :, key[0], :] * (w * self.Nc)
                    x[key] = sfft.irfft(spec, n=self.Nc, axis=0)
                prod = slopes_t[r, :, a, None] * x[key]
                out[r, :, a, :] = sfft.rfft(prod, axis=0)[self.K] / self.Nc
        return out

    def _hysteretic_response(self, anchors: np.ndarray, d_delta: np.ndarray,
                             n_grid: int) -> np.ndarray:
        """A hysteretic column's spectra (F0, n) for motion perturbations ``d_delta`` (F0, n)
        on a grid of ``n_grid`` points per period (the basis's own fine grid, where
        :meth:`basis_spectra` evaluates it, for the exact response): the elongation moves
        by ``d_delta[t] - d_delta[start of the stick phase]`` while stuck and not at all
        while slipping."""
        spec = np.zeros((n_grid // 2 + 1, d_delta.shape[1]), complex)
        spec[self.K] = d_delta * n_grid
        x = sfft.irfft(spec, n=n_grid, axis=0)
        prod = np.where((anchors >= 0)[:, None], x - x[np.maximum(anchors, 0)], 0.0)
        return sfft.rfft(prod, axis=0)[self.K] / n_grid

    def _anchors(self, delta: np.ndarray, basis) -> dict | None:
        """Stick-phase starts of the hysteretic columns, ``{column: {n_grid: [per
        realisation]}}`` on the basis's fine grid and the convolution grid, or None."""
        columns = [a for a in range(self.s) if basis[self.column_element[a]].hysteretic]
        if not columns:
            return None
        from fnsi_lab.ident.core.hysteresis import periodic_play_anchors   # numba: +0.2 s

        out = {}
        for a in columns:
            e = self.column_element[a]
            nl = basis[e]
            out[a] = {n: [periodic_play_anchors(self._signals(delta[r], r, n)[0][:, e]
                                                + nl.offset, nl.slip) for r in range(self.R)]
                      for n in {self.Nf, self.Nc}}
        return out

    def _strong_lines(self, delta_r: np.ndarray) -> np.ndarray:
        """Lines of one realisation that hold all but ``_WEAK_ENERGY`` of each motion's energy."""
        energy = np.abs(delta_r) ** 2
        energy = energy / np.maximum(energy.sum(axis=0, keepdims=True), 1e-300)
        share = energy.max(axis=1)
        order = np.argsort(share)[::-1]
        cum = np.cumsum(share[order]) / max(share.sum(), 1e-300)
        n = int(np.searchsorted(cum, 1.0 - _WEAK_ENERGY)) + 1
        n = min(n, self.F0, max(1, _MAX_STRONG_UNKNOWNS // (2 * self.n_el)))
        return np.sort(order[:n])

    def _loop_lu(self, slopes_r: np.ndarray, strong: np.ndarray, gain: np.ndarray):
        """LU of the real form of ``I - T`` on the strong lines of one realisation."""
        Ks = self.K[strong]
        diff = (Ks[:, None] - Ks[None]) % self.Nc
        summ = (Ks[:, None] + Ks[None]) % self.Nc
        n, ne = Ks.size, self.n_el
        P = np.zeros((ne, n, ne, n), complex)
        Q = np.zeros_like(P)
        for a in range(self.s):
            e2 = self.column_element[a]
            w = (1j * self.omega_lines[strong]) if self.column_velocity[a] else np.ones(n)
            g = gain[strong, :, a]                                    # (n, n_el)
            P[:, :, e2, :] += g.T[:, :, None] * (slopes_r[diff, a] * w[None])[None]
            Q[:, :, e2, :] += g.T[:, :, None] * (slopes_r[summ, a] * np.conj(w)[None])[None]
        P = P.reshape(ne * n, ne * n)
        Q = Q.reshape(ne * n, ne * n)
        k = ne * n
        M = np.empty((2 * k, 2 * k))    # I - [[Pr + Qr, Qi - Pi], [Pi + Qi, Pr - Qr]]
        np.negative(P.real + Q.real, out=M[:k, :k])
        np.subtract(P.imag, Q.imag, out=M[:k, k:])
        np.negative(P.imag + Q.imag, out=M[k:, :k])
        np.subtract(Q.real, P.real, out=M[k:, k:])
        M[np.diag_indices(2 * k)] += 1.0
        return sla.lu_factor(M, overwrite_a=True, check_finite=False)

    def _diagonal_block(self, slopes_r: np.ndarray, gain: np.ndarray,
                        anchors: dict | None, r: int) -> np.ndarray:
        """``I - T_kk`` per line: each line's response to itself, (F0, n_el, n_el).

        A memoryless column's is its mean slope (the slope's spectrum at 0). A hysteretic
        column's is :func:`_stick_response`: a line's perturbation moves the elongation only
        by its change since the stick phase began, so lines slow against the stick phases
        barely move it, where the mean slope (the stuck fraction) says they all do. With the
        mean slope, GMRES preconditioned by it left 0.9 of the residual after 70
        iterations on the Bouc-Wen beam's Jenkins model (600 strong lines of the 2600 that
        hold its motion), worse than no preconditioner; with the stick response, 8e-4 after
        10 (bench/RESULTS_beam.md).
        """
        out = np.broadcast_to(np.eye(self.n_el, dtype=complex),
                              (self.F0, self.n_el, self.n_el)).copy()
        for a in range(self.s):
            if anchors is not None and a in anchors:
                response = _stick_response(anchors[a][self.Nf][r], self.K)
            else:   # a velocity argument's perturbation is j w times the motion's
                w = 1j * self.omega_lines if self.column_velocity[a] else np.ones(self.F0)
                response = slopes_r[0, a] * w
            out[:, :, self.column_element[a]] -= gain[:, :, a] * response[:, None]
        return out

    def linearise(self, state: BalanceState, loop_gain: np.ndarray, basis=None, *,
                  preconditioner: bool = False) -> None:
        """Attach the linearisation at ``state`` for the loop gain ``Lambda G_h`` (F0, n_el, s).

        The slopes and the loop gain (what ``T`` is) are always renewed; the preconditioner
        (the strong lines' LU, the costly part) only with ``preconditioner`` or when there
        is none: one from a nearby point still preconditions GMRES well, and
        :meth:`solve_linear` renews it when GMRES slows down.
        """
        basis = self.basis if basis is None else tuple(basis)
        slopes = self._slope_spectra(state.delta, basis)
        anchors = self._anchors(state.delta, basis)
        state._linear = _Linearisation(
            slopes=slopes, slopes_t=sfft.ifft(slopes, axis=1).real * self.Nc,
            weak_diagonal=[self._diagonal_block(slopes[r], loop_gain, anchors, r)
                           for r in range(self.R)],
            loop_gain=loop_gain, anchors=anchors)
        if preconditioner or state._preconditioner is None:
            self._renew_preconditioner(state)

    def _renew_preconditioner(self, state: BalanceState) -> None:
        linear = state.linearisation
        strong = [self._strong_lines(state.delta[r]) for r in range(self.R)]
        if linear.anchors:   # memory: no convolution form, the coupling column by column
            lu = [self._loop_lu_by_columns(state, r, strong[r]) for r in range(self.R)]
        else:
            lu = [self._loop_lu(linear.slopes[r], strong[r], linear.loop_gain)
                  for r in range(self.R)]
        state._preconditioner = _Preconditioner(strong=strong, lu=lu)

    def _loop_lu_by_columns(self, state: BalanceState, r: int, strong: np.ndarray):
        """LU of the real form of ``I - T`` on the strong lines of realisation ``r``, built
        by applying ``T`` to each real and imaginary unit perturbation of a strong line (in
        chunks; hysteretic columns on the convolution grid): for hysteretic elements, whose
        response to a line's perturbation is no convolution (their stick phases hold the
        motion at the phase's start)."""
        ne, n = self.n_el, strong.size
        k = ne * n
        M = np.eye(2 * k)
        chunk = 64
        for start in range(0, 2 * k, chunk):
            cols = np.arange(start, min(start + chunk, 2 * k))
            X = np.zeros((self.R, self.F0, ne, cols.size), complex)
            j = cols % k
            X[r, strong[j % n], j // n, np.arange(cols.size)] = np.where(cols < k, 1.0, 1j)
            TX = self._loop(state, X, coarse=True)[r][strong]         # (n, ne, c)
            flat = TX.transpose(1, 0, 2).reshape(k, cols.size)        # element-major
            M[:k, cols] -= flat.real
            M[k:, cols] -= flat.imag
        return sla.lu_factor(M, overwrite_a=True, check_finite=False)

    def _precondition(self, state: BalanceState, v: np.ndarray) -> np.ndarray:
        """The block lower-triangular inverse: exact on the strong lines' mutual coupling; the
        weak lines receive the strong lines' effect and keep only their own response
        (:meth:`_diagonal_block`: ``I - Lambda G_h F(0)``, the average contact stiffness, for
        memoryless columns), not their mutual coupling."""
        x = v.copy()
        ne = self.n_el
        pre = state.preconditioner
        for r in range(self.R):
            S = pre.strong[r]
            vs = v[r, S].transpose(1, 0, 2).reshape(ne * S.size, -1)   # element-major
            sol = sla.lu_solve(pre.lu[r], np.concatenate([vs.real, vs.imag]),
                               check_finite=False)
            xs = sol[:ne * S.size] + 1j * sol[ne * S.size:]
            x[r] = 0.0
            x[r, S] = xs.reshape(ne, S.size, -1).transpose(1, 0, 2)
        feed = self._loop(state, x)
        for r in range(self.R):
            weak = np.ones(self.F0, bool)
            weak[pre.strong[r]] = False
            x[r, weak] = np.linalg.solve(state.linearisation.weak_diagonal[r][weak],
                                         v[r, weak] + feed[r, weak])
        return x

    def _loop(self, state: BalanceState, x: np.ndarray, *, coarse: bool = False) -> np.ndarray:
        """``T x = Lambda G_h C x``, shapes (R, F0, n_el, n) (``coarse``: see
        :meth:`apply_slopes`)."""
        return np.einsum("kes,rksn->rken", state.linearisation.loop_gain,
                         self.apply_slopes(state, x, coarse=coarse))

    def solve_linear(self, state: BalanceState, v: np.ndarray, tolerance: float = 1e-6,
                     max_iterations: int = 30) -> np.ndarray:
        """Solve ``(I - T) x = v`` with the linearisation of ``state``.

        GMRES (right-preconditioned by the block lower-triangular inverse,
        :meth:`_precondition`), every column of ``v`` at once. The preconditioner alone
        leaves about 0.2 of the error on the 3-DOF chain, and iterating it (Richardson)
        diverged at some trial points of a refinement; GMRES cannot. GMRES takes 5-6
        iterations with a fresh preconditioner; when it needs more than
        ``_RENEW_AFTER`` (``_RENEW_AFTER_MEMORY`` with hysteretic elements), the
        preconditioner is renewed at ``state`` and GMRES restarted.

        Parameters
        ----------
        v : complex ndarray, shape (R, F0, n_el, n)
        tolerance : float
            Relative residual of each column.

        Returns
        -------
        complex ndarray, shape (R, F0, n_el, n)
        """
        def run(limit):
            return _gmres(lambda x: x - self._loop(state, x),
                          lambda x: self._precondition(state, x), v, tolerance, limit)

        x, done = run(_RENEW_AFTER_MEMORY if state.linearisation.anchors else _RENEW_AFTER)
        if not done:
            self._renew_preconditioner(state)
            x, _ = run(max_iterations)
        return x

    # ------------------------------------------------------------------ the balance
    def solve(self, G: np.ndarray, *, basis=None, start: BalanceState | None = None,
              guess: np.ndarray | None = None, tolerance: float = 1e-9,
              max_iterations: int = 40, acceptable: float | None = None) -> BalanceState:
        """The predicted motions of the model with transfer function ``G``.

        Parameters
        ----------
        G : complex ndarray, shape (F0, p, m_e)
            The model's transfer function at :attr:`z`, the predicted lines (physical basis
            units).
        basis : sequence of Nonlinearity, optional
            Basis parameters (default those given at construction).
        start : BalanceState, optional
            A previous solution: its motions start the iterations and its preconditioner is
            reused until GMRES slows down.
        guess : complex ndarray, shape (R, F0, n_el), optional
            A better first iterate than ``start``'s motions (e.g. extrapolated by the
            motion's sensitivity to a parameter step).
        tolerance : float
            On ``||delta - Lambda G e(delta)|| / ||delta||``.
        acceptable : float, optional
            Where no attempt reaches ``tolerance``, the best iterate of the full model
            (from the start, or the continuation's last step) is returned all the same when
            its residual is at most this (a piecewise-linear force's Newton steps can crawl).

        Raises
        ------
        BalanceError
            No convergence (the model predicts no nearby steady state).
        """
        basis = self.basis if basis is None else tuple(basis)
        gain = np.einsum("ep,kpa,k->kea", self.L_out, G, self.to_displacement)   # (F0, n_el, m_e)
        linear = np.einsum("kei,rki->rke", gain[:, :, :self.m], self.U)
        loop_gain = gain[:, :, self.m:]
        delta = (guess if guess is not None else self.measured if start is None
                 else start.delta).copy()
        scale = max(float(np.linalg.norm(delta)), 1e-300)
        state = BalanceState(delta=delta, H=np.empty(0), iterations=0, residual=np.inf)
        if start is not None:   # its preconditioner serves nearby models too
            state._preconditioner = start._preconditioner
        if self._newton(state, linear, loop_gain, basis, scale, tolerance, max_iterations):
            return state
        best = replace(state)        # the full model's best iterate so far
        if start is None:
            # continuation from the linear response: the nonlinear forces switched on in
            # steps (a model whose clearances the search put 10-15 % off had no steady state
            # that Newton steps could reach from the measured motion)
            total = state.iterations
            state.delta = linear.copy()
            for share in (0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0):
                done = self._newton(state, linear, share * loop_gain, basis, scale,
                                    tolerance if share == 1.0 else 1e-6, max_iterations)
                total += state.iterations
                if not done:
                    if share == 1.0 and state.residual < best.residual:
                        best = replace(state)
                    break
            else:
                if state._linear is not None:   # the last share's linearisation, full gain
                    state._linear = replace(state._linear, loop_gain=loop_gain)
                state.iterations = total
                return state
        if acceptable is not None and best.residual <= acceptable:
            return best
        first = ("the given first iterate" if guess is not None else
                 "the measured motion" if start is None else "the previous solution")
        tried = first + ("" if start is not None else ", nor from the linear response with "
                         "the nonlinear forces switched on in steps")
        tried = "from " + tried
        raise BalanceError(f"the harmonic balance found no periodic steady state of the model "
                           f"({tried}: relative residual {state.residual:.2g} left after "
                           f"{state.iterations} Newton iterations)")

    def _newton(self, state: BalanceState, linear: np.ndarray, loop_gain: np.ndarray, basis,
                scale: float, tolerance: float, max_iterations: int) -> bool:
        """Damped Newton iterations from ``state.delta``; True when they converged (``state``
        then holds the solution, else the last iterate)."""
        def residual(d):
            H = self.basis_spectra(d, basis)
            F = d - linear - np.einsum("kes,rks->rke", loop_gain, H)
            return H, F, float(np.linalg.norm(F)) / scale

        delta = state.delta
        H, F, res = residual(delta)
        for it in range(max_iterations + 1):
            if not np.isfinite(res):
                return False
            state.delta, state.H, state.iterations, state.residual = delta, H, it, res
            if res < tolerance:
                return True
            self.linearise(state, loop_gain, basis)
            step = self.solve_linear(state, F[..., None], 1e-6)[..., 0]
            # damped Newton: halve the step until the residual falls (full steps diverged
            # from a poor start, a model far from the data)
            for _ in range(_MAX_HALVINGS):
                H_new, F_new, res_new = residual(delta - step)
                if res_new < res:
                    break
                step = 0.5 * step
            else:
                return False
            delta, H, F, res = delta - step, H_new, F_new, res_new
        return False


def _stick_response(anchors: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """A hysteretic column's response on each line to a perturbation of that same line.

    Parameters
    ----------
    anchors : int ndarray, shape (n_grid,)
        Per sample of the period, the sample where its stick phase began (-1: slipping;
        :func:`ident.core.hysteresis.periodic_play_anchors`).
    lines : int ndarray, shape (F,)
        DFT lines.

    Returns
    -------
    complex ndarray, shape (F,)
        ``(1/N) sum_t stuck(t) (1 - exp(-j w_k tau(t)))`` with ``tau(t)`` the time since the
        stick phase began: the perturbation ``exp(j w_k t)`` moves the elongation by
        ``exp(j w_k t) - exp(j w_k (t - tau))`` while stuck. One FFT of the histogram of
        ``tau``: the stuck fraction minus its spectrum.
    """
    n_grid = anchors.size
    stuck = anchors >= 0
    age = (np.flatnonzero(stuck) - anchors[stuck]) % n_grid
    ages = np.fft.fft(np.bincount(age, minlength=n_grid).astype(float)) / n_grid
    return stuck.mean() - ages[np.asarray(lines) % n_grid]


def _gmres(apply, precondition, b: np.ndarray, tolerance: float, max_iterations: int):
    """Right-preconditioned GMRES for a *real*-linear operator on complex arrays.

    Returns ``(x, converged)``.

    The operator involves complex conjugates (the spectrum of a real signal), so it is linear
    over the reals only: Krylov vectors are complex arrays, inner products ``Re <x, y>`` and
    the coefficients real. Every column of ``b`` (last axis) has its own Krylov space; the
    operator is applied to all of them at once.
    """
    shape = b.shape
    n = shape[-1]
    flat = b.reshape(-1, n)
    beta = np.sqrt(np.sum(np.abs(flat) ** 2, axis=0))
    live = beta > 0
    beta = np.where(live, beta, 1.0)
    V = [flat / beta]
    Z = []
    H = np.zeros((max_iterations + 1, max_iterations, n))
    y = np.zeros((0, n))
    for j in range(max_iterations):
        z = precondition(V[j].reshape(shape)).reshape(-1, n)
        w = apply(z.reshape(shape)).reshape(-1, n)
        Z.append(z)
        for i in range(j + 1):          # modified Gram-Schmidt, real inner products
            h = np.sum((V[i].conj() * w).real, axis=0)
            w = w - h * V[i]
            H[i, j] = h
        H[j + 1, j] = np.sqrt(np.sum(np.abs(w) ** 2, axis=0))
        V.append(w / np.where(H[j + 1, j] > 0, H[j + 1, j], 1.0))
        rhs = np.zeros(j + 2)
        rhs[0] = 1.0
        y = np.empty((j + 1, n))
        res = np.empty(n)
        for c in range(n):
            sol, *_ = np.linalg.lstsq(H[:j + 2, :j + 1, c], rhs, rcond=None)
            y[:, c] = sol
            res[c] = np.linalg.norm(H[:j + 2, :j + 1, c] @ sol - rhs)
        if np.all(res < tolerance):
            break
    x = sum(Z[i] * y[i] for i in range(len(Z))) * (beta * live)
    return x.reshape(shape), bool(np.all(res < tolerance))
