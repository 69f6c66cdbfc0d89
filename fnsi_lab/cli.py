"""The ``fnsi-lab`` command: one dispatcher, subcommands contributed by each package.

Each of ``daq.cli``, ``ident.cli``, ``replay.cli`` and ``viewer.cli`` exposes
``register(subparsers)`` which adds its subcommands; a subcommand's handler takes the
parsed ``argparse.Namespace`` and returns an exit status. Errors derived from
:class:`~fnsi_lab.errors.FnsiLabError` are printed on one line (exit 2), never as a
traceback; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from fnsi_lab import __version__
from fnsi_lab.errors import FnsiLabError

#: Modules that contribute subcommands, in help order.
COMMAND_MODULES = ("fnsi_lab.daq.cli", "fnsi_lab.daq.drive_cli", "fnsi_lab.ident.cli", "fnsi_lab.replay.cli", "fnsi_lab.viewer.cli")

EPILOG = """\
examples:
  fnsi-lab run                         # simulated SmallSat: acquire -> MCAP -> identify -> Rerun
  fnsi-lab acquire --out test.mcap     # record the default SmallSat experiment
  fnsi-lab info test.mcap              # what is in a recording
  fnsi-lab ident test.mcap --config ident.yaml --auto --json result.json

'fnsi-lab COMMAND --help' explains each command with an example.
"""


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (every available subcommand registered)."""
    parser = argparse.ArgumentParser(
        prog="fnsi-lab",
        description="Nonlinear structural identification in the test lab: multisine "
                    "acquisition to MCAP, frequency-domain nonlinear subspace identification "
                    "(FNSI) with robust order selection and spurious-pole removal, and live "
                    "views in Rerun.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"fnsi-lab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # package not written yet: its commands are absent
                continue
            raise
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 0
    try:
        return int(handler(args) or 0)
    except FnsiLabError as exc:
        print(f"fnsi-lab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"fnsi-lab {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `fnsi-lab info x.mcap | head`
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
