"""Basis parameters from the data: clearances and offsets of stops, exponents of polynomials.

A stop's gap or a polynomial's exponent enters FNSI only through the extended input
``E = [P; H(theta)]``; for a given ``theta`` the rest is the usual linear problem. The
objective is the **model error of the FNSI fit** as a function of ``theta``:

``V(theta) = sum_k |Y_k - (C (z_k I - A)^-1 B + D) E_k(theta)|^2 / sum_k |Y_k|^2``

over the processed lines, where ``A``, ``C`` come from one QR + one SVD of the data with
``H(theta)`` (:func:`ident.core.fnsi.subspace_decomposition`, few block rows:
:func:`search_block_rows`) and ``B``, ``D`` from one linear least squares
(:func:`ident.core.fast_bd.fast_estimate_bd`). Holding ``A``, ``C`` fixed while ``theta`` moves
is *not* enough: the identified linear dynamics absorb a wrong gap (3-DOF chain: with
``A``, ``C`` from a gap 2x too large, the minimum over the gap sat at 1.8x the truth), so
every candidate pays its own decomposition; with 6 block rows that is about 40-80 ms for
the 39-channel SmallSat.

Continuous parameters (clearances, a stop's offset, a signed exponent): a coarse scan of
each interval (one parameter at a time, log-spaced; linear for an offset; scanned again from
the stops open when a clearance lands at its lowest point, :func:`_better_start`), then Newton
steps on a quadratic model of ``V`` from a central finite-difference stencil. ``V`` is close
to quadratic near its minimum while the residual vector is strongly curved, so Gauss-Newton
on the residual crawled (SmallSat: 20 iterations without reaching the minimum) where Newton
on ``V`` converged in 4-5. The
standard deviation is curvature-based: ``cov = 2 V_min / dof * H^-1`` (``H`` the Hessian of
``V``, ``dof`` the residual degrees of freedom), i.e. ``s^2 (J^T J)^-1`` with the residual
variance ``s^2`` estimated from the fit. Discrete parameters (candidate exponents) are
evaluated one by one.

The search refuses (:class:`ident.errors.NotIdentifiableError`) rather than guesses when the
motion never reaches the search interval (a stop never in contact), when the minimum lies
on the interval's edge (the truth is outside, or the element barely acts), when the
objective is flat (relative standard deviation above ``max_relative_std``), when two
candidate exponents fit equally well (``min_margin``), and when the objective around the
estimate does not rise as its curvature says (a lucky low point of a rough objective,
``roughness``). With the noise correction it also compares the residual with the output
noise (``noise_misfit``; a warning above 10). docs/ident.md, "Unknown basis parameters",
explains the objective and its limits.

Noise in the measured motion adds to ``V`` a share that grows with the contact time (gaps
come out too large). With displacement outputs and at least 2 periods the continuous
parameters are refined on the noise-weighted model error less that share
(:class:`MotionNoise`), the weights held fixed at the previous estimate.

Shapes: ``FrequencyData`` as in :mod:`ident.core.periodic`; residual vectors stack the real and
imaginary parts of ``Y - Y_hat``, shape ``(2 F p,)``.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.errors import IdentError, NotIdentifiableError
from fnsi_lab.ident.core.fast_bd import fast_estimate_bd
from fnsi_lab.ident.core.periodic import FrequencyData, as_displacement_outputs, with_basis

__all__ = ["Unknown", "ParameterEstimate", "ParameterSearchResult", "search_spaces",
           "fixed_state_residual", "estimate_basis_parameters", "MotionNoise", "has_unknown_parameters",
           "AUTO_EXPONENTS", "DEFAULT_SEARCH_ORDER", "AUTO_SIGNED_EXPONENT_INTERVAL",
           "AUTO_CLEARANCE_FRACTION"]

#: ``exponent: auto`` of an unsigned polynomial: the whole exponents tried.
AUTO_EXPONENTS: tuple[float, ...] = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0)
#: ``exponent: auto`` of a signed polynomial ``|x|^(e-1) x``: the search interval (``e = 1``
#: is a linear spring, indistinguishable from the underlying linear stiffness).
AUTO_SIGNED_EXPONENT_INTERVAL: tuple[float, float] = (1.5, 7.0)
#: Model order of the search when the caller gives none (the configuration's ``order``
#: otherwise; capped by the largest order of the sweep).
DEFAULT_SEARCH_ORDER = 30
#: ``clearances: auto``: fraction of the largest recorded excursion towards that side
#: searched (a gap of 0 is a linear spring; a gap at the largest excursion never touches).
AUTO_CLEARANCE_FRACTION: tuple[float, float] = (0.02, 0.98)
#: Narrowest finite-difference stencil of the noise-corrected objective, relative to the
#: parameter: its noise term jumps when samples enter or leave contact. On the 3-DOF chain
#: with 1 % noise the Hessian at the final +-2 * step stencil turned indefinite in one of
#: eight seeds (a refusal); at +-0.5 % every seed gave a positive curvature.
_CORRECTED_MIN_STEP = 5e-3
#: Smallest motion noise, relative to a clearance, at which the search corrects for it. The
#: plain bias grows like the square of that ratio (3-DOF chain: +0.6 % to +7.8 % at 4-5 %),
#: so below 1 % it is a few tenths of a percent at most, while the correction costs 1.2-1.5x
#: the plain search (SmallSat, 6 noisy periods: 68-78 fits against 55-63, each with the
#: noise terms) and changed nothing there (noise 0.33 % of the gaps: 0.02-0.3 %).
_MIN_CORRECTED_NOISE = 0.01


def has_unknown_parameters(basis: Sequence[Nonlinearity]) -> bool:
    """True if an element of ``basis`` has a parameter left to the data."""
    return any(nl.unknown for nl in basis)


@dataclass(frozen=True)
class Unknown:
    """One free basis parameter with its resolved search space.

    Attributes
    ----------
    element : int
        Index of the element in the basis.
    name : str
        Element name.
    parameter : {'g_neg', 'g_pos', 'clearance', 'offset', 'exponent'}
    interval : (float, float) or None
        Continuous search interval (clearances and offsets in the outputs' length unit).
    candidates : tuple of float or None
        Discrete values.
    reach : float or None
        Largest recorded excursion of the element's argument towards the stop (clearances).
    scale : float or None
        Offsets: the length that steps and standard deviations are relative to (the smaller
        clearance; an offset can be 0). None: the parameter's own value.
    """

    element: int
    name: str
    parameter: str
    interval: tuple[float, float] | None = None
    candidates: tuple[float, ...] | None = None
    reach: float | None = None
    scale: float | None = None

    @property
    def label(self) -> str:
        """``NAME.parameter``."""
        return f"{self.name}.{self.parameter}"

    @property
    def continuous(self) -> bool:
        return self.candidates is None

    @property
    def is_length(self) -> bool:
        """A clearance or an offset (moved by the noise in the measured motion)."""
        return self.parameter in ("g_neg", "g_pos", "clearance", "offset")

    @property
    def log_spaced(self) -> bool:
        """Scanned on a log scale: a positive interval of a parameter known relative to itself."""
        return self.parameter != "offset" and self.interval is not None and self.interval[0] > 0

    @property
    def bounds(self) -> tuple[float, float]:
        """The search interval of a continuous parameter."""
        if self.interval is None:
            raise IdentError(f"{self.label}: a discrete parameter has no search interval")
        return self.interval

    @property
    def choices(self) -> tuple[float, ...]:
        """The candidates of a discrete parameter."""
        if self.candidates is None:
            raise IdentError(f"{self.label}: a continuous parameter has no candidates")
        return self.candidates

    def magnitude(self, value):
        """``|value|``, or the offset's length scale where that is larger (array-friendly)."""
        return np.maximum(np.abs(value), self.scale or 0.0)


@dataclass
class ParameterEstimate:
    """The estimate of one parameter and the evidence for it.

    Attributes
    ----------
    unknown : Unknown
    value : float
    std : float
        Standard deviation (NaN for discrete candidates).
    profile_values : ndarray, shape (n_points,)
        Parameter values of the objective profile (sorted): the coarse scan of the interval
        (the other parameters at their values at that stage) and a local scan around the
        estimate (the other parameters at their estimates).
    profile_objective : ndarray, shape (n_points,)
        Relative model error ``V`` at each.
    margin : float
        ``(V_other - V_best) / s^2`` in chi-square units (``s^2`` the residual variance per
        degree of freedom at the estimate): ``V_other`` is the runner-up candidate (discrete)
        or the better end of the coarse scan (continuous).
    motion_noise_std : float or None
        Clearances: standard deviation of the noise left in the averaged ``L^T q`` per
        sample (from the period-to-period spread); None without a noise estimate.
    noise_corrected : bool
        The objective had the motion noise's expected share removed
        (:class:`MotionNoise`); ``profile_objective`` is then that corrected,
        noise-weighted model error.
    roughness : float
        Continuous parameters: how far the local profile (``profile_offsets`` around the
        estimate) departs from the curvature the standard deviation comes from, as the
        largest factor between the chi-square rise it shows and the rise
        ``(offset / std)^2`` the curvature predicts (1: a smooth quadratic minimum; NaN
        without local points).
    """

    unknown: Unknown
    value: float
    std: float
    profile_values: np.ndarray
    profile_objective: np.ndarray
    margin: float = float("nan")
    motion_noise_std: float | None = None
    noise_corrected: bool = False
    roughness: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record."""
        u = self.unknown
        return {"name": u.name, "parameter": u.parameter, "value": self.value, "std": self.std,
                "interval": None if u.interval is None else list(u.interval),
                "candidates": None if u.candidates is None else list(u.candidates),
                "reach": u.reach, "margin": self.margin, "motion_noise_std": self.motion_noise_std,
                "noise_corrected": self.noise_corrected, "roughness": self.roughness,
                "profile": {"values": self.profile_values, "objective": self.profile_objective}}


@dataclass
class ParameterSearchResult:
    """Outcome of :func:`estimate_basis_parameters`.

    Attributes
    ----------
    basis : tuple of Nonlinearity
        The basis with every parameter filled in.
    estimates : list of ParameterEstimate
    objective : float
        ``V`` at the estimate (final state matrices).
    order : int
        Model order of the search.
    n_evaluations : int
        Objective evaluations (one QR + SVD and one B, D least squares each).
    block_rows : int
        ``i`` of the search's decompositions.
    timings_s : dict
    warnings : list of str
        What the engineer must read about the estimates (noise in the motion).
    noise_misfit : float
        With the noise correction: the noise-weighted squared residual at the estimate over
        the noise-weighted output noise variance (about 1 when the model explains the data
        to the noise; NaN otherwise).
    motion_noise_warnings : list of str
        The ``warnings`` about what the measured motion's noise does to the estimates (an
        output-error refinement that reads no measured motion makes them moot).
    """

    basis: tuple[Nonlinearity, ...]
    estimates: list[ParameterEstimate]
    objective: float
    order: int
    n_evaluations: int
    block_rows: int = 0
    timings_s: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    noise_misfit: float = float("nan")
    motion_noise_warnings: list = field(default_factory=list)

    def for_element(self, name: str) -> list[ParameterEstimate]:
        """Estimates of the element ``name``."""
        return [e for e in self.estimates if e.unknown.name == name]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (profiles included)."""
        return {"order": self.order, "objective": self.objective,
                "n_evaluations": self.n_evaluations, "block_rows": self.block_rows,
                "estimates": [e.to_dict() for e in self.estimates], "timings_s": self.timings_s,
                "warnings": list(self.warnings), "noise_misfit": self.noise_misfit}


