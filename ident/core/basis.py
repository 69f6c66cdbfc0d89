"""Nonlinear basis functions ``h_a`` and the extended input (docs/method.md §1.1, §1.2, §2.5).

Each :class:`Nonlinearity` acts on a **signed** combination of measured output channels,
``delta = L^T q`` (``L = {channel: weight}``; ``+1`` at DOF j and ``-1`` at DOF k for an
element between j and k, ``+1`` alone for an element to ground). The restoring force of the
element on the structure is ``c h(delta) L`` and ``c`` is the physical coefficient (N/m^3,
N/m, N s^2/m^2, N...). Flipping the sign of ``L`` (and, for gaps, swapping the two
clearances) describes the same physics and gives the same ``c``.

Kinds
-----
``polynomial``
    ``h = delta**exponent``; with ``signed: true``, ``h = |delta|**(exponent-1) delta``
    (e.g. ``|x| x``). ``argument: velocity`` uses ``delta' = L^T q'`` instead.
``trilinear``
    Two known clearances ``(g_neg, g_pos)`` (positive distances), two coefficients named
    ``NAME:neg`` and ``NAME:pos``:
    ``h_neg = delta + g_neg if delta < -g_neg else 0``,
    ``h_pos = delta - g_pos if delta > g_pos else 0``; restoring force
    ``k_neg h_neg + k_pos h_pos``.
``bilinear``
    One-sided stop: ``side: pos`` gives ``h = delta - g if delta > g else 0``,
    ``side: neg`` gives ``h = delta + g if delta < -g else 0``.
``quadratic_damping``
    ``h = |delta'| delta'``.
``coulomb``
    ``h = tanh(delta' / velocity_scale)`` (regularized Coulomb friction; ``c`` is the
    friction force in N).
``jenkins``
    Hysteretic friction (a bolted joint that sticks and slips): a spring in series with a
    Coulomb slider, ``h = z`` the spring's elongation, the play operator of ``delta`` with
    the slip displacement ``slip`` (m, ``F_s / k``; :mod:`ident.core.hysteresis`), in
    periodic steady state. ``c`` is the spring's stiffness ``k`` (N/m); the slip force is
    ``c * slip``. ``slip: auto`` leaves it to the data.
``spline``
    No assumed shape: a piecewise-linear restoring force in ``delta`` with slope changes at
    ``knots`` (one column per knot, ``max(delta - t, 0)`` for ``t >= 0``,
    ``min(delta - t, 0)`` for ``t < 0``: the force and its slope are zero on the segment
    holding ``delta = 0``, the rest is the underlying linear stiffness), optionally the same
    in ``delta'`` (``velocity_knots``, plus a ramp column ``clip(delta', t_-, t_+)`` between
    the two innermost velocity knots: friction's sticking slope). ``c`` of a column is the
    slope change at its knot (N/m). A knot count instead of positions is spread over the measured range by
    :func:`ident.core.spline.resolve_knots` (docs/discovery.md).

``offset`` (m) is a static relative position added to ``delta`` (needed for gaps and even
polynomials when the outputs are accelerations, whose DC is lost, or displacement sensors
with a DC offset). A trilinear stop's offset may be left to the data when both clearances
are given (``offset: auto``): the two contact points then fix it.

Unknown parameters
------------------
A clearance, a stop's offset or an exponent may be left to the data (``clearances: auto``
in the YAML): the element then lists it in ``unknown`` (a :class:`ParameterSpace`: search
interval or candidates), cannot be evaluated, and :mod:`ident.refine.parameter_search` returns
the element with the estimate filled in (:meth:`Nonlinearity.with_parameters`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import ChannelError, IdentError

Kind = Literal["polynomial", "trilinear", "bilinear", "quadratic_damping", "coulomb", "spline",
               "jenkins"]
KINDS: tuple[str, ...] = ("polynomial", "trilinear", "bilinear", "quadratic_damping", "coulomb",
                          "spline", "jenkins")

#: Parameters that can be estimated, per kind (``g_neg``/``g_pos``: the two clearances).
ESTIMABLE: dict[str, tuple[str, ...]] = {"trilinear": ("g_neg", "g_pos", "offset"),
                                         "bilinear": ("clearance",),
                                         "polynomial": ("exponent",),
                                         "jenkins": ("slip",)}


@dataclass(frozen=True)
class ParameterSpace:
    """A basis parameter left to the data.

    Parameters
    ----------
    parameter : {'g_neg', 'g_pos', 'clearance', 'offset', 'exponent', 'slip'}
    interval : (float, float), optional
        Continuous search interval (clearances and offsets in the outputs' length unit; an
        offset's may be signed); None: from the recorded motion (clearances, offset) or the
        default exponent range.
    candidates : tuple of float, optional
        Discrete values to choose from (exponents); exclusive with ``interval``.
    """

    parameter: str
    interval: tuple[float, float] | None = None
    candidates: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.interval is not None:
            lo, hi = (float(v) for v in self.interval)
            signed = self.parameter == "offset"
            if not ((signed or 0 <= lo) and lo < hi):
                raise IdentError(f"search interval of {self.parameter} must be [low, high] with "
                                 f"{'' if signed else '0 <= '}low < high, got {plain.value(self.interval)}")
            object.__setattr__(self, "interval", (lo, hi))
        if self.candidates is not None:
            c = tuple(sorted({float(v) for v in self.candidates}))
            if len(c) < 2:
                raise IdentError(f"{self.parameter}: give at least two candidates, "
                                 f"got {plain.value(c)}")
            object.__setattr__(self, "candidates", c)


@dataclass(frozen=True)
class Nonlinearity:
    """One nonlinear element ``c h(L^T q, L^T q')``.

    Parameters
    ----------
    name : str
        Coefficient name (``NAME:neg``/``NAME:pos`` for trilinear).
    kind : {'polynomial', 'trilinear', 'bilinear', 'quadratic_damping', 'coulomb', 'spline', 'jenkins'}
    channels : mapping str -> float
        Signed location vector ``L`` on measured output channels.
    exponent : float
        Polynomial exponent (default 3).
    signed : bool
        Polynomial only: ``|delta|**(exponent-1) delta``.
    argument : {'displacement', 'velocity'}
        Polynomial only: argument quantity.
    clearances : (float, float)
        Trilinear ``(g_neg, g_pos)`` in m, positive distances.
    clearance : float
        Bilinear gap in m (positive).
    side : {'pos', 'neg'}
        Bilinear side.
    velocity_scale : float
        Coulomb regularization velocity (m/s).
    slip : float
        Jenkins only: slip displacement ``F_s / k`` (m, the outputs' length unit), > 0.
    knots, velocity_knots : tuple of float
        Spline only: knot positions in ``delta`` (m) and in ``delta'`` (m/s).
    knot_count, velocity_knot_count : int
        Spline only: knots still to be spread over the measured range
        (:func:`ident.core.spline.resolve_knots`); the element cannot be evaluated before.
    offset : float
        Static relative position added to ``delta`` (m).
    unknown : tuple of ParameterSpace
        Parameters to estimate from the data (their fields above hold placeholders).
    """

    name: str
    kind: Kind
    channels: Mapping[str, float]
    exponent: float = 3.0
    signed: bool = False
    argument: Literal["displacement", "velocity"] = "displacement"
    clearances: tuple[float, float] = (0.0, 0.0)
    clearance: float = 0.0
    side: Literal["pos", "neg"] = "pos"
    velocity_scale: float = 1e-3
    slip: float = 0.0
    knots: tuple[float, ...] = ()
    velocity_knots: tuple[float, ...] = ()
    knot_count: int = 0
    velocity_knot_count: int = 0
    offset: float = 0.0
    truth: tuple[float, ...] | None = field(default=None, compare=False)
    unknown: tuple[ParameterSpace, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise IdentError(f"nonlinearity {self.name!r}: unknown kind {self.kind!r} "
                             f"(use one of {plain.names(KINDS)})")
        if not self.channels:
            raise IdentError(f"nonlinearity {self.name!r}: 'channels' is empty")
        object.__setattr__(self, "channels", {str(k): float(v) for k, v in self.channels.items()})
        if self.kind == "trilinear":
            g = tuple(float(v) for v in self.clearances)
            if len(g) != 2 or min(g) < 0:
                raise IdentError(f"nonlinearity {self.name!r}: clearances must be two "
                                 f"non-negative distances [g_neg, g_pos], got {plain.value(self.clearances)}")
            object.__setattr__(self, "clearances", g)
        if self.kind == "bilinear" and self.clearance < 0:
            raise IdentError(f"nonlinearity {self.name!r}: clearance must be >= 0")
        if self.kind == "spline":
            for key in ("knots", "velocity_knots"):
                object.__setattr__(self, key, tuple(sorted(float(t) for t in getattr(self, key))))
            if not (self.knots or self.knot_count or self.velocity_knots
                    or self.velocity_knot_count):
                raise IdentError(f"nonlinearity {self.name!r}: a spline needs knots "
                                 "(a count such as 12, or positions)")
        if self.kind == "coulomb" and not self.velocity_scale > 0:
            raise IdentError(f"nonlinearity {self.name!r}: velocity_scale must be > 0")
        object.__setattr__(self, "unknown", tuple(self.unknown))
        if (self.kind == "jenkins" and not self.slip > 0
                and "slip" not in {sp.parameter for sp in self.unknown}):
            raise IdentError(f"nonlinearity {self.name!r}: a jenkins element needs slip > 0 "
                             "(the slip displacement F_s / k) or slip: auto")
        allowed = ESTIMABLE.get(self.kind, ())
        for sp in self.unknown:
            if sp.parameter not in allowed:
                raise IdentError(f"nonlinearity {self.name!r}: {sp.parameter!r} cannot be "
                                 f"estimated for a {self.kind} element (estimable: {plain.names(allowed, empty='nothing')})"
                                 + ("; a one-sided stop's offset and clearance are one "
                                    "parameter: leave the clearance to the data"
                                    if (self.kind, sp.parameter) == ("bilinear", "offset") else ""))
        left = {sp.parameter for sp in self.unknown}
        if "offset" in left and left & {"g_neg", "g_pos"}:
            # the offset moves both contact points, a clearance one of them: from the two
            # contact points the data give, the offset follows only with both gaps known
            raise IdentError(f"nonlinearity {self.name!r}: an offset left to the data needs both "
                             "clearances given; or give the offset (0: the clearances then "
                             "count from the recorded zero) and leave the clearances to the data")

    def parameter(self, name: str) -> float:
        """Current value of an estimable parameter (``g_neg``, ``g_pos``, ``clearance``,
        ``offset``, ``exponent``, ``slip``)."""
        if name == "g_neg":
            return self.clearances[0]
        if name == "g_pos":
            return self.clearances[1]
        if name in ("clearance", "offset", "exponent", "slip"):
            return float(getattr(self, name))
        raise IdentError(f"nonlinearity {self.name!r}: no parameter {name!r}")

    def with_parameters(self, values: Mapping[str, float]) -> "Nonlinearity":
        """The element with these parameter values; they are no longer unknown.

        Parameters
        ----------
        values : mapping str -> float
            ``{'g_pos': 1.3e-3, ...}``; names from ``ESTIMABLE[kind]``.
        """
        from dataclasses import replace

        kw: dict = {}
        g = list(self.clearances)
        for name, v in values.items():
            self.parameter(name)  # validates the name
            if name == "g_neg":
                g[0] = float(v)
            elif name == "g_pos":
                g[1] = float(v)
            else:
                kw[name] = float(v)
        if self.kind == "trilinear":
            kw["clearances"] = tuple(g)
        left = tuple(sp for sp in self.unknown if sp.parameter not in values)
        return replace(self, unknown=left, **kw)

    @property
    def coefficient_names(self) -> tuple[str, ...]:
        """Names of the coefficients (columns) this element contributes."""
        if self.kind == "trilinear":
            return (f"{self.name}:neg", f"{self.name}:pos")
        if self.kind == "spline":
            return (tuple(f"{self.name}:x{i}" for i in range(len(self.knots) or self.knot_count))
                    + tuple(f"{self.name}:v{i}" for i in
                            range(len(self.velocity_knots) or self.velocity_knot_count))
                    + ((f"{self.name}:v_ramp",) if self.velocity_knots
                       or self.velocity_knot_count else ()))
        return (self.name,)

    @property
    def needs_velocity(self) -> bool:
        """True if ``h`` depends on ``L^T q'``."""
        return self.kind in ("quadratic_damping", "coulomb") or bool(
            self.kind == "spline" and (self.velocity_knots or self.velocity_knot_count)) or (
            self.kind == "polynomial" and self.argument == "velocity")

    def location_vector(self, output_names: Sequence[str]) -> np.ndarray:
        """Signed location vector ``L`` on the outputs, shape ``(p,)``.

        Raises
        ------
        ChannelError
            If a channel of ``L`` is not among the outputs.
        """
        names = list(output_names)
        vec = np.zeros(len(names))
        for ch, w in self.channels.items():
            if ch not in names:
                raise ChannelError(f"nonlinearity {self.name!r}: channel {ch!r} is not among "
                                   f"the identified outputs {plain.names(names)} (fix: list it under "
                                   "outputs: in the ident config, or check its name)")
            vec[names.index(ch)] += w
        return vec

    def evaluate(self, delta: np.ndarray, delta_dot: np.ndarray | None = None) -> np.ndarray:
        """Evaluate the basis column(s).

        Parameters
        ----------
        delta : ndarray, shape (n_samples,)
            ``L^T q`` (m), offset not yet added.
        delta_dot : ndarray, shape (n_samples,), optional
            ``L^T q'`` (m/s); required when :attr:`needs_velocity`.

        Returns
        -------
        h : ndarray, shape (n_samples, n_columns)

        Raises
        ------
        IdentError
            A parameter of the element is still unknown.
        """
        if self.unknown:
            raise IdentError(f"nonlinearity {self.name!r}: "
                             f"{plain.names([sp.parameter for sp in self.unknown])} not estimated yet "
                             "(ident.refine.parameter_search resolves 'auto' parameters)")
        if self.kind == "spline" and (len(self.knots) < self.knot_count or
                                      len(self.velocity_knots) < self.velocity_knot_count):
            raise IdentError(f"nonlinearity {self.name!r}: knots not placed yet "
                             "(ident.core.spline.resolve_knots spreads a knot count over the motion)")
        d = np.asarray(delta, float) + self.offset
        if self.needs_velocity:
            if delta_dot is None:
                raise IdentError(f"nonlinearity {self.name!r} needs velocities")
            v = np.asarray(delta_dot, float)
        if self.kind == "polynomial":
            x = v if self.argument == "velocity" else d
            if self.signed:
                h = np.abs(x) ** (self.exponent - 1.0) * x
            else:
                e = float(self.exponent)
                h = x ** int(e) if e.is_integer() else np.abs(x) ** e
            return h[:, None]
        if self.kind == "trilinear":
            gn, gp = self.clearances
            h_neg = np.where(d < -gn, d + gn, 0.0)
            h_pos = np.where(d > gp, d - gp, 0.0)
            return np.stack([h_neg, h_pos], axis=1)
        if self.kind == "bilinear":
            g = self.clearance
            if self.side == "pos":
                return np.where(d > g, d - g, 0.0)[:, None]
            return np.where(d < -g, d + g, 0.0)[:, None]
        if self.kind == "spline":
            cols = [hinge_columns(d, self.knots)]
            if self.velocity_knots:
                cols.append(hinge_columns(v, self.velocity_knots, ramp=True))
            return np.concatenate(cols, axis=1)
        if self.kind == "quadratic_damping":
            return (np.abs(v) * v)[:, None]
        if self.kind == "jenkins":   # numba only where needed (+0.2 s of import)
            from fnsi_lab.ident.core.hysteresis import periodic_play
            return periodic_play(d, self.slip)[:, None]
        return np.tanh(v / self.velocity_scale)[:, None]  # coulomb

    @property
    def hysteretic(self) -> bool:
        """True if ``h`` has memory: read on one period of a periodic motion, in time order."""
        return self.kind == "jenkins"

    def slope(self, delta: np.ndarray, delta_dot: np.ndarray | None = None) -> np.ndarray:
        """Derivative of the basis column(s) with respect to the element's argument.

        The argument is ``delta'`` for velocity-dependent elements, else ``delta``. Central
        differences of :meth:`evaluate` with a step of ``1e-6`` times the argument's RMS (a
        stop's slope is 0, 1 or 1/2 on a sample at its kink), except for a hysteretic
        element, whose tangent along its cycle is exact (1 sticking, 0 slipping; shifting
        the whole record would leave it unchanged).

        Parameters
        ----------
        delta, delta_dot : ndarray, shape (n_samples,)
            As in :meth:`evaluate`.

        Returns
        -------
        ndarray, shape (n_samples, n_columns)
        """
        if self.kind == "jenkins":
            from fnsi_lab.ident.core.hysteresis import periodic_play_slope
            return periodic_play_slope(np.asarray(delta, float) + self.offset, self.slip)[:, None]
        if self.needs_velocity:
            if delta_dot is None:
                raise IdentError(f"nonlinearity {self.name!r} needs velocities")
            v = np.asarray(delta_dot, float)
            h = 1e-6 * max(float(np.sqrt(np.mean(v ** 2))), 1e-300)
            return (self.evaluate(delta, v + h) - self.evaluate(delta, v - h)) / (2 * h)
        d = np.asarray(delta, float)
        h = 1e-6 * max(float(np.sqrt(np.mean(d ** 2))), 1e-300)
        return (self.evaluate(d + h) - self.evaluate(d - h)) / (2 * h)


Basis = tuple[Nonlinearity, ...]


def coefficient_names(basis: Sequence[Nonlinearity]) -> tuple[str, ...]:
    """All basis-column names, in extended-input order."""
    return tuple(n for nl in basis for n in nl.coefficient_names)


def location_matrix(basis: Sequence[Nonlinearity], output_names: Sequence[str]) -> np.ndarray:
    """Location vectors of every basis column, shape ``(p, s)`` (columns repeat for trilinear)."""
    cols = []
    for nl in basis:
        vec = nl.location_vector(output_names)
        cols.extend([vec] * len(nl.coefficient_names))
    return np.stack(cols, axis=1) if cols else np.zeros((len(output_names), 0))


def evaluate_basis(basis: Sequence[Nonlinearity], q: np.ndarray, q_dot: np.ndarray | None,
                   output_names: Sequence[str]) -> np.ndarray:
    """Evaluate every basis column on displacements (and velocities).

    Parameters
    ----------
    basis : sequence of Nonlinearity
    q : ndarray, shape (n_samples, p)
        Displacements of the outputs (m).
    q_dot : ndarray, shape (n_samples, p), optional
        Velocities (m/s), needed by velocity-dependent elements.
    output_names : sequence of str, length p

    Returns
    -------
    h : ndarray, shape (n_samples, s)
    """
    q = np.asarray(q, float)
    if not basis:
        return np.zeros((q.shape[0], 0))
    cols = []
    for nl in basis:
        L = nl.location_vector(output_names)
        dv = q_dot @ L if (nl.needs_velocity and q_dot is not None) else None
        cols.append(nl.evaluate(q @ L, dv))
    return np.concatenate(cols, axis=1)


def nonlinearity_from_dict(d: Mapping) -> Nonlinearity:
    """Build a :class:`Nonlinearity` from a plain mapping (already validated)."""
    return Nonlinearity(**dict(d))


def hinge_columns(x: np.ndarray, knots: Sequence[float], *, ramp: bool = False) -> np.ndarray:
    """Piecewise-linear columns with zero force and slope on the segment holding 0.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Relative displacement (or velocity).
    knots : sequence of float
        Knot positions (sorted).
    ramp : bool
        Add ``clip(x, t_-, t_+)`` between the innermost negative and positive knots (or
        ``+-`` the innermost knot when all are on one side).

    Returns
    -------
    ndarray, shape (n, len(knots) + ramp)
    """
    x = np.asarray(x, float)
    cols = [np.maximum(x - t, 0.0) if t >= 0 else np.minimum(x - t, 0.0) for t in knots]
    if ramp:
        t = np.asarray(knots, float)
        neg, pos = t[t < 0], t[t >= 0]
        lo = float(neg.max()) if neg.size else -float(np.min(np.abs(t)))
        hi = float(pos.min()) if pos.size else float(np.min(np.abs(t)))
        cols.append(np.clip(x, lo, hi))
    return np.stack(cols, axis=1) if cols else np.zeros((x.size, 0))
