"""Degrees of freedom and units of lab files: node/direction from channel names, UFF codes.

Channel names in test labs usually say where the sensor sits: ``NC2-Z``, ``12:+X``,
``P7_Y``, ``acc3 -Z``. :func:`parse_node_direction` splits such a name into a node label
and a signed direction; the Universal File Format stores the same as an integer node and a
direction code (``1..3`` = ``+X..+Z`` translations, ``4..6`` rotations, negative = minus
direction), converted by :func:`direction_code` / :func:`direction_from_code`.
:func:`quantity_from_unit` tells the physical quantity of a channel from its unit text.
"""

from __future__ import annotations

import re

#: UFF direction code of each direction (record 6 of dataset 58, node columns of 55).
DIRECTION_CODES: dict[str, int] = {"X": 1, "Y": 2, "Z": 3, "RX": 4, "RY": 5, "RZ": 6}
_CODE_NAMES = {v: k for k, v in DIRECTION_CODES.items()}

# node, a separator (-, _, :, space or a dot), optional sign, direction at the end.
_NAME_RE = re.compile(r"^(?P<node>.*?[^-_:.\s+])[-_:.\s]\s*(?P<sign>[+-]?)(?P<dir>R?[XYZ])$",
                      re.IGNORECASE)

_FORCE_UNITS = {"n", "kn", "mn", "lbf", "kgf"}
_DISPLACEMENT_UNITS = {"m", "mm", "um", "µm", "μm", "nm", "cm", "in", "mil", "ft"}
_VELOCITY_UNITS = {f"{d}/s" for d in _DISPLACEMENT_UNITS} | {"ips"}
_ACCELERATION_UNITS = ({f"{d}/s^2" for d in _DISPLACEMENT_UNITS}
                       | {f"{d}/s2" for d in _DISPLACEMENT_UNITS}
                       | {f"{d}/s²" for d in _DISPLACEMENT_UNITS}
                       | {f"{d}/s/s" for d in _DISPLACEMENT_UNITS}
                       | {"g", "gn", "g0"})


def parse_node_direction(name: str) -> tuple[str, str] | None:
    """Node label and signed direction encoded in a channel name.

    Parameters
    ----------
    name : str
        Channel name such as ``NC2-Z``, ``12:+X``, ``P7_-Y`` or ``hub RZ``.

    Returns
    -------
    (node, direction) or None
        ``direction`` is ``+X``, ``-Z``, ``+RY``...; None when the name does not end in a
        direction after a separator.

    Examples
    --------
    >>> parse_node_direction("NC2-Z")
    ('NC2', '+Z')
    >>> parse_node_direction("12:-x")
    ('12', '-X')
    """
    m = _NAME_RE.match(name.strip())
    if m is None:
        return None
    return m.group("node"), (m.group("sign") or "+") + m.group("dir").upper()


def direction_code(direction: str) -> int:
    """UFF code of a signed direction (``+Z`` -> 3, ``-RX`` -> -4).

    Raises
    ------
    ValueError
        Not one of X, Y, Z, RX, RY, RZ with an optional sign.
    """
    text = direction.strip().upper()
    sign = -1 if text.startswith("-") else 1
    code = DIRECTION_CODES.get(text.lstrip("+-"))
    if code is None:
        raise ValueError(f"direction {direction!r} is not one of X, Y, Z, RX, RY, RZ "
                         "(with an optional + or - sign)")
    return sign * code


def direction_from_code(code: int) -> str:
    """Signed direction of a UFF code (3 -> ``+Z``); empty for 0 (scalar) or unknown codes."""
    name = _CODE_NAMES.get(abs(int(code)))
    if name is None:
        return ""
    return ("-" if code < 0 else "+") + name


def _normalise_unit(unit: str) -> str:
    text = unit.strip().lower().replace(" ", "").replace("**", "^")
    return text.replace("sec", "s").replace("meter", "m").replace("metre", "m")


def quantity_from_unit(unit: str) -> str | None:
    """Physical quantity of a channel from its unit text.

    Returns
    -------
    {'force', 'displacement', 'velocity', 'acceleration'} or None
        None when the unit is empty or says nothing (``V``, ``mV/g`` ...).
    """
    u = _normalise_unit(unit)
    if u in _FORCE_UNITS:
        return "force"
    if u in _DISPLACEMENT_UNITS:
        return "displacement"
    if u in _VELOCITY_UNITS:
        return "velocity"
    if u in _ACCELERATION_UNITS:
        return "acceleration"
    return None
