"""``fnsi-lab batch`` (identify many inputs on Dask) and ``fnsi-lab campaign`` (compare them)."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from fnsi_lab import arguments as opt
from fnsi_lab.errors import ConfigError
from fnsi_lab.progress import Progress

BATCH_EXAMPLES = """\
examples:
  fnsi-lab batch 'runs/*.mcap' --config smallsat39 --auto --out campaign.parquet
  fnsi-lab batch runs/ --config ident.yaml --order 22 --out c.parquet --workers 2
  fnsi-lab batch 'runs/*.mcap' --config ident.yaml --auto --out c.parquet \\
      --scheduler tcp://10.0.0.5:8786          # a running 'dask scheduler' + 'dask worker's

Re-running the same command resumes: inputs whose result exists for the same content and
config are 'skipped'. Exit status 1 when any input failed (the table is still written).
docs/campaigns.md explains the table and the cluster set-ups.
"""

CAMPAIGN_EXAMPLES = """\
examples:
  fnsi-lab campaign campaign.parquet --rrd campaign.rrd && rerun campaign.rrd
  fnsi-lab campaign campaign.parquet --html campaign.html
  fnsi-lab campaign campaign.parquet --json comparison.json --output NC2W-Z
"""


def _batch(args: argparse.Namespace) -> int:
    from fnsi_lab.campaign.batch import (check_result_paths, dask_client, expand_inputs,
                                         find_done, make_spec, plan_inputs, run_batch)
    from fnsi_lab.campaign.table import is_campaign_table, read_table, write_table
    from fnsi_lab.outputs import check_output_folder, check_output_path

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"{args.workers} workers", field="--workers", fix="give N >= 1")
    spec = replace(make_spec(args.config, order=args.order, auto=args.auto, orders=args.orders),
                   crc_check=not getattr(args, "no_crc_check", False))
    inputs = expand_inputs(args.inputs)
    out = Path(args.out)
    # a campaign table is this command's own state (rewritten on resume); anything else
    # under that name is the user's and needs --force
    check_output_path(out, force=args.force or is_campaign_table(out), option="--out",
                      inputs=[spec.config, *inputs])
    # --results "" is refused, not read as "the folder of --out"
    results_dir = check_output_folder(args.results if args.results is not None else out.parent,
                                      option="--results", parents=True)
    t0 = time.perf_counter()
    planned = plan_inputs(inputs, results_dir)
    check_result_paths(planned, force=args.force)  # a user's file is never overwritten
    previous_rows = {}
    if out.exists() and is_campaign_table(out):
        rows, settings = read_table(out)
        if settings.get("config_sha256") == spec.config_sha256:
            previous_rows = {r["input_sha256"]: r for r in rows if r.get("input_sha256")}
    settings = {"config": spec.config, "config_sha256": spec.config_sha256,
                "method": "auto" if spec.auto else "order", "order": spec.order,
                "orders": spec.orders, "results": str(results_dir)}
    progress = Progress(len(planned), "batch", enabled=not args.quiet)

    def on_row(row: dict, counts) -> None:
        progress.update(1, counts.note())

    done = find_done(planned, spec, previous_rows)
    # nothing new: no cluster to start
    scheduler = args.scheduler if len(done) < len(planned) else "serial"
    with dask_client(scheduler, args.workers) as client:
        rows = run_batch(planned, spec, client=client, done=done, on_row=on_row)
    write_table(rows, out, settings)
    failed = [r for r in rows if r["status"] == "error"]
    n_ok = sum(r["status"] == "ok" for r in rows)
    n_skipped = sum(r["status"] == "skipped" for r in rows)
    print(f"{len(rows)} inputs: {n_ok} identified, {n_skipped} skipped (done before), "
          f"{len(failed)} failed in {time.perf_counter() - t0:.1f} s -> {out} "
          f"(results in {results_dir})")
    for r in failed:
        print(f"  failed: {r['file']}: {r['error']}", file=sys.stderr)
    return 1 if failed else 0


def _campaign(args: argparse.Namespace) -> int:
    from fnsi_lab.campaign.compare import compare_campaign, format_comparison
    from fnsi_lab.campaign.table import read_table
    from fnsi_lab.outputs import check_output_path, write_json

    written = [args.table]
    for target, option in ((args.rrd, "--rrd"), (args.json, "--json"), (args.html, "--html")):
        if target not in (None, "-"):  # '' is refused there
            check_output_path(target, force=args.force, option=option, inputs=written)
            written.append(target)
    rows, settings = read_table(args.table)
    comparison = compare_campaign(rows, output=args.output,
                                  driving_points=_driving_points(settings.get("config")),
                                  max_relative_spread=args.max_relative_spread,
                                  min_contact=args.min_contact)
    text = format_comparison(comparison)
    if args.json != "-":
        print(text)
    if args.rrd:
        from fnsi_lab.campaign.view import save_campaign_rrd

        save_campaign_rrd(comparison, args.rrd, summary=f"```\n{text}\n```")
        print(f"wrote {args.rrd} (open with: rerun {args.rrd})")
    if args.html:
        from fnsi_lab.campaign.report import render_campaign_report
        from fnsi_lab.outputs import atomic_output

        page = render_campaign_report(comparison, rows,
                                      title=f"fnsi-lab campaign: {Path(args.table).stem}")
        with atomic_output(args.html) as fh:
            fh.write(page)
        print(f"wrote {args.html}")
    write_json(comparison.to_json(), args.json, force=True)
    return 0


def _driving_points(config: str | None) -> dict[str, str]:
    """Input -> driving-point output of the campaign's ident config ({} if unreadable)."""
    import fnsi_lab
    from fnsi_lab.errors import FnsiLabError

    if not config:
        return {}
    try:
        return dict(fnsi_lab.load_config(config).driving_points or {})
    except (FnsiLabError, OSError):  # the config moved: the FRF then shows the first output
        return {}


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``batch`` and ``campaign`` to the ``fnsi-lab`` parser."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "batch", formatter_class=fmt,
        help="identify many recordings in parallel on Dask; one table row per input",
        description="Identify every INPUT (recordings or .npz/.mat files; folders and globs "
                    "accepted) as one Dask task through the same pipeline as 'fnsi-lab "
                    "ident', write each input's JSON result and one Parquet table (file, "
                    "status, worker, order, n_modes, force_rms and its unit, each coefficient, "
                    "its spread and unit). Resumable; one failing input never stops the others.",
        epilog=BATCH_EXAMPLES)
    p.add_argument("inputs", type=opt.INPUT, nargs="+", metavar="INPUT",
                   help="recording, array file, folder or quoted glob pattern")
    p.add_argument("--config", type=opt.INPUT, required=True, metavar="IDENT.yaml",
                   help="ident configuration, or a packaged name such as smallsat39")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--auto", action="store_true",
                     help="robust automatic pipeline (order by information criterion, "
                          "spurious poles removed)")
    how.add_argument("--order", type=opt.ORDER, metavar="N",
                     help="fixed model order (default: the config's 'order')")
    p.add_argument("--orders", type=opt.ORDERS, metavar="FIRST:LAST",
                   help="order sweep of --auto (default: the config's, else 2:60)")
    p.add_argument("--out", required=True, metavar="CAMPAIGN.parquet", help="the campaign table")
    p.add_argument("--results", metavar="DIR",
                   help="folder of the per-input JSON results (default: the folder of --out)")
    p.add_argument("--scheduler", default="local", metavar="local|serial|ADDRESS",
                   help="'local' (default): a local Dask cluster of worker processes; "
                        "'serial': no Dask, one input after the other in this process; or "
                        "the address of a running 'dask scheduler' (tcp://host:8786)")
    p.add_argument("--workers", type=opt.WORKERS, metavar="N",
                   help="local cluster: worker processes (default: CPU count); running "
                        "scheduler: wait for N workers (default 1)")
    p.add_argument("--force", action="store_true",
                   help="replace an --out file that is not a campaign table, and files in "
                        "the results folder that are not this command's results")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=_batch)

    p = sub.add_parser(
        "campaign", formatter_class=fmt,
        help="compare a campaign across force levels (coefficients, frequencies, FRFs)",
        description="Read a campaign table (fnsi-lab batch --out) and its JSON results: "
                    "nonlinear coefficients and natural frequencies against force level with "
                    "their spreads, the underlying linear FRFs of all runs overlaid (they "
                    "coincide when the model is right), and a warning wherever a coefficient "
                    "is not identifiable at a level (stop never in contact, or too large a "
                    "spread).",
        epilog=CAMPAIGN_EXAMPLES)
    p.add_argument("table", type=opt.INPUT, metavar="CAMPAIGN.parquet")
    p.add_argument("--rrd", metavar="FILE.rrd", help="Rerun recording of the comparison")
    p.add_argument("--html", metavar="FILE.html",
                   help="the comparison as one offline HTML page (figures inline, as "
                        "'fnsi-lab report')")
    p.add_argument("--json", metavar="OUT.json", help="the comparison as JSON ('-' for stdout)")
    p.add_argument("--output", metavar="CHANNEL",
                   help="output channel of the FRF overlay (default: the driving point)")
    p.add_argument("--max-relative-spread", type=opt.RELATIVE_SPREAD, default=0.1, metavar="R",
                   help="a coefficient whose spread exceeds R times |mean| is flagged "
                        "(default 0.1)")
    p.add_argument("--min-contact", type=opt.CONTACT_FRACTION, default=0.001, metavar="F",
                   help="a coefficient whose stop is closed less than this fraction of the "
                        "time is flagged (default 0.001; simulated recordings carry it)")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.set_defaults(handler=_campaign)
