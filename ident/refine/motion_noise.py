"""The noise of the measured motion in the search's objective
(:mod:`ident.refine.parameter_search`): what it adds to the squared residual of a candidate
(:class:`MotionNoise`), its size per element, whether the search corrects for it, and why it
could not.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.refine.search_space import Unknown

__all__ = ["MotionNoise", "motion_noise_std", "uncorrected_motion_noise",
           "corrects_motion_noise", "CORRECTED_MIN_STEP"]

#: Narrowest finite-difference stencil of the noise-corrected objective, relative to the
#: parameter: its noise term jumps when samples enter or leave contact. On the 3-DOF chain
#: with 1 % noise the Hessian at the final +-2 * step stencil turned indefinite in one of
#: eight seeds (a refusal); at +-0.5 % every seed gave a positive curvature.
CORRECTED_MIN_STEP = 5e-3
#: Smallest motion noise, relative to a clearance, at which the search corrects for it. The
#: plain bias grows like the square of that ratio (3-DOF chain: +0.6 % to +7.8 % at 4-5 %),
#: so below 1 % it is a few tenths of a percent at most, while the correction costs 1.2-1.5x
#: the plain search (SmallSat, 6 noisy periods: 68-78 fits against 55-63, each with the
#: noise terms) and changed nothing there (noise 0.33 % of the gaps: 0.02-0.3 %).
_MIN_CORRECTED_NOISE = 0.01


class MotionNoise:
    """What the noise in the averaged motion adds to ``|Y_k - Y_hat_k|^2``, per line and output.

    The basis functions read the measured motion ``q + n``; to first order each column
    carries ``dh_a = h_a'(L_a^T q) L_a^T n`` (``h'`` the slope of the basis function: 1 in
    contact and 0 out of it for a stop), whose line ``k`` has the covariance
    ``C_ab(k) = sum_j F_a(k - j) F_b(k - j)^* L_a^T S(j) L_b`` (``F_a`` the spectrum of
    ``h_a'``, ``S`` the noise cross-spectrum of the motion). Through the model it adds
    ``G_k C(k) G_k^H`` to the expected squared residual, less twice the correlation with
    the same noise in ``Y`` (``F_a(0) L_a^T E[n n_y^H]``). Both grow with the time spent in
    contact, so the plain model error prefers gaps that are too large (docs/ident.md,
    "Unknown basis parameters").

    Parameters
    ----------
    data : FrequencyData
        With ``motion.noise_spectrum`` (displacement outputs, ``P >= 2``).
    basis : sequence of Nonlinearity
        The elements (their location vectors; parameters may still be unknown).
    integrated : bool
        Use ``motion.line_noise`` instead, which velocity and acceleration outputs have too
        (the output-error refinement's decision; the search corrects displacements only).

    Notes
    -----
    ``S`` lives on the lines ``|j| <= N/2`` and only ``k <= N/2`` is needed, so only
    ``F_m`` for ``-N/2 <= m <= N`` enters and a circular convolution of length ``2N`` is
    exact; the noise spectra are transformed once per search.
    """

    def __init__(self, data: FrequencyData, basis: Sequence[Nonlinearity], *,
                 integrated: bool = False) -> None:
        motion = data.motion
        S = None if motion is None else (motion.line_noise if integrated
                                         else motion.noise_spectrum)
        if motion is None or S is None:
            raise IdentError("these frequency data hold no noise spectrum of the motion "
                             "(displacement outputs and at least 2 periods are needed)")
        self.motion = motion
        n_half = S.shape[0]
        self.n_period = 2 * (n_half - 1)
        self.size = 2 * self.n_period                               # circular length
        locs = [nl.location_vector(motion.channels) for nl in basis
                for _ in nl.coefficient_names]
        self.L = np.array(locs)                                     # (s, c)
        s = len(locs)
        self.pairs = [(a, b) for a in range(s) for b in range(a, s)]
        two_sided = np.zeros((len(self.pairs), self.size), complex)
        for i, (a, b) in enumerate(self.pairs):
            S_ab = np.einsum("i,kij,j->k", self.L[a], S, self.L[b])
            two_sided[i, :n_half] = S_ab
            two_sided[i, self.size - n_half + 1:] = np.conj(S_ab[1:][::-1])  # S(-j) = S(j)^*
        self.S_fft = np.fft.fft(two_sided, axis=1)
        cross = None if integrated else motion.noise_output_cross  # (F0, c, p) or None
        self.cross = None if cross is None else np.einsum("ac,kcp->kap", self.L, cross)

    def _slopes(self, basis: Sequence[Nonlinearity]) -> np.ndarray:
        """``h_a'`` on the fine grid of every realization, shape (R, N_fine, s)."""
        out = []
        for nl in basis:
            L = nl.location_vector(self.motion.channels)
            if nl.needs_velocity:            # no noise spectrum for velocities
                R, n_fine, _ = self.motion.displacement.shape
                out.append(np.zeros((R, n_fine, len(nl.coefficient_names))))
                continue
            arg = self.motion.displacement @ L + nl.offset                    # (R, N_fine)
            if nl.hysteretic:
                out.append(np.stack([nl.slope(x - nl.offset) for x in arg]))
                continue
            step = 1e-6 * float(np.max(np.abs(arg))) or 1e-12
            out.append(np.stack([(nl.evaluate(x + step) - nl.evaluate(x - step)) / (2 * step)
                                 for x in arg]))
        return np.concatenate(out, axis=2)

    def terms(self, G_basis: np.ndarray, basis: Sequence[Nonlinearity]
              ) -> tuple[np.ndarray, np.ndarray]:
        """Expected share of the motion noise in the squared residual of a candidate.

        Parameters
        ----------
        G_basis : complex ndarray, shape (F, p, s)
            FRF from the (unscaled) basis columns to the outputs on the processed lines.
        basis : sequence of Nonlinearity
            The candidate basis (every parameter known).

        Returns
        -------
        variance, bias : ndarrays, shape (F, p)
            ``variance = diag(G C G^H)``; ``bias`` = ``variance`` less the correlation
            term: the expected excess of ``|r_kp|^2`` over the fit to noise-free motion.
        """
        slope = self._slopes(basis)
        R, n_fine, s = slope.shape
        N, M = self.n_period, self.size
        F = np.fft.rfft(slope, axis=1) / n_fine                   # (R, n_fine/2+1, s)
        top = min(N, F.shape[1] - 1)
        Fm = np.zeros((R, M, s), complex)                         # F_m, -N/2 <= m <= N
        Fm[:, :top + 1] = F[:, :top + 1]
        Fm[:, M - N // 2:] = np.conj(F[:, 1:N // 2 + 1][:, ::-1])
        lines = self.motion.lines
        cov = np.empty((R, lines.size, s, s), complex)
        for i, (a, b) in enumerate(self.pairs):
            W = Fm[:, :, a] * np.conj(Fm[:, :, b])                    # (R, M)
            conv = np.fft.ifft(np.fft.fft(W, axis=1) * self.S_fft[i], axis=1)[:, lines]
            cov[:, :, a, b] = conv
            cov[:, :, b, a] = np.conj(conv)
        cov_lines = cov.reshape(-1, s, s)                          # (F, s, s)
        G = G_basis
        variance = np.einsum("kpa,kab,kpb->kp", G, cov_lines, G.conj(), optimize=True).real
        if self.cross is None:
            return np.maximum(variance, 0.0), variance
        mean_slope = F[:, 0, :].real                               # (R, s)
        X = (mean_slope[:, None, :, None] * self.cross[None]).reshape(-1, s, self.cross.shape[2])
        corr = np.einsum("kpa,kap->kp", G, X, optimize=True).real
        return np.maximum(variance, 0.0), variance - 2.0 * corr


def motion_noise_std(data: FrequencyData, nl: Nonlinearity) -> float | None:
    """Per-sample noise std of the averaged ``L^T q`` of an element (None if unknown)."""
    motion = data.motion
    cov = motion.noise_cov if motion is not None else None
    if motion is None or cov is None:
        return None
    L = nl.location_vector(motion.channels)
    return float(np.sqrt(max(L @ cov @ L, 0.0)))

def corrects_motion_noise(data: FrequencyData, basis: Sequence[Nonlinearity],
                          unknowns: Sequence[Unknown], values: np.ndarray,
                          cont: Sequence[int]) -> bool:
    """Whether the noise correction is worth its cost at ``values``: False when every
    continuous parameter ``cont`` is a length (clearances, offsets) and the motion noise is
    below :data:`_MIN_CORRECTED_NOISE` of each; True otherwise."""
    if not (cont and all(unknowns[k].is_length for k in cont)):
        return True
    ratio = max((motion_noise_std(data, basis[unknowns[k].element]) or 0.0)
                / unknowns[k].magnitude(values[k]) for k in cont)
    return ratio >= _MIN_CORRECTED_NOISE


def uncorrected_motion_noise(data: FrequencyData, quantity: str) -> list[str]:
    """Why the clearances could not be corrected for the noise in the motion, when the data
    may be noisy (nothing for displacement data whose noise is below the record resolution)."""
    if data.n_periods < 2:
        return ["one steady period per realisation: the noise in the measured motion cannot be "
                "estimated, so the clearances were not corrected for it; with noisy data they "
                "come out too large, by more than their standard deviation says (3-DOF chain, "
                "1 % output noise, 16 one-period realisations: +47 % to +71 %); record at "
                "least 2 periods per realisation (docs/ident.md, 'Unknown basis parameters')"]
    noisy = data.noise_var is not None and (data.noise_resolved is None
                                            or bool(np.any(data.noise_resolved)))
    if quantity != "displacement" and noisy:
        return [f"the noise in the motion integrated from {quantity} outputs is not corrected "
                "for (the correction needs displacement outputs): with noisy data the "
                "clearances come out too large (docs/ident.md, 'Unknown basis parameters')"]
    return []
