"""Universal File Format writers: modes as dataset 55, FRFs as dataset 58 (ASCII).

Layouts follow the UFF dataset definitions (80-column records, fixed-width fields):

- **55, data at nodes**, analysis type 3 (complex eigenvalue, first order): record 8
  holds the eigenvalue ``lambda = 2 pi f (-zeta + j sqrt(1 - zeta^2))`` (rad/s), modal A
  and B (0: unscaled shapes); then per node its number and the complex X, Y, Z
  components (data characteristic 2, three translations per node).
- **58, function at nodal DOF**, function type 4 (FRF), complex double precision, the
  response and reference node and direction of each output/input pair, abscissa in Hz
  (even spacing when the lines are equally spaced, else every frequency is written).

Precision: the fields of records 7/8 (55) and 7 (58) and the abscissa values are 13
characters wide (``E13.5`` in the definition, six significant digits). Every such field
here holds the decimal text of at most 12 characters (a leading blank kept as separator)
with the most significant digits, e.g. ``628.31853072`` rather than ``6.28319E+02``: a
valid number for Fortran ``E13.5`` input, fixed-width and whitespace-splitting readers,
and 9 to 11 significant digits instead of 6, so frequency and damping read back to about
1e-10. Ordinates of 58 use ``E20.12`` (13 significant digits), as defined.
"""

from __future__ import annotations

import datetime as _dt
import math
from typing import Iterable, Sequence

import numpy as np

from fnsi_lab.export.dofs import Dof
from fnsi_lab.export.result import FRF_KINDS, ResultArrays

#: UFF specific data type of each quantity (record 6 of 55, records 9/10 of 58).
SPECIFIC_DATA_TYPES = {"displacement": 8, "velocity": 11, "acceleration": 12, "force": 13}


def number_field(value: float, width: int = 13) -> str:
    """``value`` right-aligned in ``width`` characters with the most significant digits.

    The text keeps one leading blank and always a decimal point (Fortran reads digits
    without one as implied decimals). Fixed and exponent notation are both tried; the one
    closest to ``value`` wins.

    Examples
    --------
    >>> number_field(628.3185307179586)
    ' 628.31853072'
    >>> number_field(-1.2345678901e-7)
    ' -1.2345679e-7'
    """
    x = float(value)
    if not math.isfinite(x):
        return f"{'NaN' if math.isnan(x) else ('Inf' if x > 0 else '-Inf'):>{width}}"
    if x == 0.0:
        return f"{'0.0':>{width}}"
    room = width - 1
    candidates = []
    for d in range(room, 0, -1):
        text = f"{x:.{d}f}"
        if len(text) <= room:
            candidates.append(text)
            break
    for d in range(room, 0, -1):
        mantissa, _, exponent = f"{x:.{d}e}".partition("e")
        text = f"{mantissa}e{int(exponent)}"
        if len(text) <= room:
            candidates.append(text)
            break
    best = min(candidates, key=lambda t: (abs(float(t) - x), len(t)))
    return f"{best:>{width}}"


def _e20(value: float) -> str:
    return f"{value:20.12e}"


def _id_line(text: str) -> str:
    return f"{text.encode('ascii', 'replace').decode()[:80]:<80}\n"


def _uff_date(when: _dt.datetime) -> str:
    return when.strftime("%d-%b-%y %H:%M:%S").upper()


def eigenvalue(frequency_hz: float, damping_ratio: float) -> complex:
    """Continuous-time pole of a mode: ``2 pi f (-zeta + j sqrt(1 - zeta^2))`` (rad/s)."""
    wn = 2.0 * math.pi * float(frequency_hz)
    z = float(damping_ratio)
    return complex(-z * wn, wn * math.sqrt(max(1.0 - z * z, 0.0)))


def mode_from_eigenvalue(lam: complex) -> tuple[float, float]:
    """Inverse of :func:`eigenvalue`: ``(frequency_hz, damping_ratio)``."""
    wn = abs(lam)
    return wn / (2.0 * math.pi), -lam.real / wn


