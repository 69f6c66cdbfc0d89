"""CSV tables of an identification result: modes, mode shapes, coefficients and spectra.

Numbers are written with Python's shortest round-trip text (every digit of the double),
NaN as an empty cell. Files are written atomically (:func:`fnsi_lab.outputs.atomic_output`).
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from fnsi_lab.export.dofs import Dof
from fnsi_lab.export.result import ResultArrays
from fnsi_lab.outputs import atomic_output

#: File names written into the ``--csv`` folder.
CSV_FILES = ("modes.csv", "mode_shapes.csv", "coefficients.csv", "coefficient_spectra.csv")


def _cell(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    if isinstance(value, (float, np.floating)):
        return repr(float(value)) if math.isfinite(value) else ""
    if isinstance(value, (int, np.integer)):
        return int(value)
    return "" if value is None else value


def write_csv(path: str | os.PathLike[str], header: Sequence[str],
              rows: Iterable[Sequence[Any]]) -> None:
    """Write ``header`` and ``rows`` to ``path`` atomically."""
    with atomic_output(path, "w", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([_cell(v) for v in row])


def _scalar_keys(rows: Sequence[dict], first: Sequence[str]) -> list[str]:
    keys = list(first)
    for row in rows:
        for k, v in row.items():
            if k not in keys and (v is None or isinstance(v, (int, float, str, bool))):
                keys.append(k)
    return keys


def write_tables(folder: str | os.PathLike[str], result: ResultArrays,
                 output_dofs: Sequence[Dof] | None = None) -> list[Path]:
    """Write the CSV tables of ``result`` into ``folder`` (which must exist).

    Files
    -----
    ``modes.csv``
        ``mode, frequency_hz, damping_ratio, stable`` and the other scalar fields of
        each mode in the result.
    ``mode_shapes.csv``
        One row per mode and output: ``mode, channel, node, direction, re, im,
        magnitude, phase_deg`` (node and direction empty without DOFs).
    ``coefficients.csv``
        The coefficient summaries (every scalar field; ``unit`` second when the result
        records units), when the result has any.
    ``coefficient_spectra.csv``
        ``frequency_hz, excited`` and ``<name>_re [unit], <name>_im [unit]`` per
        coefficient (``<name>_re`` without a unit for results that record none), when the
        result has the spectra.

    Returns
    -------
    list of Path
        The files written.
    """
    out = Path(folder)
    written = []
    rows = [dict(r, mode=k + 1, frequency_hz=float(result.frequency_hz[k]),
                 damping_ratio=float(result.damping_ratio[k]), stable=bool(result.stable[k]))
            for k, r in enumerate(result.mode_rows)]
    keys = _scalar_keys(rows, ["mode", "frequency_hz", "damping_ratio", "stable"])
    write_csv(out / "modes.csv", keys, ([r.get(k) for k in keys] for r in rows))
    written.append(out / "modes.csv")
    by_channel = {d.channel: d for d in output_dofs or ()}
    shape_rows = []
    for k, shape in enumerate(result.shapes):
        for name, value in zip(result.outputs, shape):
            dof = by_channel.get(name)
            shape_rows.append([k + 1, name, dof.node if dof else "", dof.direction if dof else "",
                               value.real, value.imag, abs(value),
                               math.degrees(math.atan2(value.imag, value.real))])
    write_csv(out / "mode_shapes.csv", ["mode", "channel", "node", "direction", "re", "im",
                                        "magnitude", "phase_deg"], shape_rows)
    written.append(out / "mode_shapes.csv")
    if result.coefficients:
        first = ["name", "unit"] if any("unit" in c for c in result.coefficients) else ["name"]
        ckeys = _scalar_keys(result.coefficients, first)
        write_csv(out / "coefficients.csv", ckeys,
                  ([c.get(k) for k in ckeys] for c in result.coefficients))
        written.append(out / "coefficients.csv")
    if result.spectra and result.spectra_frequency_hz is not None:
        names = list(result.spectra)
        units = result.units.get("coefficients") or {}
        header = ["frequency_hz", "excited"] + [
            f"{n}_{part}" + (f" [{units[n]}]" if units.get(n) else "")
            for n in names for part in ("re", "im")]
        excited = (result.spectra_excited if result.spectra_excited is not None
                   else np.ones(result.spectra_frequency_hz.size, bool))
        columns = [result.spectra[n] for n in names]
        write_csv(out / "coefficient_spectra.csv", header,
                  ([f, bool(e)] + [p for c in columns for p in (c[i].real, c[i].imag)]
                   for i, (f, e) in enumerate(zip(result.spectra_frequency_hz, excited))))
        written.append(out / "coefficient_spectra.csv")
    return written
