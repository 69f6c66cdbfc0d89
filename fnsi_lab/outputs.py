"""Writing output files without ever destroying a user's data.

Every command that writes a file (recordings, JSON results, reports, exports, drive
signals) goes through :func:`check_output_path` before the work starts and writes through
:func:`atomic_output` so that a crash never leaves a half-written file under the final
name: the content goes to a temporary sibling (``.NAME.partial-PID``) that is renamed onto
the final name only when the writer finished without an exception.

Recordings are the exception to the rename rule: a growing MCAP file must stay under its
final name while it is written so that ``replay --follow`` can read it and ``recover``
can salvage it after a crash (docs/recording-format.md); they only use the existence
check.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from fnsi_lab.errors import DataFileError, FnsiLabError


class OutputExistsError(FnsiLabError, FileExistsError):
    """The output file exists and ``--force`` was not given."""


def check_output_path(path: str | os.PathLike[str] | None, *, force: bool = False,
                      option: str = "--out",
                      inputs: Iterable[str | os.PathLike[str] | None] = (),
                      outputs: Mapping[str, str | os.PathLike[str] | None] | None = None
                      ) -> Path:
    """Validate an output path before any work is done: the one check every command uses.

    Parameters
    ----------
    path : path-like
        Where the output will be written.
    force : bool
        Allow replacing an existing regular file (never one of ``inputs``).
    option : str
        Name of the CLI option, for the error message.
    inputs : iterable of path-like
        The command's input files (recordings, configs, results); an output that is one of
        them is refused even with ``force`` (None entries are ignored).
    outputs : mapping of str to path-like, optional
        The command's other outputs, by option (``{"--json": "val.json"}``; None and '-'
        entries are ignored): two outputs under one name would leave only the one written
        last, so one that is also ``path`` is refused, ``force`` or not.

    Returns
    -------
    Path

    Raises
    ------
    DataFileError
        Empty path, a directory, an input or another output of the command, or a parent
        folder that does not
        exist or cannot be written (tried with a temporary file: permission bits say
        nothing for root or on a read-only file system).
    OutputExistsError
        The file exists and ``force`` is False.
    """
    text = "" if path is None else os.fspath(path)
    if not str(text).strip():
        raise DataFileError(f"{option} is empty (fix: give a file name)")
    p = Path(text)
    if p.is_dir():
        raise DataFileError(f"{option} {p}: is a folder (fix: give a file name inside it)")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise DataFileError(f"{option} {p}: folder {parent} does not exist (fix: create it)")
    _refuse_inputs(p, option, inputs)
    for other_option, other in (outputs or {}).items():
        if other is not None and os.fspath(other) != "-" and _same_file(p, other):
            raise DataFileError(f"{option} {p}: is also the {other_option} output of this "
                                "command; nothing was written (fix: give each output its own "
                                "name)")
    if p.exists() and not force:
        raise OutputExistsError(f"{option} {p}: file exists; nothing was written "
                                "(fix: choose another name, or add --force to replace it)")
    _require_writable(parent, f"{option} {p}: folder {parent}")
    return p


def check_output_folder(path: str | os.PathLike[str] | None, *, option: str,
                        parents: bool = False, create: bool = True,
                        inputs: Iterable[str | os.PathLike[str] | None] = ()) -> Path:
    """Validate a folder the command writes files into (before any work), and create it.

    Parameters
    ----------
    path : path-like
        The folder (``export --csv DIR``, ``batch --results DIR``).
    option : str
        Name of the CLI option, for the error message.
    parents : bool
        Create missing parent folders too (else the parent must exist).
    create : bool
        Create the folder now; False: only check that it could be (the caller creates it
        when it writes, so a failed command leaves no empty folder).
    inputs : iterable of path-like
        Input files of the command; the folder may not be one of them.

    Returns
    -------
    Path

    Raises
    ------
    DataFileError
        Empty path, an existing file, a folder that cannot be created or written.
    """
    text = "" if path is None else os.fspath(path)
    if not str(text).strip():
        raise DataFileError(f"{option} is empty (fix: give a folder name)")
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise DataFileError(f"{option} {p}: is a file, not a folder (fix: give a folder)")
    _refuse_inputs(p, option, inputs)
    if not p.is_dir():
        parent = p.parent if str(p.parent) else Path(".")
        if not parents and not parent.is_dir():
            raise DataFileError(f"{option} {p}: folder {parent} does not exist "
                                "(fix: create it)")
        if not create:
            while not parent.is_dir() and parent != parent.parent:
                parent = parent.parent
            _require_writable(parent, f"{option} {p}: cannot be created, folder {parent}")
            return p
        try:
            p.mkdir(parents=parents, exist_ok=True)
        except OSError as exc:
            raise DataFileError(f"{option} {p}: cannot create the folder "
                                f"({exc.strerror or exc}) (fix: choose a writable place)"
                                ) from None
    _require_writable(p, f"{option} {p}: folder")
    return p


def _refuse_inputs(p: Path, option: str,
                   inputs: Iterable[str | os.PathLike[str] | None]) -> None:
    """An output that is one of the command's inputs would destroy it: refused, --force
    or not."""
    for given in inputs:
        if given is not None and _same_file(p, given):
            raise DataFileError(f"{option} {p}: is also an input of this command ({given}); "
                                "nothing was written (fix: give the output another name)")


def _same_file(p: Path, given: str | os.PathLike[str]) -> bool:
    """``p`` and ``given`` name the same file (existing or not; '' names none)."""
    if not str(os.fspath(given)).strip():
        return False
    other = Path(os.fspath(given))
    try:
        return (os.path.samefile(p, other) if p.exists() and other.exists()
                else p.resolve() == other.resolve())
    except OSError:
        return False


def _require_writable(folder: Path, what: str) -> None:
    """Create and remove a temporary file in ``folder``: the only test that holds for root,
    read-only file systems and ACLs alike."""
    if os.access(folder, os.W_OK):
        try:
            fd, probe = tempfile.mkstemp(prefix=".fnsi-lab-probe-", dir=folder)
        except OSError:
            pass
        else:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(probe)
            return
    raise DataFileError(f"{what} is not writable (fix: choose another folder, or make it "
                        "writable)")


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], mode: str = "w", *,
                  encoding: str | None = "utf-8") -> Iterator[Any]:
    """Open a temporary sibling of ``path`` for writing; rename it onto ``path`` on success.

    On an exception the temporary file is removed and ``path`` is untouched. Disk-full and
    permission errors become one-line :class:`DataFileError` naming the file.
    """
    final = Path(path)
    tmp = final.with_name(f".{final.name}.partial-{os.getpid()}")
    binary = "b" in mode
    try:
        fh = open(tmp, mode, **({} if binary else {"encoding": encoding}))
    except OSError as exc:
        raise DataFileError(f"cannot write {final}: {exc.strerror or exc}") from None
    try:
        with fh:
            yield fh
        os.replace(tmp, final)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise DataFileError(f"cannot write {final}: {exc.strerror or exc}"
                            " (nothing was written under that name)") from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def json_safe(obj: Any, *, unknown: str = "str") -> Any:
    """``obj`` with numpy scalars/arrays as Python values and NaN/inf as None (JSON null).

    Complex numbers become ``{"re", "im"}``, paths text, sets sorted lists and objects with
    a ``to_dict()`` method their dictionary. ``unknown`` says what happens to anything
    else: ``'str'`` (default) stores ``str(obj)``, ``'error'`` raises ``TypeError`` (the
    recordings: a metadata value that is not data is a bug to report, not text to store).
    """
    def rec(v: Any) -> Any:
        return json_safe(v, unknown=unknown)

    if isinstance(obj, dict):
        return {str(k): rec(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        # long lists of plain numbers (spectra, FRFs) without a call per element
        if obj and all(type(v) in _PLAIN_NUMBERS for v in obj):
            return [v if type(v) is not float or math.isfinite(v) else None for v in obj]
        if obj and isinstance(obj[0], list):   # nested numbers (FRFs): as one array
            try:
                arr = np.asarray(obj)
            except ValueError:                 # ragged
                arr = None
            if arr is not None and arr.dtype.kind in "biuf":
                return rec(arr)
        return [rec(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "biu":
            return obj.tolist()
        if obj.dtype.kind == "f":
            finite = np.isfinite(obj)
            if finite.all():
                return obj.tolist()
            out = obj.astype(object)
            out[~finite] = None
            return out.tolist()
        return rec(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, (complex, np.complexfloating)):
        return {"re": rec(obj.real), "im": rec(obj.imag)}
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, (set, frozenset)):
        try:
            items = sorted(obj)
        except TypeError:
            items = sorted(obj, key=repr)
        return [rec(v) for v in items]
    to_dict = getattr(obj, "to_dict", None)
    if callable(to_dict):
        try:
            d = to_dict()
        except TypeError:  # a to_dict that needs arguments is not a plain serialisation
            d = None
        if isinstance(d, dict):
            return rec(d)
    if unknown == "error":
        raise TypeError(f"{type(obj).__name__} is not JSON serializable")
    return str(obj)


_PLAIN_NUMBERS = (float, int, bool)


def dumps(obj: Any, *, unknown: str = "str", indent: int | None = None, **kw: Any) -> str:
    """The one JSON encoder of fnsi-lab: :func:`json_safe`, then strict JSON (no NaN).

    ``unknown`` as in :func:`json_safe`; other keywords go to :func:`json.dumps`
    (``separators``...). With ``indent``, objects and lists of objects are laid out one
    member per line while arrays of numbers or strings stay on one line each: a result file
    stays readable, and its spectra and FRFs (about a million numbers for the SmallSat) go
    through the C encoder instead of Python's indenting one (1.2 s per result before).
    Used for result files, campaign tables and the JSON inside recordings (metadata
    records, events, auxiliary topics).
    """
    safe = json_safe(obj, unknown=unknown)
    if indent is None:
        return json.dumps(safe, allow_nan=False, **kw)
    return _laid_out(safe, int(indent), 0, kw)


def _is_leaf(value: Any) -> bool:
    """An array of scalars (or of such arrays): one line. Result arrays are homogeneous,
    so the first element decides."""
    while isinstance(value, list) and value:
        value = value[0]
    return not isinstance(value, (dict, list))


def _laid_out(value: Any, indent: int, level: int, kw: dict) -> str:
    if isinstance(value, dict) and value:
        pad, inner = " " * (indent * level), " " * (indent * (level + 1))
        members = (f"{inner}{json.dumps(str(k))}: {_laid_out(v, indent, level + 1, kw)}"
                   for k, v in value.items())
        return "{\n" + ",\n".join(members) + "\n" + pad + "}"
    if isinstance(value, list) and value and not _is_leaf(value):
        pad, inner = " " * (indent * level), " " * (indent * (level + 1))
        items = (inner + _laid_out(v, indent, level + 1, kw) for v in value)
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False, **kw)


def write_json(obj: Any, target: str | os.PathLike[str] | None, *, force: bool = True) -> None:
    """Write ``obj`` as indented JSON to ``target`` ('-' = stdout, None = nowhere)."""
    if target is None or target == "":
        return
    text = dumps(obj, indent=2)
    if os.fspath(target) == "-":
        print(text)
        return
    check_output_path(target, force=force, option="--json")
    with atomic_output(target) as fh:
        fh.write(text + "\n")
