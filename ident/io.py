"""Reading the INPUT of ``fnsi-lab ident``: fnsi-lab MCAP, ``.npz`` or MATLAB ``.mat``.

Array files hold
  ``u``   forces, shape ``(n_samples,)`` or ``(n_samples, n_inputs)`` (also
          ``(n_periods, N, n_inputs)`` or ``(n_realizations, n_periods, N, n_inputs)``);
  ``y``   outputs, shape ``(n_samples, n_outputs)`` (same leading axes as ``u``);
  ``fs``  sampling rate (Hz), scalar;
  ``N``   optional samples per period (default: the config's, else one period);
  ``channels``        optional output names (default ``y0, y1, ...``);
  ``input_channels``  optional input names (default ``u0, ...``);
  ``quantity``        optional output quantity (displacement | velocity | acceleration).
MCAP recordings are read with :func:`daq.recording.reader.read_periodic` (imported lazily,
so ``ident`` itself needs only numpy and scipy).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fnsi_lab.ident.errors import ChannelError, IdentDataError, IdentError
from fnsi_lab.ident.periodic import OUTPUT_QUANTITIES, as_periodic


@dataclass(frozen=True, eq=False)
class IdentInput:
    """Periodic data ready for :func:`ident.periodic.prepare_frequency_data`.

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
    """

    u: np.ndarray
    y: np.ndarray
    sample_rate_hz: float
    samples_per_period: int
    input_channels: tuple[str, ...]
    output_channels: tuple[str, ...]
    transient_periods: int | None = None
    excited_lines: np.ndarray | None = None
    output_quantity: str | None = None
    truth: dict | None = None
    path: str = ""
    notes: tuple[str, ...] = field(default=())


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


def _from_arrays(arrays: dict, path: str, samples_per_period: int | None) -> IdentInput:
    for key in ("u", "y", "fs"):
        if key not in arrays:
            raise IdentDataError(f"{path}: missing array {key!r} (needs u, y, fs; optional N, "
                                 "channels, input_channels)")
    fs = np.asarray(arrays["fs"], float).reshape(-1)
    if fs.size != 1 or not fs[0] > 0:
        raise IdentDataError(f"{path}: 'fs' must be one positive number, got {arrays['fs']!r}")
    N = samples_per_period
    if "N" in arrays:
        n_file = int(np.asarray(arrays["N"]).reshape(-1)[0])
        if N is not None and N != n_file:
            raise IdentDataError(f"{path}: N={n_file} in the file but samples_per_period={N}")
        N = n_file
    u = np.asarray(arrays["u"], float)
    y = np.asarray(arrays["y"], float)
    if u.ndim == 2 and y.ndim == 2 and u.shape[0] != y.shape[0] and u.shape[1] == y.shape[0]:
        pass  # leave the error to the shape check below (no silent transposes)
    if u.ndim == 1:
        u = u[:, None]
    if y.ndim == 1:
        y = y[:, None]
    if u.shape[:-1] != y.shape[:-1]:
        raise IdentDataError(f"{path}: u {u.shape} and y {y.shape} do not have the same number "
                             "of samples (expected u (n_samples, n_inputs), y (n_samples, n_outputs))")
    try:
        u4 = as_periodic(u, N, "u")
        y4 = as_periodic(y, N, "y")
    except IdentError as exc:
        raise IdentDataError(f"{path}: {exc}") from None
    q = arrays.get("quantity")
    q = None if q is None else str(np.asarray(q).squeeze())
    if q is not None and q not in OUTPUT_QUANTITIES:
        raise IdentDataError(f"{path}: quantity {q!r} is not one of {list(OUTPUT_QUANTITIES)}")
    return IdentInput(u=u4, y=y4, sample_rate_hz=float(fs[0]), samples_per_period=u4.shape[2],
                      input_channels=_names(arrays.get("input_channels"), u4.shape[3], "u",
                                            "input_channels", path),
                      output_channels=_names(arrays.get("channels"), y4.shape[3], "y",
                                             "channels", path),
                      output_quantity=q, path=path)


def _from_mcap(path: str, samples_per_period: int | None) -> IdentInput:
    try:
        from fnsi_lab.daq.recording.reader import read_periodic
    except ImportError as exc:  # pragma: no cover - daq is part of the install
        raise IdentDataError(f"{path}: cannot read MCAP ({exc})") from None
    rec = read_periodic(path, samples_per_period)
    outs = tuple(getattr(c, "name", str(c)) for c in rec.output_channels)
    ins = tuple(getattr(c, "name", str(c)) for c in rec.input_channels)
    quants = {getattr(c, "quantity", None) for c in rec.output_channels}
    q = quants.pop() if len(quants) == 1 else None
    exc = np.asarray(rec.excited_lines, int) if rec.excited_lines is not None else None
    return IdentInput(u=np.asarray(rec.u, float), y=np.asarray(rec.y, float),
                      sample_rate_hz=float(rec.sample_rate_hz),
                      samples_per_period=int(rec.samples_per_period), input_channels=ins,
                      output_channels=outs, transient_periods=rec.transient_periods,
                      excited_lines=exc if exc is not None and exc.size else None,
                      output_quantity=q if q in OUTPUT_QUANTITIES else None, truth=rec.truth,
                      path=path, notes=tuple(getattr(rec, "notes", ())))


def load_input(path: str | Path, *, samples_per_period: int | None = None) -> IdentInput:
    """Load an identification INPUT file (format from the extension).

    Parameters
    ----------
    path : str or Path
        ``.mcap`` (fnsi-lab recording), ``.npz`` or ``.mat``.
    samples_per_period : int, optional
        ``N`` (checked against the file's when both are given).

    Returns
    -------
    IdentInput

    Raises
    ------
    IdentDataError
        Missing file, unknown extension, missing array, wrong shape (one line).
    """
    p = Path(path)
    sp = str(p)
    if not p.exists():
        raise IdentDataError(f"{sp}: file not found")
    ext = p.suffix.lower()
    if ext == ".mcap":
        return _from_mcap(sp, samples_per_period)
    if ext == ".npz":
        try:
            with np.load(sp, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - any unreadable file is one message
            raise IdentDataError(f"{sp}: not a readable .npz file ({exc})") from None
        return _from_arrays(arrays, sp, samples_per_period)
    if ext == ".mat":
        import scipy.io
        try:
            raw = scipy.io.loadmat(sp, squeeze_me=False)
        except Exception as exc:  # noqa: BLE001
            raise IdentDataError(f"{sp}: not a readable MATLAB file ({exc}); v7.3 files are "
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
        return _from_arrays(arrays, sp, samples_per_period)
    raise IdentDataError(f"{sp}: unknown format {ext!r} (use .mcap, .npz or .mat)")


def select_channels(inp: IdentInput, *, outputs: Sequence[str] | None = None,
                    inputs: Sequence[str] | None = None) -> IdentInput:
    """Keep (and order) the named output and input channels.

    Raises
    ------
    ChannelError
        A name is not in the file (the message lists the available ones).
    """
    u, y = inp.u, inp.y
    ins, outs = inp.input_channels, inp.output_channels
    if outputs:
        missing = [o for o in outputs if o not in outs]
        if missing:
            raise ChannelError(f"{inp.path}: output channel(s) {missing} not in the file "
                               f"(outputs: {list(outs)})")
        y = y[..., [outs.index(o) for o in outputs]]
        outs = tuple(outputs)
    if inputs:
        missing = [i for i in inputs if i not in ins]
        if missing:
            raise ChannelError(f"{inp.path}: input channel(s) {missing} not in the file "
                               f"(inputs: {list(ins)})")
        u = u[..., [ins.index(i) for i in inputs]]
        ins = tuple(inputs)
    return replace(inp, u=u, y=y, input_channels=ins, output_channels=outs)
