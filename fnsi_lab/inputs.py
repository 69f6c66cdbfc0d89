"""Reading identification inputs from files: the edge between recordings and ``ident``.

:func:`load_input` turns an fnsi-lab MCAP recording, an ``.npz`` file or a MATLAB ``.mat``
file into the arrays of :class:`fnsi_lab.ident.core.io.IdentInput` (the array format is documented
in :mod:`fnsi_lab.ident.core.io` and docs/ident.md); :func:`input_from_record` does the same for a
periodic record assembled in memory (the live service). ``ident`` itself never opens a file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from fnsi_lab.ident.errors import IdentDataError
from fnsi_lab.ident.core.io import IdentInput, input_from_arrays
from fnsi_lab.ident.core.periodic import OUTPUT_QUANTITIES

__all__ = ["load_input", "input_from_record"]


def input_from_record(rec: Any, path: str = "") -> IdentInput:
    """An :class:`IdentInput` from a periodic record.

    Parameters
    ----------
    rec : PeriodicRecord-like
        ``u`` (R, P, N, m), ``y`` (R, P, N, p), ``sample_rate_hz``, ``samples_per_period``,
        ``input_channels``/``output_channels`` (``ChannelInfo`` or names),
        ``transient_periods``, ``excited_lines``, optional ``truth`` and ``notes``.
    path : str
        Where it came from (messages and the JSON ``input``).
    """
    outs = tuple(getattr(c, "name", str(c)) for c in rec.output_channels)
    ins = tuple(getattr(c, "name", str(c)) for c in rec.input_channels)
    quants = {getattr(c, "quantity", None) for c in rec.output_channels}
    q = quants.pop() if len(quants) == 1 else None
    lines = getattr(rec, "excited_lines", None)
    exc = np.asarray(lines, int) if lines is not None else None
    # One memory layout whatever the reader produced (read_periodic's channel selection is
    # strided): numpy's sums round differently on strided arrays, and a recording must
    # identify exactly like the same samples given as .npz (issue 17).
    return IdentInput(u=np.ascontiguousarray(rec.u, float),
                      y=np.ascontiguousarray(rec.y, float),
                      sample_rate_hz=float(rec.sample_rate_hz),
                      samples_per_period=int(rec.samples_per_period), input_channels=ins,
                      output_channels=outs,
                      transient_periods=getattr(rec, "transient_periods", None),
                      excited_lines=exc if exc is not None and exc.size else None,
                      output_quantity=q if q in OUTPUT_QUANTITIES else None,
                      truth=getattr(rec, "truth", None), path=path,
                      notes=tuple(getattr(rec, "notes", ())),
                      channel_units={c.name: c.unit for c in (*rec.input_channels,
                                                               *rec.output_channels)
                                     if getattr(c, "unit", "")})


def _read_mat(path: str) -> dict[str, Any]:
    import scipy.io

    try:
        raw = scipy.io.loadmat(path, squeeze_me=False)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is one message
        raise IdentDataError(f"{path}: not a readable MATLAB file ({exc}); v7.3 files are "
                             "HDF5: save with -v7") from None
    arrays = {k: v for k, v in raw.items() if not k.startswith("__")}
    for k in ("u", "y"):
        if k in arrays and arrays[k].ndim == 2 and 1 in arrays[k].shape:
            arrays[k] = arrays[k].reshape(-1)  # MATLAB vectors are 2-D
    for k in ("channels", "input_channels"):
        if k in arrays and arrays[k].dtype.kind in "US":
            arrays[k] = np.array([str(s).strip() for s in np.atleast_1d(arrays[k].squeeze())])
    if "quantity" in arrays:
        arrays["quantity"] = str(np.asarray(arrays["quantity"]).squeeze())
    return arrays


def load_input(path: str | os.PathLike[str], *,
               samples_per_period: int | None = None) -> IdentInput:
    """Load an identification input file (format from the extension).

    Parameters
    ----------
    path : path-like
        ``.mcap`` (fnsi-lab recording), ``.npz`` or ``.mat``.
    samples_per_period : int, optional
        ``N`` (checked against the file's when both are given).

    Returns
    -------
    IdentInput

    Raises
    ------
    IdentDataError, RecordingError
        Missing file, unknown extension, missing array, wrong shape, damaged recording
        (one line naming the file).
    """
    p = Path(path)
    sp = str(p)
    if not p.exists():
        raise IdentDataError(f"{sp}: file not found")
    ext = p.suffix.lower()
    if ext == ".mcap":
        from fnsi_lab.daq.recording.reader import read_periodic

        return input_from_record(read_periodic(sp, samples_per_period), sp)
    if ext == ".npz":
        try:
            with np.load(sp, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - any unreadable file is one message
            raise IdentDataError(f"{sp}: not a readable .npz file ({exc})") from None
        return input_from_arrays(arrays, sp, samples_per_period)
    if ext == ".mat":
        return input_from_arrays(_read_mat(sp), sp, samples_per_period)
    raise IdentDataError(f"{sp}: unknown format {ext!r} (use .mcap, .npz or .mat)")
