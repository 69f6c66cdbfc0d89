"""The campaign table: one row per input, written to and read from Parquet.

Columns, in this order:

==================  =======  ==========================================================
``file``            string   the input as given on the command line
``status``          string   ``ok``, ``error`` or ``skipped`` (result reused on resume)
``error``           string   one-line reason when ``status='error'``, else null
``worker``          string   address of the Dask worker that identified it
``order``           int64    order of the final model
``n_modes``         int64    physical modes of the final model
``force_rms``       float64  excitation level of the recording (null when not recorded)
``wall_time_s``     float64  time the identification of this input took
``input_sha256``    string   content hash of the input (resume key)
``result``          string   its JSON result, relative to the table's folder
``force_unit``      string   unit of ``force_rms`` (the force channel's, e.g. ``N``)
``<name>``          float64  each nonlinear coefficient: mean of its real part over the band
``<name>:std``      float64  its spread (standard deviation of the real part over the band)
``<name>:contact``  float64  fraction of time the matching stop was closed (simulated
                             recordings only)
``<name>:unit``     string   unit of ``<name>`` and ``<name>:std`` (``coefficients[].unit``
                             of the JSON result, e.g. ``N/mm``)
==================  =======  ==========================================================

The numeric columns with a unit also carry it in their Arrow field metadata (``unit``:
``s`` for ``wall_time_s``, the force unit for ``force_rms``, the coefficient's unit for
``<name>`` and ``<name>:std``, ``1`` for ``<name>:contact``) when every row agrees.

The table's schema metadata ``fnsi_lab.campaign`` holds the campaign settings (config,
its hash, the order choice): ``fnsi-lab batch`` only rewrites a Parquet file that carries
it, and ``fnsi-lab campaign`` reads it back.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from fnsi_lab.errors import DataFileError
from fnsi_lab.outputs import atomic_output, dumps


@dataclass(frozen=True)
class PlannedInput:
    """One input of the campaign and where its result goes."""

    path: Path
    sha256: str
    result_path: Path


#: Schema metadata key of a campaign table.
METADATA_KEY = b"fnsi_lab.campaign"

#: Leading columns and their Arrow types (names of the pyarrow type factories).
FIXED_COLUMNS: dict[str, str] = {
    "file": "string", "status": "string", "error": "string", "worker": "string",
    "order": "int64", "n_modes": "int64", "force_rms": "float64", "wall_time_s": "float64",
    "input_sha256": "string", "result": "string", "force_unit": "string",
}

#: Suffixes of the per-coefficient columns (``<name><suffix>``); ``<name>`` alone is the mean.
COEFFICIENT_SUFFIXES = (":std", ":contact", ":unit")

STATUSES = ("ok", "error", "skipped")


def physical_modes(result: Mapping[str, Any]) -> list[dict]:
    """The modes of a result: ``modes`` (robust pipeline), else its stable ``poles``."""
    modes = result.get("modes")
    if isinstance(modes, list):
        return modes
    return [p for p in result.get("poles") or [] if p.get("stable", True)]


def result_row(result: Mapping[str, Any], item: "PlannedInput", *, status: str) -> dict[str, Any]:
    """The table row of one identified input.

    Parameters
    ----------
    result : dict
        Its JSON result (``fnsi-lab ident --json`` plus the ``campaign`` section).
    item : PlannedInput
    status : {'ok', 'skipped'}
    """
    meta = result.get("campaign") or {}
    units = result.get("units") or {}
    row: dict[str, Any] = {
        "file": str(item.path), "status": status, "error": None,
        "worker": meta.get("worker"), "order": result.get("order"),
        "n_modes": len(physical_modes(result)), "force_rms": meta.get("force_rms"),
        "wall_time_s": meta.get("wall_time_s"), "input_sha256": item.sha256,
        "result": str(item.result_path),
        "force_unit": units.get("force") if meta.get("force_rms") is not None else None,
    }
    contact = meta.get("contact_fraction") or {}
    for c in result.get("coefficients") or []:
        name = str(c["name"])
        row[name] = c.get("mean_real")
        row[f"{name}:std"] = c.get("std_real")
        if name in contact:
            row[f"{name}:contact"] = contact[name]
        unit = c.get("unit") or (units.get("coefficients") or {}).get(name)
        if unit:
            row[f"{name}:unit"] = str(unit)
    return row


def error_row(item: "PlannedInput", *, worker: str, error: str) -> dict[str, Any]:
    """The table row of an input that could not be identified."""
    return {"file": str(item.path), "status": "error", "error": error, "worker": worker,
            "input_sha256": item.sha256, "result": None}


def coefficient_names(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Coefficient names found in ``rows``, in order of first appearance."""
    names: dict[str, None] = {}
    for row in rows:
        for key in row:
            if key not in FIXED_COLUMNS and not key.endswith(COEFFICIENT_SUFFIXES):
                names.setdefault(key, None)
    return list(names)