def uff55_mode(mode_number: int, frequency_hz: float, damping_ratio: float,
               node_vectors: dict[int, np.ndarray], *, specific_data_type: int,
               id_lines: Sequence[str]) -> str:
    """One complex mode as dataset 55 text.

    Parameters
    ----------
    mode_number : int
        1-based.
    frequency_hz, damping_ratio : float
    node_vectors : dict of int to ndarray of complex, shape (3,)
        X, Y, Z shape components of each node (0 where not measured).
    specific_data_type : int
        8 displacement, 11 velocity, 12 acceleration.
    id_lines : sequence of 5 str
    """
    lam = eigenvalue(frequency_hz, damping_ratio)
    out = [f"{-1:6d}\n", f"{55:6d}{'':74s}\n"]
    out += [_id_line(t) for t in list(id_lines)[:5] + ["NONE"] * (5 - len(id_lines))]
    # model type 1 (structural), analysis 3 (complex eigenvalue), data characteristic 2
    # (three translations), data type 5 (complex single; values as text), 3 values per node
    out.append(f"{1:10d}{3:10d}{2:10d}{specific_data_type:10d}{5:10d}{3:10d}\n")
    out.append(f"{2:10d}{6:10d}{1:10d}{mode_number:10d}\n")
    out.append("".join(number_field(v) for v in (lam.real, lam.imag, 0.0, 0.0, 0.0, 0.0)) + "\n")
    for node in sorted(node_vectors):
        vec = np.asarray(node_vectors[node], complex)
        out.append(f"{node:10d}\n")
        out.append("".join(number_field(c.real) + number_field(c.imag) for c in vec) + "\n")
    out.append(f"{-1:6d}\n")
    return "".join(out)


def _abscissa(frequency_hz: np.ndarray) -> tuple[bool, float, float]:
    """(even, first, step) of the FRF frequencies."""
    f = np.asarray(frequency_hz, float)
    if f.size >= 2:
        steps = np.diff(f)
        if np.allclose(steps, steps[0], rtol=1e-9, atol=0):
            return True, float(f[0]), float((f[-1] - f[0]) / (f.size - 1))
    return False, 0.0, 0.0


def uff58_frf(values: np.ndarray, frequency_hz: np.ndarray, *, response: Dof, reference: Dof,
              numerator_type: int, id_lines: Sequence[str], function_id: int,
              abscissa_text: Sequence[str] | None = None) -> str:
    """One FRF as dataset 58 text (function type 4, complex double).

    Parameters
    ----------
    values : ndarray of complex, shape (n_lines,)
    frequency_hz : ndarray, shape (n_lines,)
    response, reference : Dof
        Output and input DOFs.
    numerator_type : int
        Specific data type of the output (8/11/12); the denominator is 13 (force).
    id_lines : sequence of 5 str
    function_id : int
        Record 6 field 2 (a running number).
    abscissa_text : sequence of str, optional
        Pre-formatted 13-character frequencies (shared by every FRF of a file).
    """
    h = np.asarray(values, complex).reshape(-1)
    even, first, step = _abscissa(frequency_hz)
    out = [f"{-1:6d}\n", f"{58:6d}{'':74s}\n"]
    out += [_id_line(t) for t in list(id_lines)[:5] + ["NONE"] * (5 - len(id_lines))]
    out.append(f"{4:5d}{function_id:10d}{0:5d}{0:10d} {'NONE':>10s}{response.node:10d}"
               f"{response.code:4d} {'NONE':>10s}{reference.node:10d}{reference.code:4d}\n")
    out.append(f"{6:10d}{h.size:10d}{int(even):10d}{number_field(first)}{number_field(step)}"
               f"{number_field(0.0)}\n")
    out.append(f"{18:10d}{0:5d}{0:5d}{0:5d} {'Frequency':<20s} {'Hz':<20s}\n")
    out.append(f"{numerator_type:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}\n")
    out.append(f"{13:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}\n")
    out.append(f"{0:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}\n")
    if even:
        flat = np.column_stack([h.real, h.imag]).reshape(-1)
        for i in range(0, flat.size, 4):
            out.append("".join(_e20(v) for v in flat[i:i + 4]) + "\n")
    else:
        xs = abscissa_text or [number_field(f) for f in frequency_hz]
        for x, v in zip(xs, h):
            out.append(f"{x}{_e20(v.real)}{_e20(v.imag)}\n")
    out.append(f"{-1:6d}\n")
    return "".join(out)


