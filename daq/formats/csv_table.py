"""Reading time data from CSV / delimited text files.

Layout (what spreadsheet and DAQ exports write)::

    # sample_rate_hz: 1000          <- optional '# key: value' lines (also fs,
    # samples_per_period: 8192         samples_per_period, transient_periods)
    time [s],F-X3 [N],X1 [m],X2 [m] <- header: names, unit in [..] or (..) optional
    0.000,0.51,1.2e-5,3.1e-6
    ...

- delimiter ``,``, ``;``, tab or spaces, detected from the header line; with ``;`` or a
  tab a decimal comma (``1,25``) is accepted;
- a second header line of units (no number in it) is accepted instead of units in the
  names;
- a first column named ``time``/``t`` (unit s or none) gives the sample rate and is not
  imported; without it the rate comes from ``# sample_rate_hz`` or ``--fs``.
"""

from __future__ import annotations

import os
import re

import numpy as np

from fnsi_lab.daq.formats.dof import parse_node_direction, quantity_from_unit
from fnsi_lab.daq.formats.errors import LabFileError
from fnsi_lab.daq.formats.table import LabChannel, LabTable, rate_from_times, require_finite

_UNIT_RE = re.compile(r"^(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")
_TIME_NAMES = {"time", "t", "time_s", "zeit"}
_KEYS = {"sample_rate_hz": "sample_rate_hz", "fs": "sample_rate_hz",
         "sample_rate": "sample_rate_hz", "samples_per_period": "samples_per_period",
         "transient_periods": "transient_periods"}


def _split(line: str, delimiter: str | None) -> list[str]:
    return [c.strip().strip('"') for c in (line.split(delimiter) if delimiter else line.split())]


def _is_number(text: str, decimal_comma: bool = False) -> bool:
    try:
        float(text.replace(",", ".") if decimal_comma else text)
    except ValueError:
        return False
    return True


def _name_unit(cell: str) -> tuple[str, str]:
    m = _UNIT_RE.match(cell)
    return (m.group("name").strip(), m.group("unit").strip()) if m else (cell.strip(), "")


