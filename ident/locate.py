"""Where is the structure nonlinear? Candidate locations ranked by the distortion they explain.

``fnsi-lab locate REC --config IDENT.yaml`` (docs/discovery.md, "Localisation"). A nonlinear
element between the DOFs of a location vector ``L`` adds the term ``G_L(z) h(L^T q)`` to the
output of the underlying linear system. Its shape is unknown, so each candidate location gets
a *generic* restoring force (:func:`generic_columns`): odd and stop-like columns in the
relative displacement ``x = L^T q`` (``x|x|``, ``x^3``, hinges at half the range on either
side) and a damping pair in the relative velocity (``v|v|``, a smoothed sign: friction),
each with its part linear in ``(1, x, v)`` removed. The question per candidate is then one of
linear least squares: how much of what the linear model leaves do these columns explain?

Two stages (:func:`locate_input`, the one entry point)
------------------------------------------------------
*Screen* (:func:`rank_locations`, every candidate, milliseconds each). One linear FNSI model
of order ``n`` gives the poles ``mu`` and output shapes ``c = C Phi``. A conjugate pair's
shapes ``c`` and ``conj(c)`` are nearly collinear for lightly damped modes, so the outputs
are projected line by line on the pair's *real* directions ``Re c``, ``Im c`` (the latter
when above 10 % of the former; noise-weighted when the lines carry a covariance). In pair
coordinate ``xi`` the steady state of any input is a partial fraction,
``(z - mu)(z - conj mu) xi(k) = (b0 + b1 z + b2 z^2) E(k)`` (``b2``: the feedthrough that
band-limited samples need), and an equation-error term ``(a0 + a1 z) xi`` re-fits the pair's
denominator (the linear model's poles are the best linear approximation's, not the
underlying ones). Per coordinate: a weighted regression on the forces, then the reduction
the candidate's columns add (a Schur complement of size ``3 s``). The cross-coordinate
correlation is neglected. Score: the fraction of the linear residual removed.

*Refinement* (:func:`refine_locations`, the screen's best few): a full FNSI at order ``n``
with the candidate's generic columns as extended input, its steady-state residual (in noise
variances when weighted) against the linear model's at the same order.

Score and significance
----------------------
``score`` is the fraction of the linear model's residual a candidate removes.
``significance`` is ``-log10 p`` of the F-test of that reduction,
``F = (dRSS / df1) / (RSS / df2)`` with ``df1`` the real parameters the columns add and
``df2`` the real residuals left: the residual left after the candidate stands for the noise
(noise-weighted when the periods give it), so no threshold is tuned to a case. The best
refined candidate is ``located`` when its test passes at ``p < 1e-3``; a candidate is ``as
likely as the best`` when the same test cannot tell its residual from the best's,
``significant`` when its own test passes, else ``not significant``.
"""

from __future__ import annotations

import itertools
import re
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.parallel import parallel_map
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.location_result import (P_SIGNIFICANT, Localisation, LocationScore,
                                            location_name)

__all__ = ["LocationScore", "Localisation", "candidate_locations", "generic_columns",
           "rank_locations", "locate_input", "read_candidates_file", "GENERIC_COLUMNS",
           "P_SIGNIFICANT"]

#: Names of the generic restoring-force columns (displacement then velocity terms).
GENERIC_COLUMNS: tuple[str, ...] = ("x|x|", "x^3", "max(x - max(x)/2, 0)",
                                    "min(x - min(x)/2, 0)", "v|v|", "tanh(v / (0.05 max|v|))")
#: Hinge positions, as fractions of the largest relative displacement on each side.
HINGES: tuple[float, ...] = (0.5,)
#: ``significance`` is capped here: p-values below 1e-300 underflow (the JSON would hold
#: infinity); such a reduction is beyond any doubt from the noise.
MAX_SIGNIFICANCE = 300.0
#: Friction's smoothed sign: ``tanh(v / (FRICTION_SCALE max|v|))``.
FRICTION_SCALE = 0.05
_DIRECTION_RE = re.compile(r"[-_:.\s][+-]?(R?[XYZ])$", re.IGNORECASE)


def channel_direction(name: str) -> str | None:
    """Direction a channel name ends with (``NC2W-Z`` -> ``Z``), None if it says none."""
    m = _DIRECTION_RE.search(name.strip())
    return m.group(1).upper() if m else None


def candidate_locations(output_names: Sequence[str], kind: str = "all") -> list[dict]:
    """Candidate location vectors over the measured outputs.

    Parameters
    ----------
    output_names : sequence of str
    kind : {'all', 'channels', 'pairs'}
        ``channels``: each channel to ground; ``pairs``: each pair of channels measured in
        the same direction (the name's ending ``-X``, ``_Y``, ``:+Z``...; every pair when
        the names carry no direction); ``all``: both.

    Returns
    -------
    list of dict str -> float
    """
    if kind not in ("all", "channels", "pairs"):
        raise IdentError(f"candidates {kind!r} is not one of all, channels, pairs or a file")
    names = list(output_names)
    out: list[dict] = []
    if kind in ("all", "channels"):
        out += [{c: 1.0} for c in names]
    if kind in ("all", "pairs"):
        dirs = [channel_direction(c) for c in names]
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                if dirs[i] == dirs[j] or dirs[i] is None or dirs[j] is None:
                    out.append({names[i]: 1.0, names[j]: -1.0})
    return out


