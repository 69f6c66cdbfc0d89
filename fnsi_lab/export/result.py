"""An identification result file (``fnsi-lab ident --json``) as arrays.

:func:`load_result` reads the JSON written by ``fnsi-lab ident --json`` /
``fnsi_lab.identify(...).to_json()`` and returns :class:`ResultArrays`: modes, complex
mode shapes, FRFs and coefficient spectra as numpy arrays, with one-line errors naming the
field that is missing or malformed. Complex numbers are stored in the JSON as
``{"re": [...], "im": [...]}`` (parallel arrays) or lists of ``{"re", "im"}``; JSON
``null`` (a non-finite value) becomes NaN.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError, DataFileError

#: FRF kinds of the ``frf`` section, in export order.
FRF_KINDS = ("measured", "model", "underlying_linear")


class ResultFileError(DataFileError):
    """The result JSON lacks what an export needs."""


def _nested_float(value: Any) -> np.ndarray:
    """Nested lists with None -> float array of their shape (None -> NaN)."""
    def conv(v: Any) -> Any:
        if isinstance(v, list):
            return [conv(x) for x in v]
        return np.nan if v is None else float(v)
    return np.asarray(conv(value), dtype=float)


def complex_array(value: Any, *, path: str, field_name: str) -> np.ndarray:
    """A complex array from its JSON form (``{"re", "im"}`` or a list of such pairs)."""
    try:
        if isinstance(value, dict) and "re" in value and "im" in value:
            re, im = _nested_float(value["re"]), _nested_float(value["im"])
            if re.shape != im.shape:
                raise ConfigError(f"re {re.shape} and im {im.shape} differ in shape")
            return re + 1j * im
        if isinstance(value, list):
            def conv(v: Any) -> Any:
                if isinstance(v, list):
                    return [conv(x) for x in v]
                if isinstance(v, dict):
                    return complex(np.nan if v.get("re") is None else v["re"],
                                   np.nan if v.get("im") is None else v["im"])
                return complex(np.nan if v is None else v)
            return np.asarray(conv(value), dtype=complex)
    except (TypeError, ValueError) as exc:
        raise ResultFileError(f"{path}: {field_name}: not a complex array ({exc})") from None
    raise ResultFileError(f"{path}: {field_name}: expected {{\"re\": [...], \"im\": [...]}}, "
                          f"got {type(value).__name__}")


@dataclass(frozen=True, eq=False)
class ResultArrays:
    """What an export takes from an identification result.

    Attributes
    ----------
    path : str
        The JSON file.
    outputs, inputs : tuple of str
        Output and input channel names (order of the shapes and FRFs).
    output_quantity : str
        ``displacement``, ``velocity`` or ``acceleration``.
    frequency_hz, damping_ratio : ndarray, shape (n_modes,)
        Natural frequency (Hz) and damping ratio of each mode.
    stable : ndarray of bool, shape (n_modes,)
    shapes : ndarray of complex, shape (n_modes, n_outputs)
        Mode shapes at the outputs.
    mode_rows : list of dict
        The modes as in the JSON (every scalar field, for the CSV table).
    frf_frequency_hz : ndarray, shape (n_lines,) or None
    frf : dict of str to ndarray of complex, shape (n_lines, n_outputs, n_inputs)
        ``measured``, ``model``, ``underlying_linear`` (those present).
    spectra_frequency_hz : ndarray, shape (n_lines,) or None
    spectra_excited : ndarray of bool, shape (n_lines,) or None
    spectra : dict of str to ndarray of complex, shape (n_lines,)
        Coefficient spectra ``c_a(w)`` by coefficient name.
    coefficients : list of dict
        Coefficient summaries as in the JSON.
    order : int or None
    input_path : str
        The identification's input file as recorded in the result (``input``).
    units : dict
        The result's ``units`` block (``force``, ``output``, ``frf``, ``coefficients``
        {name: unit}...); empty for results written before units were recorded.
    """

    path: str
    outputs: tuple[str, ...]
    inputs: tuple[str, ...]
    output_quantity: str
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    stable: np.ndarray
    shapes: np.ndarray
    mode_rows: list[dict]
    frf_frequency_hz: np.ndarray | None = None
    frf: dict[str, np.ndarray] = field(default_factory=dict)
    spectra_frequency_hz: np.ndarray | None = None
    spectra_excited: np.ndarray | None = None
    spectra: dict[str, np.ndarray] = field(default_factory=dict)
    coefficients: list[dict] = field(default_factory=list)
    order: int | None = None
    input_path: str = ""
    units: dict = field(default_factory=dict)


def result_from_dict(res: dict, path: str = "<result>") -> ResultArrays:
    """:class:`ResultArrays` from the result dict (``Identification.to_json()``).

    Raises
    ------
    ResultFileError
        ``outputs``/``modes`` missing, a mode without frequency, damping or a shape of
        the outputs' length, FRF arrays of the wrong shape.
    """
    if not isinstance(res, dict):
        raise ResultFileError(f"{path}: not an fnsi-lab result (a JSON object is expected)")
    outputs = res.get("outputs")
    if not isinstance(outputs, list) or not outputs:
        raise ResultFileError(f"{path}: field 'outputs' (the output channel names) is missing; "
                              "write the file with `fnsi-lab ident --json`")
    outputs = tuple(str(o) for o in outputs)
    inputs = tuple(str(i) for i in res.get("inputs") or ())
    modes = res.get("modes")
    if not isinstance(modes, list):
        raise ResultFileError(f"{path}: field 'modes' is missing")
    n, p = len(modes), len(outputs)
    freq, damp = np.empty(n), np.empty(n)
    stable = np.ones(n, bool)
    shapes = np.empty((n, p), complex)
    rows = []
    for k, m in enumerate(modes):
        where = f"modes[{k}]"
        for key in ("frequency_hz", "damping_ratio"):
            if not isinstance(m.get(key), (int, float)) or isinstance(m.get(key), bool):
                raise ResultFileError(f"{path}: {where}.{key} is missing or not a number")
        freq[k], damp[k] = float(m["frequency_hz"]), float(m["damping_ratio"])
        stable[k] = bool(m.get("stable", True))
        if "shape" not in m:
            raise ResultFileError(f"{path}: {where}.shape is missing (the mode shapes are written "
                                  "by fnsi-lab ident since the lab-formats release; re-run it)")
        shape = complex_array(m["shape"], path=path, field_name=f"{where}.shape").reshape(-1)
        if shape.size != p:
            raise ResultFileError(f"{path}: {where}.shape has {shape.size} entries for "
                                  f"{p} outputs")
        shapes[k] = shape
        rows.append({k2: v for k2, v in m.items() if k2 != "shape"})
    frf: dict[str, np.ndarray] = {}
    frf_f = None
    section = res.get("frf")
    if isinstance(section, dict) and section.get("frequency_hz") is not None:
        frf_f = _nested_float(section["frequency_hz"]).reshape(-1)
        fin = tuple(str(i) for i in section.get("inputs") or inputs)
        fout = tuple(str(o) for o in section.get("outputs") or outputs)
        if fout != outputs:
            raise ResultFileError(f"{path}: frf.outputs ({plain.names(fout)}) differ from outputs "
                                  f"({plain.names(outputs)})")
        inputs = inputs or fin
        for kind in FRF_KINDS:
            if section.get(kind) is None:
                continue
            h = complex_array(section[kind], path=path, field_name=f"frf.{kind}")
            if h.shape != (frf_f.size, p, len(fin)):
                raise ResultFileError(f"{path}: frf.{kind} has shape {' x '.join(map(str, h.shape))}, expected "
                                      f"{frf_f.size} lines x {p} outputs x {len(fin)} inputs")
            frf[kind] = h
    spectra: dict[str, np.ndarray] = {}
    sp_f = sp_exc = None
    cs = res.get("coefficient_spectra")
    if isinstance(cs, dict) and cs.get("frequency_hz") is not None:
        sp_f = _nested_float(cs["frequency_hz"]).reshape(-1)
        exc = cs.get("excited")
        sp_exc = np.asarray(exc, bool).reshape(-1) if exc is not None else None
        for name, value in (cs.get("values") or {}).items():
            arr = complex_array(value, path=path,
                                field_name=f"coefficient_spectra.values.{name}").reshape(-1)
            if arr.size != sp_f.size:
                raise ResultFileError(f"{path}: coefficient_spectra.values.{name} has {arr.size} "
                                      f"lines, frequency_hz {sp_f.size}")
            spectra[str(name)] = arr
    return ResultArrays(
        path=path, outputs=outputs, inputs=inputs,
        output_quantity=str(res.get("output_quantity") or "displacement"),
        frequency_hz=freq, damping_ratio=damp, stable=stable, shapes=shapes, mode_rows=rows,
        frf_frequency_hz=frf_f, frf=frf, spectra_frequency_hz=sp_f, spectra_excited=sp_exc,
        spectra=spectra, coefficients=list(res.get("coefficients") or []),
        order=res.get("order"), input_path=str(res.get("input") or ""),
        units=dict(res.get("units") or {}))


def load_result(path: str | os.PathLike[str]) -> ResultArrays:
    """Read a result JSON file (``fnsi-lab ident --json``).

    Raises
    ------
    ResultFileError
        Missing file, not JSON, or see :func:`result_from_dict`.
    """
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8") as fh:
            res = json.load(fh)
    except FileNotFoundError:
        raise ResultFileError(f"{p}: no such file (write it with `fnsi-lab ident ... --json "
                              f"{p}`)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultFileError(f"{p}: cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise ResultFileError(f"{p}: not JSON (line {exc.lineno}, column {exc.colno}: "
                              f"{exc.msg})") from None
    return result_from_dict(res, p)
