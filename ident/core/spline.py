"""The shape of a nonlinear element without assuming it: ``kind: spline`` (docs/discovery.md).

A spline element is a piecewise-linear restoring force in the relative displacement
``delta = L^T q`` (optionally also in the relative velocity): one basis column per knot
``t``, ``max(delta - t, 0)`` for ``t >= 0`` and ``min(delta - t, 0)`` for ``t < 0``. Its
coefficient is the slope change (the stiffness added) at the knot. The segment holding
``delta = 0`` has zero force and zero slope by construction: a slope there is a linear
stiffness, which FNSI cannot tell from the underlying linear system (a column linear in the
outputs is no input), so the curve is the force *beyond* the linear spring around the rest
position. Velocity knots add the same hinges in ``delta'`` and one ramp
``clip(delta', t_-, t_+)`` between the innermost velocity knots (a friction's sticking
slope), so a step such as Coulomb friction is a steep ramp with flat outer segments.

This module places a knot count over the measured range (:func:`resolve_knots`), reads the
identified coefficients back into a force curve with its confidence band
(:func:`spline_curves`) and suggests the parametric form that fits the curve, with its
parameters, ready to paste into a config (:func:`suggest_parametric`): a clearance where the
stiffness kinks (trilinear or bilinear stop), a hardening exponent (signed polynomial), a
friction level (Coulomb).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity, hinge_columns
from fnsi_lab.ident.errors import IdentError

__all__ = ["hinge_columns", "spread_knots", "resolve_knots", "needs_knots", "SplineCurve", "spline_curves",
           "suggest_parametric", "suggested_config", "determined_suggestion", "CURVE_POINTS",
           "SEARCH_MARGIN"]

#: Knots of the spline that ``nonlinearities: auto`` puts at the located element (on the
#: SmallSat, 12 knots read the NC2-Z clearances within 1.8 % and the contact stiffnesses
#: within 1.5 %; 24 within 1.7 % and 0.9 %: docs/discovery.md).
AUTO_KNOTS = 12
#: Points of a reported curve over the measured range.
CURVE_POINTS = 201
#: A suggested clearance is searched within this fraction of the value read off the curve
#: (the read-off is a piecewise-linear approximation; the search then pins it down).
SEARCH_MARGIN = 0.1
#: A suggested form must explain at least half of the curve (relative misfit below this):
#: above, it fits the curve worse than half of "no force at all" and none is suggested.
MAX_MISFIT = 0.5
#: A side of the curve whose outer stiffness is below this fraction of the largest secant
#: stiffness on either side is free (no stop there).
FREE_SIDE = 0.05


def needs_knots(basis: Sequence[Nonlinearity]) -> bool:
    """True if a spline element still holds a knot count instead of positions."""
    return any(nl.kind == "spline" and (len(nl.knots) < nl.knot_count or
                                         len(nl.velocity_knots) < nl.velocity_knot_count)
               for nl in basis)


def spread_knots(values: np.ndarray, count: int) -> tuple[float, ...]:
    """``count`` knots evenly inside ``[min, max]`` of the values (ends excluded)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    if not hi > lo:
        raise IdentError("the element's relative motion is constant: no range to place knots on")
    return tuple(lo + (hi - lo) * i / (count + 1) for i in range(1, count + 1))


def resolve_knots(basis: Sequence[Nonlinearity], motion: Any) -> tuple[Nonlinearity, ...]:
    """Place the knot counts of spline elements evenly over their measured range.

    Parameters
    ----------
    basis : sequence of Nonlinearity
    motion : ident.core.frequency_data.BasisMotion
        The averaged motion (``displacement``/``velocity`` ``(R, N_fine, c)``, ``channels``).

    Returns
    -------
    tuple of Nonlinearity
        Spline elements with ``knots`` (and ``velocity_knots``) as positions; others as given.
    """
    out = []
    chans = list(motion.channels)
    for nl in basis:
        if nl.kind != "spline" or not needs_knots([nl]):
            out.append(nl)
            continue
        L = nl.location_vector(chans)
        kw: dict = {}
        if len(nl.knots) < nl.knot_count:
            kw["knots"] = spread_knots(motion.displacement @ L + nl.offset, nl.knot_count)
        if len(nl.velocity_knots) < nl.velocity_knot_count:
            if motion.velocity is None:
                raise IdentError(f"nonlinearity {nl.name!r}: no velocity kept for its knots")
            kw["velocity_knots"] = spread_knots(motion.velocity @ L, nl.velocity_knot_count)
        out.append(replace(nl, **kw))
    return tuple(out)