def read_csv(path: str | os.PathLike[str]) -> LabTable:
    """Read a delimited text file of equally sampled channels.

    Parameters
    ----------
    path : path-like
        ``.csv``, ``.txt`` or ``.tsv`` file (layout in the module docstring).

    Returns
    -------
    LabTable

    Raises
    ------
    LabFileError
        No header, duplicate or empty names, a row of the wrong width, a cell that is not
        a number (row and column named), an unequally spaced time column.
    """
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise LabFileError(f"{p}: cannot read the file ({exc})") from None
    header: dict[str, float] = {}
    start = 0
    for start, line in enumerate(lines):  # noqa: B007 - start is used after the loop
        text = line.strip()
        if not text:
            continue
        if not text.startswith("#"):
            break
        m = re.match(r"#\s*([A-Za-z_ ]+?)\s*[:=]\s*(\S+)", text)
        if m and m.group(1).strip().lower().replace(" ", "_") in _KEYS:
            key = _KEYS[m.group(1).strip().lower().replace(" ", "_")]
            if not _is_number(m.group(2)):
                raise LabFileError(f"{p}: line {start + 1}: {m.group(1).strip()} = "
                                   f"{m.group(2)!r} is not a number")
            header[key] = float(m.group(2))
    else:
        raise LabFileError(f"{p}: no header line (fix: the first line that is not a '#' comment "
                           "must name the channels, e.g. 'time [s],F1 [N],X1 [m]')")
    head = lines[start]
    delimiter = next((d for d in ("\t", ";", ",") if d in head), None)
    # decimal commas where the comma is not the delimiter (spreadsheet exports with ';')
    comma = delimiter in (";", "\t")
    cells = _split(head, delimiter)
    if all(_is_number(c, comma) for c in cells if c):
        raise LabFileError(f"{p}: line {start + 1} holds numbers, not channel names (fix: add a "
                           "header line naming the channels, e.g. 'F1 [N],X1 [m]')")
    names, units = zip(*(_name_unit(c) for c in cells))
    names, units = list(names), list(units)
    body = start + 1
    units_line = False
    if body < len(lines):
        # a units line holds no number (read with the file's decimal separator: with
        # decimal commas, the first data row is not a units line)
        second = _split(lines[body], delimiter)
        if len(second) == len(names) and not any(_is_number(c, comma) for c in second if c):
            units = [u or s for u, s in zip(units, second)]
            body += 1
            units_line = True
    for j, n in enumerate(names):
        if not n:
            raise LabFileError(f"{p}: line {start + 1}: column {j + 1} has no name")
        if names.index(n) != j:
            raise LabFileError(f"{p}: line {start + 1}: two columns are named {n!r} (fix: give "
                               "each channel its own name)")
    rows = [ln for ln in lines[body:] if ln.strip() and not ln.lstrip().startswith("#")]
    if comma:
        rows = [ln.replace(",", ".") for ln in rows]  # decimal comma of ';' exports
    try:
        data = np.loadtxt(rows, delimiter=delimiter, dtype=np.float64, ndmin=2)
    except ValueError:
        _raise_bad_cell(p, lines, body, delimiter, names)
        raise  # pragma: no cover - _raise_bad_cell always raises
    if data.shape[0] == 0:
        raise LabFileError(f"{p}: no data rows after the header")
    if data.shape[0] != len(rows):  # every data line is a row, or the file is refused
        raise LabFileError(f"{p}: {data.shape[0]} rows read from {len(rows)} data lines "
                           "(fix: one row of numbers per line, no comment after the values)")
    if data.shape[1] != len(names):
        raise LabFileError(f"{p}: {data.shape[1]} columns of data but {len(names)} names in "
                           f"line {start + 1}")
    require_finite(data, names, path=p, kind="column")
    rate = header.get("sample_rate_hz")
    first = names[0].lower()
    notes = [f"line {start + 2} read as the channels' units"] if units_line else []
    if first in _TIME_NAMES and units[0] in ("s", ""):
        if data.shape[0] >= 2:
            time_rate = rate_from_times(data[:, 0], path=p, field=f"column {names[0]!r}")
            if rate is not None and abs(time_rate - rate) > 1e-6 * rate:
                raise LabFileError(f"{p}: column {names[0]!r} gives {time_rate:.9g} Hz but "
                                   f"'# sample_rate_hz' says {rate:.9g} Hz")
            rate = time_rate
        data, names, units = data[:, 1:], names[1:], units[1:]
        notes.append(f"column {first!r} used as the time axis")
    if not names:
        raise LabFileError(f"{p}: no channel besides the time column")
    channels = []
    for n, u in zip(names, units):
        where = parse_node_direction(n)
        channels.append(LabChannel(name=n, unit=u, quantity=quantity_from_unit(u),
                                   node=where[0] if where else "",
                                   direction=where[1] if where else ""))
    integers = {}
    for key in ("samples_per_period", "transient_periods"):
        if key in header:
            value = header[key]
            if value != int(value) or value < 0:
                raise LabFileError(f"{p}: '# {key}' = {value:g} is not a whole number >= 0")
            integers[key] = int(value)
    return LabTable(path=p, format="csv", data=np.ascontiguousarray(data),
                    channels=tuple(channels), sample_rate_hz=rate,
                    samples_per_period=integers.get("samples_per_period"),
                    transient_periods=integers.get("transient_periods"),
                    properties={"delimiter": delimiter or "whitespace"}, notes=tuple(notes))


def _raise_bad_cell(path: str, lines: list[str], body: int, delimiter: str | None,
                    names: list[str]) -> None:
    """Find the first cell that is not a number and raise naming its line and column."""
    for i in range(body, len(lines)):
        line = lines[i]
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = _split(line, delimiter)
        if len(cells) != len(names):
            raise LabFileError(f"{path}: line {i + 1} has {len(cells)} values for "
                               f"{len(names)} columns")
        for name, cell in zip(names, cells):
            if not _is_number(cell, delimiter in (";", "\t")):
                raise LabFileError(f"{path}: line {i + 1}, column {name!r}: {cell!r} is not a "
                                   "number")
    raise LabFileError(f"{path}: the data cannot be read as numbers")
