"""``fnsi-lab export``: an identification result -> UFF 55/58 and CSV tables."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fnsi_lab.arguments import INPUT
from fnsi_lab.errors import ConfigError, DataFileError
from fnsi_lab.export.dofs import (assign_dofs, channel_table_mapping, parse_mapping,
                                  read_mapping_file)
from fnsi_lab.export.result import FRF_KINDS, ResultArrays, load_result
from fnsi_lab.export.tables import CSV_FILES, write_tables
from fnsi_lab.export.uff import uff_text
from fnsi_lab.outputs import atomic_output, check_output_folder, check_output_path

EXAMPLES = """\
examples:
  fnsi-lab ident run.mcap --config smallsat39 --auto --json result.json
  fnsi-lab export result.json --uff result.uff --csv result-tables
  fnsi-lab export result.json --uff lumped.uff --map X1=1:+X X2=2:+X X3=3:+X F-X3=3:+X
  fnsi-lab export result.json --uff modes.uff --frf none --map-file dofs.csv

The UFF file holds every mode as dataset 55 (complex eigenvalue, complex shape at the
outputs) and the measured, model and underlying linear FRFs as dataset 58. Node and
direction come from --map / --map-file, else from the identified recording's channel table
(a UFF 58 import keeps the response nodes there), else from channel names like NC2-Z or
12:+X. See docs/formats.md.
"""


def register(subparsers) -> None:
    """Add the ``export`` subcommand to the ``fnsi-lab`` dispatcher."""
    p = subparsers.add_parser(
        "export", help="write an identification result as UFF 55/58 and CSV tables",
        description="Export the modes (UFF dataset 55: frequency, damping, complex shape per "
                    "measured channel), the measured, model and underlying linear FRFs (UFF "
                    "dataset 58) and CSV tables (modes, shapes, coefficients, coefficient "
                    "spectra) of a result written by `fnsi-lab ident --json`.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", type=INPUT, metavar="RESULT.json", help="result of fnsi-lab ident --json")
    p.add_argument("--uff", default=None, metavar="OUT.uff", help="UFF file to write")
    p.add_argument("--csv", default=None, metavar="DIR",
                   help=f"folder for the CSV tables ({', '.join(CSV_FILES)}); created if "
                        "missing")
    p.add_argument("--map", nargs="+", default=[], metavar="NAME=NODE:DIR",
                   help="node (number or label) and direction of channels whose names do "
                        "not say, e.g. X1=101:+Z F-NC2W-Z=NC2W:+Z")
    p.add_argument("--map-file", default=None, metavar="DOFS.csv",
                   help="CSV rows channel,node,direction (same meaning as --map)")
    p.add_argument("--recording", default=None, metavar="F.mcap",
                   help="recording whose channel table gives node and direction (default: "
                        "the result's input, when it is an .mcap file that exists)")
    p.add_argument("--frf", default=",".join(FRF_KINDS), metavar="KINDS",
                   help="FRFs to write as dataset 58, comma-separated from "
                        f"{', '.join(FRF_KINDS)}, or 'none' (default: all)")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(handler=run_export)


def _frf_kinds(text: str) -> tuple[str, ...]:
    if text.strip().lower() == "none":
        return ()
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in FRF_KINDS]
    if bad:
        raise ConfigError(f"unknown FRF kind {bad[0]!r}", field="--frf",
                          fix=f"use {', '.join(FRF_KINDS)} or none")
    return kinds


def recorded_dofs(result: ResultArrays, recording: str | None) -> dict[str, tuple[str, str]]:
    """Node and direction from the channel table of the identified recording.

    ``recording`` is given (``--recording``) or, by default, the result's input when it is
    an existing ``.mcap`` file (as written, or relative to the result file's folder; the
    first of several records identified together).
    """
    if recording is None:   # several records identified together: the first one's table
        given = Path(result.input_path.split(" + ")[0]) if result.input_path else None
        if given is None or given.suffix.lower() != ".mcap":
            return {}
        found = [p for p in (given, Path(result.path).parent / given) if p.is_file()]
        if not found:
            return {}
        recording = str(found[0])
    from fnsi_lab.daq.recording.reader import open_recording

    with open_recording(recording) as rec:
        return channel_table_mapping(rec.channels)


def run_export(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab export``; returns the exit status."""
    if args.uff is None and args.csv is None:
        raise ConfigError("nothing to write", field="--uff/--csv",
                          fix="give --uff OUT.uff and/or --csv DIR")
    kinds = _frf_kinds(args.frf)
    inputs = [args.result, args.map_file, args.recording]
    uff_path = (check_output_path(args.uff, force=args.force, option="--uff", inputs=inputs)
                if args.uff is not None else None)  # --uff "" is refused, not ignored
    csv_dir = None
    if args.csv is not None:
        # the folder (created when the tables are written) and every table in it
        if uff_path is not None and Path(args.csv).resolve() == uff_path.resolve():
            raise ConfigError(f"--uff and --csv both name {args.csv}: the CSV tables go in a "
                              "folder, the UFF file beside it", field="--csv",
                              fix="give --csv a folder name other than the UFF file")
        csv_dir = check_output_folder(args.csv, option="--csv", create=False, inputs=inputs)
        for name in CSV_FILES:
            if csv_dir.is_dir():
                check_output_path(csv_dir / name, force=args.force, option="--csv",
                                  inputs=[*inputs, uff_path])
    result = load_result(args.result)
    explicit = read_mapping_file(args.map_file) if args.map_file else {}
    explicit.update(parse_mapping(args.map))
    # explicit mapping > the recording's channel table > the channel names
    channels = set(result.outputs) | set(result.inputs)
    mapping = {k: v for k, v in recorded_dofs(result, args.recording).items() if k in channels}
    mapping.update(explicit)
    out_dofs = in_dofs = None
    if uff_path is not None:
        if not result.inputs and kinds:
            raise DataFileError(f"{result.path}: the result names no input channel, so FRFs "
                                "have no reference (fix: --frf none)")
        out_dofs, in_dofs = assign_dofs(result.outputs, result.inputs if kinds else (), mapping)
    else:
        try:
            out_dofs, _ = assign_dofs(result.outputs, (), {k: v for k, v in mapping.items()
                                                           if k in result.outputs})
        except ConfigError:
            out_dofs = None  # the CSV tables then leave node and direction empty
    notes: list[str] = []
    if uff_path is not None:
        from fnsi_lab import __version__

        text, notes = uff_text(result, out_dofs, in_dofs, kinds=kinds,
                               software=f"fnsi-lab {__version__}")
        with atomic_output(uff_path, "w", encoding="ascii") as fh:
            fh.write(text)
    written = []
    if csv_dir is not None:
        try:
            csv_dir.mkdir(exist_ok=True)
        except OSError as exc:
            raise DataFileError(f"--csv {csv_dir}: cannot create the folder "
                                f"({exc.strerror or exc}) (fix: choose a writable place)"
                                ) from None
        written = write_tables(csv_dir, result, out_dofs)
    if not args.quiet:
        if uff_path is not None:
            n_frf = sum(1 for k in kinds if k in result.frf) * len(out_dofs) * len(in_dofs)
            print(f"{uff_path}: {len(result.frequency_hz)} modes (dataset 55), {n_frf} FRFs "
                  "(dataset 58)")
            for d in out_dofs + in_dofs:
                print(f"  {d.channel:<20} node {d.node:<6d} {d.direction}"
                      + (f"   (label {d.node_label})" if str(d.node) != d.node_label else ""))
        for path in written:
            print(f"{path}")
        for note in notes:
            print(f"  note: {note}", file=sys.stderr)
    return 0