def read_candidates_file(path: str) -> list[dict]:
    """Candidates from a YAML/JSON file: a list of ``{channels: {A: 1, B: -1}}`` or of
    channel mappings (``- {A: 1, B: -1}``).

    Raises
    ------
    IdentError
        One line naming the file and the fix.
    """
    from fnsi_lab.validate import load_yaml

    data, _ = load_yaml(path)
    items = data.get("candidates") if isinstance(data, dict) else data
    return candidate_list(items, path)


def candidate_list(items: Any, source: str = "candidates") -> list[dict]:
    """Location vectors from a list of ``{channels: {A: 1, B: -1}}`` or of channel mappings
    (``{A: 1, B: -1}``), as a file or the API give them.

    Raises
    ------
    IdentError
        One line naming ``source``, the item and the fix.
    """
    fix = "give a list like [{channels: {NC2W-Z: 1, NC2B-Z: -1}}, {channels: {IP1-Z: 1}}]"
    if isinstance(items, (str, bytes)) or not isinstance(items, Sequence) or not items:
        raise IdentError(f"{source}: expected a list of candidate locations ({fix})")
    out: list[dict] = []
    for i, it in enumerate(items):
        chs = it.get("channels", it) if isinstance(it, Mapping) else None
        if (not isinstance(chs, Mapping) or not chs or not all(
                isinstance(w, (int, float)) and not isinstance(w, bool) and w != 0
                for w in chs.values())):
            raise IdentError(f"{source}: candidates[{i}] is not a mapping channel -> non-zero "
                             f"weight ({fix})")
        out.append({str(k): float(v) for k, v in chs.items()})
    return out


def check_candidate_channels(candidates: Sequence[Mapping[str, float]], names: Sequence[str],
                             source: str | None = None) -> None:
    """Refuse a candidate naming a channel that is not an output: one line naming the
    ``source`` (a candidates file), the candidate, the channel and the outputs."""
    for c in candidates:
        unknown = [ch for ch in c if ch not in names]
        if unknown:
            raise IdentError(f"{source + ': ' if source else ''}candidate {location_name(c)}: "
                             f"channel(s) {', '.join(unknown)} not among the outputs "
                             f"({', '.join(names)})")


def generic_columns(x: np.ndarray, v: np.ndarray | None) -> np.ndarray:
    """The generic restoring-force columns of one location (:data:`GENERIC_COLUMNS`).

    Stop-like hinges of the relative displacement at a third and two thirds of its range on
    either side (``max(x - t, 0)``, ``min(x + t, 0)``: piecewise-linear springs, which
    combine into stops, clearances, hardening and softening, odd or not) and, with the
    velocity, ``v|v|`` and a smoothed sign (friction).

    Parameters
    ----------
    x : ndarray, shape (R, n_samples)
        Relative displacement ``L^T q``.
    v : ndarray, shape (R, n_samples) or None
        Relative velocity ``L^T q'``; None drops the two damping columns.

    Returns
    -------
    ndarray, shape (R, n_samples, s)
        Each column with its part linear in ``(1, x, v)`` removed (that is the linear
        model's stiffness and damping: an output read as an input would explain outputs),
        at unit RMS (a column with no motion stays zero).
    """
    x = x - x.mean()
    hi, lo = float(np.max(x)), float(np.min(x))
    scale = max(hi, -lo)
    s = len(GENERIC_COLUMNS) - (2 if v is None else 0)
    if not scale > 1e-12 * (np.max(np.abs(x)) + np.finfo(float).tiny) or not scale > 0:
        return np.zeros(x.shape + (s,))   # no relative motion: nothing to explain with
    cols = [np.abs(x) * x / scale, x ** 3 / scale ** 2] + \
        [np.maximum(x - f * hi, 0.0) for f in HINGES] + [np.minimum(x - f * lo, 0.0) for f in HINGES]
    lin = [np.ones_like(x), x]
    if v is not None:
        vs = v / max(float(np.max(np.abs(v))), np.finfo(float).tiny)
        cols += [np.abs(vs) * vs, np.tanh(vs / FRICTION_SCALE)]
        lin.append(vs)
    h = np.stack(cols, axis=-1)
    linear = np.stack(lin, axis=-1)
    flat, lflat = h.reshape(-1, h.shape[-1]), linear.reshape(-1, linear.shape[-1])
    gram = lflat.T @ lflat
    coef = np.linalg.lstsq(gram, lflat.T @ flat, rcond=None)[0]   # 3 x 3 normal equations
    h = (flat - lflat @ coef).reshape(h.shape)
    rms = np.sqrt(np.mean(h ** 2, axis=(0, 1)))
    return h / np.where(rms > 1e-12 * max(hi - lo, np.finfo(float).tiny), rms, np.inf)


