"""Root of the fnsi-lab exception tree.

Every error that a user can cause (bad config, bad file, missing channel...) derives from
:class:`FnsiLabError`; the CLI prints its message on one line and exits with status 2,
never with a traceback. Sub-packages root their own trees here, inheriting a builtin as
well (``ConfigError(FnsiLabError, ValueError)``), in the pattern of python-can's
``exceptions.py``.
"""

from __future__ import annotations


class FnsiLabError(Exception):
    """Base class of every error fnsi-lab raises on purpose.

    ``exit_code`` is the status the command line exits with: 2 (usage or input error) by
    default, 1 for :class:`WorkFailedError` (docs/cli.md).
    """

    exit_code = 2


class WorkFailedError(FnsiLabError, RuntimeError):
    """The input was fine but the work failed (identification, disk full...): exit 1."""

    exit_code = 1


class ConfigError(FnsiLabError, ValueError):
    """A configuration file or option is wrong.

    Parameters
    ----------
    message : str
        What is wrong.
    file : str, optional
        The file it was read from.
    field : str, optional
        Dotted path of the offending field (``excitation.band_hz``).
    fix : str, optional
        What to do about it.
    """

    def __init__(self, message: str, *, file: str | None = None, field: str | None = None,
                 fix: str | None = None) -> None:
        self.file = file
        self.field = field
        self.fix = fix
        self.reason = message
        parts = []
        where = ": ".join(p for p in (file, field) if p)
        if where:
            parts.append(where)
        parts.append(message)
        text = ": ".join(parts)
        if fix:
            text += f" (fix: {fix})"
        super().__init__(text)


class DataFileError(FnsiLabError, OSError):
    """A data or recording file is missing, unreadable or not what it claims to be."""


class SourceError(FnsiLabError, RuntimeError):
    """A data source failed (device gone, closed source read, ...)."""
