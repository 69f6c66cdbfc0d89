"""One validation helper for every YAML file fnsi-lab reads.

:class:`Section` walks a mapping read from YAML, takes each known key with its type and
checks, and raises :class:`~fnsi_lab.errors.ConfigError` naming the file, the dotted field
and the fix. :meth:`Section.finish` rejects keys nobody asked for (typos are the most
common config bug).

Examples
--------
>>> sec = Section({"rate": 1000}, file="exp.yaml")
>>> sec.number("rate", positive=True)
1000.0
>>> sec.finish()
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence, TypeVar, overload

import yaml

from fnsi_lab import plain
from fnsi_lab.errors import ConfigError

_MISSING = object()
_Choice = TypeVar("_Choice", bound=str)


def load_yaml(path: str | Path, *, missing_fix: str = "check the path") -> tuple[Any, str]:
    """Read a YAML file, returning (data, text); every failure is a one-line ConfigError.

    ``missing_fix`` is the advice when the file does not exist (only a caller whose option
    has a default may suggest omitting it).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("file not found", file=str(path), fix=missing_fix) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read: {exc}", file=str(path)) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"not valid YAML{where}: {problem}", file=str(path)) from None
    return data, text


class Section:
    """A mapping being validated.

    Parameters
    ----------
    data : mapping
        The parsed YAML mapping.
    file : str, optional
        File name for messages.
    prefix : str, optional
        Dotted path of this mapping inside the file.
    """

    def __init__(self, data: Any, *, file: str | None = None, prefix: str = "") -> None:
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise ConfigError(f"expected a mapping (key: value), got {type(data).__name__}",
                              file=file, field=prefix or None)
        self.data = dict(data)
        self.file = file
        self.prefix = prefix
        self._used: set[str] = set()

    # -------------------------------------------------------------- helpers
    def field(self, key: str) -> str:
        """Dotted path of ``key``."""
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str | None, message: str, fix: str | None = None) -> ConfigError:
        """A ConfigError located at ``key`` of this section."""
        return ConfigError(message, file=self.file,
                           field=self.field(key) if key else (self.prefix or None), fix=fix)

    def has(self, key: str) -> bool:
        """True if the key is present (and marks it as known)."""
        self._used.add(key)
        return key in self.data

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        """The untyped value; raises if missing and no default."""
        self._used.add(key)
        if key in self.data and self.data[key] is not None:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, "missing required field", fix=f"add '{key}:'")
        return default

    def section(self, key: str, *, required: bool = False) -> "Section":
        """A nested mapping as its own Section."""
        value = self.raw(key, _MISSING if required else {})
        return Section(value, file=self.file, prefix=self.field(key))

    # -------------------------------------------------------------- typed getters
    def string(self, key: str, default: Any = _MISSING, *,
               choices: Sequence[str] | None = None) -> str:
        """A string, optionally one of ``choices``."""
        value = self.raw(key, default)
        if value is None:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"expected text, got {plain.value(value)}")
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, choices, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise self.error(key, f"{value!r} is not allowed", fix=f"{hint}use one of {plain.names(choices)}")
        return value

    @overload
    def choice(self, key: str, choices: Sequence[_Choice], default: None) -> _Choice | None: ...

    @overload
    def choice(self, key: str, choices: Sequence[_Choice], default: str = ...) -> _Choice: ...

    def choice(self, key: str, choices: Sequence[_Choice], default: Any = _MISSING
               ) -> _Choice | None:
        """One of ``choices`` (:meth:`string`), typed as they are: choices given as literal
        strings give a literal type. None when absent with the default None."""
        value = self.string(key, default, choices=choices)
        return None if value is None else next(c for c in choices if c == value)

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        """A true/false value."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {plain.value(value)}")
        return value

    def number(self, key: str, default: Any = _MISSING, *, positive: bool = False,
               nonnegative: bool = False, minimum: float | None = None,
               maximum: float | None = None) -> float:
        """A real number with optional bounds."""
        value = self.raw(key, default)
        if value is None:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"expected a number, got {plain.value(value)}")
        value = float(value)
        if positive and not value > 0:
            raise self.error(key, f"must be > 0, got {value:g}")
        if nonnegative and not value >= 0:
            raise self.error(key, f"must be >= 0, got {value:g}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum:g}, got {value:g}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be <= {maximum:g}, got {value:g}")
        return value

    def integer(self, key: str, default: Any = _MISSING, *, minimum: int | None = None,
                maximum: int | None = None) -> int:
        """An integer with optional bounds."""
        value = self.raw(key, default)
        if value is None:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise self.error(key, f"expected a whole number, got {plain.value(value)}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be <= {maximum}, got {value}")
        return int(value)

    def numbers(self, key: str, default: Any = _MISSING, *, length: int | None = None) -> tuple[float, ...]:
        """A list of numbers, optionally of fixed length."""
        value = self.raw(key, default)
        if value is None:
            return value
        if not isinstance(value, (list, tuple)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise self.error(key, f"expected a list of numbers, got {plain.value(value)}")
        if length is not None and len(value) != length:
            raise self.error(key, f"expected {length} numbers, got {len(value)}")
        return tuple(float(v) for v in value)

    def items(self, key: str, default: Any = _MISSING) -> list[Any]:
        """A list of anything (validated by the caller)."""
        value = self.raw(key, default)
        if not isinstance(value, list):
            raise self.error(key, f"expected a list, got {type(value).__name__}")
        return value

    # -------------------------------------------------------------- closing
    def finish(self, extra_allowed: Iterable[str] = ()) -> None:
        """Raise on keys that were never asked for (typos)."""
        allowed = self._used | set(extra_allowed)
        unknown = [k for k in self.data if k not in allowed]
        if unknown:
            key = str(unknown[0])
            close = difflib.get_close_matches(key, sorted(allowed), n=1)
            fix = f"did you mean {close[0]!r}?" if close else f"remove it; known keys: {plain.names(sorted(allowed))}"
            raise self.error(key, "unknown key", fix=fix)
