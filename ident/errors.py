"""Exceptions of the ``ident`` package.

Every error a user can cause while identifying (wrong array shape, unknown channel, a
configuration that cannot give a nonlinear coefficient...) is an :class:`IdentError`, which
is both a :class:`fnsi_lab.errors.FnsiLabError` (the CLI prints it on one line, exit 2) and
a :class:`ValueError` (pattern of python-can's ``exceptions.py``).
"""

from __future__ import annotations

from fnsi_lab.errors import ConfigError, DataFileError, FnsiLabError, WorkFailedError


class IdentError(FnsiLabError, ValueError):
    """Identification cannot proceed with these data or options."""


class ChannelError(IdentError, KeyError):
    """A channel name (output, input, driving point, basis-function channel) is unknown."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class NotIdentifiableError(IdentError):
    """The requested quantity is not available from this measurement set-up.

    Example: the nonlinear coefficient needs the driving-point output (docs/method.md §2.3).

    Parameters
    ----------
    message : str
        One line: what cannot be told, why, and the fix.
    element : str, optional
        The basis element the refusal is about (a parameter search's), else None.
    """

    def __init__(self, message: str, *, element: str | None = None) -> None:
        super().__init__(message)
        self.element = element


class DeadBasisError(IdentError):
    """Basis functions identically zero on the data: their element never acts on the record
    (a clearance larger than the motion, or wrong channels).

    Parameters
    ----------
    message : str
    dead : sequence of str
        The coefficient names of the zero basis functions.
    """

    def __init__(self, message: str, *, dead: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.dead = tuple(dead)


class NoExcitedLineError(IdentError, WorkFailedError):
    """The processed band holds no excited line: no model can be driven there (exit 1).

    The data were read and are valid; the identification has nothing to work on (an ident
    config ``band_hz`` that misses the excitation), so the work failed (docs/cli.md).
    """

    exit_code = 1


class IdentConfigError(ConfigError, IdentError):
    """The ident YAML configuration is wrong (file, field and fix in the message)."""


class IdentDataError(DataFileError, IdentError):
    """An ident INPUT file is missing, unreadable or has the wrong content."""


class IdentWarning(UserWarning):
    """Something is suspicious but identification can continue (e.g. not in steady state)."""


__all__ = ["IdentError", "ChannelError", "NotIdentifiableError", "NoExcitedLineError",
           "IdentConfigError",
           "IdentDataError", "IdentWarning"]
