"""Errors of the lab-file importers (one line: which file, channel and field, and the fix)."""

from __future__ import annotations

from fnsi_lab.errors import DataFileError


class LabFileError(DataFileError):
    """A lab file (TDMS, UFF, CSV) cannot be imported as it is."""