def _pair_coordinates(data, a_d: np.ndarray, c_d: np.ndarray, weighted: bool):
    """Per mode pair: the output coordinate along its real shape(s), the pair's denominator.

    A conjugate pair ``mu, conj(mu)`` with output shape ``c = a + j b`` puts its response on
    the two real directions ``a`` and ``b`` (``b`` small for a nearly real shape); modal
    coordinates per pole would divide by the near-collinear ``c``, ``conj(c)``. The outputs
    are projected on every real direction kept (``b`` when above 10 % of ``a``; real poles'
    shapes too, not scored), line by line, noise-weighted when the lines carry a covariance.

    Returns
    -------
    xi : complex ndarray, shape (F, nc)
        Coordinates of the scored directions.
    den : complex ndarray, shape (F, nc)
        ``(z_k - mu)(z_k - conj(mu))`` of the direction's pair.
    var : ndarray, shape (F, nc)
        Variance of ``xi`` (noise units when weighted, else of unit output noise).
    """
    mu, phi = np.linalg.eig(a_d)
    ct = c_d @ phi                                                  # (p, n)
    dirs: list[np.ndarray] = []
    dens: list[np.ndarray | None] = []
    scored: list[bool] = []
    for j in np.flatnonzero(np.imag(mu) >= 0):
        c = ct[:, j]
        if abs(mu[j].imag) <= 1e-12 * max(abs(mu[j]), 1.0):        # real pole: kept, unscored
            dirs.append(np.real(c))
            scored.append(False)
            dens.append(None)
            continue
        c = c * np.exp(-0.5j * np.angle(np.sum(c * c)))             # the largest real part
        den = (data.z - mu[j]) * (data.z - np.conj(mu[j]))
        for v in (np.real(c), np.imag(c)):
            if v is np.imag(c) and np.linalg.norm(v) < 0.1 * np.linalg.norm(np.real(c)):
                continue
            dirs.append(v)
            scored.append(True)
            dens.append(den)
    basis = np.stack(dirs, axis=1)
    basis = basis / np.linalg.norm(basis, axis=0)
    Y = data.Y
    # the variances only: a full covariance from a few periods is rank-deficient (P - 1 < p;
    # the pipeline weights by the variances then too, ident.core.fnsi._inverse_covariance)
    var_y = data.noise_var if weighted else None
    if var_y is None:
        ginv = np.linalg.pinv(basis.T @ basis)
        xi = Y @ (ginv @ basis.T).T
        var = np.broadcast_to(np.diag(ginv), xi.shape)
    else:
        wb = basis[None] / var_y[:, :, None]                        # W_k Phi, (F, p, nc)
        ginv = np.linalg.pinv(np.einsum("pi,kpj->kij", basis, wb), hermitian=True)
        xi = np.einsum("kij,kj->ki", ginv, np.einsum("kpi,kp->ki", wb.conj(), Y))
        var = np.real(np.einsum("kii->ki", ginv))
    keep = np.asarray(scored)
    den = np.stack([d for d, k in zip(dens, scored) if k and d is not None], axis=1)
    return xi[:, keep], den, np.asarray(var)[:, keep]


#: The screen uses every excited line and at most this many lines in all: the non-excited
#: lines (distortion alone) are thinned evenly, which keeps their band and costs the screen
#: proportionally less (the refinement uses every line).
SCREEN_MAX_LINES = 1000


def screen_lines(data) -> np.ndarray:
    """Lines of the screen: the excited ones and an even share of the others, bool (F,)."""
    exc = np.asarray(data.excited, bool)
    keep = exc.copy()
    others = np.flatnonzero(~exc)
    room = max(SCREEN_MAX_LINES - int(exc.sum()), 0)
    if others.size <= room:
        keep[others] = True
    elif room > 0:
        keep[others[np.linspace(0, others.size - 1, room).round().astype(int)]] = True
    return keep


