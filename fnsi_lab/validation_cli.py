"""``fnsi-lab validate RESULT.json RECORD``: an identified model on a record it was not fitted to."""

from __future__ import annotations

import argparse
import sys
from typing import Any

EPILOG = """\
examples:
  fnsi-lab ident low.mcap --config duffing.yaml --auto --json low.json
  fnsi-lab validate low.json high.mcap                      # simulate low.json's model on high.mcap
  fnsi-lab validate low.json high.mcap --json val.json --svg val.svg
  fnsi-lab validate r98.json gvt/aircraft-rms84.mcap        # aircraft GVT, another level

Per output: the RMS of the measured output over the model's band, and of the simulation
error of the nonlinear model and of its underlying linear model, in the record's units and
in dB relative to the output (negative: below it). Exit status 1 when the nonlinear model
has no steady state on the record (the linear figures are still printed and written).
"""


def _validate(args: argparse.Namespace) -> int:
    from fnsi_lab.model_validation import figure_validation, load_result, validate_model
    from fnsi_lab.outputs import atomic_output, check_output_path, write_json

    if args.transient_periods is not None and args.transient_periods < 0:
        from fnsi_lab.errors import ConfigError

        raise ConfigError(f"{args.transient_periods}: a count of periods cannot be negative",
                          field="--transient-periods",
                          fix="give the number of leading periods to drop, 0 or more")
    if args.json_out is not None and args.json_out != "-":  # '' is refused there, not ignored
        check_output_path(args.json_out, force=args.force, option="--json",
                          inputs=[args.result, args.record])
    if args.svg is not None:
        check_output_path(args.svg, force=args.force, option="--svg",
                          inputs=[args.result, args.record], outputs={"--json": args.json_out})
    result, name = load_result(args.result)   # a wrong RESULT: one line, before the progress
    if not args.quiet:
        print(f"validating {args.result} on {args.record} ...", file=sys.stderr)
    v = validate_model(result, args.record, method=args.method,
                       samples_per_period=args.samples_per_period,
                       transient_periods=args.transient_periods, simulate=args.model,
                       result_name=name)
    _print(v)
    if args.json_out:
        write_json(v.to_json(), args.json_out)
    if args.svg:
        with atomic_output(args.svg) as fh:
            figure_validation(v).savefig(fh, format="svg")
    if not v.converged:
        print("fnsi-lab validate: the nonlinear model has no steady state on this record "
              f"({v.simulation.info.get('reason')})", file=sys.stderr)
        return 1
    return 0


def _print(v: Any, out=None) -> None:
    out = out or sys.stdout
    info = v.info
    lo, hi = info["band_hz"]
    extra = (f", {info['n_periods']} periods averaged" if info.get("n_periods") else "")
    print(f"validation ({v.method}, {lo:g}-{hi:g} Hz{extra}; nonlinear terms: "
          f"{', '.join(info['nonlinearities']) or 'none'})", file=out)
    has_fit = any("linear_fit_error_rms" in r for r in v.outputs)
    print(f"{'output':14s} {'output RMS':>12s}  {'nonlinear error':>24s}  {'linear error':>24s}"
          + (f"  {'linear fit error':>24s}" if has_fit else ""), file=out)
    for r in v.outputs:
        nl = ("-" if r["error_rms"] is None
              else f"{r['error_rms']:.4g} ({r['error_db']:+.1f} dB)")
        lin = f"{r['linear_error_rms']:.4g} ({r['linear_error_db']:+.1f} dB)"
        fit = (f"  {r['linear_fit_error_rms']:.4g} ({r['linear_fit_error_db']:+.1f} dB)"
               .rjust(26) if "linear_fit_error_rms" in r else "")
        print(f"{r['name']:14s} {r['output_rms']:>12.4g}  {nl:>24s}  {lin:>24s}{fit}   "
              f"[{r.get('unit', '')}]", file=out)
    if has_fit:
        print("(linear error: the answer's underlying linear model; linear fit: the linear "
              "model identified on the same data, nonlinear_vs_linear)", file=out)
    for w in info.get("warnings", []):
        print(f"  warning: {w}", file=out)


def register(subparsers) -> None:
    """Add ``validate`` to the ``fnsi-lab`` parser."""
    p = subparsers.add_parser(
        "validate", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="simulate an identified model on another record and compare (nonlinear vs linear)",
        description="Simulate the nonlinear model of an 'fnsi-lab ident --json' result, and "
                    "its underlying linear model, with a record's measured force (periodic "
                    "record: harmonic balance, the model's motion predicted on every line; "
                    "otherwise time integration from rest) and compare with the measured "
                    "outputs over the identified band (docs/validate.md). "
                    "The record may be .mcap, .npz or .mat, as for 'fnsi-lab ident'.",
        epilog=EPILOG)
    p.add_argument("result", metavar="RESULT.json", help="result of fnsi-lab ident --json")
    p.add_argument("record", metavar="RECORD", help="recording or array file (.mcap, .npz, .mat)")
    p.add_argument("--json", dest="json_out", metavar="OUT.json",
                   help="write outputs[].{name, output_rms, error_rms, error_db, "
                        "linear_error_rms, linear_error_db} and the method's details")
    p.add_argument("--svg", metavar="FIG.svg",
                   help="figure: measured output spectrum and both errors per output")
    p.add_argument("--method", choices=("auto", "balance", "time"), default="auto",
                   help="auto (default): harmonic balance for periodic records, time "
                        "integration otherwise")
    p.add_argument("--model", choices=("answer", "nonlinear"), default="answer",
                   help="answer (default): the result's answer, the linear fit when its "
                        "nonlinear terms were found not supported (nonlinear_vs_linear); "
                        "nonlinear: the nonlinear model whatever that decision")
    p.add_argument("--samples-per-period", type=int, metavar="N",
                   help="N of an array file that does not give it")
    p.add_argument("--transient-periods", type=int, metavar="K",
                   help="leading periods of RECORD to drop (default: the record's own count, "
                        "else the identification's)")
    p.add_argument("--force", action="store_true", help="replace existing --json/--svg files")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(handler=_validate)
