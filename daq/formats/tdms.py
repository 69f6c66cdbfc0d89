"""Reading NI TDMS files (LabVIEW, DAQmx loggers) with npTDMS.

What is taken from the file:

- every numeric channel of every group (a channel name present in two groups becomes
  ``group/channel``); npTDMS applies DAQmx raw-data scaling;
- the unit from the channel property ``unit_string`` (LabVIEW's standard property);
- the sample rate from ``wf_increment`` (waveform channels), else from a time channel
  (name ``time``/``t``, unit ``s``) which is then not imported;
- ``samples_per_period`` and ``transient_periods`` from channel, group or file
  properties of those names, when present.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.formats.dof import parse_node_direction, quantity_from_unit
from fnsi_lab.daq.formats.errors import LabFileError
from fnsi_lab.daq.formats.table import (LabChannel, LabTable, common_rate, rate_from_increment,
                                        rate_from_times, stack_columns)

_TIME_NAMES = {"time", "t", "time_s", "zeit"}


def _where(obj: Any) -> str:
    """'the file' or 'group NAME', for messages."""
    is_group = hasattr(obj, "channels") and hasattr(obj, "name")
    return f"group {obj.name!r}" if is_group else "the file"


def _integer_property(objects: list[Any], key: str, path: str) -> int | None:
    """First ``key`` property (case-insensitive) found on ``objects``, as a positive int."""
    for obj in objects:
        for name, value in obj.properties.items():
            if name.lower() != key:
                continue
            try:
                number = int(value)
            except (TypeError, ValueError):
                raise LabFileError(f"{path}: property {name!r} of {_where(obj)}: {plain.value(value)} is "
                                   "not a whole number (fix: correct the file or give the option "
                                   f"--{key.replace('_', '-')})") from None
            if number < 0 or number != float(value):
                raise LabFileError(f"{path}: property {name!r} of {_where(obj)}: {plain.value(value)} is "
                                   "not a whole number >= 0")
            return number
    return None


def read_tdms(path: str | os.PathLike[str]) -> LabTable:
    """Read the channels of a TDMS file.

    Parameters
    ----------
    path : path-like
        The ``.tdms`` file (its ``.tdms_index`` is used when present).

    Returns
    -------
    LabTable

    Raises
    ------
    LabFileError
        Not a TDMS file, no numeric channel, channels of different lengths or sample
        rates, a non-finite sample.
    """
    from nptdms import TdmsFile

    p = os.fspath(path)
    try:
        tdms = TdmsFile.read(p)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is one message
        raise LabFileError(f"{p}: not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    found = [(g, c) for g in tdms.groups() for c in g.channels()]
    counts: dict[str, int] = {}
    for _, c in found:
        counts[c.name] = counts.get(c.name, 0) + 1
    columns: list[np.ndarray] = []
    channels: list[LabChannel] = []
    rates: list[tuple[str, float]] = []
    time_column: tuple[str, np.ndarray] | None = None
    notes: list[str] = []
    for group, ch in found:
        name = ch.name if counts[ch.name] == 1 else f"{group.name}/{ch.name}"
        values = ch[:]
        if values.dtype.kind not in "fiu":
            notes.append(f"channel {name!r} skipped: {values.dtype} data")
            continue
        unit = str(ch.properties.get("unit_string", "") or "").strip()
        if ch.name.strip().lower() in _TIME_NAMES and unit in ("s", ""):
            time_column = (name, np.asarray(values, float))
            continue
        if "wf_increment" in ch.properties:
            rates.append((name, rate_from_increment(float(ch.properties["wf_increment"]), path=p,
                                                    field=f"channel {name!r}: wf_increment")))
        where = parse_node_direction(name)
        channels.append(LabChannel(name=name, unit=unit, quantity=quantity_from_unit(unit),
                                   node=where[0] if where else "",
                                   direction=where[1] if where else ""))
        columns.append(np.asarray(values, dtype=np.float64))
    if not columns:
        raise LabFileError(f"{p}: no numeric channel in the TDMS file (groups: "
                           f"{plain.names([g.name for g in tdms.groups()])})")
    names = [c.name for c in channels]
    data = stack_columns(columns, names, path=p, kind="channel")
    rate = common_rate(rates, path=p, kind="channel")
    if rate is None and time_column is not None:
        rate = rate_from_times(time_column[1], path=p,
                               field=f"time channel {time_column[0]!r}")
    scopes = [tdms] + list(tdms.groups())
    return LabTable(
        path=p, format="tdms", data=data, channels=tuple(channels), sample_rate_hz=rate,
        samples_per_period=_integer_property(scopes, "samples_per_period", p),
        transient_periods=_integer_property(scopes, "transient_periods", p),
        properties={"groups": [g.name for g in tdms.groups()],
                    "file_properties": {k: str(v) for k, v in tdms.properties.items()}},
        notes=tuple(notes))
