"""``fnsi-lab acquire | info | recover``: the acquisition half of the command line."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fnsi_lab.arguments import INPUT
from fnsi_lab.progress import Progress, announce_simulator_compile


def _acquire(args: argparse.Namespace) -> int:
    import gc

    # No cyclic garbage collection during the start-up of the `fnsi-lab acquire` process:
    # the imports, the model and numba's registries create ~120k long-lived objects that
    # every full collection would traverse again (~0.15 s of the default acquisition).
    # Frozen and collected normally again from the first block on (a long hardware
    # acquisition keeps its collector). Not when main() runs inside another program.
    restart_gc = gc.isenabled() and getattr(args, "whole_process", False)
    if restart_gc:
        gc.disable()
    try:
        return _acquire_started(args, restart_gc)
    finally:
        if restart_gc and not gc.isenabled():
            gc.enable()


def _acquire_started(args: argparse.Namespace, restart_gc: bool) -> int:
    import gc

    import numpy  # noqa: F401 - loads OpenBLAS, so that its thread count can be set

    from fnsi_lab.blas import limit_blas_threads
    from fnsi_lab.daq.acquisition import record_experiment
    from fnsi_lab.daq.config import load_experiment

    # The simulated sources' small dense solves (model construction, 96x96 eigenproblems)
    # run ~30x slower in CPU time with several OpenBLAS threads on a shared small machine.
    limit_blas_threads(1)

    from fnsi_lab.outputs import check_output_path

    config = load_experiment(args.config)
    if getattr(args, "level", None) is not None:
        config = _at_level(config, float(args.level))
    if config.excitation is not None and config.excitation.levels:
        if restart_gc:  # several recordings: the collector on from the start
            gc.freeze()
            gc.enable()
        return _acquire_levels(args, config)
    output = str(check_output_path(config.output if args.out is None else args.out,
                                   force=args.force, inputs=[args.config, config.file]))
    total = None
    if config.excitation is not None and config.source.kind in ("simulated", "smallsat", "aircraft"):
        ex = config.excitation
        total = ex.samples_per_period * ex.periods * ex.realizations
    progress = Progress(total or 1, "acquire", enabled=not args.quiet and total is not None)

    def on_block(block: Any, report: Any) -> None:
        if restart_gc and not gc.isenabled():  # start-up over (see _acquire)
            gc.freeze()
            gc.enable()
        progress.update(block.n_samples)

    if not args.quiet:
        what = f"{config.name} ({config.source.kind})"
        pace = "at wall-clock speed" if args.realtime else "as fast as possible"
        print(f"acquiring {what} {pace} -> {output}", file=sys.stderr)
    announce_simulator_compile(config.source.kind, enabled=not args.quiet)
    report = record_experiment(config, output, realtime=args.realtime,
                               on_block=on_block, stop=None)
    print(report.summary())
    if report.interrupted:
        print("fnsi-lab acquire: interrupted", file=sys.stderr)
        return 130
    if not args.no_info:
        from fnsi_lab.daq.recording.info import format_info, recording_info
        print(format_info(recording_info(output)))
    return 0


def _at_level(config: Any, level: float) -> Any:
    """``--level``: one run at ``level`` RMS (a level sweep's ``levels`` dropped), recorded
    to ``<name>-rms<level>.mcap`` like the sweep's files unless ``--out`` is given."""
    from dataclasses import replace

    if config.excitation is None:
        raise config.error("excitation", "--level needs an experiment with an excitation",
                           fix="drop --level, or use a config with an 'excitation:' section")
    if not level > 0:
        raise config.error("excitation.rms", f"--level {level:g}: must be an RMS > 0",
                           fix="e.g. --level 98")
    excitation = replace(config.excitation, rms=level, levels=())
    return replace(config, excitation=excitation, output=f"{config.name}-rms{level:g}.mcap")


def _acquire_levels(args: argparse.Namespace, config: Any) -> int:
    """``excitation.levels``: one recording per force level in a campaign folder."""
    from pathlib import Path

    from fnsi_lab.daq.acquisition import record_experiment
    from fnsi_lab.outputs import check_output_path

    folder = Path(args.out or Path(config.output).with_suffix(""))
    if folder.suffix == ".mcap":
        raise config.error("excitation.levels", f"--out {folder}: a level sweep records one "
                           "file per level into a folder",
                           fix="give a folder name for --out, e.g. --out campaign/")
    folder.mkdir(parents=True, exist_ok=True)
    runs = config.level_runs(folder)
    for _, run in runs:  # refuse before recording anything
        check_output_path(run.output, force=args.force, inputs=[args.config, config.file])
    for i, (level, run) in enumerate(runs, 1):
        if not args.quiet:
            print(f"level {i}/{len(runs)}: {level:g} RMS -> {run.output}", file=sys.stderr)
        report = record_experiment(run, run.output, realtime=args.realtime)
        print(report.summary())
        if report.interrupted:
            return 130
    print(f"campaign folder {folder}: {len(runs)} recordings "
          f"(next: fnsi-lab batch {folder} --config IDENT.yaml --auto --out {folder}/campaign.parquet)")
    return 0


def _info(args: argparse.Namespace) -> int:
    from fnsi_lab.daq.recording.info import format_info, recording_info

    info = recording_info(args.file)
    if args.json:
        from fnsi_lab.outputs import dumps
        print(dumps(info, indent=2))
    else:
        print(format_info(info))
    return 0


def _recover(args: argparse.Namespace) -> int:
    from fnsi_lab.daq.recording.recover import recover
    from fnsi_lab.outputs import check_output_path

    check_output_path(args.out, force=args.force, option="OUT", inputs=[args.broken])
    report = recover(args.broken, args.out)
    print(report.summary())
    if not report.sample_messages:
        print(f"fnsi-lab recover: error: {args.broken}: no intact sample block to recover; "
              f"{args.out} was not written", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``acquire``, ``info`` and ``recover`` to the ``fnsi-lab`` parser."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "acquire", formatter_class=fmt,
        help="record an experiment (default: the simulated SmallSat) to MCAP",
        description="Run an experiment's source and record every block to one MCAP file "
                    "(zstd chunks, flushed every second, experiment config, channel table, "
                    "excitation and, for simulated structures, the truth stored inside). "
                    "Without --config, the paper's SmallSat experiment runs: multisine "
                    "5-50 Hz, 100 N RMS at NC2 wheel side, 8192 samples per period at 1 kHz, "
                    "6 periods of which 5 transient.",
        epilog="examples:\n"
               "  fnsi-lab acquire --out smallsat.mcap\n"
               "  fnsi-lab acquire --config my_rig.yaml --realtime   # pace as hardware would\n"
               "  fnsi-lab acquire --config lumped.yaml              # packaged small model\n"
               "  fnsi-lab acquire --config sweep.yaml --out campaign/  # excitation.levels: one file per level\n"
               "  fnsi-lab acquire --config aircraft --level 98      # aircraft-like GVT at 98 N RMS\n")
    p.add_argument("--config", type=INPUT, metavar="FILE.yaml", help="experiment YAML (default: packaged smallsat.yaml)")
    p.add_argument("--out", metavar="FILE.mcap", help="output file (default: the config's 'output')")
    p.add_argument("--realtime", action="store_true",
                   help="pace a simulated source at wall-clock speed, as hardware would deliver it")
    p.add_argument("--level", type=float, metavar="RMS",
                   help="one run at this excitation RMS (force unit, e.g. N) instead of the "
                        "config's rms or levels; default output <name>-rms<RMS>.mcap")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-info", action="store_true", help="do not print the recording summary afterwards")
    p.add_argument("--force", action="store_true",
                   help="replace an existing output file (or the recordings of a level sweep)")
    p.set_defaults(handler=_acquire)

    p = sub.add_parser(
        "info", formatter_class=fmt, help="show what an MCAP recording holds",
        description="Print the channels, duration, periods, excitation, metadata and (for "
                    "simulated structures) the truth of an fnsi-lab recording.",
        epilog="examples:\n  fnsi-lab info smallsat.mcap\n  fnsi-lab info smallsat.mcap --json | jq .truth.modes\n")
    p.add_argument("file", type=INPUT, metavar="FILE.mcap")
    p.add_argument("--json", action="store_true",
                   help="one JSON object (channels, duration_s, sample_rate_hz, samples_per_period, "
                        "periods, messages, excitation, truth...)")
    p.set_defaults(handler=_info)

    p = sub.add_parser(
        "recover", formatter_class=fmt,
        help="rebuild a clean, indexed file from an unfinished or damaged recording",
        description="Salvage a recording whose writer was killed (no summary, no footer) or "
                    "whose bytes were damaged: every chunk that passes its CRC is copied, with "
                    "its schemas, channels, metadata and attachments, into a new indexed MCAP "
                    "file. A damaged chunk is skipped and reading resumes at the next intact "
                    "one; the report gives the damaged byte ranges and the seconds of signal "
                    "missing. Exit 1 when no sample block could be recovered (nothing is "
                    "written then).",
        epilog="examples:\n  fnsi-lab recover crashed.mcap crashed.recovered.mcap\n"
               "  fnsi-lab recover damaged.mcap fixed.mcap --force   # replace fixed.mcap\n")
    p.add_argument("broken", type=INPUT, metavar="BROKEN.mcap")
    p.add_argument("out", metavar="OUT.mcap")
    p.add_argument("--force", action="store_true", help="replace OUT.mcap if it exists")
    p.set_defaults(handler=_recover)
