"""The local minimisation of the search's objective over the continuous parameters
(:mod:`ident.refine.parameter_search`): Newton steps on a quadratic model from central
finite-difference stencils, and the curvature at the estimate the standard deviations come
from.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.ident.refine.search_space import Unknown

__all__ = ["newton_minimise", "wider_curvature"]


def newton_minimise(objectives, values, cont, unknowns, dof, *, rel_step=0.02, tolerance=5e-4,
                    trust=0.3, max_iterations=8, noise_level=None, min_rel_step=0.0):
    """Minimise ``V`` over the continuous parameters by Newton steps on a quadratic model.

    Stops when every step is below ``tolerance`` relative to the value (an offset: to its
    length scale, :meth:`ident.refine.search_space.Unknown.magnitude`; likewise below) or
    below a tenth of the value's standard deviation (``dof``: residual degrees of freedom; the residual level
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
    their magnitudes (:meth:`ident.refine.search_space.Unknown.magnitude`) as a function of
    their values."""
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


def wider_curvature(objectives, values, cont, unknowns, hess: np.ndarray) -> np.ndarray:
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
