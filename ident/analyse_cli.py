"""``fnsi-lab analyse``: nonlinear distortion analysis of multisine records, before any model.

A thin layer over :func:`fnsi_lab.analyse` (the one entry point, shared with the API and the
benchmarks): parse the options, call it, print the verdicts, write the JSON, the Rerun
recording and the HTML report.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

EXAMPLES = """\
examples:
  fnsi-lab analyse test.mcap
  fnsi-lab analyse low.mcap mid.mcap high.mcap --config smallsat39 --json levels.json
  fnsi-lab analyse data.npz --rrd analysis.rrd --report analysis.html

Per record and output: the best linear approximation (FRF), its noise (period-to-period
spread) and nonlinear-distortion levels (non-excited odd/even detection lines, and the
spread over realisations), and a verdict whose false-alarm probability is at most --alpha
per record. Several records of one structure (e.g. force levels): the resonances' shift
and the distortion against level. Design tests for it with an odd random-phase multisine
with detection lines ('excitation: {grid: random-odd}', docs/discovery.md).
"""


def register(subparsers) -> None:
    """Add the ``analyse`` subcommand to the ``fnsi-lab`` dispatcher."""
    p = subparsers.add_parser(
        "analyse", help="is it nonlinear? noise and distortion levels of multisine records",
        description="Nonlinear distortion analysis of periodic multisine records: best "
                    "linear approximation, noise and odd/even distortion levels per line, "
                    "a verdict per output, resonances and their shift with level.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", metavar="REC",
                   help="recordings (.mcap) or array files (.npz, .mat) of one structure")
    p.add_argument("--config", default=None, metavar="IDENT.yaml",
                   help="ident configuration: its drive (inputs[0].name), outputs and "
                        "transient_periods are used; a bare name picks a packaged example")
    p.add_argument("--band", nargs=2, type=float, default=None, metavar=("F1", "F2"),
                   help="analysed band in Hz (default: lowest excited line to 3x the "
                        "highest, at most 0.45 fs)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="false-alarm probability of a 'nonlinear' verdict per record "
                        "(default 0.01)")
    p.add_argument("--json", dest="json_out", default=None, metavar="OUT.json",
                   help="write the analysis as JSON ('-' for stdout)")
    p.add_argument("--spectra", action="store_true",
                   help="include the per-line levels in the JSON (large with many channels)")
    p.add_argument("--rrd", default=None, metavar="OUT.rrd",
                   help="write a Rerun recording of the analysis (open with 'fnsi-lab view')")
    p.add_argument("--report", default=None, metavar="OUT.html",
                   help="write an offline HTML report with the level plots")
    p.add_argument("--output", action="append", default=None, metavar="NAME",
                   help="output(s) drawn in the Rerun recording and the report (default: "
                        "the three whose distortion stands highest above the noise)")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no summary on stdout")
    p.set_defaults(handler=run_analyse)


def _approx(resolution_hz: float | None) -> str:
    """``~`` before a frequency read at a line (half power), else nothing."""
    return "~" if resolution_hz else ""


def _fmt_db(x: Any) -> str:
    return "     -" if x is None else f"{x:6.1f}"


def print_summary(report: Any, out=None) -> None:
    """Verdicts, levels and resonances of every record; the comparison by level."""
    out = out or sys.stdout
    for rec in report.records:
        d = rec.to_dict()
        exc = d["excitation"]
        print(f"{rec.path or '<arrays>'}: input {rec.input_channel} RMS {rec.input_rms:.4g}, "
              f"{rec.n_realizations} realisation(s) x {rec.n_periods} period(s), "
              f"{exc['n_excited']} excited lines ({exc['grid']}), analysed "
              f"{d['analysis_band_hz'][0]:.4g}-{d['analysis_band_hz'][1]:.4g} Hz; noise: "
              f"{rec.noise_source}", file=out)
        print("  output           output  noise    odd   even  (dB)  verdict", file=out)
        for o in rec.outputs:
            print(f"  {o.name:15s} {_fmt_db(o.output_db)} {_fmt_db(o.noise_db)} "
                  f"{_fmt_db(o.odd_distortion_db)} {_fmt_db(o.even_distortion_db)}        "
                  f"{o.verdict}", file=out)
        for note in rec.notes:
            print(f"  note: {note}", file=out)
        if rec.resonances:
            print("  resonances: " + ", ".join(
                f"{_approx(r.resolution_hz)}{r.frequency_hz:.4g} Hz ({100 * r.damping_ratio:.2f} %)"
                for r in rec.resonances), file=out)
            coarse = [r.resolution_hz for r in rec.resonances if r.resolution_hz]
            if coarse:
                print(f"  (~: read at the peak's line by its half-power points, +-{coarse[0]:.3g}"
                      " Hz; the others from a second-order fit)", file=out)
    for note in report.notes:
        print(f"note: {note}", file=out)
    lv = report.levels
    if lv:
        print("by level (input RMS " + ", ".join(f"{x:.4g}" for x in lv["input_rms"]) + "):",
              file=out)
        for row in sorted(lv["resonances"] + lv.get("resonances_appearing", []),
                          key=lambda r: next(f for f in r["frequency_hz"] if f is not None)):
            f = ", ".join("-" if v is None else f"{_approx(r)}{v:.4g}"
                          for v, r in zip(row["frequency_hz"], row["resolution_hz"]))
            s = ", ".join("-" if v is None else f"{v:+.2f}" for v in row["shift_percent"])
            z = ", ".join("-" if v is None else f"{100 * v:.2f}" for v in row["damping_ratio"])
            print(f"  resonance {f} Hz (shift {s} %; damping {z} %)", file=out)
        from fnsi_lab.ident.core.level_comparison import SAME_SHAPE_MAC

        print("  (a resonance is followed from level to level where its frequency is the "
              + (f"nearest and its shape agrees, MAC >= {SAME_SHAPE_MAC}"
                 if len(lv["outputs"]) >= 2 else
                 # one output: every MAC is 1 (docs/discovery.md)
                 f"nearest; one output compared ({lv['outputs'][0]['name']}): the shapes "
                 "cannot tell modes apart, so by frequency alone")
              + ("; ~: read at a line, +- half the line spacing)"
                 if any(r for row in lv["resonances"] + lv.get("resonances_appearing", [])
                        for r in row["resolution_hz"]) else ")"),
              file=out)
        rising = [r["name"] for r in lv["outputs"]
                  if None not in r["relative_distortion_db"]
                  and r["relative_distortion_db"][-1] > r["relative_distortion_db"][0]]
        print(f"  distortion relative to the output rises with level on {len(rising)} of "
              f"{len(lv['outputs'])} outputs", file=out)


def run_analyse(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab analyse``; returns the exit status."""
    import fnsi_lab
    from fnsi_lab.outputs import check_output_path, write_json

    if args.json_out not in (None, "-"):
        check_output_path(args.json_out, force=args.force, option="--json",
                          inputs=[*args.inputs, args.config])
    if args.rrd is not None:
        check_output_path(args.rrd, force=args.force, option="--rrd",
                          inputs=[*args.inputs, args.config], outputs={"--json": args.json_out})
    if args.report is not None:
        check_output_path(args.report, force=args.force, option="--report",
                          inputs=[*args.inputs, args.config],
                          outputs={"--json": args.json_out, "--rrd": args.rrd})
    if not 0 < args.alpha < 1:
        from fnsi_lab.errors import ConfigError
        raise ConfigError(f"--alpha {args.alpha} is not a probability", field="--alpha",
                          fix="give a value between 0 and 1, e.g. 0.01")
    report = fnsi_lab.analyse(args.inputs, args.config, band_hz=args.band, alpha=args.alpha)
    if not args.quiet and args.json_out != "-":
        print_summary(report)
    write_json(report.to_json(spectra=args.spectra), args.json_out, force=True)
    if args.rrd is not None:
        from fnsi_lab.viewer.distortion import save_rrd

        save_rrd(report, args.rrd, outputs=args.output)
        if not args.quiet and args.json_out != "-":
            print(f"Rerun recording: {args.rrd}")
    if args.report is not None:
        from fnsi_lab.viewer.distortion import write_report

        write_report(report, args.report, outputs=args.output)
        if not args.quiet and args.json_out != "-":
            print(f"report: {args.report}")
    return 0
