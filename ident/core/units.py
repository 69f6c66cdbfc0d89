"""Units of an identification's numbers, derived from the channel table.

A recording knows each channel's unit (the SmallSat: displacements in mm, force in N). The
coefficient of a basis function ``h`` multiplies ``h`` to give a force, so its unit is the
force unit over the unit of ``h``: a stop's contact stiffness is ``N/mm``, a cubic
spring's ``N/mm^3``, a viscous term's ``N s/mm``, a Coulomb force's ``N``. FRFs are output
over force (``mm/N``). Inputs without a unit table (``.npz``/``.mat`` files) are in SI
(N, m) as docs/ident.md says, and the JSON says that they were assumed.

Pure functions over strings; :func:`result_units` builds the JSON's ``units`` block and
:func:`add_coefficient_units` writes ``unit`` into every coefficient of a result dict.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from fnsi_lab.ident.core.basis import Nonlinearity

__all__ = ["length_unit", "coefficient_unit", "result_units", "add_coefficient_units",
           "SI_FORCE", "SI_LENGTH"]

SI_FORCE = "N"
SI_LENGTH = "m"
#: Time-derivative suffixes of a length unit (``mm/s``, ``m/s^2``...), longest first.
_RATE_SUFFIXES = ("/s^2", "/s²", "/s2", "/s/s", "/s")


def length_unit(unit: str, quantity: str | None) -> str:
    """The length unit under a motion channel's unit: ``mm/s`` -> ``mm``, ``m/s^2`` -> ``m``.

    Parameters
    ----------
    unit : str
        The channel's unit as recorded (empty: unknown).
    quantity : {'displacement', 'velocity', 'acceleration'} or None

    Returns
    -------
    str
        The length unit; ``m`` when ``unit`` is empty; ``unit s^2`` (e.g. ``g s^2``) for an
        acceleration unit that is not a length over time squared.
    """
    u = (unit or "").strip()
    if not u:
        return SI_LENGTH
    if quantity in (None, "displacement"):
        return u
    for suffix in _RATE_SUFFIXES:
        if u.endswith(suffix) and len(u) > len(suffix):
            return u[: -len(suffix)]
    return f"{u} s^2" if quantity == "acceleration" else f"{u} s"


def _power(base: str, exponent: float) -> str:
    e = float(exponent)
    text = f"{int(e)}" if e.is_integer() else f"{e:g}"
    if text == "1":
        return base
    return f"({base})^{text}" if "/" in base or " " in base else f"{base}^{text}"


def coefficient_unit(nl: Nonlinearity, force: str, length: str, name: str | None = None) -> str:
    """Unit of the coefficient(s) of one basis element.

    Parameters
    ----------
    nl : Nonlinearity
    force, length : str
        The input (force) unit and the outputs' length unit.

    Returns
    -------
    str
        ``force / unit(h)``: ``N/mm`` (stops, linear springs, a Jenkins element's spring), ``N/mm^3`` (cubic), ``N s/mm``
        (linear viscous), ``N s^2/mm^2`` (quadratic damping), ``N`` (Coulomb).
    """
    if nl.kind in ("trilinear", "bilinear", "jenkins"):
        return f"{force}/{length}"
    if nl.kind == "spline":   # slope changes: of force over displacement, or over velocity
        return f"{force} s/{length}" if name and ":v" in name else f"{force}/{length}"
    if nl.kind == "coulomb":
        return force
    if nl.kind == "quadratic_damping":
        return f"{force} s^2/{_power(length, 2)}"
    e = float(nl.exponent)
    if nl.argument == "velocity":
        s = _power("s", e)
        return f"{force} {s}/{_power(length, e)}"
    return f"{force}/{_power(length, e)}"


def result_units(channel_units: Mapping[str, str], input_names: Sequence[str],
                 output_names: Sequence[str], output_quantity: str | None,
                 basis: Sequence[Nonlinearity]) -> dict[str, Any]:
    """The JSON's ``units`` block.

    Parameters
    ----------
    channel_units : mapping str -> str
        Unit of each channel by name (empty mapping: none known, SI assumed).
    input_names, output_names : sequence of str
    output_quantity : str or None
    basis : sequence of Nonlinearity

    Returns
    -------
    dict
        ``force`` (inputs' unit), ``output`` (outputs' unit), ``length``, ``frf``
        (``output/force``), ``channels`` {name: unit}, ``coefficients`` {name: unit},
        ``assumed`` (True when the input carried no units and SI was assumed).
    """
    known = {k: str(v) for k, v in channel_units.items() if v}
    assumed = not known
    si_out = {"velocity": "m/s", "acceleration": "m/s^2"}.get(output_quantity or "", SI_LENGTH)
    ins = [known.get(n, SI_FORCE) for n in input_names]
    outs = [known.get(n, si_out) for n in output_names]
    force = ins[0] if ins and len(set(ins)) == 1 else (ins[0] if ins else SI_FORCE)
    output = outs[0] if outs and len(set(outs)) == 1 else (outs[0] if outs else si_out)
    length = length_unit(output, output_quantity)
    coefs = {name: coefficient_unit(nl, force, length, name)
             for nl in basis for name in nl.coefficient_names}
    return {"force": force, "output": output, "length": length, "frf": f"{output}/{force}",
            "channels": {**dict(zip(input_names, ins)), **dict(zip(output_names, outs))},
            "coefficients": coefs, "assumed": assumed}


def add_coefficient_units(result: dict, units: Mapping[str, Any]) -> dict:
    """Write ``unit`` into every coefficient entry of a result dict, in place.

    The list under the top-level ``coefficients`` key and under the ``coefficients`` key of
    every top-level block (``full_model``, ``reduced``, ``selected_model``,
    ``output_error``...): each dict with a ``name`` of the basis gets ``unit``; other
    ``coefficients`` keys (lists of names) are left alone. Call it on a copy (the JSON).

    Returns
    -------
    dict
        ``result``.
    """
    table = units.get("coefficients") or {}

    def mark(entries: Any) -> None:
        if isinstance(entries, list):
            for c in entries:
                if isinstance(c, dict) and c.get("name") in table:
                    c["unit"] = table[c["name"]]

    mark(result.get("coefficients"))
    for value in result.values():  # full_model, reduced, selected_model, output_error...
        if isinstance(value, dict):
            mark(value.get("coefficients"))
    return result