# ---------------------------------------------------------------------------- search spaces
def _argument(nl: Nonlinearity, data: FrequencyData) -> np.ndarray:
    """``L^T q + offset`` of an element on the fine grid of every realization, flattened."""
    motion = data.motion
    if motion is None or not all(c in motion.channels for c in nl.channels):
        raise IdentError("these frequency data do not hold the motion of the basis channels "
                         "(prepare them with motion_for=)")
    L = nl.location_vector(motion.channels)
    if nl.kind == "polynomial" and nl.argument == "velocity":
        return (motion.velocity @ L).ravel()
    return (motion.displacement @ L).ravel() + nl.offset


def search_spaces(data: FrequencyData, basis: Sequence[Nonlinearity]) -> list[Unknown]:
    """The free parameters of ``basis`` with their search spaces resolved on the data.

    ``auto`` clearances are searched over ``AUTO_CLEARANCE_FRACTION`` of the largest
    excursion towards that side; an ``auto`` offset of a trilinear stop over the offsets at
    which the recorded motion touches both stops (:func:`_offset_space`); ``auto``
    exponents over ``AUTO_EXPONENTS`` (unsigned) or ``AUTO_SIGNED_EXPONENT_INTERVAL``
    (signed).

    Raises
    ------
    NotIdentifiableError
        The motion never reaches a stop's search interval (the stop is never in contact),
        or no offset puts both stops of a trilinear element in contact.
    """
    out = []
    for i, nl in enumerate(basis):
        for sp in nl.unknown:
            if sp.parameter == "offset":
                out.append(_offset_space(i, nl, sp.interval, _argument(nl, data) - nl.offset))
                continue
            if sp.parameter == "exponent":
                if sp.candidates is not None:
                    out.append(Unknown(i, nl.name, "exponent", candidates=sp.candidates))
                elif sp.interval is not None:
                    out.append(Unknown(i, nl.name, "exponent", interval=sp.interval))
                elif nl.signed:
                    out.append(Unknown(i, nl.name, "exponent",
                                       interval=AUTO_SIGNED_EXPONENT_INTERVAL))
                else:
                    out.append(Unknown(i, nl.name, "exponent", candidates=AUTO_EXPONENTS))
                continue
            d = _argument(nl, data)
            side = {"g_neg": "neg", "g_pos": "pos"}.get(sp.parameter, nl.side)
            reach = float(np.max(d if side == "pos" else -d))
            lo, hi = (sp.interval if sp.interval is not None
                      else tuple(f * max(reach, 0.0) for f in AUTO_CLEARANCE_FRACTION))
            if not reach > lo or not hi > lo:
                raise NotIdentifiableError(
                    f"nonlinearity {nl.name!r}: the data cannot tell {sp.parameter}: the "
                    f"largest excursion towards the {side} stop is {reach:.4g}, "
                    f"{'below' if sp.interval is not None else 'not beyond'} the search "
                    f"interval [{lo:.4g}, {hi:.4g}] (the stop is never in contact; excite "
                    "harder, or give the clearance or drop the element)")
            out.append(Unknown(i, nl.name, sp.parameter,
                               interval=(float(lo), float(min(hi, reach))), reach=reach))
    return out


