"""``fnsi-lab excitation``: export an experiment's drive for a signal generator or DAQ output."""

from __future__ import annotations

import argparse

from fnsi_lab import arguments as opt
from fnsi_lab.progress import Progress


def _excitation(args: argparse.Namespace) -> int:
    from fnsi_lab.daq.config import load_experiment
    from fnsi_lab.daq.drive import design_drive, sidecar_path, write_drive, write_sidecar
    from fnsi_lab.outputs import check_output_path

    out = check_output_path(args.out, force=args.force, option="--out", inputs=[args.config])
    side = check_output_path(sidecar_path(out), force=args.force, option="--out's sidecar",
                             inputs=[args.config, out])
    config = load_experiment(args.config)
    if config.excitation is None:
        raise config.error("excitation", "the experiment has no excitation to export",
                           fix="add an 'excitation:' multisine section")
    progress = Progress(3, "excitation", enabled=not args.quiet)
    definition, signal = design_drive(config.excitation, config.sample_rate_hz,
                                      volts_per_newton=args.volts_per_newton, periods=args.periods)
    progress.update(1)
    definition = write_drive(out, definition, signal, wav_encoding=args.wav_encoding,
                             full_scale=args.full_scale)
    progress.update(1)
    write_sidecar(side, definition)
    progress.update(1)
    ex = definition.excitation
    f = definition.file
    print(f"wrote {out}: {f['n_samples']} samples at {definition.sample_rate_hz:g} Hz "
          f"({ex.realizations} realization(s) x {ex.periods} periods x {ex.samples_per_period}), "
          f"{definition.excited_lines.size} lines {definition.frequencies_hz[0]:.4g}-"
          f"{definition.frequencies_hz[-1]:.4g} Hz, RMS {ex.rms * definition.scale:.6g} "
          f"{definition.unit}" + (f"; {f['scale']}" if "scale" in f else ""))
    print(f"wrote {side}: the definition (lines, amplitudes, phases, seed, scaling, sha256 "
          f"{definition.signal_sha256[:12]}...); use it as 'excitation: {{file: {side.name}}}'")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``excitation`` to the ``fnsi-lab`` parser."""
    p = sub.add_parser(
        "excitation", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="export the experiment's drive signal (WAV/CSV/NPY/TDMS) and its definition",
        description="Write the exact multisine drive of an experiment (every realization and "
                    "period, at the experiment's sample rate) for a signal generator or a DAQ "
                    "output, plus DRIVE.json next to it: lines, amplitudes, phases, seed, N, "
                    "scaling and SHA-256 hashes. Without --volts-per-newton the file holds "
                    "newtons. WAV values are digital = drive / full scale (stated in the JSON "
                    "and printed). Put 'excitation: {file: DRIVE.json}' in a hardware "
                    "experiment so the recording knows the excited lines and the period "
                    "(docs/hardware.md).",
        epilog="examples:\n"
               "  fnsi-lab excitation --out drive.wav --volts-per-newton 0.01\n"
               "  fnsi-lab excitation --config rig.yaml --out drive.tdms --periods 100\n"
               "  fnsi-lab excitation --out drive.wav --wav-encoding pcm24 --full-scale 5\n"
               "  fnsi-lab excitation --out drive.csv        # newtons, time_s,drive_N\n")
    p.add_argument("--config", type=opt.INPUT, metavar="EXP.yaml",
                   help="experiment YAML (default: packaged smallsat.yaml)")
    p.add_argument("--out", required=True, metavar="DRIVE.{wav,csv,npy,tdms}",
                   help="drive file; its format follows the extension; DRIVE.json is written "
                        "next to it")
    p.add_argument("--volts-per-newton", type=opt.POSITIVE_SCALE, metavar="K",
                   help="scale the force to the amplifier input in volts (default: newtons)")
    p.add_argument("--periods", type=opt.PERIODS, metavar="P",
                   help="periods per realization in the file (default: the experiment's)")
    p.add_argument("--wav-encoding", choices=("float32", "pcm24"), default="float32",
                   help="WAV samples: 32-bit float (default) or 24-bit PCM")
    p.add_argument("--full-scale", type=opt.POSITIVE_SCALE, metavar="VALUE",
                   help="WAV: drive value (V or N) of digital full scale (default: the peak)")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=_excitation)
