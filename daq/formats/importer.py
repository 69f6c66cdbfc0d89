"""Lab file -> fnsi-lab recording: channel roles, period, provenance, MCAP.

:func:`read_lab_file` picks the reader from the extension; :func:`plan_import` decides
(arrays and names only, no I/O) which channels are inputs, the quantity of each output,
the sample rate and the period; :func:`write_recording` writes the result with the
project's :class:`~fnsi_lab.daq.recording.writer.Recorder`, so ``info``, ``ident`` and
``replay`` read it like any acquisition. The recording's ``source`` metadata says where
it came from (file, format, SHA-256, options); ``excitation`` holds the period when known.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.formats.errors import LabFileError
from fnsi_lab.daq.formats.table import LabTable, check_rate

#: Reader of each file extension (module, function), imported on use.
READERS: dict[str, tuple[str, str]] = {
    ".tdms": ("fnsi_lab.daq.formats.tdms", "read_tdms"),
    ".uff": ("fnsi_lab.daq.formats.uff58", "read_uff58"),
    ".unv": ("fnsi_lab.daq.formats.uff58", "read_uff58"),
    ".csv": ("fnsi_lab.daq.formats.csv_table", "read_csv"),
    ".txt": ("fnsi_lab.daq.formats.csv_table", "read_csv"),
    ".tsv": ("fnsi_lab.daq.formats.csv_table", "read_csv"),
}

#: Quantities an output (response) channel can have.
OUTPUT_QUANTITIES = ("displacement", "velocity", "acceleration")

#: Samples per recorded block (one MCAP message); any size reads back the same.
BLOCK_SAMPLES = 4096


def read_lab_file(path: str | os.PathLike[str]) -> LabTable:
    """Read a TDMS, UFF 58 or CSV file (format from the extension).

    Raises
    ------
    LabFileError
        Missing file, unknown extension, or what the format's reader reports.
    """
    import importlib

    p = Path(path)
    if not p.is_file():
        raise LabFileError(f"{p}: no such file" + (" (it is a folder)" if p.is_dir() else ""))
    reader = READERS.get(p.suffix.lower())
    if reader is None:
        raise LabFileError(f"{p}: unknown file type {p.suffix!r} (fix: give a .tdms, .uff/.unv "
                           "(dataset 58) or .csv/.txt/.tsv file)")
    module, function = reader
    return getattr(importlib.import_module(module), function)(p)


@dataclass(frozen=True)
class ImportPlan:
    """What the recording will hold (decided before anything is written).

    Attributes
    ----------
    channels : tuple of ChannelInfo
        Recorded channels in file order (excluded ones left out).
    columns : tuple of int
        Column of the table for each recorded channel.
    sample_rate_hz : float
    samples_per_period, transient_periods : int or None
    notes : tuple of str
    """

    channels: tuple[ChannelInfo, ...]
    columns: tuple[int, ...]
    sample_rate_hz: float
    samples_per_period: int | None
    transient_periods: int | None
    notes: tuple[str, ...] = field(default=())


def _agree(file_value: int | None, option: int | None, *, path: str, name: str) -> int | None:
    least = 1 if name == "samples-per-period" else 0
    if option is not None and option < least:
        raise LabFileError(f"--{name} {option}: must be >= {least}")
    if file_value is not None and option is not None and file_value != option:
        raise LabFileError(f"{path}: the file says {name.replace('-', '_')} = {file_value} but "
                           f"--{name} says {option} (fix: omit --{name}, or correct it)")
    return option if option is not None else file_value


def plan_import(table: LabTable, *, inputs: Sequence[str] | None = None,
                sample_rate_hz: float | None = None, samples_per_period: int | None = None,
                transient_periods: int | None = None, output_quantity: str | None = None,
                exclude: Sequence[str] = ()) -> ImportPlan:
    """Decide channel roles, rate and period of an import.

    Parameters
    ----------
    table : LabTable
        What the reader found.
    inputs : sequence of str, optional
        Names of the input (force) channels; default: the channels the file marks as
        forces (unit N, UFF data type 9/13).
    sample_rate_hz : float, optional
        ``--fs``; required when the file does not give the rate, checked when it does.
    samples_per_period, transient_periods : int, optional
        Multisine period N and transient periods K (checked against the file's).
    output_quantity : {'displacement', 'velocity', 'acceleration'}, optional
        Quantity of outputs whose unit does not say (``V``, none...).
    exclude : sequence of str
        Channels not to import.

    Returns
    -------
    ImportPlan

    Raises
    ------
    LabFileError
        An unknown channel name, no input, an output of unknown quantity, a force channel
        not named as an input, a rate or period that disagrees with the file.
    """
    p = table.path
    names = table.names
    for option, given in (("--inputs", inputs or ()), ("--exclude", exclude)):
        unknown = [n for n in given if n not in names]
        if unknown:
            raise LabFileError(f"{p}: {option}: no channel named {unknown[0]!r} (channels in the "
                               f"file: {', '.join(names)})")
    both = set(inputs or ()) & set(exclude)
    if both:
        raise LabFileError(f"channel {sorted(both)[0]!r} is in both --inputs and --exclude")
    if output_quantity is not None and output_quantity not in OUTPUT_QUANTITIES:
        raise LabFileError(f"--output-quantity {output_quantity!r}: not one of displacement, "
                           "velocity, acceleration")
    kept = [j for j, n in enumerate(names) if n not in exclude]
    if inputs:
        is_input = {j: names[j] in inputs for j in kept}
    else:
        is_input = {j: table.channels[j].quantity == "force" for j in kept}
        if not any(is_input.values()):
            raise LabFileError(f"{p}: no channel is marked as a force in the file (fix: name the "
                               "input channel(s) with --inputs NAME ...; channels: "
                               f"{', '.join(names)})")
    channels = []
    notes = list(table.notes)
    for j in kept:
        lab = table.channels[j]
        if is_input[j]:
            quantity = "force"
            if lab.quantity not in (None, "force"):
                notes.append(f"channel {lab.name!r} is an input but its unit {lab.unit!r} is "
                             f"that of a {lab.quantity}")
        elif lab.quantity == "force":
            raise LabFileError(f"{p}: channel {lab.name!r}: unit {lab.unit or 'force'!r} is a "
                               "force but the channel is not among --inputs (fix: add it to "
                               f"--inputs, or leave it out with --exclude {lab.name})")
        elif lab.quantity is None:
            if output_quantity is None:
                raise LabFileError(f"{p}: channel {lab.name!r}: unit {lab.unit!r} does not say "
                                   "displacement, velocity or acceleration (fix: "
                                   "--output-quantity acceleration|velocity|displacement, or "
                                   f"--exclude {lab.name})")
            quantity = output_quantity
        else:
            quantity = lab.quantity
        channels.append(ChannelInfo(name=lab.name, quantity=quantity, unit=lab.unit,
                                    node=lab.node, direction=lab.direction))
    if not any(c.is_force for c in channels) or all(c.is_force for c in channels):
        raise LabFileError(f"{p}: an identification needs at least one input and one output "
                           f"channel (inputs: {plain.names([c.name for c in channels if c.is_force])}; "
                           f"outputs: {plain.names([c.name for c in channels if not c.is_force])})")
    fs = check_rate(table.sample_rate_hz, sample_rate_hz, path=p, field="sample rate")
    n = _agree(table.samples_per_period, samples_per_period, path=p, name="samples-per-period")
    k = _agree(table.transient_periods, transient_periods, path=p, name="transient-periods")
    n_samples = table.data.shape[0]
    if n is not None:
        if n > n_samples:
            raise LabFileError(f"{p}: {n_samples} samples are less than one period of "
                               f"{n} (fix: check --samples-per-period)")
        if n_samples % n:
            notes.append(f"{n_samples % n} samples after the last whole period of {n}")
        if k is not None and k >= n_samples // n:
            raise LabFileError(f"{p}: --transient-periods {k} leaves no steady-state period out "
                               f"of {n_samples // n}")
    elif k is not None:
        raise LabFileError("--transient-periods needs the period: add --samples-per-period N")
    return ImportPlan(channels=tuple(channels), columns=tuple(kept), sample_rate_hz=fs,
                      samples_per_period=n, transient_periods=k, notes=tuple(notes))


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file (hex), read in 1 MiB pieces."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for piece in iter(lambda: fh.read(1 << 20), b""):
            digest.update(piece)
    return digest.hexdigest()


def import_metadata(table: LabTable, plan: ImportPlan, options: dict[str, Any]) -> dict[str, Any]:
    """The recording metadata of an import: ``experiment``, ``source``, ``excitation``.

    ``source`` says where the data came from: ``kind`` ``import``, ``format``, ``file``
    (absolute path), ``sha256``, ``size_bytes``, ``imported_at`` (UTC), the file's
    channels and properties, the options given, and the reader's notes.
    """
    path = Path(table.path)
    meta: dict[str, Any] = {
        "experiment": {"name": path.stem, "source_kind": "import",
                       "imported_from": str(path.resolve())},
        "source": {"kind": "import", "format": table.format, "file": str(path.resolve()),
                   "sha256": file_sha256(path), "size_bytes": path.stat().st_size,
                   "imported_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                   "channels_in_file": [{"name": c.name, "unit": c.unit} for c in table.channels],
                   "samples_in_file": int(table.data.shape[0]),
                   "sample_rate_in_file_hz": table.sample_rate_hz,
                   "properties": table.properties, "options": options,
                   "notes": list(plan.notes)},
    }
    if plan.samples_per_period is not None:
        n = plan.samples_per_period
        exc: dict[str, Any] = {"kind": "imported", "samples_per_period": n,
                               "periods": int(table.data.shape[0] // n),
                               "sample_rate_hz": plan.sample_rate_hz}
        if plan.transient_periods is not None:
            exc["transient_periods"] = plan.transient_periods
        meta["excitation"] = exc
    return meta


def write_recording(table: LabTable, plan: ImportPlan, out: str | os.PathLike[str], *,
                    options: dict[str, Any] | None = None,
                    on_block: Callable[[int, int], None] | None = None) -> Path:
    """Write the planned channels of ``table`` as an fnsi-lab recording.

    Parameters
    ----------
    table : LabTable
    plan : ImportPlan
        From :func:`plan_import`.
    out : path-like
        The ``.mcap`` file (created or replaced; check it first with
        :func:`fnsi_lab.outputs.check_output_path`). It is written under a temporary name
        and renamed when complete.
    options : dict, optional
        The import options, stored in the ``source`` metadata.
    on_block : callable (samples_done, samples_total), optional
        Progress callback.

    Returns
    -------
    Path
        ``out``.
    """
    from fnsi_lab.daq.recording.writer import Recorder

    data = table.data[:, list(plan.columns)]
    fs = plan.sample_rate_hz
    total = data.shape[0]
    block_samples = plan.samples_per_period or BLOCK_SAMPLES
    # Blocks of one period (or 4096 samples): recorded sizes stay moderate either way; at
    # most one second each, so that a chunk holds at most one second (docs/cli.md).
    block_samples = min(max(block_samples, 256), 1 << 16, max(int(fs), 1))
    meta = import_metadata(table, plan, dict(options or {}))
    final = Path(out)
    # Unlike an acquisition, nothing reads the file while it grows: write a temporary
    # sibling and rename it, so an interrupted import leaves no partial recording behind.
    tmp = final.with_name(f".{final.name}.partial-{os.getpid()}")
    try:
        with Recorder(tmp, plan.channels, fs, metadata=meta) as rec:
            for seq, start in enumerate(range(0, total, block_samples)):
                chunk = np.ascontiguousarray(data[start:start + block_samples])
                rec.write_block(Block(data=chunk, channels=plan.channels, sample_rate_hz=fs,
                                      sequence=seq, first_sample=start,
                                      t0_ns=int(round(start * 1e9 / fs))))
                if on_block is not None:
                    on_block(min(start + block_samples, total), total)
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return final