@dataclass
class SplineCurve:
    """A restoring-force curve read off a spline element's coefficients.

    Attributes
    ----------
    element : str
    argument : {'displacement', 'velocity'}
    x : ndarray, shape (n,)
        Relative displacement (or velocity) over the measured range (output units).
    force : ndarray, shape (n,)
        Force beyond the linear spring (or damper) at rest (N, or the model's force unit).
    std : ndarray, shape (n,)
        Standard error of ``force``: the spread of the curve read at each excited line
        (the coefficients' spectra) over the square root of the number of lines.
    knots : tuple of float
    slopes : ndarray
        The coefficients (slope changes at the knots; the ramp's slope last for velocity).
    density : ndarray, shape (n,) or None
        Fraction of the measured samples nearest each point of ``x`` (how well the data
        determine the curve there).
    suggestion : dict
        :func:`suggest_parametric` of this curve.
    """

    element: str
    argument: str
    x: np.ndarray
    force: np.ndarray
    std: np.ndarray
    knots: tuple
    slopes: np.ndarray
    density: np.ndarray | None = None
    suggestion: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"element": self.element, "argument": self.argument, "x": self.x,
                "force": self.force, "std": self.std, "knots": list(self.knots),
                "slopes": self.slopes, "density": self.density}


def spline_curves(basis: Sequence[Nonlinearity], spectra: Any, values: Mapping[str, float],
                  motion: Any = None) -> list[SplineCurve]:
    """The force curves of every spline element, with their confidence bands.

    Parameters
    ----------
    basis : sequence of Nonlinearity
        Elements with knots placed.
    spectra : ident.core.coefficients.CoefficientSpectra
        ``c_a(w)`` of the answer (the band: the curve's spread over the excited lines).
    values : mapping str -> float
        The declared coefficient values (``coefficients[].value``).
    motion : BasisMotion, optional
        The measured range of each element (else from the knots' span).

    Returns
    -------
    list of SplineCurve
    """
    names = list(spectra.names)
    exc = np.asarray(spectra.excited, bool)
    out = []
    for nl in basis:
        if nl.kind != "spline":
            continue
        cols = list(nl.coefficient_names)
        groups = [("displacement", nl.knots, [c for c in cols if ":x" in c], False)]
        if nl.velocity_knots:
            groups.append(("velocity", nl.velocity_knots, [c for c in cols if ":v" in c], True))
        for argument, knots, cnames, ramp in groups:
            measured = _motion_of(nl, motion, argument)
            lo, hi = _range(measured, knots)
            x = np.linspace(lo, hi, CURVE_POINTS)
            phi = hinge_columns(x, knots, ramp=ramp)                  # (n, k)
            c = np.array([values[n] for n in cnames], float)
            idx = [names.index(n) for n in cnames]
            per_line = np.real(spectra.values[exc][:, idx]) @ phi.T   # (F_exc, n)
            ok = np.all(np.isfinite(per_line), axis=1)
            n_ok = max(int(ok.sum()), 1)
            std = (np.std(per_line[ok], axis=0) / np.sqrt(n_ok) if ok.sum() > 1
                   else np.full(x.size, np.nan))
            curve = SplineCurve(element=nl.name, argument=argument, x=x, force=phi @ c,
                                std=std, knots=tuple(knots), slopes=c,
                                density=_density(measured, x))
            curve.suggestion = suggest_parametric(curve)
            out.append(curve)
    return out


def _motion_of(nl: Nonlinearity, motion: Any, argument: str) -> np.ndarray | None:
    """The element's measured argument (all samples), or None when not kept."""
    if motion is None or not all(c in motion.channels for c in nl.channels):
        return None
    L = nl.location_vector(list(motion.channels))
    arr = motion.displacement if argument == "displacement" else motion.velocity
    if arr is None:
        return None
    return (arr @ L + (nl.offset if argument == "displacement" else 0.0)).reshape(-1)


def _range(values: np.ndarray | None, knots: Sequence[float]) -> tuple[float, float]:
    """Measured range of the element's argument (the knots' span widened when unknown)."""
    if values is not None:
        return float(np.min(values)), float(np.max(values))
    t = np.asarray(knots, float)
    pad = (t.max() - t.min()) / max(len(t) - 1, 1)
    return float(t.min() - pad), float(t.max() + pad)