def _cross(w: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_k w_kc conj(a_kca) b_kcb`` per coordinate c, shape (nc, A, B)."""
    return np.einsum("kc,kca,kcb->cab", w, a.conj(), b, optimize=True)


def _with_z(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``[x, z x, z^2 x]`` on the last axis: the numerator of a pair's partial fractions
    and a feedthrough (``D``: band-limited samples of a continuous-time system need it)."""
    zz = z.reshape((-1,) + (1,) * (x.ndim - 1))
    return np.concatenate([x, x * zz, x * zz ** 2], axis=-1)


def rank_locations(data, model, candidates: Sequence[Mapping[str, float]], *,
                   weighted: bool = True, progress: Callable[[int], None] | None = None
                   ) -> Localisation:
    """Rank candidate locations by the distortion their generic columns explain.

    Parameters
    ----------
    data : FrequencyData
        Linear data (forces only in ``E``; displacement outputs) whose ``motion`` holds the
        displacements (and velocities) of every candidate channel.
    model : StateSpaceModel
        The linear model (its ``a_d``, ``c_d``).
    candidates : sequence of mapping str -> float
        Location vectors ``L``.
    weighted : bool
        Weight by the noise covariance of the lines when the data hold one.
    progress : callable(int), optional
        Called with the number of candidates done.

    Returns
    -------
    Localisation
    """
    t0 = time.perf_counter()
    weighted = bool(weighted and data.noise_var is not None)
    keep = screen_lines(data)
    xi, den, var = _pair_coordinates(data, model.a_d, model.c_d, weighted)
    xi, den, var = xi[keep], den[keep], var[keep]
    zeta = xi * den
    w = 1.0 / (np.abs(den) ** 2 * var)
    F, nc = zeta.shape
    U = data.E[keep, :data.n_inputs]
    z = data.z[keep]
    # mode pair c: den_c(z) xi_c = (b0 + b1 z) E + (a0 + a1 z) xi_c: the forces' numerator
    # and (equation error) a re-fit of the pair's denominator, then the candidate's columns
    base = np.concatenate([_with_z(np.broadcast_to(U[:, None, :], (F, nc, U.shape[1])), z),
                           _with_z(xi[:, :, None], z)[:, :, :2]], axis=2)   # (F, nc, 2m + 2)
    g_bb = _cross(w, base, base)
    r_b = np.einsum("kca,kc->ca", base.conj(), w * zeta)
    sol_b = np.linalg.solve(g_bb, r_b[..., None])[..., 0]
    rss_lin = float(np.sum(w * np.abs(zeta) ** 2) - np.real(np.sum(r_b.conj() * sol_b)))
    g_inv = np.linalg.inv(g_bb)
    # the candidate's regressors are [H, z H, z^2 H]: their Gram sums carry z^(r'-r), so five
    # weighted sums of conj(H_a) H_b give the whole (3 s)^2 block
    w_shift = np.concatenate([w * (z ** d)[:, None] for d in range(-2, 3)], axis=1).T
    wbase_z = np.ascontiguousarray(np.stack(
        [np.transpose(w[:, :, None] * base.conj() * (z ** r)[:, None, None], (1, 2, 0))
         for r in range(3)]))                                              # (3, nc, nb, F)
    w_shift = np.ascontiguousarray(w_shift)
    wzeta_z = np.stack([w * zeta * (z ** -r)[:, None] for r in range(3)])  # (3, F, nc)
    motion = data.motion
    chans = list(motion.channels)
    # the sampled motion (the band-limited interpolation passes through the samples): the
    # screen reads the generic columns at the acquisition rate, the refinement finer
    stride = max(motion.displacement.shape[1] // data.samples_per_period, 1)
    q = motion.displacement[:, ::stride]                    # (R, N, c)
    qd = None if motion.velocity is None else motion.velocity[:, ::stride]
    t1 = time.perf_counter()
    vectors = []
    for cand in candidates:
        L = np.zeros(len(chans))
        for ch, wgt in cand.items():
            if ch not in chans:
                raise IdentError(f"candidate {location_name(cand)}: channel {ch!r} is not among "
                                 f"the outputs ({plain.names(chans)})")
            L[chans.index(ch)] = wgt
        vectors.append(L)
    done = itertools.count(1)   # next() is atomic: the threads count without a lock

    def reduction(L: np.ndarray) -> tuple[float, int]:
        """The weighted residual one candidate's columns remove, and their count."""
        h = generic_columns(q @ L, None if qd is None else qd @ L)          # (R, Nf, s)
        H = (np.fft.rfft(h, axis=1)[:, motion.lines] / h.shape[1]).reshape(-1, h.shape[2])[keep]
        ns = H.shape[1]
        prod = (H.conj()[:, :, None] * H[:, None, :]).reshape(F, ns * ns)
        gd = (w_shift @ prod).reshape(5, nc, ns, ns)
        g_hh = np.concatenate([np.concatenate([gd[c - r + 2] for c in range(3)], axis=2)
                               for r in range(3)], axis=1)                   # (nc, 3s, 3s)
        g_bh = np.concatenate(list(wbase_z @ H), axis=2)                     # (nc, nb, 3s)
        r_h = np.concatenate([(H.conj().T @ wzeta_z[r]).T for r in range(3)], axis=1)
        x = g_inv @ g_bh                                                      # (nc, nb, 2s)
        schur = g_hh - np.conj(np.swapaxes(g_bh, 1, 2)) @ x
        resid = r_h - np.einsum("cam,ca->cm", x.conj(), r_b)
        # columns without motion (coincident nodes) or collinear: a ridge of 1e-10 of the
        # trace (a pseudo-inverse per coordinate cost 3x more)
        ridge = 1e-10 * np.real(np.trace(schur, axis1=1, axis2=2)) + np.finfo(float).tiny
        schur = schur + ridge[:, None, None] * np.eye(schur.shape[1])
        sol = np.linalg.solve(schur, resid[..., None])
        red = float(np.real(np.sum(resid.conj() * sol[..., 0])))
        if progress is not None:
            progress(next(done))
        return max(red, 0.0), 3 * ns

    # independent candidates on two threads (FFTs and solves release the lock; 273
    # SmallSat candidates 1.3 -> 0.7 s), the same numbers as one
    raw = [(dict(cand), red, n_cols) for cand, (red, n_cols)
           in zip(candidates, parallel_map(reduction, vectors))]
    t2 = time.perf_counter()
    return _verdicts(raw, rss_lin, F, nc, base.shape[2], weighted, model.order,
                     {"projection": t1 - t0, "candidates": t2 - t1})


def _verdicts(raw, rss_lin: float, n_lines: int, n: int, m: int, weighted: bool, order: int,
              timings: dict) -> Localisation:
    """Scores, F-tests and verdicts of the candidates' residual reductions."""
    out: list[LocationScore] = []
    s = max((r[2] for r in raw), default=0)
    df1, df2 = 2 * s * n, max(2 * n_lines * n - 2 * (m + s) * n, 1)
    rss = np.array([max(rss_lin - r[1], 1e-300) for r in raw])
    best = float(rss.min()) if rss.size else 1.0
    order_idx = np.argsort(rss, kind="stable")
    for rank, i in enumerate(order_idx):
        cand, red, _ = raw[i]
        with np.errstate(over="ignore"):
            fstat = (red / df1) / (rss[i] / df2)
        sig = _neg_log10_sf(fstat, df1, df2)
        if rank == 0:
            verdict = "located" if sig > -np.log10(P_SIGNIFICANT) else "not significant"
        elif sig <= -np.log10(P_SIGNIFICANT):
            verdict = "not significant"
        elif (_f_test(float(rss[i]), best, df1, df2)[1] <= -np.log10(P_SIGNIFICANT)
              and out[0].verdict == "located"):
            verdict = "as likely as the best"
        else:
            verdict = "significant"
        out.append(LocationScore(channels=cand, score=float(red / rss_lin) if rss_lin > 0 else 0.0,
                                 significance=sig, f_statistic=float(fstat),
                                 rss_ratio_to_best=float(rss[i] / best), verdict=verdict))
    return Localisation(candidates=out, order=int(order), n_lines=int(n_lines),
                        columns=GENERIC_COLUMNS, degrees_of_freedom=(int(df1), int(df2)),
                        weighted=weighted, timings_s=timings)


# ---------------------------------------------------------------------------- refinement
#: Spline knots the refinement adds to the generic columns (0: the generic columns alone).
#: The generic columns told the SmallSat's NC2 pair from the wheel point against the other
#: bracket points by 2 % of residual, a 24-knot spline by 24 % (at 3x the time), while on
#: 3 outputs (the aircraft-like GVT) 12-30 columns made the fixed-order fit worse than the
#: linear model's: docs/discovery.md.
REFINE_KNOTS = 0
#: Candidates of the screen refined by FNSI (on the SmallSat at 40 dB the screen put the
#: stop 8th of 273: 12 leaves room).
REFINE_TOP = 12
#: ``form='auto'`` offers a Jenkins element first when there are at most this many
#: candidates: its slip search costs 0.4-0.7 s per candidate (3 channels and their pairs:
#: 6; 4 channels: 10), where the generic screen costs milliseconds.
AUTO_STICK_SLIP_CANDIDATES = 10


def _weighted_rss(data, Y_hat: np.ndarray, weighted: bool) -> float:
    """``sum |Y - Y_hat|^2`` over lines and outputs, in noise variances when weighted."""
    r = np.abs(data.Y - Y_hat) ** 2
    if weighted and data.noise_var is not None:
        r = r / data.noise_var
    return float(np.sum(r))


def _block_rows(data, order: int) -> int | None:
    """Block rows of the refinement's decompositions: the default for few outputs (they need
    many), else the observability rule plus margin, at least 8 (a fixed-order fit, no sweep:
    on the SmallSat i = 8 gave the same ranking as the default 20 in a quarter of the time)."""
    from fnsi_lab.ident.robust.order_selection import FEW_OUTPUTS

    p = data.n_outputs
    if p <= FEW_OUTPUTS:
        return None
    return max(8, -(-order // p) + 2)


def candidate_input(data, candidate: Mapping[str, float], *, knots: int = 0):
    """The data with a candidate's generic columns (and spline hinges) as extended input.

    Parameters
    ----------
    data : FrequencyData
        Linear data whose ``motion`` holds the candidate's channels (and velocities).
    candidate : mapping str -> float
    knots : int
        Spline hinges over the measured relative displacement added to the generic columns
        (:func:`ident.core.spline.hinge_columns`; 0: the generic columns alone).

    Returns
    -------
    FrequencyData
    """
    from fnsi_lab.ident.core.spline import hinge_columns, spread_knots

    motion = data.motion
    chans = list(motion.channels)
    L = np.zeros(len(chans))
    for ch, wgt in candidate.items():
        L[chans.index(ch)] = wgt
    x = motion.displacement @ L
    v = None if motion.velocity is None else motion.velocity @ L
    h = generic_columns(x, v)
    if knots:
        t = spread_knots(x, knots)
        extra = np.stack([hinge_columns(x[r], t) for r in range(x.shape[0])])
        h = np.concatenate([extra, h], axis=2)
    rms_h = np.sqrt(np.mean(h ** 2, axis=(0, 1)))
    h = h[:, :, rms_h > 0]
    H = (np.fft.rfft(h, axis=1)[:, motion.lines] / h.shape[1]).reshape(-1, h.shape[2])
    m = data.n_inputs
    sigma = motion.force_rms / rms_h[rms_h > 0]
    return replace(data, E=np.concatenate([data.E[:, :m], H * sigma], axis=1),
                   input_scale=np.concatenate([np.ones(m), sigma]),
                   basis_names=tuple(f"generic{i}" for i in range(H.shape[1])))


def refine_candidate(data, candidate: Mapping[str, float], *, order: int, weighted: bool,
                     knots: int = 0, block_rows: int | None = None) -> tuple[float, int]:
    """FNSI with the generic restoring force (and a spline) at one candidate location.

    Parameters
    ----------
    data : FrequencyData
    candidate : mapping str -> float
    order : int
    weighted : bool
    knots : int
        Spline knots added to the generic columns (:func:`candidate_input`).
    block_rows : int, optional

    Returns
    -------
    (float, int)
        Residual sum of squares of the model's steady state (noise variances when weighted)
        and the number of nonlinear columns.
    """
    from fnsi_lab.ident.core.fnsi import model_at_order, subspace_decomposition

    d = candidate_input(data, candidate, knots=knots)
    dec = subspace_decomposition(d, max_order=order, weighted=weighted, block_rows=block_rows)
    model = model_at_order(dec, d, order)
    return _weighted_rss(d, model.steady_state_output(d), weighted), d.n_extended_inputs - d.n_inputs


def _f_test(rss_big: float, rss_small: float, df1: int, df2: int) -> tuple[float, float]:
    """F statistic and ``-log10 p`` of a residual reduction ``rss_big -> rss_small``."""
    fstat = max(rss_big - rss_small, 0.0) / df1 / (max(rss_small, 1e-300) / df2)
    return float(fstat), _neg_log10_sf(fstat, df1, df2)


def _neg_log10_sf(fstat: float, df1: int, df2: int) -> float:
    """``-log10`` of the F-test p-value, capped at :data:`MAX_SIGNIFICANCE` (p underflows)."""
    from scipy.special import fdtrc   # F survival function (scipy.stats: +0.35 s of import)

    with np.errstate(divide="ignore"):
        v = float(-np.log10(fdtrc(df1, df2, max(fstat, 0.0))))
    return MAX_SIGNIFICANCE if not np.isfinite(v) or v > MAX_SIGNIFICANCE else v


def refine_locations(data, screened: "Localisation", *, order: int, weighted: bool,
                     rss_linear: float, top: int = REFINE_TOP, knots: int = REFINE_KNOTS,
                     progress: Callable[[str], None] | None = None) -> "Localisation":
    """Re-rank the screen's best candidates by a full FNSI with their generic columns.

    The screen fixes the linear model's output shapes and fits each mode pair apart; the
    refinement lets FNSI find the model with the candidate's columns as inputs, which tells
    apart candidates whose relative motions differ by a few percent (a wheel point against
    several points of one stiff bracket). ``knots`` adds a spline (finer still, costlier).
    The refined candidates come first, by their residual; the others keep their screen
    verdict after them (``located`` and ``as likely as the best`` become ``significant``).
    """
    head = screened.candidates[:top]
    p, F = data.n_outputs, data.n_lines
    rows = _block_rows(data, order)

    def refined(c: LocationScore) -> tuple[LocationScore, float, int]:
        if progress is not None:
            progress(c.name)
        rss, s = refine_candidate(data, c.channels, order=order, weighted=weighted,
                                  knots=knots, block_rows=rows)
        return c, rss, s

    # independent FNSI fits: on threads (the same numbers; SmallSat's 12 about 1.6x faster)
    results = parallel_map(refined, head)
    results.sort(key=lambda r: r[1])
    best_rss = results[0][1] if results else 1.0
    out: list[LocationScore] = []
    m = data.n_inputs
    for rank, (c, rss, s) in enumerate(results):
        df1 = s * (order + p)                              # B and D columns of the spline
        df2 = max(2 * F * p - order * (m + s + p) - p * (m + s), 1)
        fstat, sig = _f_test(rss_linear, rss, df1, df2)
        _, sig_vs_best = _f_test(rss, best_rss, df1, df2)
        if sig <= -np.log10(P_SIGNIFICANT):
            verdict = "not significant"
        elif rank == 0:
            verdict = "located"
        elif sig_vs_best <= -np.log10(P_SIGNIFICANT) and out[0].verdict == "located":
            verdict = "as likely as the best"
        else:
            verdict = "significant"
        out.append(LocationScore(channels=c.channels, score=float(1 - rss / rss_linear)
                                 if rss_linear > 0 else 0.0, significance=sig,
                                 f_statistic=fstat, rss_ratio_to_best=float(rss / best_rss),
                                 verdict=verdict, stage="fnsi"))
    rest = [replace(c, stage="screen") for c in screened.candidates[top:]]
    for c in rest:   # a screen verdict relative to the refined best is not comparable
        if c.verdict in ("located", "as likely as the best"):
            c.verdict = "significant"
    misfit = (rss_linear / (2 * F * p)) if weighted and data.noise_var is not None else None
    return replace(screened, candidates=out + rest, refined=len(out), refine_knots=knots,
                   linear_misfit=misfit)


# ---------------------------------------------------------------------------- entry point
def _linear_order(data, weighted: bool, max_order: int = 40) -> int:
    """Order of the linear model when the config gives none: the minimum of the
    minimum-description-length criterion over the even orders up to ``max_order``."""
    from fnsi_lab.ident.core.fnsi import model_at_order, subspace_decomposition
    from fnsi_lab.ident.robust.order_selection import information_criterion

    top = int(min(max_order, 2 * data.n_lines // 4))
    dec = subspace_decomposition(data, max_order=top, weighted=weighted)
    orders = list(range(2, dec.max_order + 1, 2))
    den = float(np.sum(np.abs(data.Y) ** 2))
    best, best_ic = orders[0], np.inf
    for n in orders:
        model = model_at_order(dec, data, n)
        if not model.stable:
            continue
        v = float(np.sum(np.abs(data.Y - model.steady_state_output(data)) ** 2)) / den
        ic = float(information_criterion(v, n, data.n_lines, criterion="mdl",
                                         n_outputs=data.n_outputs,
                                         n_extended_inputs=data.n_extended_inputs))
        if ic < best_ic:
            best, best_ic = n, ic
    return best


def locate_input(inp, cfg, *, candidates: Any = "all", order: int | None = None,
                 refine: int = REFINE_TOP, knots: int = REFINE_KNOTS, form: str = "auto",
                 progress: Callable[[str], None] | None = None) -> Localisation:
    """Where is the structure nonlinear: THE entry point (CLI, API, ``nonlinearities: auto``).

    Parameters
    ----------
    inp : IdentInput
    cfg : IdentConfig
        Band, inputs, outputs, order; its nonlinearities are ignored (the question).
    candidates : {'all', 'channels', 'pairs'} or sequence of mapping
        Candidate location vectors (:func:`candidate_locations`) or the list itself.
    order : int, optional
        Order of the linear model and of the refinement's fits (default: the config's,
        else :func:`_linear_order`).
    refine : int
        The screen's best ``refine`` candidates are re-ranked by a full FNSI with a spline
        of ``knots`` knots at each (0: the screen alone).
    form : {'auto', 'generic', 'jenkins'}
        The restoring force offered at each candidate: the generic columns (screen and
        refinement), or a Jenkins element ranked by the information criterion
        (:mod:`ident.locate_stick_slip`; every candidate, about 0.7 s each on 3 channels).
        ``auto`` (default): with at most :data:`AUTO_STICK_SLIP_CANDIDATES` candidates the
        Jenkins element first, kept when it locates one (a held-out test: the nested test on
        other periods), else the generic columns; with more, the generic columns.
    progress : callable(str), optional

    Returns
    -------
    Localisation
    """
    from dataclasses import replace as _replace

    from fnsi_lab.ident.core.basis import Nonlinearity
    from fnsi_lab.ident.core.fnsi import model_at_order, subspace_decomposition
    from fnsi_lab.ident.core.periodic import as_displacement_outputs
    from fnsi_lab.ident.session import prepare_session

    t0 = time.perf_counter()
    lin_cfg = _replace(cfg, nonlinearities=(), nonlinearities_auto=False)
    names = list(cfg.outputs or inp.output_channels)
    if isinstance(candidates, str):
        cands = candidate_locations(names, candidates)
    else:
        cands = candidate_list(list(candidates))
    if not cands:
        raise IdentError("no candidate location (give at least one channel)")
    check_candidate_channels(cands, names)
    reader = Nonlinearity(name="locate", kind="quadratic_damping",
                          channels={c: 1.0 for c in sorted({ch for c in cands for ch in c})})
    session = prepare_session(inp, lin_cfg, motion_for=(reader,))
    data = session.data
    if form not in ("auto", "generic", "jenkins"):
        raise IdentError(f"form {form!r} is not one of auto, generic, jenkins")
    notes: list[str] = []
    if form == "jenkins" or form == "auto" and len(cands) <= AUTO_STICK_SLIP_CANDIDATES:
        from fnsi_lab.ident.locate_stick_slip import rank_stick_slip

        ranked = rank_stick_slip(session, cands, progress=progress)
        ranked.warnings = list(session.warnings)
        if order is not None:
            ranked.warnings.append(
                f"order {order} is not used by the Jenkins ranking: it compares each "
                f"candidate's information criterion, minimised over the orders up to 30, with "
                f"the linear model's (order {ranked.order}); form generic uses it")
        ranked.timings_s["total"] = time.perf_counter() - t0
        if form == "jenkins" or ranked.located is not None:
            ranked.form = "jenkins"
            return ranked
        best = ranked.candidates[0] if ranked.candidates else None
        notes.append("form auto: a Jenkins element (stick-slip friction) located nothing"
                     + (f" (its best, {best.name}: {best.note or best.verdict})" if best else "")
                     + "; the generic columns below")
    shown = as_displacement_outputs(data)     # D = 0 for the screen's partial fractions
    n = int(order or cfg.order or _linear_order(data, session.weighted))
    t1 = time.perf_counter()
    if progress is not None:
        progress(f"linear model, order {n}")
    rows = _block_rows(data, n)
    dec = subspace_decomposition(shown, max_order=n, weighted=session.weighted, block_rows=rows)
    lin_shown = model_at_order(dec, shown, n, d_zero=True)
    screened = rank_locations(shown, lin_shown, cands, weighted=session.weighted)
    t2 = time.perf_counter()
    if refine > 0:   # displacement outputs: the screen's decomposition serves (one QR less)
        dec0 = dec if shown is data else subspace_decomposition(
            data, max_order=n, weighted=session.weighted, block_rows=rows)
        lin = model_at_order(dec0, data, n)
        rss0 = _weighted_rss(data, lin.steady_state_output(data), session.weighted)
        screened = refine_locations(data, screened, order=n, weighted=session.weighted,
                                    rss_linear=rss0, top=refine, knots=knots,
                                    progress=None if progress is None
                                    else (lambda name: progress(f"refining {name}")))
    if screened.located is not None:
        notes += _veto_without_distortion(session, screened)
    t3 = time.perf_counter()
    screened.timings_s.update(prepare=t1 - t0, screen=t2 - t1, refine=t3 - t2, total=t3 - t0)
    screened.warnings = list(session.warnings) + notes + list(screened.warnings)
    screened.order = n
    screened.form = "generic"
    return screened


def _veto_without_distortion(session, located: "Localisation") -> list[str]:
    """Nothing is located where the distortion analysis calls every output linear within
    the noise (the Jenkins ranking's rule, :mod:`ident.locate_stick_slip`): the generic
    columns' F-test then reads the linear model's own misfit, not a nonlinearity. On a
    simulated joint that never slips (bench/independent_joint.py, 3 N) it had located
    drive - bracket, box or drive - box by the noise realisation, -log10 p 144-179, with
    the linear model's residual at 3.1 noise variances per value. Demotes ``located`` and
    ``as likely as the best`` to ``significant`` in place; returns the warning."""
    from fnsi_lab.ident.locate_stick_slip import _linear_within_the_noise

    if not _linear_within_the_noise(session):
        return []
    best = located.candidates[0]
    for c in located.candidates:
        if c.verdict in ("located", "as likely as the best"):
            c.verdict = "significant"
    return [f"nothing located: the distortion analysis (fnsi-lab analyse) calls every output "
            f"linear within the noise, so the generic columns' best ({best.name}, -log10 p "
            f"{best.significance:.1f}) explains the linear model's misfit, not a nonlinearity"]


def with_located_element(inp: Any, cfg: Any, *, order: int | None = None,
                         progress: Callable[[str], None] | None = None) -> tuple[Any, Localisation]:
    """``nonlinearities: auto``: the config with a spline element where :func:`locate_input`
    locates the nonlinearity, and the localisation (its JSON goes to the answer's evidence).
    ``order``: the identification's fixed order, the localisation's linear model's too (else
    the config's, else the criterion's: on 39 channels that search costs a minute).

    With no located candidate the config has no element (the linear answer; the
    localisation says why: :attr:`Localisation.located` is None).
    """
    from dataclasses import replace

    from fnsi_lab.ident.core.basis import Nonlinearity
    from fnsi_lab.ident.core.spline import AUTO_KNOTS
    located = locate_input(inp, cfg, order=order, progress=progress)
    best = located.located
    if best is None:   # nothing to characterise: the linear answer (ident.pipeline says so)
        return replace(cfg, nonlinearities_auto=False, nonlinearities=()), located
    # the location, whichever force found it; the shape is the spline's to show (a Jenkins
    # element also locates the Silverbox's hardening spring, which is no friction)
    element = Nonlinearity(name=best.name.replace(" - ", "/"), kind="spline",
                           channels=best.channels, knot_count=AUTO_KNOTS)
    return replace(cfg, nonlinearities_auto=False, nonlinearities=(element,)), located
