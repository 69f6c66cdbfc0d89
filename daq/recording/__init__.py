"""MCAP recording of sample blocks: writer, reader, recovery and ``info``.

One file per experiment: protobuf sample blocks (schema built at run time), JSON events,
metadata records ``fnsi_lab.<key>``, attachments (``experiment.yaml``...), zstd chunks
flushed about every second. The format is described in ``docs/recording-format.md``;
names live in :mod:`daq.recording.topics`.

- :class:`Recorder` writes (one thread), :func:`open_recording` / :func:`read_periodic`
  read, :func:`recover` salvages an unfinished file, :func:`recording_info` /
  :func:`format_info` describe one.
"""

from fnsi_lab.daq.recording.errors import (MissingChannelsError, NotMcapError, RecorderClosedError,
                                  RecordingError, RecordingNotFoundError,
                                  UnfinishedRecordingError, WrongSchemaError)
from fnsi_lab.daq.recording.info import format_info, recording_info
from fnsi_lab.daq.recording.reader import PeriodicRecord, Recording, open_recording, read_periodic
from fnsi_lab.daq.recording.recover import RecoverReport, recover
from fnsi_lab.daq.recording.writer import Recorder, experiment_attachment

__all__ = [
    "Recorder", "experiment_attachment", "Recording", "PeriodicRecord", "open_recording",
    "read_periodic", "RecoverReport", "recover", "recording_info", "format_info",
    "RecordingError", "RecordingNotFoundError", "NotMcapError", "UnfinishedRecordingError",
    "WrongSchemaError", "MissingChannelsError", "RecorderClosedError",
]
