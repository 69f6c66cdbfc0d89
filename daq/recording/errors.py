"""Errors of the recording layer; all are :class:`fnsi_lab.errors.DataFileError`.

Every message is one line naming the file and the fix, because the CLI prints it as is.
"""

from __future__ import annotations

from fnsi_lab.errors import DataFileError


class RecordingError(DataFileError):
    """A recording cannot be written or read as an fnsi-lab MCAP file."""


class RecordingNotFoundError(RecordingError, FileNotFoundError):
    """The recording file does not exist."""


class NotMcapError(RecordingError):
    """The file is not an MCAP file at all."""


class UnfinishedRecordingError(RecordingError):
    """The MCAP file has no footer (writer crashed or was killed): run ``fnsi-lab recover``."""


class DamagedRecordingError(RecordingError):
    """A CRC mismatch or an unparsable record inside a recording: run ``fnsi-lab recover``."""


class WrongSchemaError(RecordingError):
    """A valid MCAP file without the fnsi-lab sample topic or with another schema."""


class MissingChannelsError(RecordingError):
    """The channel table is absent or does not match the sample blocks."""


class RecordingWriteError(RecordingError):
    """Writing the recording failed (disk full, file too large, I/O error): exit status 1.

    What was flushed before stays recoverable with ``fnsi-lab recover``.
    """

    exit_code = 1


class RecorderClosedError(RecordingError):
    """A write was attempted on a closed :class:`~daq.recording.writer.Recorder`."""