def write_table(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike[str],
                settings: Mapping[str, Any]) -> None:
    """Write the campaign table (atomically) with ``settings`` as schema metadata.

    Result paths are stored relative to the table's folder, so the folder can be moved.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    folder = Path(path).resolve().parent
    columns: dict[str, Any] = {}
    for name, kind in FIXED_COLUMNS.items():
        values = [row.get(name) for row in rows]
        if name == "result":
            values = [None if v is None else os.path.relpath(Path(v).resolve(), folder)
                      for v in values]
        columns[name] = pa.array(values, type=getattr(pa, kind)())
    field_units = {"wall_time_s": "s", "force_rms": _common(rows, "force_unit")}
    for name in coefficient_names(rows):
        unit = _common(rows, f"{name}:unit")
        for col in (name, f"{name}:std", f"{name}:contact"):
            values = [row.get(col) for row in rows]
            if col == name or any(v is not None for v in values):
                columns[col] = pa.array([None if v is None else float(v) for v in values],
                                        type=pa.float64())
                field_units[col] = "1" if col.endswith(":contact") else unit
        units = [row.get(f"{name}:unit") for row in rows]
        if any(u is not None for u in units):
            columns[f"{name}:unit"] = pa.array(units, type=pa.string())
    schema = pa.schema([pa.field(col, array.type,
                                 metadata={b"unit": field_units[col].encode()}
                                 if field_units.get(col) else None)
                        for col, array in columns.items()],
                       metadata={METADATA_KEY: dumps(settings).encode()})
    table = pa.table(columns, schema=schema)
    with atomic_output(path, "wb") as fh:
        pq.write_table(table, fh)


def _common(rows: Sequence[Mapping[str, Any]], key: str) -> str | None:
    """The one value of ``key`` over the rows that have it (None when none or several)."""
    values = {str(row[key]) for row in rows if row.get(key) is not None}
    return values.pop() if len(values) == 1 else None


def is_campaign_table(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a Parquet file written by :func:`write_table`."""
    import pyarrow.parquet as pq

    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, ValueError):
        return False
    return METADATA_KEY in metadata


def read_table(path: str | os.PathLike[str]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Rows (result paths made absolute) and campaign settings of a campaign table.

    Raises
    ------
    DataFileError
        Not a readable Parquet file, or not a campaign table.
    """
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (OSError, ValueError) as exc:
        raise DataFileError(f"{path}: not a readable Parquet file ({_first_line(exc)}) "
                            "(fix: give the --out of fnsi-lab batch)") from None
    metadata = table.schema.metadata or {}
    if METADATA_KEY not in metadata:
        raise DataFileError(f"{path}: not a campaign table (no fnsi_lab.campaign metadata) "
                            "(fix: give the --out of fnsi-lab batch)")
    folder = Path(path).resolve().parent
    rows = table.to_pylist()
    for row in rows:
        if row.get("result"):
            row["result"] = str(folder / row["result"])
    return rows, json.loads(metadata[METADATA_KEY])


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [type(exc).__name__])[0]
