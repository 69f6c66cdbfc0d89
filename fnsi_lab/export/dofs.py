"""Channel -> UFF degree of freedom (integer node, signed direction code).

UFF files address a measurement by an integer node number and a direction code. A
channel named like ``NC2-Z`` or ``12:+X`` says both (:func:`fnsi_lab.daq.formats.dof.
parse_node_direction`); node labels that are not integers (``NC2``) are numbered 1, 2, ...
in order of appearance, skipping the numbers that integer labels already use. Channels
whose names do not say (``X1``, ``F-X3``) or say another node than meant (a force named
``F-NC2W-Z`` acts at node ``NC2W``, not ``F-NC2W``) take node and direction from the
recording's channel table (:func:`channel_table_mapping`; a UFF 58 import keeps the
response node and direction there) or from a mapping, ``NAME=NODE:DIR`` (``--map``) or a
CSV file of ``channel,node,direction`` rows (``--map-file``); NODE is a number or a label.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from fnsi_lab.daq.formats.dof import direction_code, parse_node_direction
from fnsi_lab.errors import ConfigError


@dataclass(frozen=True)
class Dof:
    """Where one channel measures, in UFF terms.

    Attributes
    ----------
    channel : str
    node_label : str
        The node as the channel name or the mapping gives it (``NC2``, ``12``).
    node : int
        UFF node number.
    direction : str
        Signed direction, ``+X`` ... ``-RZ``.
    code : int
        UFF direction code (``+Z`` = 3, ``-X`` = -1, rotations 4..6).
    """

    channel: str
    node_label: str
    node: int
    direction: str
    code: int


def _parse_target(text: str, *, source: str, channel: str) -> tuple[str, str]:
    node, sep, direction = text.partition(":")
    if not sep or not node.strip() or not direction.strip():
        raise ConfigError(f"{channel}={text!r} is not NODE:DIR", file=source or None,
                          field="--map", fix="write e.g. X1=101:+Z")
    try:
        direction_code(direction)
    except ValueError as exc:
        raise ConfigError(str(exc), file=source or None, field=f"--map {channel}",
                          fix="use X, Y, Z, RX, RY or RZ with an optional sign") from None
    node, direction = node.strip(), direction.strip().upper()
    if node.lstrip("+-").isdigit() and int(node) < 1:
        raise ConfigError(f"node {node!r} of channel {channel!r} is not a positive number",
                          file=source or None, field=f"--map {channel}",
                          fix="UFF nodes are numbered from 1: write e.g. X1=101:+Z")
    return node, ("-" if direction.startswith("-") else "+") + direction.lstrip("+-")


def parse_mapping(items: Sequence[str]) -> dict[str, tuple[str, str]]:
    """``["X1=101:+Z", "F-NC2W-Z=NC2W:+Z"]`` -> ``{"X1": ("101", "+Z"), ...}``.

    A node is a UFF node number or a label (numbered like the labels of channel names, so
    ``NC2W`` is the node of the channel ``NC2W-Z``).

    Raises
    ------
    ConfigError
        An item that is not ``NAME=NODE:DIR``, a node number below 1, an unknown direction.
    """
    out: dict[str, tuple[str, str]] = {}
    for item in items:
        name, sep, target = item.rpartition("=")
        if not sep or not name.strip():
            raise ConfigError(f"{item!r} is not NAME=NODE:DIR", field="--map",
                              fix="write e.g. --map X1=101:+Z")
        out[name.strip()] = _parse_target(target.strip(), source="", channel=name.strip())
    return out


def read_mapping_file(path: str | os.PathLike[str]) -> dict[str, tuple[str, str]]:
    """Read ``channel,node,direction`` rows (a header row naming those columns is allowed).

    Raises
    ------
    ConfigError
        Missing file, a row without three values, a bad node or direction (row named).
    """
    p = os.fspath(path)
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise ConfigError(f"cannot read ({exc.strerror or exc})", file=p,
                          fix="give a CSV file of channel,node,direction rows") from None
    out: dict[str, tuple[str, str]] = {}
    for i, row in enumerate(rows, 1):
        cells = [c.strip() for c in row]
        if not any(cells) or cells[0].startswith("#"):
            continue
        if i == 1 and [c.lower() for c in cells[:3]] == ["channel", "node", "direction"]:
            continue
        if len(cells) < 3:
            raise ConfigError(f"row {i} has {len(cells)} values", file=p, field=f"row {i}",
                              fix="write channel,node,direction (e.g. X1,101,+Z)")
        out[cells[0]] = _parse_target(f"{cells[1]}:{cells[2]}", source=p, channel=cells[0])
    return out


def channel_table_mapping(channels: Sequence[Any]) -> dict[str, tuple[str, str]]:
    """Node and signed direction of the channels of a recording's channel table.

    Parameters
    ----------
    channels : sequence of ChannelInfo
        ``name``, ``node``, ``direction`` (``Z`` or ``+Z``...).

    Returns
    -------
    dict of str to (node, direction)
        Channels with a node and a known direction only (the others are left to their
        names or an explicit mapping).
    """
    out: dict[str, tuple[str, str]] = {}
    for c in channels:
        node, direction = str(c.node).strip(), str(c.direction).strip().upper()
        if not node or not direction:
            continue
        signed = direction if direction[:1] in "+-" else "+" + direction
        try:
            direction_code(signed)
        except ValueError:
            continue
        out[str(c.name)] = (node, signed)
    return out


def assign_dofs(outputs: Sequence[str], inputs: Sequence[str] = (),
                mapping: Mapping[str, tuple[str, str]] | None = None
                ) -> tuple[list[Dof], list[Dof]]:
    """Node number and direction of each output and input channel.

    Parameters
    ----------
    outputs, inputs : sequence of str
        Channel names; nodes are numbered once over both. An input may sit on the DOF of
        an output (driving point).
    mapping : dict of str to (node, direction), optional
        Explicit DOFs; they win over the names.

    Returns
    -------
    output_dofs, input_dofs : list of Dof
        In the order of ``outputs`` and ``inputs``.

    Raises
    ------
    ConfigError
        Channels whose names do not say node and direction and that are not mapped (all
        of them named), a mapping entry for no channel, two outputs (or two inputs) on
        the same DOF.
    """
    channels = list(outputs) + list(inputs)
    mapping = dict(mapping or {})
    unknown = [n for n in mapping if n not in channels]
    if unknown:
        raise ConfigError(f"no channel named {unknown[0]!r} in the result",
                          field="--map", fix=f"channels: {', '.join(channels)}")
    labelled: list[tuple[str, str, str]] = []
    missing = []
    for name in channels:
        where = mapping.get(name) or parse_node_direction(name)
        if where is None:
            missing.append(name)
        else:
            labelled.append((name, where[0], where[1]))
    if missing:
        raise ConfigError(f"the names of {', '.join(missing)} do not say node and direction",
                          field="--map",
                          fix=f"map them, e.g. --map {missing[0]}=1:+Z, or --map-file dofs.csv")
    numbers: dict[str, int] = {}
    used = {int(label) for _, label, _ in labelled if label.isdigit() and int(label) > 0}
    next_free = 1
    for _, label, _ in labelled:
        if label in numbers:
            continue
        if label.isdigit() and int(label) > 0:
            numbers[label] = int(label)
            continue
        while next_free in used:
            next_free += 1
        numbers[label] = next_free
        used.add(next_free)
    dofs = [Dof(channel=n, node_label=label, node=numbers[label], direction=d,
                code=direction_code(d)) for n, label, d in labelled]
    n_out = len(outputs)
    for group in (dofs[:n_out], dofs[n_out:]):
        seen: dict[tuple[int, int], str] = {}
        for d in group:
            key = (d.node, abs(d.code))
            if key in seen:
                raise ConfigError(f"channels {seen[key]!r} and {d.channel!r} are both node "
                                  f"{d.node} direction {d.direction.lstrip('+-')}",
                                  field="--map", fix="map one of them to another node or "
                                                     "direction")
            seen[key] = d.channel
    return dofs[:n_out], dofs[n_out:]