def node_vectors(shape: np.ndarray, dofs: Sequence[Dof]) -> tuple[dict[int, np.ndarray], list[str]]:
    """Per-node X/Y/Z vectors of one mode shape.

    Parameters
    ----------
    shape : ndarray of complex, shape (n_outputs,)
    dofs : sequence of Dof, length n_outputs

    Returns
    -------
    vectors : dict of int to ndarray of complex, shape (3,)
        A channel along ``-Z`` contributes ``-shape`` to Z.
    skipped : list of str
        Channels measuring rotations (dataset 55 with complex values holds translations).
    """
    vectors: dict[int, np.ndarray] = {}
    skipped = []
    for value, dof in zip(shape, dofs):
        axis = abs(dof.code)
        if axis > 3:
            skipped.append(dof.channel)
            continue
        vec = vectors.setdefault(dof.node, np.zeros(3, complex))
        vec[axis - 1] = np.sign(dof.code) * value
    return vectors, skipped


def uff_text(result: ResultArrays, output_dofs: Sequence[Dof], input_dofs: Sequence[Dof], *,
             kinds: Iterable[str] = FRF_KINDS, created: _dt.datetime | None = None,
             software: str = "fnsi-lab") -> tuple[str, list[str]]:
    """The whole export: every mode as 55, every FRF of ``kinds`` as 58.

    Parameters
    ----------
    result : ResultArrays
    output_dofs, input_dofs : sequence of Dof
        DOFs of ``result.outputs`` and ``result.inputs``, in their order.
    kinds : iterable of str
        FRF kinds to write (those present in the result).
    created : datetime, optional
        Date in ID line 3 (default now, UTC).
    software : str
        Written in ID line 2.

    Returns
    -------
    text : str
    notes : list of str
        What was left out (rotation channels in the shapes, FRF kinds absent).
    """
    when = _uff_date(created or _dt.datetime.now(_dt.timezone.utc))
    notes: list[str] = []
    parts = []
    spec = SPECIFIC_DATA_TYPES.get(result.output_quantity, 8)
    for k, (f, z, shape) in enumerate(zip(result.frequency_hz, result.damping_ratio,
                                          result.shapes)):
        vectors, skipped = node_vectors(shape, output_dofs)
        if skipped and k == 0:
            notes.append(f"rotation channels {skipped} are not in the UFF 55 shapes "
                         "(complex shapes there hold translations)")
        parts.append(uff55_mode(
            k + 1, f, z, vectors, specific_data_type=spec,
            id_lines=[f"mode {k + 1}: {f:.6f} Hz, damping {100 * z:.4f} %",
                      f"{software}: identified mode shape at the outputs (unscaled)",
                      when, f"order {result.order}" if result.order is not None else "NONE",
                      f"from {result.path}"[-80:]]))
    present = [k for k in kinds if k in result.frf]
    for k in kinds:
        if k not in result.frf:
            notes.append(f"no {k} FRF in the result")
    if present and result.frf_frequency_hz is not None:
        f = result.frf_frequency_hz
        x_text = [number_field(v) for v in f]
        fid = 0
        for kind in present:
            h = result.frf[kind]
            for i, out_dof in enumerate(output_dofs):
                for j, in_dof in enumerate(input_dofs):
                    fid += 1
                    parts.append(uff58_frf(
                        h[:, i, j], f, response=out_dof, reference=in_dof,
                        numerator_type=spec, function_id=fid, abscissa_text=x_text,
                        id_lines=[f"{kind} FRF {out_dof.channel} / {in_dof.channel}",
                                  f"{software}: {kind.replace('_', ' ')} frequency response",
                                  when,
                                  f"response {out_dof.channel} node {out_dof.node} "
                                  f"{out_dof.direction}, reference {in_dof.channel} node "
                                  f"{in_dof.node} {in_dof.direction}",
                                  f"from {result.path}"[-80:]]))
    return "".join(parts), notes