def _offset_space(element: int, nl: Nonlinearity, interval: tuple[float, float] | None,
                  motion: np.ndarray) -> Unknown:
    """The search space of a trilinear stop's offset (both clearances known).

    ``motion`` is ``L^T q`` without offset. The stops are touched where
    ``motion + offset`` passes ``g_pos`` or ``-g_neg``, so both are touched for offsets in
    ``[g_pos - max(motion), -g_neg - min(motion)]``. ``auto`` searches the part of it where
    the joint at rest touches neither stop, ``(-g_neg, g_pos)``, less 2 % of its width at
    each end. Beyond that one stop is in contact most of the time, its column becomes
    nearly a copy of the motion and the model error falls again (3-DOF chain, noise-free
    accelerations: 4e-6 at 10 clearances against 2e-6 at the true offset, with a hump of
    1e-3 in between); an offset outside needs an explicit interval (a displacement
    sensor's DC offset larger than the clearances).
    """
    g_neg, g_pos = nl.clearances
    lo_both, hi_both = g_pos - float(np.max(motion)), -g_neg - float(np.min(motion))
    lo, hi = max(lo_both, -g_neg), min(hi_both, g_pos)
    span = float(np.max(motion) - np.min(motion))
    if interval is None:
        if not hi > lo:
            raise NotIdentifiableError(
                f"nonlinearity {nl.name!r}: the data cannot tell offset: the recorded relative "
                f"motion spans {span:.4g}, too little for both stops (clearances "
                f"{g_neg:.4g}, {g_pos:.4g}) to be touched from a position between them; give "
                "the offset, a search interval [low, high] for it, or excite harder")
        width = hi - lo
        interval = (lo + AUTO_CLEARANCE_FRACTION[0] * width, lo + AUTO_CLEARANCE_FRACTION[1] * width)
    positive = [g for g in (g_neg, g_pos) if g > 0]
    scale = min(positive) if positive else 0.5 * span
    return Unknown(element, nl.name, "offset", interval=(float(interval[0]), float(interval[1])),
                   scale=float(scale))


def _resolve(basis: Sequence[Nonlinearity], unknowns: Sequence[Unknown],
             values: Sequence[float] | np.ndarray) -> tuple[Nonlinearity, ...]:
    per: dict[int, dict[str, float]] = {}
    for u, v in zip(unknowns, values):
        per.setdefault(u.element, {})[u.parameter] = float(v)
    return tuple(nl.with_parameters(per[i]) if i in per else nl for i, nl in enumerate(basis))


# ---------------------------------------------------------------------------- objective
def fixed_state_residual(a_d: np.ndarray, c_d: np.ndarray, data: FrequencyData, *,
                         d_zero: bool = False) -> np.ndarray:
    """Residual of the B, D least squares with ``A``, ``C`` fixed (variable projection).

    Parameters
    ----------
    a_d : ndarray, shape (n, n)
    c_d : ndarray, shape (p, n)
    data : FrequencyData
        With the extended input of the candidate basis.
    d_zero : bool
        ``D = 0``.

    Returns
    -------
    ndarray, shape (2 F p,)
        Real, then imaginary parts of ``Y - (C (z I - A)^-1 B + D) E`` (output units).
    """
    r = _fixed_state_fit(a_d, c_d, data, d_zero=d_zero).residual
    return np.concatenate([r.real.ravel(), r.imag.ravel()])


@dataclass
class _Fit:
    """B, D of a candidate with ``A``, ``C`` fixed; ``G_basis`` = FRF to the basis columns."""

    residual: np.ndarray   # (F, p) complex, output units
    G_basis: np.ndarray    # (F, p, s) complex, output units per basis unit


def _fixed_state_fit(a_d: np.ndarray, c_d: np.ndarray, data: FrequencyData, *,
                     d_zero: bool = False) -> _Fit:
    bd = fast_estimate_bd(a_d, c_d, data, d_zero=d_zero)
    if bd is None:  # ill-conditioned eigenvectors: the core's solver
        bd = fnsi.estimate_bd(a_d, c_d, data, d_zero=d_zero, weighted=False)
    b_d, d_d = bd
    E = data.E_physical
    m = data.n_inputs
    mu, phi = np.linalg.eig(a_d)
    if np.linalg.cond(phi) < 1e8:    # modal form: O(F n m_e)
        bh = np.linalg.solve(phi, b_d.astype(complex))
        inv = 1.0 / (data.z[:, None] - mu[None, :])                    # (F, n)
        X = ((E @ bh.T) * inv) @ phi.T
        cphi = c_d @ phi
        G_basis = np.einsum("pn,kn,ns->kps", cphi, inv, bh[:, m:], optimize=True)
    else:                            # defective A: batched solves of (z I - A)
        zi = data.z[:, None, None] * np.eye(a_d.shape[0]) - a_d
        X = np.linalg.solve(zi, (E @ b_d.T)[:, :, None])[:, :, 0]
        G_basis = c_d @ np.linalg.solve(zi, np.broadcast_to(b_d[:, m:], (len(data.z),)
                                                            + b_d[:, m:].shape))
    G_basis = G_basis + d_d[None, :, m:]
    return _Fit(data.Y - X @ c_d.T - E @ d_d.T, G_basis)


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


