"""Rerun views of fnsi-lab: entity paths, ``log_*`` functions, the blueprint, ``fnsi-lab view``.

- :mod:`viewer.paths`: entity paths and timelines (one constants module);
- :mod:`viewer.log`: one ``log_*`` function per entity subtree, explicit RecordingStream;
- :mod:`viewer.blueprint`: the declarative layout, origins from :mod:`viewer.paths`;
- :mod:`viewer.cli`: sinks (``--rrd``, ``--spawn``, ``--connect``, ``--serve-web``) and the
  ``view`` command.
"""

from typing import Any

__all__ = ["paths", "blueprint"]


def __getattr__(name: str) -> Any:  # lazy: importing the package does not load rerun
    import importlib

    # import_module, not `from fnsi_lab.viewer import paths`: that asks this hook again
    if name == "paths":
        return importlib.import_module("fnsi_lab.viewer.paths")
    if name == "blueprint":
        return importlib.import_module("fnsi_lab.viewer.blueprint").blueprint
    raise AttributeError(f"module 'fnsi_lab.viewer' has no attribute {name!r}")
