"""Identification input as arrays: :class:`IdentInput` and the user-data array format.

Reading files happens at the edge (:mod:`fnsi_lab.inputs`: fnsi-lab MCAP, ``.npz``,
MATLAB ``.mat``); this module only validates arrays. The array format
(:func:`input_from_arrays`) holds
  ``u``   forces, shape ``(n_samples,)`` or ``(n_samples, n_inputs)`` (also
          ``(n_periods, N, n_inputs)`` or ``(n_realizations, n_periods, N, n_inputs)``);
  ``y``   outputs, shape ``(n_samples, n_outputs)`` (same leading axes as ``u``);
  ``fs``  sampling rate (Hz), scalar;
  ``N``   optional samples per period (default: the config's, else one period);
  ``channels``        optional output names (default ``y0, y1, ...``);
  ``input_channels``  optional input names (default ``u0, ...``);
  ``quantity``        optional output quantity (displacement | velocity | acceleration);
  ``excited_lines``   optional DFT bins of one period the multisine excites (else detected
                      from ``u``: :mod:`ident.core.excitation`);
  ``realization_starts``, ``transient_samples``  optional: ``u``, ``y`` are one long record
                      whose realisation ``r`` starts at sample ``realization_starts[r]``;
                      ``transient_samples`` are dropped after each start, then whole periods
                      of ``N`` samples (:func:`ident.core.averaging.cut_realizations`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import ChannelError, IdentDataError, IdentError
from fnsi_lab.ident.core.averaging import as_periodic, cut_realizations
from fnsi_lab.ident.core.frequency_data import OUTPUT_QUANTITIES, OutputQuantity


@dataclass(frozen=True, eq=False)
class IdentInput:
    """Periodic data ready for :func:`ident.core.periodic.prepare_frequency_data`.

    Attributes
    ----------
    u : ndarray, shape (R, P, N, m)
    y : ndarray, shape (R, P, N, p)
    sample_rate_hz : float
    samples_per_period : int
    input_channels, output_channels : tuple of str
    transient_periods : int or None
        From the recording metadata (None: unknown).
    excited_lines : ndarray of int or None
    output_quantity : str or None
        Common quantity of the outputs when known.
    truth : dict or None
    path : str
    channel_units : mapping str -> str
        Unit of each channel by name, from the recording's channel table (empty: not
        known, SI assumed; ``ident.core.units``).
    parts : tuple of (str, int)
        For records stacked by :func:`stack_records`: each record's path and number of
        realisations, in order (empty for one record).
    """

    u: np.ndarray
    y: np.ndarray
    sample_rate_hz: float
    samples_per_period: int
    input_channels: tuple[str, ...]
    output_channels: tuple[str, ...]
    transient_periods: int | None = None
    excited_lines: np.ndarray | None = None
    output_quantity: OutputQuantity | None = None
    truth: dict | None = None
    path: str = ""
    notes: tuple[str, ...] = field(default=())
    channel_units: Mapping[str, str] = field(default_factory=dict)
    parts: tuple[tuple[str, int], ...] = field(default=())


def _names(value: Any, n: int, prefix: str, what: str, path: str) -> tuple[str, ...]:
    if value is None:
        return tuple(f"{prefix}{i}" for i in range(n))
    arr = np.asarray(value)
    if arr.dtype.kind in "US" and arr.ndim <= 1:
        names = [str(s).strip() for s in np.atleast_1d(arr)]
    elif arr.dtype == object:  # MATLAB cell array
        names = [str(np.asarray(s).squeeze()).strip() for s in arr.reshape(-1)]
    else:
        raise IdentDataError(f"{path}: '{what}' must be a list of names, got dtype {arr.dtype}")
    if len(names) != n:
        raise IdentDataError(f"{path}: '{what}' has {len(names)} names for {n} channels")
    return tuple(names)


def input_from_arrays(arrays: Mapping[str, Any], path: str = "",
                      samples_per_period: int | None = None) -> IdentInput:
    """An :class:`IdentInput` from the arrays of the user-data format (module docstring).

    Raises
    ------
    IdentDataError
        A missing array, a wrong shape or a bad value, in one line naming ``path``.
    """
    for key in ("u", "y", "fs"):
        if key not in arrays:
            raise IdentDataError(f"{path}: missing array {key!r} (needs u, y, fs; optional N, "
                                 "channels, input_channels)")
    try:
        fs = np.asarray(arrays["fs"], float).reshape(-1)
    except (TypeError, ValueError):
        raise IdentDataError(f"{path}: 'fs' must be one positive number (Hz), got "
                             f"{plain.value(np.asarray(arrays['fs']).tolist())}") from None
    if fs.size != 1 or not fs[0] > 0:
        raise IdentDataError(f"{path}: 'fs' must be one positive number, got {plain.value(np.asarray(arrays['fs']).tolist())}")
    N = samples_per_period
    if "N" in arrays:
        try:
            n_value = float(np.asarray(arrays["N"], float).reshape(-1)[0])
            # int() would make N = 1.5 one sample per period, without a word
            n_file = int(n_value) if n_value == int(n_value) else 0
        except (TypeError, ValueError, IndexError, OverflowError):
            n_file = 0
        if n_file < 1:  # not "no N": a wrong value (samples per period)
            raise IdentDataError(f"{path}: 'N' (samples per period) must be a whole number >= 1, "
                                 f"got {plain.value(np.asarray(arrays['N']).tolist())}; fix it or drop N")
        if N is not None and N != n_file:
            raise IdentDataError(f"{path}: N={n_file} in the file but samples_per_period={N} "
                                 f"(fix: give a record of {N} samples per period, or make "
                                 "samples_per_period and the file's N agree)")
        N = n_file
    for key in ("u", "y"):  # a cast to float would keep the real part without a word
        if np.iscomplexobj(arrays[key]):
            raise IdentDataError(f"{path}: {key!r} holds complex numbers; time data are real "
                                 f"(fix: save the measured time signals, not spectra)")
    try:
        u = np.asarray(arrays["u"], float)
        y = np.asarray(arrays["y"], float)
    except (TypeError, ValueError):
        raise IdentDataError(f"{path}: 'u' and 'y' must be numeric arrays") from None
    if u.ndim == 2 and y.ndim == 2 and u.shape[0] != y.shape[0] and u.shape[1] == y.shape[0]:
        pass  # leave the error to the shape check below (no silent transposes)
    if u.ndim == 1:
        u = u[:, None]
    if y.ndim == 1:
        y = y[:, None]
    if u.shape[:-1] != y.shape[:-1]:
        raise IdentDataError(f"{path}: u is {plain.shape(u.shape)} and y {plain.shape(y.shape)}: "
                             "not the same number of samples (expected u samples x inputs, "
                             "y samples x outputs)")
    try:
        if "realization_starts" in arrays:   # one long record, several realisations
            if N is None or u.ndim != 2:
                raise IdentError("realization_starts needs N and 2-D u, y (n_samples, channels)")
            cut = partial(cut_realizations,
                          starts=np.asarray(arrays["realization_starts"]).reshape(-1),
                          samples_per_period=N,
                          transient_samples=int(np.asarray(arrays.get("transient_samples", 0))))
            u, y = cut(u), cut(y)
        u4 = as_periodic(u, N, "u")
        y4 = as_periodic(y, N, "y")
    except IdentError as exc:
        raise IdentDataError(f"{path}: {exc}") from None
    exc_lines = None
    if "excited_lines" in arrays:
        exc_lines = np.asarray(arrays["excited_lines"]).reshape(-1)
        if (exc_lines.size == 0 or not np.all(np.mod(exc_lines, 1) == 0)
                or exc_lines.min() < 1 or exc_lines.max() >= u4.shape[2] / 2):
            raise IdentDataError(f"{path}: 'excited_lines' must be DFT bins 1 .. N/2-1 of one "
                                 f"period (N = {u4.shape[2]}), got "
                                 f"{plain.names(exc_lines.tolist(), limit=5)}")
        exc_lines = exc_lines.astype(int)
    given = arrays.get("quantity")
    q = None if given is None else str(np.asarray(given).squeeze())
    if q is not None and q not in OUTPUT_QUANTITIES:
        raise IdentDataError(f"{path}: quantity {q!r} is not one of {plain.names(OUTPUT_QUANTITIES)}")
    quantity = None if q is None else OUTPUT_QUANTITIES[OUTPUT_QUANTITIES.index(q)]
    return IdentInput(u=u4, y=y4, sample_rate_hz=float(fs[0]), samples_per_period=u4.shape[2],
                      input_channels=_names(arrays.get("input_channels"), u4.shape[3], "u",
                                            "input_channels", path),
                      output_channels=_names(arrays.get("channels"), y4.shape[3], "y",
                                             "channels", path),
                      output_quantity=quantity, path=path, excited_lines=exc_lines)


def stack_records(records: Sequence[IdentInput]) -> IdentInput:
    """Several records of one structure (force levels, multisine realisations) as the
    realisations of one input, for one identification over all of them.

    The records must share the sample rate, the period ``N``, the number of periods, the
    channels (by name; the first record's order), the output quantity and the excited lines
    (the same multisine grid; other phases are welcome). The transient periods are the
    first record's (else the largest any record declares); the simulated records' ``truth``
    is the first record's when they all hold the same elements (the basis a config-less
    run uses), else dropped.

    Parameters
    ----------
    records : sequence of IdentInput
        ``u`` (R_k, P, N, m), ``y`` (R_k, P, N, p) each.

    Returns
    -------
    IdentInput
        ``u`` (sum R_k, P, N, m), ``y`` (sum R_k, P, N, p); ``path`` joins the paths with
        `` + ``; ``parts`` holds each record's path and number of realisations.

    Raises
    ------
    IdentDataError
        Records that cannot be stacked, one line naming the record, the mismatch and the fix.
    """
    if not records:
        raise IdentDataError("no record to identify")
    first = records[0]
    if len(records) == 1:
        return first
    seen: set[str] = set()
    for rec in records:   # one record twice would count its noise as independent twice
        key = str(Path(rec.path).resolve()) if rec.path and Path(rec.path).exists() else ""
        if key and key in seen:
            raise IdentDataError(f"{rec.path}: given twice (fix: each record once)")
        seen.add(key)
    outs, ins = list(first.output_channels), list(first.input_channels)
    units = _common_units(records, outs + ins)
    grid_from = next((r for r in records if r.excited_lines is not None), None)
    grid = None if grid_from is None else np.asarray(grid_from.excited_lines)
    us, ys, problems = [], [], []
    for rec in records:
        found = _stack_mismatches(rec, first, grid, grid_from)
        try:
            picked = select_channels(rec, outputs=outs, inputs=ins)
        except ChannelError as exc:
            found.append(str(exc).strip("\"'"))
        problems.extend(found)
        if not found:
            us.append(np.asarray(picked.u))
            ys.append(np.asarray(picked.y))
    if problems:   # every mismatch at once: one fix per record, not one per run
        raise IdentDataError("; ".join(problems))
    transient = first.transient_periods
    if transient is None:
        declared = [r.transient_periods for r in records if r.transient_periods is not None]
        transient = max(declared) if declared else None
    lines = next((r.excited_lines for r in records if r.excited_lines is not None), None)
    quantity = next((r.output_quantity for r in records if r.output_quantity), None)
    # simulated records of one structure share their elements (other levels: other values
    # of contact and slip only): the first truth keeps the basis a config-less run uses
    elements = [[(e.get("name"), e.get("kind")) for e in (r.truth or {}).get("nonlinearities")
                 or []] for r in records]
    truth = first.truth if all(e == elements[0] for e in elements) else None
    undeclared = [str(r.path) for r in records if not r.channel_units]
    notes = tuple(n for r in records for n in r.notes) + ((
        f"{', '.join(undeclared)} declare no units: taken as "
        f"{', '.join(sorted(set(units.values())))} like the other records (check: a record "
        "in m beside one in mm is a factor 1000)",) if units and undeclared else ())
    return replace(first, u=np.concatenate(us, axis=0), y=np.concatenate(ys, axis=0),
                   transient_periods=transient, excited_lines=lines, truth=truth,
                   output_quantity=quantity, path=" + ".join(str(r.path) for r in records),
                   channel_units=units, notes=notes,
                   parts=tuple((str(r.path), int(np.asarray(u_k).shape[0]))
                               for r, u_k in zip(records, us)))


def _stack_mismatches(rec: IdentInput, first: IdentInput, grid: np.ndarray | None,
                      grid_from: IdentInput | None) -> list[str]:
    """What keeps ``rec`` from being stacked under ``first``: one clause per mismatch,
    naming the record and the fix (empty: none)."""
    name = rec.path or "record"
    out = []
    if abs(rec.sample_rate_hz - first.sample_rate_hz) > 1e-9 * first.sample_rate_hz:
        out.append(f"{name}: sampled at {rec.sample_rate_hz:g} Hz, {first.path} at "
                   f"{first.sample_rate_hz:g} Hz (fix: records of one rate)")
    same_period = rec.samples_per_period == first.samples_per_period
    if not same_period or rec.u.shape[1] != first.u.shape[1]:
        out.append(f"{name}: {rec.u.shape[1]} period(s) of {rec.samples_per_period} samples, "
                   f"{first.path}: {first.u.shape[1]} of {first.samples_per_period} (fix: "
                   "records of one test plan; an array file without N gives it in the file, "
                   "or samples_per_period: in the config)")
    if (rec.output_quantity and first.output_quantity
            and rec.output_quantity != first.output_quantity):
        out.append(f"{name}: {rec.output_quantity} outputs, {first.path}: "
                   f"{first.output_quantity} (fix: records of the same sensors)")
    if same_period and not _same_grid(rec, grid):   # lines of another period mean nothing
        out.append(f"{name}: excites other lines than "
                   f"{grid_from.path if grid_from else first.path} (fix: records of one "
                   "multisine grid; other phases are fine)")
    return out


def _common_units(records: Sequence[IdentInput], names: Sequence[str]) -> dict[str, str]:
    """The channels' units where the records declare them; records that declare other units
    for a channel are refused (a record in m beside one in mm is a factor 1000)."""
    units: dict[str, str] = {}
    where: dict[str, str] = {}
    for rec in records:
        for ch in names:
            unit = (rec.channel_units or {}).get(ch)
            if not unit:
                continue
            if ch in units and units[ch] != unit:
                raise IdentDataError(f"{rec.path}: channel {ch} in {unit}, {where[ch]} in "
                                     f"{units[ch]} (fix: records in the same units)")
            units.setdefault(ch, unit)
            where.setdefault(ch, str(rec.path))
    return units


def steady_drive_power(rec: IdentInput) -> np.ndarray:
    """``|U(k)|^2`` of the drive per line, averaged over the realisations and the periods
    after the transient ones (all of them when none is left), shape ``(N // 2 + 1, m)``."""
    u = np.asarray(rec.u, float)                     # (R, P, N, m)
    skip = int(rec.transient_periods or 0)
    steady = u[:, skip:] if u.shape[1] > skip else u
    return np.mean(np.abs(np.fft.rfft(steady, axis=2)) ** 2, axis=(0, 1))


def _same_grid(rec: IdentInput, grid: np.ndarray | None) -> bool:
    """Whether ``rec`` excites the lines ``grid`` (another record's declared grid): its own
    declared lines equal them, or, undeclared, its drive carries power on all but 2 % of
    them (more than 1e-3 of their median power; a measured force dips at the structure's
    resonances). Without a declared grid anywhere there is nothing to compare."""
    if grid is None or not grid.size:
        return True
    if rec.excited_lines is not None:
        return bool(np.array_equal(np.asarray(rec.excited_lines), grid))
    power = steady_drive_power(rec).sum(axis=-1)
    if grid.max() >= power.size:
        return False
    on = power[grid]
    return bool(np.mean(on > 1e-3 * np.median(on)) >= 0.98)


def select_channels(inp: IdentInput, *, outputs: Sequence[str] | None = None,
                    inputs: Sequence[str] | None = None) -> IdentInput:
    """Keep (and order) the named output and input channels.

    Raises
    ------
    ChannelError
        A name is not in the file (the message lists the available ones).
    """
    y, outs = _pick(inp.y, inp.output_channels, outputs, "output", inp.path)
    u, ins = _pick(inp.u, inp.input_channels, inputs, "input", inp.path)
    return replace(inp, u=u, y=y, input_channels=ins, output_channels=outs)


def _pick(x: np.ndarray, names: Sequence[str], wanted: Sequence[str] | None, role: str,
          path: Any) -> tuple[np.ndarray, tuple[str, ...]]:
    """The ``wanted`` channels of ``x`` (last axis), in that order; all of them without."""
    if not wanted:
        return x, tuple(names)
    missing = [w for w in wanted if w not in names]
    if missing:
        raise ChannelError(f"{path}: {role} channel(s) {plain.names(missing, quote=True)} not in "
                           f"the file ({role}s: {plain.names(names)})")
    return x[..., [list(names).index(w) for w in wanted]], tuple(wanted)
