"""``LabTable``: the time data of a lab file as read, before it becomes a recording.

Every reader (:mod:`.tdms`, :mod:`.uff58`, :mod:`.csv_table`) returns one; the importer
(:mod:`.importer`) turns it into fnsi-lab channels and an MCAP recording. Keeping this
step free of any file format makes the conversion testable with arrays alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fnsi_lab.daq.formats.errors import LabFileError


@dataclass(frozen=True, eq=False)
class LabChannel:
    """One channel as the file describes it.

    Attributes
    ----------
    name : str
        Channel name in the file.
    unit : str
        Unit text in the file (empty when the file gives none).
    quantity : str or None
        ``force``, ``displacement``, ``velocity`` or ``acceleration`` when the file says
        (a UFF data type, a unit), else None.
    node, direction : str
        Measurement node and signed direction (``+Z``) when the file says.
    """

    name: str
    unit: str = ""
    quantity: str | None = None
    node: str = ""
    direction: str = ""


@dataclass(frozen=True, eq=False)
class LabTable:
    """Equally sampled channels of one lab file.

    Attributes
    ----------
    path : str
        The file.
    format : str
        ``tdms``, ``uff58`` or ``csv``.
    data : ndarray of float64, shape (n_samples, n_channels)
        The samples, column ``j`` is ``channels[j]``.
    channels : tuple of LabChannel, length n_channels
    sample_rate_hz : float or None
        From the file (None when it does not say).
    samples_per_period, transient_periods : int or None
        Multisine period and transient periods when the file stores them.
    properties : dict
        File-level description kept in the recording's metadata (JSON-able).
    notes : tuple of str
        What the reader skipped or assumed.
    """

    path: str
    format: str
    data: np.ndarray
    channels: tuple[LabChannel, ...]
    sample_rate_hz: float | None = None
    samples_per_period: int | None = None
    transient_periods: int | None = None
    properties: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.data.ndim != 2 or self.data.shape[1] != len(self.channels):
            raise ValueError(f"data of shape {self.data.shape} for {len(self.channels)} channels")

    @property
    def names(self) -> tuple[str, ...]:
        """Channel names in column order."""
        return tuple(c.name for c in self.channels)


def rate_from_increment(increment_s: float, *, path: str, field: str) -> float:
    """Sampling rate from a time increment written with limited precision.

    Files store ``dt`` as decimal text (UFF: 6 significant digits, ``1.95312e-05`` for
    51.2 kHz). The rate returned is the one with the fewest significant digits whose
    reciprocal rounds to the increment at the precision it was written with, so
    ``1.95312e-05`` gives 51200 Hz, while ``0.003`` (too short to be rounded) and an
    exactly stored ``dt`` give ``1 / dt``.

    Parameters
    ----------
    increment_s : float
        Time between samples, s.
    path, field : str
        For the error message.

    Raises
    ------
    LabFileError
        ``increment_s`` not a positive finite number.
    """
    dt = float(increment_s)
    if not (math.isfinite(dt) and dt > 0):
        raise LabFileError(f"{path}: {field}: time increment {increment_s!r} is not a positive "
                           "number (fix: give the sample rate with --fs HZ)")
    # Significant digits the increment was written with (shortest text giving the same float).
    # Six or more look like a rounded reciprocal (E13.5 holds six): allow half a unit of the
    # last digit; fewer are taken as exact (0.003 s is 333.33 Hz, not 300 Hz).
    digits = next(d for d in range(1, 18) if float(f"{dt:.{d - 1}e}") == dt)
    exact = 1.0 / dt
    if digits < 6:
        return exact
    tolerance = 0.5 * 10.0 ** (1 - digits) * dt
    for d in range(1, 18):
        fs = float(f"{exact:.{d - 1}e}")
        if abs(1.0 / fs - dt) <= tolerance:
            return fs
    return exact


def check_rate(file_rate_hz: float | None, option_rate_hz: float | None, *, path: str,
               field: str) -> float:
    """The sampling rate to use: the file's, or ``--fs``; both must agree when both exist.

    Agreement is to 1e-5 relative (the precision of a UFF increment).

    Raises
    ------
    LabFileError
        Neither is known, ``--fs`` not positive, or the two disagree.
    """
    if option_rate_hz is not None and not (math.isfinite(option_rate_hz) and option_rate_hz > 0):
        raise LabFileError(f"--fs {option_rate_hz!r}: the sample rate must be a positive number "
                           "of Hz")
    if file_rate_hz is None:
        if option_rate_hz is None:
            raise LabFileError(f"{path}: {field}: the file does not give the sample rate "
                               "(fix: add --fs HZ)")
        return float(option_rate_hz)
    if option_rate_hz is not None and abs(option_rate_hz - file_rate_hz) > 1e-5 * file_rate_hz:
        raise LabFileError(f"{path}: {field}: the file says {file_rate_hz:.9g} Hz but --fs "
                           f"says {option_rate_hz:.9g} Hz (fix: omit --fs, or correct it)")
    return float(option_rate_hz if option_rate_hz is not None else file_rate_hz)


def rate_from_times(times_s: np.ndarray, *, path: str, field: str) -> float:
    """Sampling rate of an equally spaced time axis (see :func:`rate_from_increment`).

    Raises
    ------
    LabFileError
        Fewer than two times, or steps differing by more than 1e-6 relative.
    """
    t = np.asarray(times_s, dtype=float).reshape(-1)
    steps = np.diff(t)
    if steps.size == 0:
        raise LabFileError(f"{path}: {field}: one sample gives no sample rate (fix: --fs HZ)")
    if not np.allclose(steps, steps[0], rtol=1e-6, atol=0):
        k = int(np.argmax(np.abs(steps - steps[0])))
        raise LabFileError(f"{path}: {field}: not equally spaced (step {k + 1} is "
                           f"{steps[k]:g} s, the first {steps[0]:g} s; fix: resample the data "
                           "to a constant rate)")
    return rate_from_increment(float((t[-1] - t[0]) / steps.size), path=path, field=field)


def common_rate(rates: list[tuple[str, float]], *, path: str, kind: str) -> float | None:
    """The one sampling rate of ``(channel, rate)`` pairs (None when empty).

    Raises
    ------
    LabFileError
        Two channels with rates differing by more than 1e-9 relative.
    """
    if not rates:
        return None
    first, rate = rates[0]
    for name, r in rates[1:]:
        if abs(r - rate) > 1e-9 * rate:
            raise LabFileError(f"{path}: {kind} {name!r}: sample rate {r:.9g} Hz but {kind} "
                               f"{first!r} has {rate:.9g} Hz (fix: export one sample rate)")
    return rate


def stack_columns(columns: list[np.ndarray], names: list[str], *, path: str,
                  kind: str) -> np.ndarray:
    """Channels side by side, ``(n_samples, n_channels)`` float64, all finite.

    Raises
    ------
    LabFileError
        Columns of different lengths, or a NaN/infinite sample (channel and index named).
    """
    lengths = [len(c) for c in columns]
    if len(set(lengths)) > 1:
        odd = next(i for i, n in enumerate(lengths) if n != lengths[0])
        raise LabFileError(f"{path}: {kind} {names[odd]!r} has {lengths[odd]} samples but "
                           f"{names[0]!r} has {lengths[0]} (fix: export the {kind}s of one "
                           "acquisition only)")
    data = np.column_stack([np.asarray(c, dtype=np.float64) for c in columns])
    require_finite(data, names, path=path, kind=kind)
    return data


def require_finite(data: np.ndarray, names: list[str], *, path: str, kind: str) -> None:
    """Raise naming the first NaN/infinite sample of ``data`` (n_samples, n_channels)."""
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise LabFileError(f"{path}: {kind} {names[col]!r}: sample {row} is {data[row, col]} "
                           "(fix: remove or repair the gap before importing)")
