"""Replay and live identification.

- :class:`replay.source.ReplaySource`: an MCAP recording as a :class:`daq.source.Source`
  (as fast as possible, paced, or following a file still being written);
- :mod:`replay.service`: the identification service (period assembly, steady state,
  re-identification as periods accumulate, in its own threads, skipping to the newest data
  when it falls behind);
- :mod:`replay.cli`: ``fnsi-lab live`` and ``fnsi-lab replay``.

Modules are imported lazily so that ``import replay`` stays cheap.
"""

__all__ = ["ReplaySource", "IdentService"]


def __getattr__(name: str):  # lazy: the registry imports replay.source on demand only
    if name == "ReplaySource":
        from fnsi_lab.replay.source import ReplaySource
        return ReplaySource
    if name == "IdentService":
        from fnsi_lab.replay.service import IdentService
        return IdentService
    raise AttributeError(name)
