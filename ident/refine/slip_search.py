"""``slip: auto``: a Jenkins element's slip displacement from the data, by the information
criterion (docs/ident.md, "Unknown basis parameters"; docs/discovery.md, bolted joints).

Why not the model error at a fixed order, as for clearances
(:mod:`ident.refine.parameter_search`): the basis column of a Jenkins element is a function
of the *measured* relative motion, and as the slip grows towards the motion's amplitude the
column becomes that motion less a constant. A column that copies an output lets the model
predict the output from itself, so the model error at a fixed order falls towards the top
of the interval whatever the joint does (aircraft-like GVT at 55 N: smallest at 400 um,
where the joint never slips; the truth is 53 um). The structure's order changes with the
slip as well (a slipping joint softens and separates modes that a stuck one couples), so
no one order suits every candidate. The information criterion (MDL over the orders, with
the search's own fits) charges each candidate for the order it needs and compares across
candidates (relative model errors): its smallest value over the orders has a clear
minimum near the truth on the aircraft-like GVT (55 N: 37-52 um for 53 um; 84 N: 37 um for
42 um) and rises steeply where the joint stops slipping.

The scan is one decomposition per candidate (``GRID_POINTS`` log-spaced slips over the
search interval, about 0.05 s each on the 3-channel GVT), then a parabola through the best
point and its neighbours on the log scale. Several unknowns are scanned one after the
other, the others at their current values, twice. A joint with friction and a clearance
(a Jenkins element and a stop on the same motion, both left to the data) is searched the
same way, the stop's clearances by the same criterion: the GVT at 98 N, whose simulated
joint has both, gives its lowest criterion near the true 0.30 mm (0.031 against 0.065 for
the Jenkins element alone and 0.083 for the linear model).
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.periodic import FrequencyData
from fnsi_lab.ident.errors import IdentError, NotIdentifiableError
from fnsi_lab.ident.refine.search_fit import order_by_information_criterion, search_block_rows
from fnsi_lab.ident.refine.search_result import ParameterEstimate, ParameterSearchResult
from fnsi_lab.ident.refine.search_space import Unknown, resolve_basis, search_spaces

__all__ = ["GRID_POINTS", "OBJECTIVE", "BY_CRITERION", "estimate_slips", "only_slips_unknown",
           "slipping_fraction"]

#: Candidate slips of the scan over the search interval (log-spaced; neighbours 1.3x apart
#: over the default interval's factor 95).
GRID_POINTS = 18
#: What the profile holds (``parameter_search.estimates[].objective`` in the JSON).
OBJECTIVE = "information criterion (mdl, smallest over the orders)"


#: Parameters searched by the criterion next to a slip (clearances of stops).
BY_CRITERION: tuple[str, ...] = ("slip", "g_neg", "g_pos", "clearance")


def only_slips_unknown(basis: Sequence[Nonlinearity]) -> bool:
    """True if some element leaves its slip to the data and every other parameter left is a
    clearance (searched by the criterion too)."""
    left = [sp.parameter for nl in basis for sp in nl.unknown]
    return "slip" in left and all(p in BY_CRITERION for p in left)


def estimate_slips(data: FrequencyData, basis: Sequence[Nonlinearity], *, max_order: int,
                   d_zero: bool = False, grid_points: int = GRID_POINTS,
                   progress: Callable[[str], None] | None = None) -> ParameterSearchResult:
    """Slip displacements of the Jenkins elements of ``basis`` (and the clearances of its
    stops) left to the data.

    Parameters
    ----------
    data : FrequencyData
        Prepared with the motion of the basis channels (``motion_for=basis``).
    basis : sequence of Nonlinearity
        Elements; only slips and clearances may be unknown, a slip among them.
    max_order : int
        Largest order of the information criterion's sweep (even orders 2..max_order).
    d_zero : bool
        ``D = 0`` in the fits.
    grid_points : int
        Candidates per scan.
    progress : callable, optional
        ``progress(note)`` after each scan.

    Returns
    -------
    ParameterSearchResult
        ``estimates[].profile_objective`` holds the criterion's value per candidate, ``std``
        is NaN (the criterion is no likelihood; the profile shows how sharp the minimum is).

    Raises
    ------
    NotIdentifiableError
        The best slip is at an end of the interval: at the top the joint does not slip
        measurably (a linear spring), at the bottom it slips all the time (a Coulomb law).
    IdentError
        Another parameter (an offset, an exponent) is left to the data too.
    """
    t0 = time.perf_counter()
    basis = tuple(basis)
    if not only_slips_unknown(basis):
        raise IdentError("slip: auto cannot be searched together with offsets or exponents "
                         "left to the data: give those, or the slip")
    unknowns = search_spaces(data, basis)
    # slips from the middle of their interval, stops from open (their clearances at the top:
    # barely touched); slips first. From the middle, a stop in contact most of the time is
    # nearly a copy of the motion and its column drove the scans to the interval ends
    # (GVT, 98 N)
    values = _starts(unknowns, basis)
    twins = _same_motion_slips(unknowns, basis)
    sweep = sorted(range(len(unknowns)), key=lambda k: unknowns[k].parameter != "slip")
    m_e = data.n_inputs + sum(len(nl.coefficient_names) for nl in basis)
    rows = search_block_rows(data.n_outputs, int(max_order), data.n_lines, m_e)
    memo: dict[tuple, tuple[int, float]] = {}

    def criterion(vals: np.ndarray) -> tuple[int, float]:
        key = tuple(np.round(np.log(vals), 12))
        if any(abs(key[a] - key[b]) < 1e-9 for a, b in twins):
            return 0, np.inf   # two elements of one slip on one motion: the same column twice
        if key not in memo:
            memo[key] = order_by_information_criterion(
                data, resolve_basis(basis, unknowns, vals), int(max_order), block_rows=rows,
                d_zero=d_zero, with_value=True)
        return memo[key]

    profiles: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for _ in range(2 if len(unknowns) > 1 else 1):
        for k in sweep:
            u = unknowns[k]
            grid = np.geomspace(*u.bounds, grid_points)
            ic = np.array([criterion(_with(values, k, v))[1] for v in grid])
            values[k], refined = _parabola_minimum(grid, ic, lambda v: criterion(_with(values, k, v))[1])
            pts = np.concatenate([grid, [values[k]]]) if refined is not None else grid
            obj = np.concatenate([ic, [refined]]) if refined is not None else ic
            order_idx = np.argsort(pts)
            profiles[k] = (pts[order_idx], obj[order_idx])
            if progress:
                progress(f"scan: {u.label}={values[k]:.4g}")
    notes = []
    alternatives: list[dict] = []
    if len(unknowns) == 1 and unknowns[0].parameter == "slip":
        u = unknowns[0]
        without_memo: list[float] = []

        def without() -> float:   # one order sweep, only when a rule needs it
            if not without_memo:
                without_memo.append(_without_element(data, basis, unknowns, values, u.element,
                                                     max_order, rows, d_zero))
            return without_memo[0]

        below = _below_the_copy(u, values[0], *profiles[0], grid_points,
                                slipping=lambda v: slipping_fraction(data, basis[u.element], v),
                                without=without,
                                evaluate=lambda v: criterion(np.array([v]))[1])
        if below is not None:
            values[0], profiles[0], note = below
            notes.append(note)
        alternatives = _other_minima(u, values[0], *profiles[0], grid_points, without=without,
                                     evaluate=lambda v: criterion(np.array([v])),
                                     slipping=lambda v: slipping_fraction(
                                         data, basis[u.element], v))
    estimates = [_estimate(u, values[k], *profiles[k], grid_points) for k, u in enumerate(unknowns)]
    order, value = criterion(values)
    return ParameterSearchResult(resolve_basis(basis, unknowns, values), estimates, value,
                                 order, len(memo), rows, {"total": time.perf_counter() - t0},
                                 notes, float("nan"), [], alternatives)


def _other_minima(u: Unknown, value: float, points: np.ndarray, objective: np.ndarray,
                  grid_points: int, *, without: Callable[[], float],
                  evaluate: Callable[[float], tuple[int, float]],
                  slipping: Callable[[float], float]) -> list[dict]:
    """The profile's other strict local minima inside the interval whose criterion beats the
    model without the element, best first, each moved to its parabola's vertex: ``{value,
    objective, order, slipping_percent, objective_without_element}`` (m, the criterion, the
    order it chose, % of the period the element slips, the criterion without it).

    Why: the criterion can have two minima of nearly one value, the joint's slip and one
    where the element barely slips and its column nearly copies the measured motion (the
    Bouc-Wen beam at 3 N, another realisation: 6.6e-3 at 498 um, slipping 0.24 % of the
    period, against 7.8e-3 at 34 um, near the law's 40 um yield, where it slips half of it;
    bench/RESULTS_beam.md, defect 6). When the lower one leaves the element's coefficient
    undetermined, the identification tries the next (:func:`ident.pipeline.identify_request`).
    """
    lo, hi = u.bounds
    step = (hi / lo) ** (1.0 / max(grid_points - 1, 1))
    inner = [i for i in range(1, points.size - 1) if np.isfinite(objective[i])
             and objective[i] < objective[i - 1] and objective[i] < objective[i + 1]
             and abs(np.log(points[i] / value)) > np.log(step)
             and lo * np.sqrt(step) < points[i] < hi / np.sqrt(step)]
    if not inner:
        return []
    reference = without()
    out = []
    for i in sorted(inner, key=lambda i: objective[i]):
        if not objective[i] < reference:
            break
        slip, _ = _parabola_minimum(points[i - 1:i + 2], objective[i - 1:i + 2],
                                    lambda v: evaluate(v)[1])
        order, criterion_value = evaluate(slip)
        out.append({"value": slip, "objective": criterion_value, "order": order,
                    "slipping_percent": 100 * slipping(slip),
                    "objective_without_element": reference})
    return sorted(out, key=lambda a: a["objective"])


def slipping_fraction(data: FrequencyData, element: Nonlinearity, slip: float) -> float:
    """Share of the period in which a Jenkins element of slip ``slip`` slips on the measured
    relative motion (all realisations), from :func:`ident.core.hysteresis.periodic_play_anchors`."""
    from fnsi_lab.ident.core.hysteresis import periodic_play_anchors   # numba: +0.2 s

    motion = data.motion
    if motion is None:
        raise IdentError("the slip search needs the motion of the basis channels")
    delta = motion.displacement @ element.location_vector(motion.channels)   # (R, N_fine)
    offset = float(getattr(element, "offset", 0.0) or 0.0)
    return float(np.mean([np.mean(periodic_play_anchors(d + offset, float(slip)) < 0)
                          for d in delta]))


def _below_the_copy(u: Unknown, value: float, points: np.ndarray, objective: np.ndarray,
                    grid_points: int, *, slipping: Callable[[float], float],
                    without: Callable[[], float], evaluate: Callable[[float], float]
                    ) -> tuple[float, tuple[np.ndarray, np.ndarray], str] | None:
    """The slip below the top of the interval when the criterion is smallest at the top.

    At the top the element barely slips and its column is the measured motion less a
    constant: the model predicts an output from itself, and the criterion can fall there
    whatever the joint does (the Bouc-Wen beam at 3 N, 16x the law's yield displacement:
    4.6e-4 at 730 um, where the element slips 0.03 % of the time, against 6.9e-3 at 34 um,
    near the law's 40 um yield, where it slips half of it; the independent Iwan joint at its
    highest level alike; bench/RESULTS_beam.md, defect 6). The lowest strict local minimum
    of the profile away from both ends is taken when its criterion is below the model's
    without the element (the element explains the data better than none); the nested test
    then decides whether it is kept, as for any estimate. Only at the top: a minimum inside
    the interval where the element slips rarely can be the joint's (the Iwan joint at 6 N:
    0.195 mm, slipping 0.9 % of the time, is its first slider's 0.200 mm). Returns ``(slip,
    profile, note)`` or None (the top stands: the refusal of :func:`_estimate`).
    """
    lo, hi = u.bounds
    step = (hi / lo) ** (1.0 / max(grid_points - 1, 1))
    if value < hi / np.sqrt(step):
        return None
    inner = [i for i in range(1, points.size - 1) if np.isfinite(objective[i])
             and objective[i] < objective[i - 1] and objective[i] < objective[i + 1]]
    if not inner:
        return None
    best = min(inner, key=lambda i: objective[i])
    reference = without()
    if not objective[best] < reference:
        return None
    slip, at_vertex = _parabola_minimum(points[best - 1:best + 2], objective[best - 1:best + 2],
                                        evaluate)
    if at_vertex is not None and at_vertex < objective[best]:
        keep = np.argsort(np.append(points, slip))
        points, objective = np.append(points, slip)[keep], np.append(objective, at_vertex)[keep]
    lowest = float(min(objective[best], at_vertex if at_vertex is not None else np.inf))
    note = (f"{u.name} slip: the information criterion is smallest at the top of the search "
            f"interval ({hi:.4g} m), where the element slips on {100 * slipping(value):.2g} % "
            "of the period and its column copies the measured motion (docs/ident.md, \"A slip "
            f"at the top of its interval\"); the lowest minimum below it, {slip:.4g} m "
            f"(slipping {100 * slipping(slip):.2g} %, criterion {lowest:.3g} against "
            f"{reference:.3g} without the element), is taken, and the nested test decides "
            "whether the element is kept")
    return slip, (points, objective), note


def _without_element(data: FrequencyData, basis: Sequence[Nonlinearity],
                     unknowns: Sequence[Unknown], values: np.ndarray, element: int,
                     max_order: int, rows: int, d_zero: bool) -> float:
    """The information criterion of the basis less ``element`` (the linear model for one)."""
    rest = [nl for e, nl in enumerate(resolve_basis(basis, unknowns, values)) if e != element]
    return float(order_by_information_criterion(data, rest, int(max_order), block_rows=rows,
                                                d_zero=d_zero, with_value=True)[1])


def _same_motion_slips(unknowns: Sequence[Unknown], basis: Sequence[Nonlinearity]
                       ) -> list[tuple[int, int]]:
    """Pairs of slip unknowns whose Jenkins elements read the same relative motion."""
    slips = [k for k, u in enumerate(unknowns) if u.parameter == "slip"]
    motion = {k: tuple(sorted(basis[unknowns[k].element].channels.items())) for k in slips}
    return [(a, b) for i, a in enumerate(slips) for b in slips[i + 1:] if motion[a] == motion[b]]


def _starts(unknowns: Sequence[Unknown], basis: Sequence[Nonlinearity]) -> np.ndarray:
    """Where the sweeps start: slips in the middle of their interval (log scale), stops open
    (their clearances at the top). Several Jenkins elements on one motion (a distributed
    joint: micro-slip, an Iwan element) start spread over the interval, the j-th of n at the
    (j + 1) / (n + 1) point: all in the middle, their columns were equal, every fit singular
    and the order sweep unstable at every order (bench/RESULTS_independent.md)."""
    values = np.array([np.sqrt(u.bounds[0] * u.bounds[1]) if u.parameter == "slip"
                       else u.bounds[1] for u in unknowns])
    groups: dict[tuple, list[int]] = {}
    for k, u in enumerate(unknowns):
        if u.parameter == "slip":
            groups.setdefault(tuple(sorted(basis[u.element].channels.items())), []).append(k)
    for members in groups.values():
        for j, k in enumerate(members if len(members) > 1 else []):
            lo, hi = unknowns[k].bounds
            values[k] = lo * (hi / lo) ** ((j + 1) / (len(members) + 1))
    return values


def _with(values: np.ndarray, k: int, v: float) -> np.ndarray:
    out = values.copy()
    out[k] = v
    return out


def _parabola_minimum(grid: np.ndarray, ic: np.ndarray,
                      evaluate: Callable[[float], float]) -> tuple[float, float | None]:
    """The best grid point, moved to the vertex of the parabola through it and its two
    neighbours (log scale) when that point's criterion is lower. Returns (value, its
    criterion; None when the value is the grid point's)."""
    finite = np.isfinite(ic)
    if not finite.any():
        return float(grid[len(grid) // 2]), None
    b = int(np.nanargmin(np.where(finite, ic, np.inf)))
    if b in (0, len(grid) - 1):
        return float(grid[b]), None
    x = np.log(grid[b - 1:b + 2])
    y = ic[b - 1:b + 2]
    if not np.all(np.isfinite(y)):   # a neighbour without an opinion: no parabola
        return float(grid[b]), None
    denom = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / denom
    if not a > 0:
        return float(grid[b]), None
    bb = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / denom
    vertex = float(np.clip(-bb / (2 * a), x[0], x[2]))
    value = float(np.exp(vertex))
    at_vertex = evaluate(value)
    # the vertex's criterion only with the vertex: the profile recorded it at the grid
    # point, a second value there (the beam at 3 N: 0.0066 and 0.118 at 498 um)
    return (value, at_vertex) if at_vertex < ic[b] else (float(grid[b]), None)


def _estimate(u: Unknown, value: float, points: np.ndarray, objective: np.ndarray,
              grid_points: int) -> ParameterEstimate:
    """The estimate with its profile; refused at an end of the interval."""
    lo, hi = u.bounds
    step = (hi / lo) ** (1.0 / max(grid_points - 1, 1))
    slip = u.parameter == "slip"
    if value >= hi / np.sqrt(step):
        raise NotIdentifiableError(
            f"nonlinearity {u.name!r}: the data cannot tell {u.parameter}: the information "
            f"criterion is smallest at the top of the search interval [{lo:.4g}, {hi:.4g}], "
            + ("where the element barely slips on the record's motion: no slip explains the "
               "data better than a linear spring, which the underlying linear model holds. "
               "Either the joint barely slips at this level (excite harder), or it slips in "
               "a way one Jenkins element does not draw (distributed micro-slip, a clearance, "
               "a drift between periods: fnsi-lab analyse tells whether the record is "
               "nonlinear; kind: spline shows the force, docs/discovery.md); or drop the "
               "element" if slip else
               "where the stop is barely touched; excite harder, or drop the element"),
            element=u.name)
    if value <= lo * np.sqrt(step):
        raise NotIdentifiableError(
            f"nonlinearity {u.name!r}: the data cannot tell {u.parameter}: the information "
            f"criterion is smallest at the bottom of the search interval [{lo:.4g}, {hi:.4g}] "
            + ("(the joint slips nearly all the time: try kind: coulomb, or a search interval "
               "reaching lower)" if slip else "(the stop is in contact nearly all the time: a "
               "linear spring)"), element=u.name)
    # inf: the criterion has no opinion there (no stable order): NaN, as the JSON's null
    return ParameterEstimate(u, float(value), float("nan"), points,
                             np.where(np.isfinite(objective), objective, np.nan),
                             objective_name=OBJECTIVE)