def _density(values: np.ndarray | None, x: np.ndarray) -> np.ndarray | None:
    """Fraction of the samples nearest each grid point."""
    if values is None:
        return None
    edges = np.concatenate([[-np.inf], (x[1:] + x[:-1]) / 2, [np.inf]])
    counts, _ = np.histogram(values, bins=edges)
    return counts / max(values.size, 1)


def _side(x: np.ndarray, f: np.ndarray, sign: int, weight: np.ndarray | None = None) -> dict:
    """Stop read off one side of a displacement curve: stiffness and clearance.

    ``f ~ k max(sign (x - x0), 0) sign`` fitted on that side by weighted least squares
    (``weight``: how often the motion visits each point, so the rarely visited ends of the
    range, where the spline's outer coefficients are least determined, count least), the
    kink ``x0`` scanned over the side's points then refined between its neighbours.
    """
    sel = (x * sign) > 0
    xs, fs = x[sel], f[sel]
    ws = np.ones(xs.size) if weight is None else np.asarray(weight, float)[sel]
    if xs.size < 3 or not np.any(ws > 0):
        return {"stiffness": 0.0, "clearance": None, "residual": np.inf}

    def fit(x0: float) -> tuple[float, float]:
        h = np.where((xs - x0) * sign > 0, xs - x0, 0.0)
        hh = float(np.sum(ws * h * h))
        if hh <= 0:
            return 0.0, float(np.sum(ws * fs ** 2))
        k = float(np.sum(ws * h * fs) / hh)
        return k, float(np.sum(ws * (fs - k * h) ** 2))

    grid = np.sort(xs)
    errs = [fit(x0)[1] for x0 in grid]
    i = int(np.argmin(errs))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    fine = np.linspace(lo, hi, 41)
    j = int(np.argmin([fit(x0)[1] for x0 in fine]))
    x0 = float(fine[j])
    k, err = fit(x0)
    den = float(np.sum(ws * fs ** 2)) or 1.0
    return {"stiffness": k, "clearance": x0 * sign, "residual": err / den}


def _power_law(x: np.ndarray, f: np.ndarray) -> dict:
    """``f = c |x|^(e-1) x``: exponent and coefficient by log-log least squares."""
    sel = (np.abs(f) > 0.05 * np.max(np.abs(f))) & (np.abs(x) > 0) & (np.sign(f) == np.sign(x))
    if sel.sum() < 4:
        return {"exponent": None, "coefficient": None, "residual": np.inf}
    e, logc = np.polyfit(np.log(np.abs(x[sel])), np.log(np.abs(f[sel])), 1)
    if not e > 0:    # a force growing as the motion shrinks is no spring law
        return {"exponent": None, "coefficient": None, "residual": np.inf}
    c = float(np.exp(logc))
    model = c * np.abs(x) ** e * np.sign(x)
    den = float(np.sum(f ** 2)) or 1.0
    res = float(np.sum((f - model) ** 2) / den)
    return {"exponent": float(e), "coefficient": c,
            "residual": res if np.isfinite(res) else np.inf}


def suggest_parametric(curve: SplineCurve) -> dict:
    """The parametric form that fits a spline curve, with its parameters.

    Displacement curves: a stop on each side (outer stiffness, and the clearance where the
    outer line meets zero: where the stiffness kinks) against a signed power law (hardening
    exponent); the form with the smaller relative misfit on the curve wins, and a side
    whose outer stiffness is below :data:`FREE_SIDE` of the other's is free (bilinear).
    Velocity curves: a friction level (the outer lines' intercepts at zero velocity) and its
    sticking velocity (Coulomb's ``velocity_scale``).

    Returns
    -------
    dict
        ``kind`` (``trilinear``, ``bilinear``, ``polynomial``, ``coulomb`` or ``none``) and
        the parameters in the config's keys (``clearances``, ``clearance``, ``side``,
        ``exponent``, ``signed``, ``velocity_scale``), ``values`` (the coefficients the
        curve implies, in the order the kind names them) and ``misfit`` (relative, on the
        curve).
    """
    x, f = curve.x, curve.force
    if not np.any(f):
        return {"kind": "none", "reason": "the curve is flat (no nonlinearity beyond the noise)"}
    out = (_friction(x, f, curve.knots) if curve.argument == "velocity"
           else _displacement_form(curve))
    if not out.get("misfit", 0.0) <= MAX_MISFIT:    # NaN too
        hint = ("; friction that is not Coulomb-like may stick and slip with memory, which "
                "no curve in the velocity draws: try kind: jenkins, slip: auto there "
                "(docs/discovery.md)" if curve.argument == "velocity" else "")
        return {"kind": "none", "reason": f"the best form ({out['kind']}) leaves "
                f"{100 * out['misfit']:.0f} % of the curve unexplained{hint}", "closest": out}
    return out


