"""The search's objective at its candidate points (:mod:`ident.refine.parameter_search`): the
candidate fits at the current order, the noise-weighted and corrected objective, a memo of
the points evaluated, the threads that evaluate new points together, and the coarse scans
over each parameter's grid (:class:`SearchObjective`).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.parallel import default_workers, parallel_map
from fnsi_lab.ident.core.periodic import FrequencyData, with_basis
from fnsi_lab.ident.errors import IdentError, NotIdentifiableError
from fnsi_lab.ident.refine.motion_noise import MotionNoise
from fnsi_lab.ident.refine.search_fit import (CandidateFit, fixed_state_fit,
                                              order_by_information_criterion, search_block_rows)
from fnsi_lab.ident.refine.search_space import Unknown, resolve_basis, with_value

__all__ = ["SearchObjective", "NARROW_RATIO"]

#: An interval whose ends differ by at most this factor is scanned at 3 points, not 7.
NARROW_RATIO = 1.25


class SearchObjective:
    """The objective of the search at its candidate points: fits, memo, threads, scans.

    Holds what the search's stages share: the current order and block rows, the noise
    weights and the motion noise model once the correction is on, and a memo of the
    candidates evaluated at the current order and weights (each point at most once; new
    points of one call evaluated in parallel, :func:`_parallel_map`).

    Parameters
    ----------
    data : FrequencyData
        Displacement outputs, with the motion of the basis channels.
    basis : tuple of Nonlinearity
    unknowns : sequence of Unknown
    values : ndarray, shape (n_unknowns,)
        The search's current values; updated in place by the search and read by
        :meth:`scan` (the same array throughout).
    order, d_zero, block_rows, weighted, grid_points, workers
        As :func:`ident.refine.parameter_search.estimate_basis_parameters`.
    note : callable
        ``note(text)`` after each stage.
    """

    def __init__(self, data: FrequencyData, basis: tuple[Nonlinearity, ...],
                 unknowns: Sequence[Unknown], values: np.ndarray, *, order: int, d_zero: bool,
                 block_rows: int | None, weighted: bool, grid_points: int,
                 workers: int | None, note: Callable[[str], None]) -> None:
        self.data, self.basis, self.unknowns, self.values = data, basis, unknowns, values
        self.d_zero, self.block_rows, self.weighted = d_zero, block_rows, weighted
        self.grid_points, self.note = grid_points, note
        self.m_e = data.n_inputs + sum(len(nl.coefficient_names) for nl in basis)
        self.order = int(order)
        self.i_search = self.rows_for(self.order)
        self.max_order, self.max_block_rows = self.order, self.i_search
        self.y_energy = float(np.sum(np.abs(data.Y) ** 2))
        self.n_workers = max(1, int(workers) if workers is not None
                             else default_workers())
        self.n_evaluations = 0
        self.cont = [k for k, u in enumerate(unknowns) if u.continuous]
        self.weights: np.ndarray | None = None      # (F, p) once the correction is on
        self.noise_model: MotionNoise | None = None  # built once the correction is decided
        self.weighted_scale = [1.0, 0.0]  # sum W |Y|^2, sum W bias at the weights' point
        self.memo: dict[tuple, tuple[float, float]] = {}
        self.rescan = False   # the profiles and margins again, in the objective minimised

    def rows_for(self, n: int) -> int:
        """Block rows of the decompositions at order ``n``."""
        return self.block_rows or search_block_rows(self.data.n_outputs, n, self.data.n_lines,
                                                    self.m_e)

    def fit_at(self, vals) -> tuple[tuple[Nonlinearity, ...], CandidateFit]:
        """The candidate basis and its FNSI fit: one QR + SVD, one B, D solve."""
        resolved = resolve_basis(self.basis, self.unknowns, vals)
        cand = with_basis(self.data, resolved)
        # noise-weighted decompositions only under the noise-weighted objective: the plain
        # model error with weighted ones was slower and rougher where the noise comes from
        # few periods (SmallSat, 39 outputs, 6 noisy periods: 55-63 fits, 4.2-4.4 s, gaps
        # -0.16 % / +0.28 %; unweighted: 37-43 fits, 1.1-1.3 s, +0.02 % / +0.03 %)
        dec = fnsi.subspace_decomposition(cand, max_order=self.order, block_rows=self.i_search,
                                          weighted=self.weighted and self.weights is not None)
        a_d, c_d = fnsi.state_matrices(dec, self.order)
        return resolved, fixed_state_fit(a_d, c_d, cand, d_zero=self.d_zero)

    def evaluate(self, vals) -> tuple[float, float]:
        """``(objective, noise level)`` at ``vals`` (thread-safe: reads shared state only).

        Plain: both the relative model error ``V``. Corrected: the weighted model error less
        the motion noise's expected share (plus that share at the weights' point, a
        constant), and the weighted model error itself; both relative to ``sum W |Y|^2``.
        """
        try:
            resolved, fit = self.fit_at(vals)
        except (IdentError, np.linalg.LinAlgError):  # e.g. a basis column zero at this value
            return float("inf"), float("inf")
        r2 = np.abs(fit.residual) ** 2
        W = self.weights
        if W is None:
            v = float(np.sum(r2)) / self.y_energy
            return v, v
        if self.noise_model is None:   # set_weights needs it: weights without it are a bug
            raise IdentError("noise-weighted objective without the motion noise model")
        _, bias = self.noise_model.terms(fit.G_basis, resolved)
        wy, offset = self.weighted_scale
        return (float(np.sum(W * (r2 - bias))) + offset) / wy, float(np.sum(W * r2)) / wy

    def set_weights(self, vals) -> None:
        """``1 / (output noise + motion noise through the model)`` per line and output at
        ``vals`` (scaled per output), held fixed while the parameters move (the expected
        share of the motion noise is subtracted, not divided out: a weight that follows the
        parameters would reward candidates that inflate it)."""
        noise_var = self.data.noise_var
        if self.noise_model is None or noise_var is None:   # `correct` requires both
            raise IdentError("the noise correction needs the motion noise model and the "
                             "output noise variance")
        resolved, fit = self.fit_at(vals)
        variance, bias = self.noise_model.terms(fit.G_basis, resolved)
        # times each output's mean noise variance: the weights follow the motion noise
        # along the lines but keep the outputs' relative scale of the plain model error
        # (1/noise across 39 SmallSat outputs made the objective a needle around the gaps,
        # and the search stopped at -8 % / -11 % with 6 noisy periods)
        W = np.mean(noise_var, axis=0) / (noise_var + variance)
        self.weights = W
        # the share removed at this point is added back as a constant: the corrected
        # objective then reads like a weighted model error (positive, log-plottable) and
        # has the same minimum and curvature
        self.weighted_scale[:] = [float(np.sum(W * np.abs(self.data.Y) ** 2)),
                                  float(np.sum(W * bias))]
        self.memo.clear()

    def evaluated_many(self, points) -> list[tuple[float, float]]:
        """``evaluate`` at each point, new ones in parallel, every one at most once."""
        keys = [tuple(np.round(v, 15)) for v in points]
        todo = {k: v for k, v in zip(keys, points) if k not in self.memo}
        self.n_evaluations += len(todo)
        self.memo.update(zip(todo, parallel_map(self.evaluate, list(todo.values()),
                                                 self.n_workers)))
        return [self.memo[k] for k in keys]

    def evaluated(self, vals) -> tuple[float, float]:
        return self.evaluated_many([vals])[0]

    def objectives(self, points) -> np.ndarray:
        return np.array([v for v, _ in self.evaluated_many(points)])

    def scan(self, k: int, u: Unknown, at: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """The objective over the scan grid of parameter ``k``, the others at ``at`` (default:
        the current values)."""
        grid = _grid(u, self.grid_points)
        return grid, self.objectives([with_value(self.values if at is None else at, k, g)
                                      for g in grid])

    def coarse_scan(self, start: np.ndarray) -> tuple[np.ndarray, dict]:
        """One parameter at a time from ``start``, each set to its scan's minimum."""
        vals, out = start.copy(), {}
        for k, u in enumerate(self.unknowns):
            grid, vs = out[k] = self.scan(k, u, vals)
            if np.all(~np.isfinite(vs)):
                raise NotIdentifiableError(f"nonlinearity {u.name!r}: no candidate "
                                           f"{u.parameter} gives a model on these data", element=u.name)
            vals[k] = (_scan_minimum(grid, vs, log=u.log_spaced) if u.continuous
                       else grid[int(np.argmin(vs))])
        return vals, out

    def dof_at(self, n: int) -> int:
        """Residual degrees of freedom of a fit at order ``n``."""
        n_lin = (n + (0 if self.d_zero else self.data.n_outputs)) * self.m_e
        return max(2 * self.data.n_lines * self.data.n_outputs - n_lin - len(self.cont), 1)

    def ic_order(self, vals: np.ndarray, with_value: bool = False):
        """The information criterion's order with the basis at ``vals`` (and its value)."""
        return order_by_information_criterion(
            self.data, resolve_basis(self.basis, self.unknowns, vals), self.max_order,
            block_rows=self.max_block_rows, d_zero=self.d_zero, with_value=with_value)

    def set_order(self, n: int, scanned: bool = True) -> None:
        """Search at order ``n`` from now on; on a change the memo goes (its objectives
        belong to the old order) and scans made are redone at the end (``rescan``)."""
        if n != self.order:
            self.order, self.rescan = n, self.rescan or scanned
            self.i_search = self.rows_for(self.order)
            self.memo.clear()
            self.note(f"order {self.order}")


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


def _grid(u: Unknown, n: int) -> np.ndarray:
    """The scan points of ``u``: its candidates, or ``n`` points over its interval."""
    if not u.continuous:
        return np.asarray(u.choices, float)
    lo, hi = u.bounds
    if 0 < lo and hi <= NARROW_RATIO * lo:
        # a narrow interval (a value read off a spline curve, +-10 %): the parabola through
        # three points starts Newton near enough (SmallSat NC2-Z: gaps 1.50022 / 1.29975
        # for 1.5 / 1.3 mm, with seven 1.49983 / 1.30004), at 13 fewer fits (24 for 37)
        n = min(n, 3)
    return np.geomspace(lo, hi, n) if u.log_spaced else np.linspace(lo, hi, n)
