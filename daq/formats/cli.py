"""``fnsi-lab import``: a lab file (TDMS, UFF 58, CSV) -> an fnsi-lab recording."""

from __future__ import annotations

import argparse
import sys

from fnsi_lab import arguments as opt
from fnsi_lab.daq.formats.importer import plan_import, read_lab_file, write_recording
from fnsi_lab.outputs import check_output_path
from fnsi_lab.progress import Progress

EXAMPLES = """\
examples:
  fnsi-lab import shaker.tdms --out shaker.mcap --inputs "Force Z" --samples-per-period 8192 \\
      --transient-periods 1
  fnsi-lab import testlab_time.uff --out run.mcap --samples-per-period 4096
  fnsi-lab import export.csv --out run.mcap --inputs F1 --fs 2048 --output-quantity acceleration
  fnsi-lab info run.mcap && fnsi-lab ident run.mcap --config ident.yaml --auto

Channel names, units and the sample rate come from the file where it has them (TDMS
unit_string and wf_increment, UFF 58 record fields, CSV header 'name [unit]' and a time
column). Forces (unit N, UFF data type 13) are the inputs unless --inputs names them.
Node and direction come from names like NC2-Z. See docs/formats.md.
"""


def register(subparsers) -> None:
    """Add the ``import`` subcommand to the ``fnsi-lab`` dispatcher."""
    p = subparsers.add_parser(
        "import", help="convert a TDMS, UFF 58 or CSV time-data file into a recording",
        description="Convert measured time data from another tool (NI TDMS, Universal File "
                    "Format dataset 58 time records, CSV) into an fnsi-lab MCAP recording "
                    "that info, ident and replay read like an acquisition; its metadata "
                    "records the source file (path, format, SHA-256) and the options.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=opt.INPUT, metavar="FILE", help=".tdms, .uff/.unv, .csv/.txt/.tsv")
    p.add_argument("--out", required=True, metavar="REC.mcap", help="recording to write")
    p.add_argument("--inputs", nargs="+", default=None, metavar="NAME",
                   help="input (force) channels; default: the channels the file marks as "
                        "forces")
    p.add_argument("--fs", type=opt.SAMPLE_RATE, default=None, metavar="HZ",
                   help="sample rate, when the file does not give it (checked when it does)")
    p.add_argument("--samples-per-period", type=opt.SAMPLES_PER_PERIOD, default=None, metavar="N",
                   help="multisine period in samples (else ident needs it in its config)")
    p.add_argument("--transient-periods", type=opt.TRANSIENT_PERIODS, default=None, metavar="K",
                   help="leading periods to drop before identification")
    p.add_argument("--output-quantity", default=None,
                   choices=("displacement", "velocity", "acceleration"),
                   help="quantity of output channels whose unit does not say (V, none...)")
    p.add_argument("--exclude", nargs="+", default=(), metavar="NAME",
                   help="channels not to import")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.add_argument("--quiet", action="store_true", help="no summary, no progress bar")
    p.set_defaults(handler=run_import)


def run_import(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab import``; returns the exit status."""
    out = check_output_path(args.out, force=args.force, option="--out", inputs=[args.file])
    table = read_lab_file(args.file)
    plan = plan_import(table, inputs=args.inputs, sample_rate_hz=args.fs,
                       samples_per_period=args.samples_per_period,
                       transient_periods=args.transient_periods,
                       output_quantity=args.output_quantity, exclude=args.exclude)
    options = {"inputs": args.inputs, "fs": args.fs,
               "samples_per_period": args.samples_per_period,
               "transient_periods": args.transient_periods,
               "output_quantity": args.output_quantity, "exclude": list(args.exclude)}
    bar = Progress(table.data.shape[0], "import", enabled=not args.quiet)
    done = [0]

    def advance(samples: int, total: int) -> None:
        bar.update(samples - done[0])
        done[0] = samples

    write_recording(table, plan, out, options=options, on_block=advance)
    if not args.quiet:
        n_in = sum(c.is_force for c in plan.channels)
        print(f"{out}: {table.data.shape[0]} samples x {len(plan.channels)} channels "
              f"({n_in} inputs) @ {plan.sample_rate_hz:g} Hz from {table.format} file "
              f"{args.file}")
        for c in plan.channels:
            role = "in " if c.is_force else "out"
            where = f"  node {c.node} {c.direction}" if c.node else ""
            print(f"  {role} {c.name:<20} {c.quantity:<13} [{c.unit}]{where}")
        if plan.samples_per_period:
            k = plan.transient_periods
            print(f"  period N = {plan.samples_per_period}, "
                  f"{table.data.shape[0] // plan.samples_per_period} periods, "
                  f"transient {k if k is not None else 'not given'}")
        for note in plan.notes:
            print(f"  note: {note}", file=sys.stderr)
    return 0
