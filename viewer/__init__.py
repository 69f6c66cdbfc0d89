"""Rerun views of fnsi-lab: entity paths, ``log_*`` functions, the blueprint, ``fnsi-lab view``.

- :mod:`viewer.paths`: entity paths and timelines (one constants module);
- :mod:`viewer.log`: one ``log_*`` function per entity subtree, explicit RecordingStream;
- :mod:`viewer.blueprint`: the declarative layout, origins from :mod:`viewer.paths`;
- :mod:`viewer.cli`: sinks (``--rrd``, ``--spawn``, ``--connect``, ``--serve-web``) and the
  ``view`` command.
"""

from fnsi_lab.viewer import paths  # noqa: F401
from fnsi_lab.viewer.blueprint import blueprint  # noqa: F401

__all__ = ["paths", "blueprint"]