def determined_suggestion(curve: SplineCurve, determined: bool,
                          located: Mapping[str, Any] | None = None, *,
                          length_unit: str = "") -> dict:
    """The curve's suggestion if the data determine the curve, else why not.

    A form read off a curve whose coefficients are all ``not identifiable`` (or that the
    nested test found unsupported: the same verdict) would be a guess printed as a finding
    (on the aircraft-like GVT: a clearance of 4 um on a friction joint whose gap is 300 um).
    Then the suggestion is ``none``, its read-off form kept as ``closest``; when the
    localisation located this element's channels with a stick-slip (Jenkins) element
    (``locate --form auto``), that form is suggested instead, with its slip from the data.

    Parameters
    ----------
    curve : SplineCurve
    determined : bool
        Some coefficient of the element is ``identified`` or ``weak`` (False: every one
        is ``not identifiable``).
    located : mapping, optional
        The localisation's located candidate (``Localisation.to_json()["candidates"][0]``)
        when it was located by a Jenkins element on this element's channels.
    length_unit : str, optional
        Unit of the slip in the reason (the outputs' length unit).

    Returns
    -------
    dict
        :func:`suggest_parametric`'s dict, or ``{"kind": "none" | "jenkins", "reason",
        "closest", ["slip"]}``.
    """
    if determined:
        return dict(curve.suggestion)
    reason = ("the data do not determine the curve (every coefficient of the element is not "
              "identifiable), so no form is read off it")
    closest = dict(curve.suggestion)
    if located is not None and located.get("slip") and curve.argument == "displacement":
        slip = float(located["slip"])
        return {"kind": "jenkins", "slip": slip, "closest": closest,
                "reason": f"{reason}; the localisation located {located.get('name', 'it')} as "
                          f"a stick-slip (Jenkins) element slipping at {slip:.3g}"
                          f"{' ' + length_unit if length_unit else ''} "
                          "(docs/discovery.md)"}
    return {"kind": "none", "reason": reason, "closest": closest}


def _displacement_form(curve: SplineCurve) -> dict:
    """Stops against a power law on a displacement curve (:func:`suggest_parametric`)."""
    x, f = curve.x, curve.force
    pos, neg = _side(x, f, +1, curve.density), _side(x, f, -1, curve.density)
    power = _power_law(x, f)
    k_ref = max(abs(pos["stiffness"]), abs(neg["stiffness"]))
    pos_on = pos["clearance"] is not None and abs(pos["stiffness"]) > FREE_SIDE * k_ref \
        and pos["clearance"] > 0
    neg_on = neg["clearance"] is not None and abs(neg["stiffness"]) > FREE_SIDE * k_ref \
        and neg["clearance"] > 0
    stop_misfit = np.mean([s["residual"] for s, on in ((pos, pos_on), (neg, neg_on)) if on]) \
        if (pos_on or neg_on) else np.inf
    if stop_misfit <= power["residual"] and pos_on and neg_on:
        return {"kind": "trilinear", "clearances": [neg["clearance"], pos["clearance"]],
                "values": [neg["stiffness"], pos["stiffness"]], "misfit": float(stop_misfit)}
    if stop_misfit <= power["residual"] and (pos_on or neg_on):
        side, s = ("pos", pos) if pos_on else ("neg", neg)
        return {"kind": "bilinear", "side": side, "clearance": s["clearance"],
                "values": [s["stiffness"]], "misfit": float(stop_misfit)}
    if power["exponent"] is None:
        return {"kind": "none", "reason": "neither a stop nor a power law fits the curve"}
    return {"kind": "polynomial", "signed": True, "exponent": power["exponent"],
            "values": [power["coefficient"]], "misfit": power["residual"]}


def _friction(v: np.ndarray, f: np.ndarray, knots: Sequence[float]) -> dict:
    """Friction level and sticking velocity of a velocity curve.

    On each side, a line fitted to the outer half of the range (beyond the sticking ramp);
    its intercept at zero velocity is the friction level on that side (the mean of the two
    is reported), its slope a viscous part left out of the suggestion.
    """
    levels = []
    for sign in (+1, -1):
        side = (v * sign) > 0
        if not np.any(side):
            continue
        outer = side & (np.abs(v) >= 0.5 * np.max(np.abs(v[side])))
        if outer.sum() < 2:
            continue
        slope, intercept = np.polyfit(v[outer], f[outer], 1)
        levels.append(float(intercept) * sign)
    level = float(np.mean(levels)) if levels else 0.0
    t = np.asarray(knots, float)
    scale = float(np.min(np.abs(t))) if t.size else 0.0
    model = level * np.tanh(v / max(scale, 1e-30))
    den = float(np.sum(f ** 2)) or 1.0
    return {"kind": "coulomb", "velocity_scale": scale, "values": [level],
            "misfit": float(np.sum((f - model) ** 2) / den)}


