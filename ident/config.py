"""The ident YAML configuration (``fnsi-lab ident INPUT --config IDENT.yaml``).

Validated with :class:`fnsi_lab.validate.Section`: every message names the file, the dotted
field and the fix; unknown keys are rejected (typos). Example (3-DOF chain, relative stop)::

    band_hz: [3, 150]            # processed band (Hz)
    samples_per_period: 4096     # optional for MCAP (from the excitation metadata)
    transient_periods: 1         # optional (MCAP: from the metadata, else 0)
    output_quantity: displacement   # displacement | velocity | acceleration
    outputs: [X1, X2, X3]        # optional subset/order of output channels
    inputs:
      - {name: F-X3, driving_point: X3}
    nonlinearities:
      - name: stop
        kind: trilinear
        channels: {X2: 1, X3: -1}
        clearances: [4.0e-4, 5.0e-4]   # (g_neg, g_pos), m; or auto, or per side a
                                       # search interval: [[3.0e-4, 6.0e-4], auto]
        truth: [2.0e4, 1.5e4]          # optional, for error_percent
    order: 6
    max_order: 20                # largest order of the decomposition (default: order)
    block_rows: null             # default from p and max_order (docs/method.md §8.2)
    d_zero: null                 # default false: estimate D (see IdentConfig.d_zero_for)
    weighting: auto              # auto | none | noise
    time_base: auto              # auto | band-limited (anti-aliased) | zoh (held input) | bilinear
    basis_oversample: 8          # basis functions on an 8x band-limited interpolation (§8.4)
    integration_min_snr: 4       # accelerations: lines below 4x their noise not integrated
    refine: auto                 # auto | output-error | none: the output-error refinement
                                 # (docs/ident.md); auto: noisy data with basis functions
    # nonlinearities: auto       # instead of the list: located (ident.locate) and
                                 # characterised by a spline there (docs/discovery.md)

    auto:                        # options of the robust pipeline (--auto; docs/robust.md)
      top_n: 3                   # e.g. keep exactly the 3 most dominant modes
      orders: "2:40"             # order sweep (same syntax as --orders)

The ``auto:`` section is parsed here, into :class:`fnsi_lab.ident.robust.options.AutoOptions`
(``IdentConfig.auto``), whatever module is imported first.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError
from fnsi_lab.validate import Section, load_yaml
from fnsi_lab.ident.core.basis import KINDS, Nonlinearity, ParameterSpace
from fnsi_lab.ident.errors import IdentConfigError, IdentError
from fnsi_lab.ident.robust.options import AutoOptions, parse_orders
from fnsi_lab.ident.core.periodic import OUTPUT_QUANTITIES, OutputQuantity

WEIGHTINGS = ("auto", "none", "noise")
#: ``refine:`` choices: ``auto`` refines noisy data with basis functions by their output error
#: (:mod:`ident.refine.output_error`), ``output-error`` always (unweighted without a noise
#: estimate), ``none`` keeps FNSI's model.
REFINEMENTS = ("auto", "output-error", "none")


@dataclass(frozen=True)
class InputSpec:
    """One force channel and the output measured at its DOF (driving point)."""

    name: str
    driving_point: str | None = None


@dataclass(frozen=True)
class IdentConfig:
    """Validated ident configuration (see the module docstring for the YAML keys)."""

    band_hz: tuple[float, float]
    nonlinearities: tuple[Nonlinearity, ...] = ()
    inputs: tuple[InputSpec, ...] = ()
    outputs: tuple[str, ...] | None = None
    samples_per_period: int | None = None
    transient_periods: int | None = None
    output_quantity: OutputQuantity | None = None
    order: int | None = None
    max_order: int | None = None
    block_rows: int | None = None
    d_zero: bool | None = None
    weighting: str = "auto"
    highpass_hz: float | None = None
    steady_state_tolerance: float = 0.05
    steady_periods: Literal["auto", "all"] = "auto"
    time_base: Literal["auto", "band-limited", "zoh", "bilinear"] = "auto"
    bilinear_period_s: float | None = None
    basis_oversample: int = 8
    integration_min_snr: float | None = 4.0
    refine: str = "auto"
    compare_linear: bool | str = "auto"
    auto: AutoOptions = field(default_factory=AutoOptions)
    orders: tuple[int, ...] | None = None
    file: str | None = None
    #: ``nonlinearities: auto``: the element is located and characterised from the data
    #: (:mod:`ident.locate`, then a ``kind: spline`` there; docs/discovery.md).
    nonlinearities_auto: bool = False

    @property
    def driving_points(self) -> dict[str, str | None]:
        """``{input name: driving-point output}``."""
        return {i.name: i.driving_point for i in self.inputs}

    def d_zero_for(self, output_quantity: str) -> bool:
        """Effective ``D = 0`` choice (default: estimate D, whatever the outputs).

        Physically ``D = 0`` for displacements and velocities, but the DT feedthrough also
        absorbs the sampling mismatch of band-limited (not ZOH) data: on the simulated 3-DOF
        cubic chain (displacements) estimating D gave -0.03 % against +0.13 % with D = 0 and
        a 3000x smaller model error. Set ``d_zero: true`` for noisy data.
        """
        if self.d_zero is not None:
            return bool(self.d_zero)
        return False


_NUMERIC_KEYS = {"band_hz", "clearances", "clearance", "truth", "exponent", "velocity_scale", "slip",
                 "knots", "velocity_knots",
                 "offset", "highpass_hz", "steady_state_tolerance", "bilinear_period_s",
                 "integration_min_snr"}
_FLOAT_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def _as_number(v: Any) -> Any:
    """PyYAML (YAML 1.1) reads ``1.0e9`` (no sign in the exponent) as text: accept it."""
    if isinstance(v, str) and _FLOAT_RE.match(v.strip()):
        return float(v)
    if isinstance(v, list):
        return [_as_number(x) for x in v]
    return v


def _coerce(d: Any) -> Any:
    """Numeric-looking strings -> floats for the numeric keys (and channel weights)."""
    if not isinstance(d, dict):
        return d
    out = dict(d)
    for k, v in out.items():
        if k in _NUMERIC_KEYS:
            out[k] = _as_number(v)
        elif k == "channels" and isinstance(v, dict):
            out[k] = {ch: _as_number(w) for ch, w in v.items()}
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _clearance_spec(sec: Section, key: str, v: Any, parameter: str) -> tuple[float, ParameterSpace | None]:
    """One clearance: a distance, ``auto`` (search over the recorded motion) or ``[low, high]``.

    Returns the value (0 as a placeholder when unknown) and the search space (None if known).
    """
    if v == "auto":
        return 0.0, ParameterSpace(parameter)
    if isinstance(v, list) and len(v) == 2 and all(_is_number(x) for x in v):
        if not 0 <= v[0] < v[1]:
            raise sec.error(key, f"search interval {plain.value(v)} must be [low, high] with 0 <= low < high",
                            fix="e.g. [1.0, 2.0] (same length unit as the outputs)")
        return 0.0, ParameterSpace(parameter, interval=(float(v[0]), float(v[1])))
    if _is_number(v) and v >= 0:
        return float(v), None
    raise sec.error(key, f"expected a non-negative distance, auto or a search interval "
                    f"[low, high], got {plain.value(v)}", fix="e.g. 1.3, auto or [1.0, 2.0]")


def _offset_spec(sec: Section, kind: str) -> tuple[float, ParameterSpace | None]:
    """A static offset: a signed distance; for a trilinear stop also ``auto`` (search where
    both stops are in contact) or a search interval ``[low, high]`` (signed)."""
    v = sec.raw("offset", 0.0)
    if v == "auto" or isinstance(v, list):
        if kind != "trilinear":
            raise sec.error("offset", f"only a trilinear stop's offset can be left to the data, "
                            f"got {plain.value(v)} for a {kind} element",
                            fix=("leave the clearance to the data instead (a one-sided stop's "
                                 "offset and clearance are one parameter)" if kind == "bilinear"
                                 else "give the offset as a number"))
        if v == "auto":
            return 0.0, ParameterSpace("offset")
        if len(v) == 2 and all(_is_number(x) for x in v) and v[0] < v[1]:
            return 0.0, ParameterSpace("offset", interval=(float(v[0]), float(v[1])))
        raise sec.error("offset", f"search interval {plain.value(v)} must be [low, high] with low < high",
                        fix="e.g. [-0.5, 0.5] (same length unit as the outputs)")
    return sec.number("offset", 0.0), None


def _nonlinearity(sec: Section, index: int) -> Nonlinearity:
    name = sec.string("name")
    kind = sec.string("kind", choices=KINDS)
    chs = sec.raw("channels")
    if not isinstance(chs, dict) or not chs:
        raise sec.error("channels", f"expected a mapping channel: weight, got {plain.value(chs)}",
                        fix="e.g. channels: {NC2W-Z: 1, NC2B-Z: -1}")
    for ch, w in chs.items():
        if isinstance(w, bool) or not isinstance(w, (int, float)) or w == 0:
            raise sec.error("channels", f"weight of {ch!r} must be a non-zero number, got {plain.value(w)}")
    kw: dict[str, Any] = {"name": name, "kind": kind, "channels": {str(k): float(v) for k, v in chs.items()}}
    unknown: list[ParameterSpace] = []
    if kind == "polynomial":
        kw["signed"] = sec.boolean("signed", False)
        kw["argument"] = sec.string("argument", "displacement", choices=("displacement", "velocity"))
        raw = sec.raw("exponent", 3.0)
        if raw == "auto" or isinstance(raw, list):
            cands = raw if isinstance(raw, list) else None
            if cands is not None and (len(cands) < 2 or not all(_is_number(v) and v > 0 for v in cands)):
                raise sec.error("exponent", f"expected a list of >= 2 positive exponents to "
                                f"choose from, got {plain.value(raw)}", fix="e.g. exponent: [2, 3, 5] or auto")
            if cands is not None and not kw["signed"] and not all(float(v).is_integer() for v in cands):
                raise sec.error("exponent", f"candidates {plain.value(raw)} are not all whole",
                                fix="use signed: true for |x|**(p-1) x with real exponents")
            unknown.append(ParameterSpace("exponent", candidates=None if cands is None
                                          else tuple(float(v) for v in cands)))
        else:
            kw["exponent"] = sec.number("exponent", 3.0, positive=True)
            if not kw["signed"] and not float(kw["exponent"]).is_integer():
                raise sec.error("exponent", f"exponent {kw['exponent']:g} is not whole",
                                fix="use signed: true for |x|**(p-1) x with a real exponent")
    elif kind == "trilinear":
        raw = sec.raw("clearances")
        sides = [raw, raw] if raw == "auto" else raw
        if not isinstance(sides, list) or len(sides) != 2:
            raise sec.error("clearances", f"expected 2 numbers [g_neg, g_pos] (each a distance, auto or "
                            f"[low, high]) or auto, got {plain.value(raw)}",
                            fix="e.g. clearances: [1.5, 1.3], auto, or [[1.0, 2.0], auto]")
        g = []
        for par, v in zip(("g_neg", "g_pos"), sides):
            value, space = _clearance_spec(sec, "clearances", v, par)
            g.append(value)
            if space is not None:
                unknown.append(space)
        kw["clearances"] = tuple(g)
    elif kind == "bilinear":
        value, space = _clearance_spec(sec, "clearance", sec.raw("clearance"), "clearance")
        kw["clearance"] = value
        if space is not None:
            unknown.append(space)
        kw["side"] = sec.string("side", "pos", choices=("pos", "neg"))
    elif kind == "coulomb":
        kw["velocity_scale"] = sec.number("velocity_scale", 1e-3, positive=True)
    elif kind == "jenkins":
        if not sec.has("slip"):
            raise sec.error("slip", "a jenkins element needs its slip displacement (F_s / k)",
                            fix="e.g. slip: auto (from the data) or slip: 5.0e-5 "
                            "(same length unit as the outputs)")
        value, space = _clearance_spec(sec, "slip", sec.raw("slip"), "slip")
        if space is None and not value > 0:
            raise sec.error("slip", f"expected a positive distance, got {plain.value(value)}",
                            fix="e.g. slip: auto or slip: 5.0e-5")
        kw["slip"] = value
        if space is not None:
            unknown.append(space)
    elif kind == "spline":
        for key, count in (("knots", "knot_count"), ("velocity_knots", "velocity_knot_count")):
            raw = sec.raw(key, None)
            if raw is None:
                continue
            if isinstance(raw, int) and not isinstance(raw, bool) and raw >= 1:
                kw[count] = int(raw)
            elif (isinstance(raw, list) and raw and all(_is_number(v) for v in raw)
                  and len(set(raw)) == len(raw)):
                kw[key] = tuple(float(v) for v in raw)
            else:
                raise sec.error(key, f"expected a knot count (e.g. 12) or a list of distinct "
                                f"positions, got {plain.value(raw)}",
                                fix="e.g. knots: 12 (spread over the measured range) or "
                                "knots: [-1.5, -0.5, 0.5, 1.5] (output length unit)")
        if "knot_count" not in kw and "knots" not in kw:
            raise sec.error("knots", "a spline element needs knots",
                            fix="e.g. knots: 12 (spread over the measured range)")
    kw["offset"], space = _offset_spec(sec, kind)
    if space is not None:
        if unknown:
            raise sec.error("offset", "an offset left to the data needs both clearances given "
                            "(the two contact points fix the offset only when the gaps are known)",
                            fix="give both clearances, or drop 'offset: auto': the clearances "
                            "then count from the recorded zero")
        unknown.append(space)
    kw["unknown"] = tuple(unknown)
    n_coef = 2 if kind == "trilinear" else 1
    if sec.has("truth"):
        t = sec.raw("truth")
        t = [t] if isinstance(t, (int, float)) and not isinstance(t, bool) else t
        if not isinstance(t, list) or len(t) != n_coef or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in t):
            raise sec.error("truth", f"expected {n_coef} number(s), got {plain.value(t)}")
        kw["truth"] = tuple(float(v) for v in t)
    sec.finish()
    try:
        return Nonlinearity(**kw)
    except IdentError as exc:
        raise sec.error(None, str(exc)) from None


def _auto_section(sec: Section) -> dict:
    """``auto:`` -> ``{'auto': AutoOptions, 'orders': tuple | None}`` (``orders`` is the sweep)."""
    raw = sec.raw("auto", None)
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise sec.error("auto", "must be a mapping of robust-pipeline options",
                        fix="e.g. auto: {top_n: 3, orders: '2:40'}")
    raw = dict(raw)
    orders = raw.pop("orders", None)
    try:
        out: dict = {"auto": AutoOptions.from_dict(raw)}
        if orders is not None:
            out["orders"] = tuple(parse_orders(orders))
    except (IdentError, TypeError) as exc:
        raise IdentConfigError(str(exc), file=sec.file, field="auto",
                               fix="allowed keys: orders, "
                               + ", ".join(AutoOptions.__dataclass_fields__)) from None
    return out


def _compare_linear(sec) -> bool | str:
    """``compare_linear``: true, false or auto (the default)."""
    value = sec.raw("compare_linear", "auto")
    if value not in (True, False, "auto"):
        raise sec.error("compare_linear", f"{plain.value(value)} is not allowed", fix="use true, false or auto")
    return value


def parse_ident_config(data: Any, *, file: str | None = None) -> IdentConfig:
    """Validate a parsed YAML mapping into :class:`IdentConfig`.

    Raises
    ------
    IdentConfigError
        One line naming the file, the field and the fix.
    """
    try:
        sec = Section(_coerce(data) if isinstance(data, dict) else data, file=file)
        band_lo, band_hi = sec.numbers("band_hz", length=2)
        band = (band_lo, band_hi)
        if not 0 <= band[0] < band[1]:
            raise sec.error("band_hz", f"need 0 <= f_min < f_max, got f_min {plain.number(band[0])}, f_max {plain.number(band[1])} Hz")
        nls = []
        names = set()
        auto_nl = sec.raw("nonlinearities", None) == "auto"
        for i, item in enumerate([] if auto_nl else sec.items("nonlinearities", [])):
            nl = _nonlinearity(Section(_coerce(item), file=file, prefix=f"nonlinearities[{i}]"), i)
            if nl.name in names:
                raise sec.error("nonlinearities", f"duplicate name {nl.name!r}")
            names.add(nl.name)
            nls.append(nl)
        inputs = []
        for i, item in enumerate(sec.items("inputs", [])):
            s = Section(item, file=file, prefix=f"inputs[{i}]")
            inputs.append(InputSpec(s.string("name"), s.string("driving_point", None)))
            s.finish()
        outputs = sec.raw("outputs", None)
        if outputs is not None:
            if not isinstance(outputs, list) or not all(isinstance(o, str) for o in outputs):
                raise sec.error("outputs", f"expected a list of channel names, got {plain.value(outputs)}")
            if len(set(outputs)) != len(outputs):
                raise sec.error("outputs", "duplicate channel names")
            outputs = tuple(outputs)
        order = sec.integer("order", None, minimum=1)
        max_order = sec.integer("max_order", None, minimum=1)
        if order is not None and max_order is not None and max_order < order:
            raise sec.error("max_order", f"max_order {max_order} < order {order}")
        cfg = IdentConfig(
            band_hz=band, nonlinearities=tuple(nls), inputs=tuple(inputs), outputs=outputs,
            samples_per_period=sec.integer("samples_per_period", None, minimum=2),
            transient_periods=sec.integer("transient_periods", None, minimum=0),
            output_quantity=sec.choice("output_quantity", OUTPUT_QUANTITIES, None),
            order=order, max_order=max_order,
            block_rows=sec.integer("block_rows", None, minimum=2),
            d_zero=sec.boolean("d_zero", None) if sec.raw("d_zero", None) is not None else None,
            weighting=sec.string("weighting", "auto", choices=WEIGHTINGS),
            highpass_hz=sec.number("highpass_hz", None, nonnegative=True),
            steady_state_tolerance=sec.number("steady_state_tolerance", 0.05, positive=True),
            steady_periods=sec.choice("steady_periods", ("auto", "all"), "auto"),
            time_base=sec.choice("time_base", ("auto", "band-limited", "zoh", "bilinear"),
                                 "auto"),
            bilinear_period_s=sec.number("bilinear_period_s", None, positive=True),
            basis_oversample=sec.integer("basis_oversample", 8, minimum=1),
            integration_min_snr=sec.number("integration_min_snr", 4.0, nonnegative=True),
            refine=sec.string("refine", "auto", choices=REFINEMENTS),
            compare_linear=_compare_linear(sec),
            nonlinearities_auto=auto_nl, file=file, **_auto_section(sec))
        sec.finish()
        return cfg
    except IdentConfigError:
        raise
    except ConfigError as exc:
        raise IdentConfigError(exc.reason, file=exc.file, field=exc.field, fix=exc.fix) from None


def load_ident_config(path: str | Path) -> IdentConfig:
    """Read and validate an ident YAML file (see the module docstring).

    Raises
    ------
    IdentConfigError
    """
    try:
        data, _ = load_yaml(path)
    except ConfigError as exc:
        raise IdentConfigError(exc.reason, file=exc.file, field=exc.field, fix=exc.fix) from None
    return parse_ident_config(data, file=str(path))


def packaged_config(name: str) -> Path:
    """Path of an example config shipped in ``ident/data`` (``smallsat3``, ``lumped-stop``...)."""
    p = Path(__file__).parent / "data" / (name if name.endswith(".yaml") else name + ".yaml")
    if not p.exists():
        avail = sorted(q.stem for q in p.parent.glob("*.yaml"))
        raise IdentConfigError(f"no packaged ident config {name!r}", fix=f"use one of {plain.names(avail)}")
    return p
