"""The ``fnsi-lab`` command: one dispatcher, subcommands contributed by each package.

Each of ``daq.cli``, ``ident.cli``, ``replay.cli`` and ``viewer.cli`` exposes
``register(subparsers)`` which adds its subcommands; a subcommand's handler takes the
parsed ``argparse.Namespace`` and returns an exit status.

Exit codes (the same for every command; docs/cli.md): 0 success, 1 the work failed
(identification failed, nothing recovered, disk full...), 2 usage or input error (bad
option, config or file), 130 interrupted by Ctrl-C or SIGTERM (after the files were
finished cleanly). Errors derived from :class:`~fnsi_lab.errors.FnsiLabError` and
operating-system errors are printed on one line, never as a traceback.

Start-up: a command imports only the module that registers it (:data:`COMMAND_INDEX`), so
``fnsi-lab acquire`` never loads the identification or the viewer.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import signal
import sys
from typing import Sequence

from fnsi_lab import __version__
from fnsi_lab.blas import restored_blas_threads
from fnsi_lab.errors import FnsiLabError

#: Modules that contribute subcommands, in help order.
COMMAND_MODULES = ("fnsi_lab.daq.cli", "fnsi_lab.daq.drive_cli", "fnsi_lab.daq.formats.cli", "fnsi_lab.ident.cli", "fnsi_lab.ident.analyse_cli", "fnsi_lab.ident.locate_cli", "fnsi_lab.export.cli", "fnsi_lab.replay.cli", "fnsi_lab.viewer.cli", "fnsi_lab.viewer.report_cli", "fnsi_lab.campaign.cli", "fnsi_lab.validation_cli")

#: Command -> module registering it, for commands whose module need not be imported to
#: find them. A module of COMMAND_MODULES whose commands are not listed here still works:
#: it is imported whenever the command is not found in this index.
COMMAND_INDEX = {
    "acquire": "fnsi_lab.daq.cli", "info": "fnsi_lab.daq.cli", "recover": "fnsi_lab.daq.cli",
    "excitation": "fnsi_lab.daq.drive_cli", "ident": "fnsi_lab.ident.cli",
    "analyse": "fnsi_lab.ident.analyse_cli", "locate": "fnsi_lab.ident.locate_cli",
    "run": "fnsi_lab.replay.cli", "live": "fnsi_lab.replay.cli", "replay": "fnsi_lab.replay.cli",
    "view": "fnsi_lab.viewer.cli", "report": "fnsi_lab.viewer.report_cli", "import": "fnsi_lab.daq.formats.cli",
    "export": "fnsi_lab.export.cli",
    "batch": "fnsi_lab.campaign.cli", "campaign": "fnsi_lab.campaign.cli",
    "validate": "fnsi_lab.validation_cli",
}

#: Commands that read recordings: they get ``--no-crc-check``.
READS_RECORDINGS = ("info", "ident", "analyse", "locate", "replay", "report", "export", "batch", "validate")

EPILOG = """\
examples:
  fnsi-lab run                         # simulated SmallSat: acquire -> MCAP -> identify -> Rerun
  fnsi-lab acquire --out test.mcap     # record the default SmallSat experiment
  fnsi-lab info test.mcap              # what is in a recording
  fnsi-lab ident test.mcap --config ident.yaml --auto --json result.json

'fnsi-lab COMMAND --help' explains each command with an example.
exit codes: 0 success, 1 the work failed, 2 usage or input error, 130 interrupted.
"""


class _Parser(argparse.ArgumentParser):
    """argparse with its refusal of a bad choice in plain words: ``invalid choice: 'xyz'
    (choose from auto, generic, jenkins)``, not the tuple-like list of reprs Python 3.11
    writes. Subcommand parsers are of this class too (``add_subparsers`` inherits it)."""

    def _check_value(self, action: argparse.Action, value: object) -> None:
        if action.choices is not None and value not in action.choices:
            raise argparse.ArgumentError(action, f"invalid choice: {value!r} (choose from "
                                                 f"{', '.join(map(str, action.choices))})")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser: every available subcommand, or only ``command``'s module's."""
    parser = _Parser(
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
    modules = COMMAND_MODULES
    if command in COMMAND_INDEX and COMMAND_INDEX[command] in COMMAND_MODULES:
        modules = (COMMAND_INDEX[command],)
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # package not written yet: its commands are absent
                continue
            raise
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    for name in READS_RECORDINGS:
        if name in sub.choices and "--no-crc-check" not in sub.choices[name]._option_string_actions:
            sub.choices[name].add_argument(
                "--no-crc-check", action="store_true",
                help="do not check the recording's CRCs (faster; a damaged chunk is then "
                     "read as it is instead of being reported)")
    return parser


def _requested_command(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv`` (first word not starting with '-'), if any."""
    for word in argv:
        if not word.startswith("-"):
            return word
        if word == "--":
            return None
    return None


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM is handled like Ctrl-C: files are finished, the exit status is 130."""
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status.

    ``argv`` None (the process's own command line): the objects left when the command
    returns are frozen out of the garbage collector, since the interpreter's exit would
    otherwise traverse them all again (0.45-0.75 s measured once numba has loaded a
    kernel; the operating system frees the memory anyway). Tests that call
    ``main([...])`` keep their collector as it is.
    """
    process = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_requested_command(argv))
    args = parser.parse_args(argv)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 0
    args.whole_process = process  # handlers may tune process-wide settings (daq.cli)
    crc_check = None
    if getattr(args, "no_crc_check", False):  # for this command only (main may run in-process)
        from fnsi_lab.daq.recording import reader as crc_check
        crc_check.set_default_crc_check(False)
    previous = None
    if threading_main():
        previous = signal.signal(signal.SIGTERM, _terminate)
    blas = contextlib.nullcontext() if process else restored_blas_threads()
    try:
        with blas:  # in-process callers keep their BLAS thread count
            return int(handler(args) or 0)
    except FnsiLabError as exc:
        print(f"fnsi-lab {args.command}: error: {exc}", file=sys.stderr)
        return int(getattr(exc, "exit_code", 2))
    except KeyboardInterrupt:
        print(f"fnsi-lab {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `fnsi-lab info x.mcap | head`
        return 0
    except OSError as exc:  # disk full, permissions, ports...: the work failed
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"fnsi-lab {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if crc_check is not None:
            crc_check.set_default_crc_check(True)
        if process:
            import gc
            gc.freeze()


def threading_main() -> bool:
    """True in the main thread (where signal handlers can be installed)."""
    import threading
    return threading.current_thread() is threading.main_thread()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