def suggestion_element(nl: Nonlinearity, suggestion: Mapping, *,
                       margin: float = SEARCH_MARGIN) -> dict | None:
    """The config entry (``nonlinearities:`` item) of a suggestion, as plain YAML data.

    Clearances are given as search intervals ``[(1 - margin) g, (1 + margin) g]`` around the
    values read off the curve, so the identification pins them down (docs/ident.md,
    "Unknown basis parameters"); the read-off values are in the comment of
    :func:`suggested_config`.
    """
    kind = suggestion.get("kind")
    if kind in (None, "none"):
        return None
    name = nl.name if suggestion.get("argument", "displacement") == "displacement" \
        else f"{nl.name}-friction"
    item: dict[str, Any] = {"name": name, "kind": kind,
                            "channels": {k: (int(v) if float(v).is_integer() else v)
                                         for k, v in nl.channels.items()}}

    def interval(g: float) -> list[float]:
        return [_round((1 - margin) * g), _round((1 + margin) * g)]

    if kind == "trilinear":
        item["clearances"] = [interval(g) for g in suggestion["clearances"]]
    elif kind == "bilinear":
        item["clearance"] = interval(suggestion["clearance"])
        item["side"] = suggestion["side"]
    elif kind == "polynomial":
        item.update(signed=True, exponent=_round(suggestion["exponent"]))
    elif kind == "coulomb":
        item["velocity_scale"] = _round(max(suggestion["velocity_scale"], 1e-12))
    elif kind == "jenkins":    # the localisation's slip is on a 1.3x grid: searched again
        item["slip"] = "auto"
    if nl.offset:
        item["offset"] = nl.offset
    return item


def _round(v: float, digits: int = 4) -> float:
    return float(f"{float(v):.{digits}g}")


def suggested_config(raw_config: Mapping | None, basis: Sequence[Nonlinearity],
                     curves: Sequence[SplineCurve]) -> tuple[dict, str]:
    """The config with each spline element replaced by its suggested parametric form.

    Parameters
    ----------
    raw_config : mapping or None
        The YAML mapping the identification was configured with (None: only the
        ``nonlinearities`` list is returned).
    basis : sequence of Nonlinearity
        The elements as identified.
    curves : sequence of SplineCurve

    Returns
    -------
    (dict, str)
        The config mapping and its YAML text, with the values read off the curves as
        comments.
    """
    import yaml

    by_el: dict[str, list] = {}
    for c in curves:
        by_el.setdefault(c.element, []).append(c)
    items: list[dict | None] = []
    notes: list[str] = []
    for nl in basis:
        if nl.kind != "spline":
            items.append(None)
            continue
        for c in by_el.get(nl.name, []):
            item = suggestion_element(nl, dict(c.suggestion, argument=c.argument))
            s = c.suggestion
            if item is None:
                notes.append(f"{nl.name} ({c.argument}): {s.get('reason', 'no form fits')}")
                continue
            items.append(item)
            if s["kind"] == "jenkins":
                notes.append(f"{nl.name} ({c.argument}): jenkins, {s['reason']}")
                continue
            read = {k: s[k] for k in ("clearances", "clearance", "exponent", "velocity_scale")
                    if k in s}
            notes.append(f"{nl.name} ({c.argument}): {s['kind']}, read off the curve "
                         + ", ".join(f"{k} {_fmt(v)}" for k, v in read.items())
                         + f", coefficients {_fmt(s['values'])}, misfit {s['misfit']:.2g}")
    raw = dict(raw_config or {})
    old = raw.get("nonlinearities")
    old = list(old) if isinstance(old, list) else []    # nonlinearities: auto
    kept = [o for o in old if not (isinstance(o, dict) and o.get("kind") == "spline")]
    raw["nonlinearities"] = kept + [i for i in items if i is not None]
    text = yaml.safe_dump(raw, sort_keys=False, default_flow_style=None)
    header = "".join(f"# {n}\n" for n in notes)
    return raw, header + text


def _fmt(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return f"{float(v):.5g}" if isinstance(v, (int, float)) else str(v)
