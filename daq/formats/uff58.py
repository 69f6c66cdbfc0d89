"""Reading time records from Universal File Format dataset 58 files with pyuff.

One dataset 58 with function type 1 (time response) is one channel. What is taken from
each record:

- the channel name from ID line 1 (or ``<node>:<direction>`` like ``12:+Z`` when it is
  ``NONE``); node and direction from the response node and direction fields;
- the quantity from the ordinate's specific data type (8 displacement, 11 velocity,
  12 acceleration, 9/13 force), else from its unit label;
- the sample rate from the abscissa increment (written with six digits by most tools,
  see :func:`~fnsi_lab.daq.formats.table.rate_from_increment`) or, for uneven abscissas,
  from the abscissa values.

Other datasets in the file (units, nodes, FRFs...) are skipped and listed in the notes.
"""

from __future__ import annotations

import os

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.formats.dof import direction_from_code, quantity_from_unit
from fnsi_lab.daq.formats.errors import LabFileError
from fnsi_lab.daq.formats.table import (LabChannel, LabTable, common_rate, rate_from_increment,
                                        rate_from_times, stack_columns)

#: Ordinate specific data types of dataset 58 (record 9, field 1) that fnsi-lab knows.
UFF_DATA_TYPES = {8: "displacement", 11: "velocity", 12: "acceleration", 9: "force",
                  13: "force"}


def _text(value: object) -> str:
    text = str(value or "").strip()
    return "" if text.upper() == "NONE" else text


def read_uff58(path: str | os.PathLike[str]) -> LabTable:
    """Read the time records (dataset 58, function type 1) of a UFF file.

    Parameters
    ----------
    path : path-like
        ``.uff`` / ``.unv`` file, ASCII or binary (58b).

    Returns
    -------
    LabTable

    Raises
    ------
    LabFileError
        Not readable by pyuff, no time record, records of different lengths or sample
        rates, two records with the same name, a non-finite or complex sample.
    """
    import pyuff

    p = os.fspath(path)
    try:
        uff = pyuff.UFF(p)
        types = list(uff.get_set_types())
    except Exception as exc:  # noqa: BLE001 - any unreadable file is one message
        raise LabFileError(f"{p}: not a readable UFF file ({type(exc).__name__}: {exc})") from None
    positions = [i for i, t in enumerate(types) if int(t) == 58]
    notes = []
    other = sorted({int(t) for t in types if int(t) != 58})
    if other:
        notes.append(f"datasets {plain.names(other)} skipped (only dataset 58 time records are imported)")
    channels: list[LabChannel] = []
    columns: list[np.ndarray] = []
    rates: list[tuple[str, float]] = []
    for k, pos in enumerate(positions):
        try:
            dset = uff.read_sets(pos)
        except Exception as exc:  # noqa: BLE001
            raise LabFileError(f"{p}: dataset 58 number {k + 1} cannot be read "
                               f"({type(exc).__name__}: {exc})") from None
        if int(dset.get("func_type", -1)) != 1:
            notes.append(f"dataset 58 number {k + 1} skipped: function type "
                         f"{dset.get('func_type')} (not a time response)")
            continue
        node = int(dset.get("rsp_node", 0) or 0)
        direction = direction_from_code(int(dset.get("rsp_dir", 0) or 0))
        name = _text(dset.get("id1")) or f"{node}:{direction or 0}"
        where = f"{p}: record {name!r} (dataset 58 number {k + 1})"
        if any(c.name == name for c in channels):
            raise LabFileError(f"{where}: a second record has the same name in ID line 1 "
                               "(fix: give each channel its own name)")
        values = np.asarray(dset.get("data"))
        if np.iscomplexobj(values):
            raise LabFileError(f"{where}: ordinate data are complex; a time record is real")
        unit = _text(dset.get("ordinate_axis_units_lab"))
        quantity = UFF_DATA_TYPES.get(int(dset.get("ordinate_spec_data_type", 0) or 0))
        quantity = quantity or quantity_from_unit(unit)
        if int(dset.get("abscissa_spacing", 1)) == 1:
            rates.append((name, rate_from_increment(float(dset.get("abscissa_inc", 0.0)),
                                                    path=p, field=f"record {name!r}: abscissa "
                                                                  "increment")))
        else:
            rates.append((name, rate_from_times(np.asarray(dset.get("x"), float), path=p,
                                                field=f"record {name!r}: abscissa")))
        channels.append(LabChannel(name=name, unit=unit, quantity=quantity,
                                   node=str(node) if node else "", direction=direction))
        columns.append(np.asarray(values, dtype=np.float64))
    if not columns:
        raise LabFileError(f"{p}: no time record (dataset 58 with function type 1) in the file "
                           f"(datasets found: {plain.names(sorted({int(t) for t in types}))})")
    names = [c.name for c in channels]
    rate = common_rate(rates, path=p, kind="record")
    data = stack_columns(columns, names, path=p, kind="record")
    return LabTable(path=p, format="uff58", data=data, channels=tuple(channels),
                    sample_rate_hz=rate, properties={"datasets": len(types)},
                    notes=tuple(notes))