# ---------------------------------------------------------------------------- the search
def search_block_rows(n_outputs: int, order: int, n_lines: int, n_extended_inputs: int) -> int:
    """Block rows ``i`` of the decompositions of the search: few, because each candidate pays one.

    ``max(ceil(n / p) + 2, 6)``, capped so that ``2 F >= i (m_e + p)``. On the SmallSat (39
    outputs, order 22) ``i = 6`` cost 0.08 s per candidate against 0.4 s at the default
    ``i = 20`` and gave a sharper objective (model error at the true gaps 5e-8 vs 7e-7);
    on the 3-DOF chain (order 6) ``i = 4..10`` all located the gap within 2e-5.
    """
    i = max(-(-int(order) // int(n_outputs)) + 2, 6)
    return int(min(i, max(2 * int(n_lines) // (int(n_extended_inputs) + int(n_outputs)), 2)))


def estimate_basis_parameters(data: FrequencyData, basis: Sequence[Nonlinearity], *, order: int,
                              d_zero: bool = False, block_rows: int | None = None,
                              weighted: bool = True, grid_points: int = 7,
                              max_relative_std: float = 0.1, min_margin: float = 25.0,
                              profile_offsets: Sequence[float] = (-0.03, 0.03),
                              noise_correction: bool = True,
                              select_order: bool = False,
                              workers: int | None = None,
                              progress: Callable[[str], None] | None = None
                              ) -> ParameterSearchResult:
    """Estimate the unknown clearances and exponents of ``basis`` from the data.

    Parameters
    ----------
    data : FrequencyData
        Prepared with the motion of the basis channels (``motion_for=basis``); its ``E``
        columns beyond the forces are ignored.
    basis : sequence of Nonlinearity
        Elements, some with ``unknown`` parameters.
    order : int
        Model order of the fits (the objective is the model error at this order).
    d_zero : bool
        ``D = 0`` in the B, D fits.
    block_rows : int, optional
        ``i`` of the decompositions (default :func:`search_block_rows`).
    weighted : bool
        Noise-weighted decompositions in the noise-corrected stages (when the data carry a
        noise covariance); the plain model error always uses unweighted ones.
    grid_points : int
        Points of the coarse scan of each continuous interval (log-spaced when it starts
        above 0: a gap is better known relative to itself).
    max_relative_std : float
        Refuse a continuous estimate whose standard deviation exceeds this fraction of it.
    min_margin : float
        Refuse a discrete choice whose runner-up, or a continuous value whose interval ends,
        fit within this chi-square distance of it (25: five standard deviations in the
        likelihood-ratio sense).
    profile_offsets : sequence of float
        Relative offsets of the local objective scan around each continuous estimate.
    noise_correction : bool
        When the data carry the noise spectrum of the motion (displacement outputs,
        ``P >= 2``, noise above the record resolution), refine continuous parameters on the
        noise-weighted model error less the share the motion noise adds to it
        (:class:`MotionNoise`; docs/ident.md). False: the plain model error.
    select_order : bool
        ``order`` is only the largest order: the information criterion (MDL over the orders
        2..``order``, with the search's own fits) picks the order of the coarse scan at the
        intervals' centres, and again at the scan's estimate for the rest of the search
        (with the second start, see Notes, it compares two orders).
        For callers without an order (the robust pipeline): above the structure's order the model error turns
        rough at the 1e-6 level (spare states fit parts of the misfit, differently for
        neighbouring candidates), and Newton stalls off the minimum (5-DOF chain of
        bench/robustness.py, noise-free, order 30: gaps -0.7 / +0.7 %; at the criterion's
        order 10: -0.006 / +0.002 %).
    workers : int, optional
        Threads that evaluate independent candidates at once (the points of a scan, of a
        Newton stencil, of a profile); default ``min(4, cores)``. Each candidate is one
        QR/SVD, FFTs and small solves that release the interpreter lock: on 2 cores two
        threads ran 16 candidates 1.5-1.9x faster and a whole noise-corrected search 1.3x
        (its Newton steps are sequential), with identical values.
    progress : callable, optional
        ``progress(note)`` after each stage (e.g. to advance a progress bar).

    Returns
    -------
    ParameterSearchResult

    Raises
    ------
    NotIdentifiableError
        The data cannot tell a parameter (see the module docstring); the message names the
        element, the parameter and the reason.
    IdentError
        Data without the basis motion, order too large for the data.

    Notes
    -----
    A search that would refuse is run once more with the second start (from the stops open,
    :func:`_better_start`) if it had not tried it, and refuses only if that fails too (the
    first refusal is raised; without an order it adds that giving one helps): without an
    order, the criterion's order at the intervals' centres (8 for a 3-DOF chain of order 6)
    once led the scan to a wrong valley that no scan point at a lower end revealed.
    """
    search = partial(_search, data, basis, order=order, d_zero=d_zero, block_rows=block_rows,
                     weighted=weighted, grid_points=grid_points,
                     max_relative_std=max_relative_std, min_margin=min_margin,
                     profile_offsets=profile_offsets, noise_correction=noise_correction,
                     select_order=select_order, workers=workers, progress=progress)
    restarted: bool | None   # whether the refused search tried the second start (None: unknown)
    try:
        return search()
    except _StartRefused as exc:
        refusal, restarted = exc.refusal, exc.restarted
    except NotIdentifiableError as exc:
        refusal, restarted = exc, None
    if restarted is False:   # the second start not tried yet
        try:
            return search(force_restart=True)
        except (_StartRefused, NotIdentifiableError):
            pass
    if select_order and restarted is not None:
        # the order came from the criterion, which wanders while the basis is wrong
        raise NotIdentifiableError(f"{refusal}; or give the structure's model order "
                                   "(order: in the configuration, --order)") from None
    raise refusal


class _StartRefused(Exception):
    """:func:`_search` refused its estimate (``refusal``, the error a user sees) after the
    second start was tried (``restarted``) or not; :func:`estimate_basis_parameters` decides
    whether to retry, and raises ``refusal`` itself."""

    def __init__(self, refusal: NotIdentifiableError, restarted: bool) -> None:
        super().__init__(str(refusal))
        self.refusal = refusal
        self.restarted = restarted


def _search(data: FrequencyData, basis: Sequence[Nonlinearity], *, order: int, d_zero: bool,
            block_rows: int | None, weighted: bool, grid_points: int, max_relative_std: float,
            min_margin: float, profile_offsets: Sequence[float], noise_correction: bool,
            select_order: bool, workers: int | None,
            progress: Callable[[str], None] | None, force_restart: bool = False
            ) -> ParameterSearchResult:
    """:func:`estimate_basis_parameters` from one start; ``force_restart``: the second start
    is tried whatever the first scan gave. A refusal of the estimate comes as
    :class:`_StartRefused` (with whether the second start was tried)."""
    t0 = time.perf_counter()
    integrated = data.output_quantity
    if integrated != "displacement":
        # compared in displacement units, where the model error falls smoothly towards the
        # true parameters (as_displacement_outputs); D is estimated, whatever the caller's
        # choice for the integrated outputs
        data, d_zero = as_displacement_outputs(data), False
    basis = tuple(basis)
    order = int(order)
    unknowns = search_spaces(data, basis)
    if not unknowns:
        return ParameterSearchResult(basis, [], float("nan"), order, 0)
    note = progress or (lambda s: None)
    n_basis_columns = sum(len(nl.coefficient_names) for nl in basis)
    m_e = data.n_inputs + n_basis_columns

    def rows_for(n: int) -> int:
        return block_rows or search_block_rows(data.n_outputs, n, data.n_lines, m_e)

    i_search = rows_for(order)
    y_energy = float(np.sum(np.abs(data.Y) ** 2))
    n_workers = max(1, int(workers) if workers is not None else min(4, os.cpu_count() or 1))
    n_eval = [0]
    cont = [k for k, u in enumerate(unknowns) if u.continuous]
    disc = [k for k, u in enumerate(unknowns) if not u.continuous]
    values = np.array([_initial(u) for u in unknowns], float)

    # the noise correction needs the noise spectrum of the motion and a resolved noise
    correct = bool(noise_correction and data.motion is not None
                   and data.motion.noise_spectrum is not None and data.noise_var is not None
                   and (data.noise_resolved is None or np.any(data.noise_resolved)))
    weights: list[np.ndarray | None] = [None]   # (F, p) once the correction is on
    noise_model: MotionNoise | None = None   # built once the correction is decided (below)
    weighted_scale = [1.0, 0.0]                 # sum W |Y|^2, sum W bias at the weights' point

    def fit_at(vals) -> tuple[tuple[Nonlinearity, ...], _Fit]:
        """The candidate basis and its FNSI fit: one QR + SVD, one B, D solve."""
        resolved = _resolve(basis, unknowns, vals)
        cand = with_basis(data, resolved)
        # noise-weighted decompositions only under the noise-weighted objective: the plain
        # model error with weighted ones was slower and rougher where the noise comes from
        # few periods (SmallSat, 39 outputs, 6 noisy periods: 55-63 fits, 4.2-4.4 s, gaps
        # -0.16 % / +0.28 %; unweighted: 37-43 fits, 1.1-1.3 s, +0.02 % / +0.03 %)
        dec = fnsi.subspace_decomposition(cand, max_order=order, block_rows=i_search,
                                          weighted=weighted and weights[0] is not None)
        a_d, c_d = fnsi.state_matrices(dec, order)
        return resolved, _fixed_state_fit(a_d, c_d, cand, d_zero=d_zero)

    def evaluate(vals) -> tuple[float, float]:
        """``(objective, noise level)`` at ``vals`` (thread-safe: reads shared state only).

        Plain: both the relative model error ``V``. Corrected: the weighted model error less
        the motion noise's expected share (plus that share at the weights' point, a
        constant), and the weighted model error itself; both relative to ``sum W |Y|^2``.
        """
        try:
            resolved, fit = fit_at(vals)
        except (IdentError, np.linalg.LinAlgError):  # e.g. a basis column zero at this value
            return float("inf"), float("inf")
        r2 = np.abs(fit.residual) ** 2
        W = weights[0]
        if W is None:
            v = float(np.sum(r2)) / y_energy
            return v, v
        if noise_model is None:   # set_weights needs it: weights without it are a bug
            raise IdentError("noise-weighted objective without the motion noise model")
        _, bias = noise_model.terms(fit.G_basis, resolved)
        wy, offset = weighted_scale
        return (float(np.sum(W * (r2 - bias))) + offset) / wy, float(np.sum(W * r2)) / wy

    def set_weights(vals) -> None:
        """``1 / (output noise + motion noise through the model)`` per line and output at
        ``vals`` (scaled per output), held fixed while the parameters move (the expected
        share of the motion noise is subtracted, not divided out: a weight that follows the
        parameters would reward candidates that inflate it)."""
        noise_var = data.noise_var
        if noise_model is None or noise_var is None:   # `correct` requires both
            raise IdentError("the noise correction needs the motion noise model and the "
                             "output noise variance")
        resolved, fit = fit_at(vals)
        variance, bias = noise_model.terms(fit.G_basis, resolved)
        # times each output's mean noise variance: the weights follow the motion noise
        # along the lines but keep the outputs' relative scale of the plain model error
        # (1/noise across 39 SmallSat outputs made the objective a needle around the gaps,
        # and the search stopped at -8 % / -11 % with 6 noisy periods)
        W = np.mean(noise_var, axis=0) / (noise_var + variance)
        weights[0] = W
        # the share removed at this point is added back as a constant: the corrected
        # objective then reads like a weighted model error (positive, log-plottable) and
        # has the same minimum and curvature
        weighted_scale[:] = [float(np.sum(W * np.abs(data.Y) ** 2)), float(np.sum(W * bias))]
        memo.clear()

    memo: dict[tuple, tuple[float, float]] = {}

    def evaluated_many(points) -> list[tuple[float, float]]:
        """``evaluate`` at each point, new ones in parallel, every one at most once."""
        keys = [tuple(np.round(v, 15)) for v in points]
        todo = {k: v for k, v in zip(keys, points) if k not in memo}
        n_eval[0] += len(todo)
        memo.update(zip(todo, _parallel_map(evaluate, list(todo.values()), n_workers)))
        return [memo[k] for k in keys]

    def evaluated(vals) -> tuple[float, float]:
        return evaluated_many([vals])[0]

    def objectives(points) -> np.ndarray:
        return np.array([v for v, _ in evaluated_many(points)])

    def scan(k: int, u: Unknown, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        grid = _grid(u, grid_points)
        return grid, objectives([_fill_one(values if at is None else at, k, g) for g in grid])

    def coarse_scan(start: np.ndarray) -> tuple[np.ndarray, dict]:
        """One parameter at a time from ``start``, each set to its scan's minimum."""
        vals, out = start.copy(), {}
        for k, u in enumerate(unknowns):
            grid, vs = out[k] = scan(k, u, vals)
            if np.all(~np.isfinite(vs)):
                raise NotIdentifiableError(f"nonlinearity {u.name!r}: no candidate "
                                           f"{u.parameter} gives a model on these data")
            vals[k] = (_scan_minimum(grid, vs, log=u.log_spaced) if u.continuous
                       else grid[int(np.argmin(vs))])
        return vals, out

    rescan = False     # the profiles and margins again, in the objective that was minimised

    def dof_at(n: int) -> int:
        """Residual degrees of freedom of a fit at order ``n``."""
        n_lin = (n + (0 if d_zero else data.n_outputs)) * m_e
        return max(2 * data.n_lines * data.n_outputs - n_lin - len(cont), 1)

    max_order, i_max = order, i_search

    def ic_order(vals: np.ndarray, with_value: bool = False):
        """The information criterion's order with the basis at ``vals`` (and its value)."""
        return _order_by_information_criterion(data, _resolve(basis, unknowns, vals),
                                               max_order, block_rows=i_max, d_zero=d_zero,
                                               with_value=with_value)

    def set_order(n: int, scanned: bool = True) -> None:
        """Search at order ``n`` from now on; on a change the memo goes (its objectives
        belong to the old order) and scans made are redone at the end (``rescan``)."""
        nonlocal order, i_search, rescan
        if n != order:
            order, rescan = n, rescan or scanned
            i_search = rows_for(order)
            memo.clear()
            note(f"order {order}")

    if select_order:   # the scan at the criterion's order at the interval centres ...
        set_order(ic_order(values), scanned=False)
    centres, scan_order = values.copy(), order
    values[:], scans = coarse_scan(values)
    note(f"scan: {_fmt(unknowns, values)}")
    if select_order:   # ... and the rest at its order at the scan's estimate
        set_order(ic_order(values))
    open_start = _stops_open(unknowns, values)
    restarted_at_all = open_start is None  # nothing to retry with one clearance or none
    if open_start is not None and (force_restart or any(   # a clearance at the scan's lowest
            u.reach and np.argmin(scans[k][1]) == 0 for k, u in enumerate(unknowns))):
        restarted_at_all = True

        def refine(vals):
            return _newton(objectives, vals, cont, unknowns, dof_at(order), tolerance=5e-3)[0]

        if not select_order:   # both starts at the given order
            values[:], scans, restarted = _better_start((values, scans),
                                                        coarse_scan(open_start), refine)
        else:
            # The criterion wanders while the basis is wrong (3-DOF chains, gaps near the
            # motion's RMS: 4 to 30 at the centres, the open stops or the corner of tiny
            # gaps; 6 only at the true gaps): the two starts are compared at the order of
            # the first scan's estimate and at the open stops' order, and the criterion's
            # own value (relative model error and order penalty, comparable across bases)
            # picks between the two winners. Comparing at the open stops' order alone
            # accepted the 2-output chain of bench/robustness.py at gaps -30 % / -44 %; at
            # the first estimate's alone 6 of 16 random gap pairs were refused.
            options = []
            first_values, first_scans, first_order = values.copy(), scans, order
            for n in dict.fromkeys((first_order, ic_order(open_start))):
                set_order(n)
                first = ((first_values.copy(), first_scans) if n == scan_order
                         else coarse_scan(centres))
                v, sc, won = _better_start(first, coarse_scan(open_start), refine)
                n_v, criterion = ic_order(v, with_value=True)
                options.append((criterion, v, sc, won, n_v))
            _, v, scans, restarted, n_v = min(options, key=lambda o: o[0])
            values[:] = v
            set_order(n_v)
        note(f"restart from the stops open ({'better' if restarted else 'not better'}): "
             f"{_fmt(unknowns, values)}")
        rescan = rescan or restarted   # the open start's scans: profiles at the estimate
    if correct and cont and all(unknowns[k].is_length for k in cont):   # clearances, offsets
        ratio = max((_motion_noise_std(data, basis[unknowns[k].element]) or 0.0)
                    / unknowns[k].magnitude(values[k]) for k in cont)
        correct = ratio >= _MIN_CORRECTED_NOISE
    if correct:
        noise_model = MotionNoise(data, basis)
    dof = dof_at(order)
    std = np.full(len(unknowns), np.nan)
    # corrected: twice, the weights taken at the previous estimate
    n_stages = 2 if correct and cont else 1
    for stage in range(n_stages):
        if correct and cont:
            set_weights(values)
        for _ in range(2 if disc and cont else 1):
            if cont:
                # the first corrected stage only has to bring the weights near the minimum
                loose = correct and stage == 0
                v_min, hess = _newton(objectives, values, cont, unknowns, dof,
                                      noise_level=lambda v: evaluated(v)[1],
                                      min_rel_step=_CORRECTED_MIN_STEP if correct else 0.0,
                                      tolerance=5e-3 if loose else 5e-4)
                if stage == n_stages - 1:   # the uncertainty comes from the last stage
                    hess = _wider_curvature(objectives, values, cont, unknowns, hess)
                # cov = s^2 (J^T J)^-1 with ||r||^2 = V y_energy, J^T J = y_energy H / 2 and
                # s^2 = ||r||^2 / dof at the minimum (the noise level, not the corrected V)
                try:
                    cov = 2.0 * evaluated(values)[1] / dof * np.linalg.inv(hess)
                    std[cont] = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.inf))
                except np.linalg.LinAlgError:
                    std[cont] = np.inf
            for k in disc if cont else ():     # the continuous ones moved: choose again
                vs = objectives([_fill_one(values, k, g) for g in unknowns[k].choices])
                values[k] = unknowns[k].choices[int(np.argmin(vs))]
                scans[k] = (np.asarray(unknowns[k].choices), vs)
    if (correct and cont) or rescan:  # profiles and margins in the objective minimised
        saved = values.copy()
        for k, u in enumerate(unknowns):
            scans[k] = scan(k, u)
        values[:] = saved
    note(f"estimate: {_fmt(unknowns, values)}")
    v_best, v_noise = evaluated(values)
    misfit = float("nan")
    if weights[0] is not None:   # the weighted residual against the output noise it should be
        W = weights[0]
        misfit = float(np.sum(W * np.abs(fit_at(values)[1].residual) ** 2)
                       / np.sum(W * data.noise_var))
    s2 = v_noise / dof   # per degree of freedom, in the objective's units
    estimates = []
    for k, u in enumerate(unknowns):
        grid, vs = scans[k]
        if u.continuous:
            lo, hi = u.bounds
            local = values[k] + u.magnitude(values[k]) * np.array(profile_offsets)
            local = local[(local >= lo) & (local <= hi)]
            lv = objectives([_fill_one(values, k, g) for g in local])
            roughness = _roughness(local - values[k], lv - v_best, std[k], s2)
            pv = np.concatenate([grid, local, [values[k]]])
            po = np.concatenate([vs, lv, [v_best]])
            edge_v = [vs[0], vs[-1]]
            margin = float((min(edge_v) - v_best) / s2) if s2 > 0 else float("inf")
        else:
            pv, po, roughness = grid, vs, float("nan")
            rest = np.sort(po)[1:]
            margin = float((rest[0] - v_best) / s2) if rest.size and s2 > 0 else float("inf")
        srt = np.argsort(pv)
        est = ParameterEstimate(u, float(values[k]),
                                float(std[k]) if u.continuous else float("nan"),
                                np.asarray(pv, float)[srt], np.asarray(po, float)[srt], margin,
                                _motion_noise_std(data, basis[u.element]) if u.is_length else None,
                                noise_corrected=correct and u.continuous, roughness=roughness)
        try:
            _refuse_if_unclear(est, basis[u.element], max_relative_std, min_margin)
        except NotIdentifiableError as refusal:   # estimate_basis_parameters may retry
            raise _StartRefused(refusal, restarted_at_all) from None
        estimates.append(est)
    noise_notes = [
        f"nonlinearity {e.unknown.name!r}: {e.unknown.parameter} = {e.value:.4g} was "
        f"estimated from a relative motion with noise {e.motion_noise_std:.3g} "
        f"({100 * e.motion_noise_std / e.value:.2g} % of it) per sample; "
        + ("its first-order effect was removed; what remains grows with that ratio and "
           "is not in the standard deviation (3-DOF chain, 4-8 noise seeds: within 2-4 % of "
           "the gap at 4-7 %, up to +15 % at 8-10 %, up to +24 % at 12-15 %; docs/ident.md, "
           "'Unknown basis parameters'): average more periods for a tighter gap"
           if e.noise_corrected else
           "noise in the motion biases gaps upwards by about as much (docs/ident.md, "
           "'Unknown basis parameters'): average more periods")
        for e in estimates
        if e.unknown.reach and e.motion_noise_std and e.motion_noise_std > 5e-3 * e.value]
    if any(e.unknown.reach for e in estimates) and not correct:
        noise_notes.extend(_uncorrected_motion_noise(data, integrated))
    notes = list(noise_notes)
    if misfit > _MAX_NOISE_MISFIT:
        notes.append(f"the model at the estimated parameters leaves residuals {misfit:.3g}x the "
                     "output noise (noise-weighted; 1.2-1.5 where the search found the truth): "
                     "the basis or the order does not explain these data, and the estimates "
                     "may sit in a wrong minimum (3-DOF chain with an unmodelled cubic spring "
                     "beside its stop: 47x, gaps +170 %); check the basis and the profiles, or "
                     "give the order or the parameters")
    if any(e.unknown.reach for e in estimates):   # clearances
        if integrated != "displacement":
            notes.append(f"clearances estimated from {integrated} outputs count from the mean "
                         "relative position during the test (integrated outputs carry no "
                         "static position; a stop whose contacts are asymmetric shifts that "
                         "mean); the contact stiffnesses do not depend on it (docs/ident.md, "
                         "'Unknown basis parameters')")
    return ParameterSearchResult(_resolve(basis, unknowns, values), estimates, v_best, order,
                                 n_eval[0], i_search, {"total": time.perf_counter() - t0}, notes,
                                 noise_misfit=misfit, motion_noise_warnings=noise_notes)


def _order_by_information_criterion(data: FrequencyData, basis: Sequence[Nonlinearity],
                                    max_order: int, *, block_rows: int, d_zero: bool,
                                    with_value: bool = False):
    """The even order 2..``max_order`` the information criterion (MDL, the robust
    pipeline's default; docs/ident.md) selects for ``data`` with ``basis``: one QR + SVD
    with the search's block rows, then per order the search's own ``A``, ``C`` and ``B``,
    ``D`` fit (about 0.06 s for the 3-DOF chain with 16 periods). ``with_value``: also the
    criterion's value at that order (``(order, value)``; relative model errors, so values
    for different bases on the same data compare; inf where there is no opinion)."""
    from fnsi_lab.ident.robust import order_selection as osel

    try:
        cand = with_basis(data, basis)
        dec = fnsi.subspace_decomposition(cand, max_order=max_order, block_rows=block_rows)
    except (IdentError, np.linalg.LinAlgError):   # e.g. a basis column zero here: no opinion
        return (int(max_order), float("inf")) if with_value else int(max_order)
    mask, band = osel.ic_line_mask(cand.frequencies_hz, cand.excited, cand.n_outputs, "auto")
    energy = float(np.sum(np.abs(cand.Y[mask]) ** 2))
    # even orders (modes come in pairs): half the fits of every order, the same choice on
    # the chains and the SmallSat
    orders = sorted(set(range(2, int(max_order) + 1, 2)) | {int(max_order)})
    errors, stable = [], []
    for n in orders:
        a_d, c_d = fnsi.state_matrices(dec, n)
        residual = _fixed_state_fit(a_d, c_d, cand, d_zero=d_zero).residual
        errors.append(float(np.sum(np.abs(residual[mask]) ** 2)) / energy)
        stable.append(bool(np.all(np.abs(np.linalg.eigvals(a_d)) < 1.0)))
    if not any(stable):
        return (int(max_order), float("inf")) if with_value else int(max_order)
    ic = osel.InformationCriterion.from_errors(
        orders, errors, stable, int(mask.sum()), band=band, criterion="mdl",
        n_outputs=cand.n_outputs, n_extended_inputs=cand.n_extended_inputs, d_zero=d_zero)
    if with_value:
        return int(ic.selected_order), float(ic.value[orders.index(int(ic.selected_order))])
    return int(ic.selected_order)


def _uncorrected_motion_noise(data: FrequencyData, quantity: str) -> list[str]:
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


def _parallel_map(fn, items: list, workers: int) -> list:
    """``[fn(x) for x in items]``, on up to ``workers`` threads."""
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(workers, len(items))) as pool:
        return list(pool.map(fn, items))


def _motion_noise_std(data: FrequencyData, nl: Nonlinearity) -> float | None:
    """Per-sample noise std of the averaged ``L^T q`` of an element (None if unknown)."""
    motion = data.motion
    cov = motion.noise_cov if motion is not None else None
    if motion is None or cov is None:
        return None
    L = nl.location_vector(motion.channels)
    return float(np.sqrt(max(L @ cov @ L, 0.0)))


def _scan_minimum(grid: np.ndarray, vs: np.ndarray, *, log: bool) -> float:
    """Best point of a coarse scan, refined by the parabola through it and its neighbours
    (in log coordinates for log-spaced scans; no extra evaluation). On the 3-DOF chain the
    Newton refinement then needed 4-5 steps instead of 8 from the best grid point."""
    i = int(np.argmin(vs))
    if not 0 < i < grid.size - 1 or not np.all(np.isfinite(vs[i - 1:i + 2])) or vs[i] <= 0:
        return float(grid[i])
    x = np.log(grid[i - 1:i + 2]) if log else grid[i - 1:i + 2].astype(float)
    y = np.log(vs[i - 1:i + 2])
    c2, c1, _ = np.polyfit(x, y, 2)
    if not c2 > 0:
        return float(grid[i])
    xv = float(np.clip(-c1 / (2 * c2), x[0], x[2]))
    return float(np.exp(xv) if log else xv)


def _stops_open(unknowns: Sequence[Unknown], values: np.ndarray) -> np.ndarray | None:
    """``values`` with every clearance at the top of its interval (the stops open: the motion
    touches them only at its largest excursions), or None with fewer than two clearances
    (then the scan of the one clearance does not depend on where it starts)."""
    reach = [k for k, u in enumerate(unknowns) if u.reach]
    if len(reach) < 2:
        return None
    out = values.copy()
    for k in reach:
        out[k] = unknowns[k].bounds[1]
    return out


def _better_start(first: tuple[np.ndarray, dict], second: tuple[np.ndarray, dict],
                  refine: Callable[[np.ndarray], float]) -> tuple[np.ndarray, dict, bool]:
    """Of two coarse scans ``(values, scans)``, the one whose refinement fits better.

    ``refine(values)`` moves ``values`` to the nearby minimum in place and returns the
    objective there. Returns the refined values and the scans of the better start, and
    whether that is ``second``.

    Why: the coarse scans run one parameter at a time. From the intervals' centres, a
    two-sided stop whose gaps are about its motion's RMS (contact at the peaks only) led one
    side's scan to a gap far too small, the other side's followed, and the corner of both
    gaps tiny (a linear spring plus a sign term) fitted better than the scan points near the
    truth, whose valley is narrower than the scan's step (3-DOF chain, gaps 1.2 / 1.5 mm,
    1 % noise: 2 of 8 seeds ended on the lower edge and were refused). Scanned from the stops
    open, each side is first fitted with the other out of contact. That start is not better
    everywhere (with gaps a third of the RMS its scan landed at 2.7x the truth, Newton needed
    30 % more fits), so it is tried only where the first scan put a clearance at its lower
    end (or the search would refuse), and the two refined starts are compared on the
    objective, at one order.
    """
    v1, scans1 = first
    v2, scans2 = second
    f1, f2 = refine(v1), refine(v2)
    return (v2, scans2, True) if f2 < f1 else (v1, scans1, False)


def _initial(u: Unknown) -> float:
    """Starting value: centre of the interval (geometric if log-spaced), or 3 (a cubic)
    among the candidates."""
    if u.continuous:
        lo, hi = u.bounds
        return float(np.sqrt(lo * hi)) if u.log_spaced else 0.5 * (lo + hi)
    candidates = u.choices
    return 3.0 if 3.0 in candidates else float(candidates[len(candidates) // 2])


def _grid(u: Unknown, n: int) -> np.ndarray:
    if not u.continuous:
        return np.asarray(u.choices, float)
    lo, hi = u.bounds
    return np.geomspace(lo, hi, n) if u.log_spaced else np.linspace(lo, hi, n)


def _fill_one(values: np.ndarray, k: int, v: float) -> np.ndarray:
    out = values.copy()
    out[k] = v
    return out


def _fmt(unknowns: Sequence[Unknown], values: np.ndarray) -> str:
    return ", ".join(f"{u.label}={v:.5g}" for u, v in zip(unknowns, values))


def _newton(objectives, values, cont, unknowns, dof, *, rel_step=0.02, tolerance=5e-4,
            trust=0.3, max_iterations=8, noise_level=None, min_rel_step=0.0):
    """Minimise ``V`` over the continuous parameters by Newton steps on a quadratic model.

    Stops when every step is below ``tolerance`` relative to the value (an offset: to its
    length scale, :meth:`Unknown.magnitude`; likewise below) or below a tenth of the
    value's standard deviation (``dof``: residual degrees of freedom; the residual level
    is ``V`` itself, or ``noise_level(values)`` when ``V`` has the noise's share removed).
    The stencil never narrows below ``min_rel_step`` of the values: the noise correction
    moves in small jumps as samples enter or leave contact, and a narrower stencil would
    measure those jumps instead of the curvature. A step moves a
    parameter by at most ``trust`` of its value (or four stencil widths).

    ``V(theta)`` is close to quadratic around its minimum (SmallSat: ``V(1.1 g)/V(1.01 g)``
    = 97 for a pure quadratic's 100) while the residual vector itself is strongly curved
    (Gauss-Newton on it crawled), so the gradient and Hessian of ``V`` come from a central
    finite-difference stencil whose width follows the steps (``objectives`` maps a list of
    parameter vectors to their values: a stencil's points are evaluated together). Updates
    ``values`` in place.

    Returns
    -------
    v_min : float
    hessian : ndarray, shape (k, k)
        Of ``V`` in the parameters' units at the last stencil (for the uncertainty).
    """
    lo, hi, f_many, magnitude = _on_continuous(objectives, values, cont, unknowns)
    x = np.clip(values[cont].astype(float), lo, hi)
    k = x.size

    def f(xx):
        return float(f_many([xx])[0])

    f0 = f(x)
    h = np.maximum(rel_step * magnitude(x), 1e-4 * (hi - lo))
    H = np.full((k, k), np.nan)
    for _ in range(max_iterations):
        # central differences, shifted inwards at a bound
        c = np.clip(x, lo + h, hi - h)
        g, H = _stencil(f_many, c, h)
        g = g + H @ (x - c)                      # gradient at x from the model around c
        try:
            step = -np.linalg.solve(H, g) if np.all(np.linalg.eigvalsh(H) > 0) else None
        except np.linalg.LinAlgError:
            step = None
        if step is None:                         # not convex here: a bounded gradient step
            step = -np.sign(g) * 2 * h
        # trust region: stay in the basin of the scan (with noise, V can be lower still where
        # the gaps are so small that the stop columns become a linear copy of the noisy
        # outputs; one unbounded step from the scan's best point landed there on the chain)
        limit = np.maximum(trust * magnitude(x), 4 * h)
        step = np.clip(np.clip(step, -limit, limit) + x, lo, hi) - x
        for _ in range(4):                       # backtrack if the model overshot
            f1 = f(x + step)
            if f1 <= f0:
                break
            step = step / 2
        if f1 <= f0:
            x, f0 = x + step, f1
        # converged: the step is below the tolerance or a tenth of the uncertainty
        level = f0
        if noise_level is not None:
            vals = values.copy()
            vals[cont] = x
            level = noise_level(vals)
        with np.errstate(divide="ignore", invalid="ignore"):
            sd = np.sqrt(np.abs(2.0 * level / dof / np.diag(H)))
        if np.all((np.abs(step) <= tolerance * magnitude(x)) | (np.abs(step) <= 0.1 * sd)):
            break
        h = np.clip(2 * np.abs(step), np.maximum(1e-5 * (hi - lo), min_rel_step * magnitude(x)),
                    h)                                     # narrow towards the minimum
    values[cont] = x
    return f0, H


def _on_continuous(objectives, values: np.ndarray, cont: Sequence[int],
                   unknowns: Sequence[Unknown]):
    """``(lo, hi, f_many, magnitude)``: the intervals of the continuous parameters ``cont``,
    the objective as a function of them alone (the other parameters held at ``values``) and
    their magnitudes (:meth:`Unknown.magnitude`) as a function of their values."""
    lo = np.array([unknowns[k].bounds[0] for k in cont])
    hi = np.array([unknowns[k].bounds[1] for k in cont])

    def magnitude(x):
        return np.array([unknowns[k].magnitude(v) for k, v in zip(cont, x)], float)

    def f_many(points):
        full = []
        for xx in points:
            vals = values.copy()
            vals[cont] = xx
            full.append(vals)
        return objectives(full)

    return lo, hi, f_many, magnitude


def _stencil(f_many, c: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient and Hessian of ``f`` at ``c`` from a central finite-difference stencil of
    half-widths ``h`` (its ``2k + 1 + k(k-1)/2`` points evaluated together by ``f_many``)."""
    k = c.size
    e = np.eye(k) * h
    pairs = [(a, b) for a in range(k) for b in range(a + 1, k)]
    pts = [c] + [c + e[j] for j in range(k)] + [c - e[j] for j in range(k)] \
        + [c + e[a] + e[b] for a, b in pairs]
    fs = np.asarray(f_many(pts), float)
    fc, fp, fm, fab = fs[0], fs[1:k + 1], fs[k + 1:2 * k + 1], fs[2 * k + 1:]
    H = np.diag((fp + fm - 2 * fc) / h ** 2)
    for (a, b), v in zip(pairs, fab):
        H[a, b] = H[b, a] = (v - fp[a] - fp[b] + fc) / (h[a] * h[b])
    return (fp - fm) / (2 * h), H


def _wider_curvature(objectives, values, cont, unknowns, hess: np.ndarray) -> np.ndarray:
    """The Hessian at the estimate, measured again on wider stencils (+-0.5 % .. +-5 % of the
    values, inside the intervals) when the last Newton stencil did not give a positive one.

    Newton's stencil narrows with its steps; on data whose model error is not smooth at that
    scale (a simulator that samples the contacts without band limit: the 5-DOF chain of
    bench/robustness.py, integrated by scipy) its curvature turned indefinite at gaps found
    within 0.5-0.9 %, and the search refused them as 'flat'."""
    if np.all(np.isfinite(hess)) and np.all(np.linalg.eigvalsh(hess) > 0):
        return hess
    lo, hi, f_many, magnitude = _on_continuous(objectives, values, cont, unknowns)
    x = values[cont].astype(float)
    for rel in (5e-3, 1e-2, 2e-2, 5e-2):
        h = np.minimum(rel * np.maximum(magnitude(x), 1e-4 * (hi - lo)), 0.49 * (hi - lo))
        c = np.clip(x, lo + h, hi - h)
        _, H = _stencil(f_many, c, h)
        if np.all(np.linalg.eigvalsh(H) > 0):
            return H
    return hess


def _roughness(offsets: np.ndarray, rise: np.ndarray, std: float, s2: float) -> float:
    """Largest factor between the chi-square rise ``rise / s2`` seen at ``offsets`` from the
    estimate and the rise ``(offsets / std)^2`` its curvature predicts (NaN if none)."""
    if not offsets.size or not (std > 0 and np.isfinite(std) and s2 > 0):
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = (rise / s2) / (offsets / std) ** 2
        factor = np.where(ratio > 0, np.maximum(ratio, 1.0 / ratio), np.inf)
    return float(np.max(factor))


#: Largest :attr:`ParameterEstimate.roughness` accepted. Smooth minima measured 0.6-2.3 (the
#: 3-DOF chain with 1 % noise, corrected; the SmallSat; offsets; signed exponents; the 5-DOF
#: ODE chain); the 5-DOF chain seen by 2 outputs, whose model error jumped by 10^4-10^19
#: within +-3 % of a lucky low point, gave 130-10^15 (at gaps -60 % / -74 %, under a first
#: version of the search's order choice).
_MAX_ROUGHNESS = 10.0
#: Largest noise misfit (:attr:`ParameterSearchResult.noise_misfit`) without a warning:
#: 1.2-1.5 where the search found the truth (3-DOF chain, 1 % noise; 5-DOF ODE chain at
#: 40 dB); 47 where an unmodelled cubic spring beside the chain's stop pushed the gaps to
#: +170 %, 30 where a 2-output view of the 5-DOF chain settled at -21 % / -70 %. A warning,
#: not a refusal: real structures leave model error beyond the noise too.
_MAX_NOISE_MISFIT = 10.0


def _refuse_if_unclear(est: ParameterEstimate, nl: Nonlinearity, max_relative_std: float,
                       min_margin: float) -> None:
    u = est.unknown
    what = f"nonlinearity {nl.name!r}: the data cannot tell {u.parameter}"
    fix = ("give it in the configuration, change the search " +
           ("interval" if u.continuous else "candidates") + ", or excite harder")
    if u.continuous:
        lo, hi = u.bounds
        if min(est.value - lo, hi - est.value) <= 0.01 * (hi - lo):
            raise NotIdentifiableError(
                f"{what}: the model error is smallest at the edge of the search interval "
                f"[{lo:.4g}, {hi:.4g}] ({est.value:.4g}), so the value is outside it or the "
                f"element barely acts; {fix}")
        if not est.std <= max_relative_std * u.magnitude(est.value):
            of = "the smaller clearance" if u.scale else "the value"
            raise NotIdentifiableError(
                f"{what}: the model error is flat around {est.value:.4g} (std {est.std:.3g}, "
                f"more than {100 * max_relative_std:g} % of {of}); {fix}")
        if not est.margin >= min_margin:
            # an end of the interval fits about as well: no single minimum (5-DOF chain seen
            # by 2 outputs at 40 dB: the model error jumped by 10^4 between scan points)
            raise NotIdentifiableError(
                f"{what}: the ends of the search interval fit about as well as "
                f"{est.value:.4g} (chi-square difference {est.margin:.3g} < {min_margin:g}); "
                f"{fix}")
        if est.roughness > _MAX_ROUGHNESS:
            # the minimum is a lucky low point of a rough objective, not a smooth valley
            raise NotIdentifiableError(
                f"{what}: the model error around {est.value:.4g} is rough (a few percent "
                f"away it changes {est.roughness:.3g}x more or less than its curvature says: "
                f"few outputs for the model order, or an unmodelled effect); {fix}")
    elif not est.margin >= min_margin:
        raise NotIdentifiableError(
            f"{what}: {est.value:g} fits no better than the next candidate (chi-square "
            f"difference {est.margin:.3g} < {min_margin:g}); {fix}")
