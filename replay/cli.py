"""``fnsi-lab live`` and ``fnsi-lab replay``: identification while data arrive, shown in Rerun.

``live``: experiment source -> :func:`daq.acquisition.record_experiment` (MCAP) with an
analysis tap -> :class:`replay.service.IdentService` -> Rerun. ``replay``: an MCAP file
(finished, or growing with ``--follow``) -> the same service -> Rerun. Both end with the
result table (the paper's Table 2 layout) on stdout.
"""

from __future__ import annotations

import logging

import argparse
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

from fnsi_lab import plain
from fnsi_lab import arguments as opt
from fnsi_lab.errors import ConfigError
from fnsi_lab.blas import limit_blas_threads
from fnsi_lab.progress import announce_simulator_compile

from fnsi_lab.ident.request import DEFAULT_ORDERS


# ---------------------------------------------------------------------------- helpers
def make_identifier(args: argparse.Namespace, metadata: dict[str, Any],
                    channels: Any = ()) -> tuple[Callable, str]:
    """The ``identify(record)`` of the run and a one-line description of it.

    ``--ident IDENT.yaml`` (an :mod:`ident.config` file: band, basis functions, driving
    points, orders) drives the robust pipeline; without it, the excited band is processed
    and a simulated recording's own nonlinear elements (its ``truth``) are the basis.
    """
    from fnsi_lab.replay.identifiers import config_identifier, frf_identifier

    if getattr(args, "method", "auto") == "frf":
        return frf_identifier, "nonparametric FRF (fast)"
    config = None
    if getattr(args, "ident", None):
        from fnsi_lab.api import load_config

        config = load_config(args.ident)  # a file, or a packaged example by name
        check_ident_channels(config, channels)
    return config_identifier(config, truth=metadata.get("truth"), orders=getattr(args, "orders", None),
                             channels=channels, harmonics=getattr(args, "harmonics", 1.0))


def check_ident_channels(config: Any, channels: Any) -> None:
    """Refuse an ident config naming channels the experiment does not record (before any
    acquisition starts).

    Raises
    ------
    ConfigError
        Naming the ident file, the field, the channel and the experiment's channel list.
    """
    if config is None or not channels:
        return
    ins = [c.name for c in channels if c.is_force]
    outs = [c.name for c in channels if not c.is_force]
    file = getattr(config, "file", None)
    fix = "use channel names of the experiment (fnsi-lab info FILE.mcap lists them)"
    for name in config.outputs or ():
        if name not in outs:
            raise ConfigError(f"output channel {name!r} is not recorded by this experiment "
                              f"(its output channels: {plain.names(outs)})", file=file, field="outputs", fix=fix)
    selected = list(config.outputs or outs)
    for spec in config.inputs:
        if spec.name not in ins:
            raise ConfigError(f"input channel {spec.name!r} is not recorded by this experiment "
                              f"(its force channels: {plain.names(ins)})", file=file, field="inputs", fix=fix)
        if spec.driving_point is not None and spec.driving_point not in selected:
            raise ConfigError(f"driving point {spec.driving_point!r} of input {spec.name!r} is "
                              f"not among the identified outputs {plain.names(selected)}", file=file,
                              field="inputs", fix="name a recorded response channel at the "
                                                  "excitation point (and list it in outputs:)")
    for nl in config.nonlinearities:
        for ch in getattr(nl, "channels", {}) or {}:
            if ch not in selected:
                where = "identified outputs" if config.outputs else "experiment's outputs"
                raise ConfigError(f"nonlinearity {nl.name!r}: channel {ch!r} is not among the "
                                  f"{where} ({plain.names(selected)})", file=file, field="nonlinearities",
                                  fix="add it to outputs: or name recorded channels")


def identification_failure(service: Any) -> str | None:
    """Why a run produced no identification (None when at least one update succeeded)."""
    st = service.status
    if service.updates:
        return None
    if st.failures:
        return st.last_error or "the identification raised an error"
    if st.periods == 0:
        return (f"no complete period was received ({st.signal_s:.1f} s of signal in "
                f"{st.blocks} blocks); record at least the transient periods plus one")
    return (f"only {st.steady_periods} steady-state period(s) of {st.periods} received; "
            "record more periods (excitation.periods) or fewer transient ones")


class LiveRun:
    """Glue between the service and Rerun: logs signals and updates, prints the status.

    Parameters
    ----------
    rec : rerun.RecordingStream
    channels : sequence of ChannelInfo
    quiet : bool
        No status line.
    decimation : int
        Signal decimation for the viewer.
    file_path : Path or None
        File whose size the status line shows.
    batch_s : float
        Signal seconds buffered before one ``send_columns`` per channel group.
    """

    def __init__(self, rec: Any, channels: Any, *, quiet: bool = False, decimation: int = 1,
                 file_path: Path | None = None, batch_s: float = 0.5) -> None:
        from fnsi_lab.viewer import log as vlog

        self.rec = rec
        self.vlog = vlog
        self.quiet = quiet
        self.decimation = decimation
        self.file_path = file_path
        names = [c.name for c in channels]
        self.groups = vlog.channel_groups(names, [c.quantity for c in channels])
        vlog.log_signal_styles(rec, self.groups, names,
                               directions=[getattr(c, "direction", "") for c in channels],
                               units=[getattr(c, "unit", "") for c in channels])
        self.service: Any = None
        self.batch_s = batch_s
        self._buf: list[tuple[float, Any]] = []
        self._buffered_s = 0.0
        self.latencies: list[float] = []
        self._stop = threading.Event()
        self._printer: threading.Thread | None = None
        self._tty = sys.stderr.isatty()
        self._last_line = ""  # a log (not a terminal) gets a status line only when it changed

    # called in the assembler thread
    def on_block(self, block: Any, acq_t0_s: float) -> None:
        # batch consecutive blocks (~0.5 s) into one send_columns per group: fewer, larger
        # chunks cost the SDK, the file and the viewer far less than one per block
        if self._buf:
            last_t0, last = self._buf[-1]
            contiguous = abs(last_t0 + last.duration_s - acq_t0_s) < 0.5 / block.sample_rate_hz
            if not contiguous or block.sample_rate_hz != last.sample_rate_hz:
                self.flush_signals()
        self._buf.append((acq_t0_s, block))
        self._buffered_s += block.duration_s
        if self._buffered_s >= self.batch_s:
            self.flush_signals()

    def flush_signals(self) -> None:
        """Send the buffered blocks (call once more after the service has finished)."""
        if not self._buf:
            return
        import numpy as np

        t0, first = self._buf[0]
        data = np.concatenate([b.data for _, b in self._buf], axis=0)
        self.vlog.log_signals(self.rec, data, t0, first.sample_rate_hz, self.groups,
                              decimation=self.decimation)
        self._buf.clear()
        self._buffered_s = 0.0

    # called in the identifier thread
    def on_update(self, update: Any) -> None:
        from fnsi_lab.replay.identifiers import AutoIdentification, FrfResult
        from fnsi_lab.viewer.views import auto_view

        if isinstance(update.result, AutoIdentification):
            view = auto_view(update)
        elif isinstance(update.result, FrfResult):
            view = frf_view(update)
        else:
            view = {}
        self.vlog.log_identification(self.rec, view, update=update.update)
        self.latencies.append(time.monotonic() - update.period_received_s)
        st = self.service.status if self.service is not None else None
        values = {"updates": update.update, "identification_s": update.ident_s,
                  "latency_s": self.latencies[-1]}
        if st is not None:
            values.update(dropped_blocks=st.dropped_blocks, skipped_updates=st.skipped,
                          periods=st.periods, behind=st.behind)
        self.vlog.log_status(self.rec, update.acq_time_s, values,
                             f"update {update.update}: {update.n_periods} steady periods, "
                             f"identified in {update.ident_s:.2f} s")

    def file_size(self) -> int | None:
        if self.file_path is None:
            return None
        try:
            return os.path.getsize(self.file_path)
        except OSError:
            return None

    def start_status(self) -> None:
        if self.quiet:
            return

        def loop() -> None:
            while not self._stop.wait(1.0):
                self.print_status()

        self._printer = threading.Thread(target=loop, name="fnsi-lab-status", daemon=True)
        self._printer.start()

    def print_status(self, final: bool = False) -> None:
        if self.quiet or self.service is None:
            return
        line = self.service.status.line(self.file_size())
        if self._tty and not final:
            sys.stderr.write("\r" + line + "\x1b[K")
        elif line == self._last_line and not self._tty:
            return  # nothing new (e.g. while the simulator compiles): no repeated line
        else:
            self._last_line = line
            sys.stderr.write(("\r" if self._tty else "") + line + "\n")
        sys.stderr.flush()

    def stop_status(self) -> None:
        self._stop.set()
        if self._printer is not None:
            self._printer.join()
        self.print_status(final=True)


def frf_view(update: Any) -> dict[str, Any]:
    """View dict of a nonparametric :class:`replay.identifiers.FrfResult` update."""
    from fnsi_lab.replay.identifiers import driving_point
    from fnsi_lab.viewer.log import summary_markdown

    res = update.result
    dp = driving_point(update.record.output_channels, update.record.input_channels)
    return {"frf": {"frequency_hz": res.frequencies_hz, "measured": res.frf[:, dp, 0]},
            "summary": summary_markdown(f"FRF update {update.update}",
                                        [("periods averaged", str(update.n_periods))])}


def format_table(update: Any) -> str:
    """Plain-text result table (the paper's Table 2 layout) of the last update."""
    from fnsi_lab.replay.identifiers import AutoIdentification
    from fnsi_lab.viewer.views import left_out_hz, mode_table, summary_rows

    if update is None:
        return "no identification (the reason follows)"
    if not isinstance(update.result, AutoIdentification):
        return f"nonparametric FRF from {update.n_periods} steady-state periods"
    lines = ["", "Result (last update)", "-" * 20]
    rows = summary_rows(update)
    width = max(len(k) for k, _ in rows)
    lines += [f"{k:<{width}}  {v}" for k, v in rows]
    table = mode_table(update.result.result, left_out_hz(update.result))
    if table:
        cols = list(table[0])
        w = [max(len(c), *(len(str(r[c])) for r in table)) for c in cols]
        lines += ["", "  ".join(c.rjust(n) for c, n in zip(cols, w))]
        lines += ["  ".join(str(r[c]).rjust(n) for c, n in zip(cols, w)) for r in table]
    conf = update.result.result.confidence.get("statement")
    if conf:
        lines += ["", conf]
    return "\n".join(lines)


def _finish_report(run: LiveRun, service: Any, sinks: Any, wall_s: float) -> None:
    st = service.status
    last = service.updates[-1] if service.updates else None
    print(format_table(last))
    lat = run.latencies
    print(f"\nservice: {st.blocks} blocks, {st.periods} periods ({st.steady_periods} steady), "
          f"{st.updates} identifications, {st.skipped} skipped (newer data arrived), "
          f"{st.dropped_blocks} blocks dropped, {st.lost_samples} samples lost, "
          f"{st.failures} failures{(' (' + st.last_error + ')') if st.last_error else ''}")
    if st.behind:
        print(f"identification could not keep up: {st.behind} of {st.updates} took longer than "
              f"the {st.update_budget_s:.2f} s between updates (each ran on the newest data; "
              f"{st.skipped} snapshots skipped)")
    if lat:
        import numpy as np

        print(f"latency end of period -> Rerun update: median {np.median(lat):.2f} s, "
              f"max {max(lat):.2f} s; wall time {wall_s:.1f} s")
    for note in sinks.notes:
        print(note, file=sys.stderr)
    if sinks.rrd:
        print(f"Rerun recording saved to {sinks.rrd} (fnsi-lab view {sinks.rrd})")


def _service_for(channels: Any, rate: float, metadata: dict[str, Any], identify: Callable,
                 run: LiveRun, args: argparse.Namespace) -> Any:
    from fnsi_lab.replay.service import IdentService

    extra = {}
    if getattr(args, "steady_tolerance", None) is not None:
        extra["steady_state_tolerance"] = args.steady_tolerance
    service = IdentService.for_recording_metadata(
        channels, rate, metadata, identify, on_update=run.on_update, on_block=run.on_block,
        every=args.every, samples_per_period=getattr(args, "samples_per_period", None),
        **extra)
    run.service = service
    return service


# ---------------------------------------------------------------------------- replay
def _cmd_replay(args: argparse.Namespace) -> int:
    from fnsi_lab.replay.source import ReplaySource
    from fnsi_lab.viewer.blueprint import blueprint
    from fnsi_lab.viewer.cli import check_viewer_output, close_stream, open_stream

    default_rrd = str(Path(args.file).with_suffix(".rrd"))
    # the .rrd before anything is read or created
    check_viewer_output(args, default_rrd, inputs=[args.file, args.ident])
    if args.blas_threads > 0:
        limit_blas_threads(args.blas_threads)

    source = ReplaySource(args.file, speed=args.speed, follow=args.follow,
                          follow_timeout_s=args.follow_timeout)
    with source:
        identify, what = make_identifier(args, source.metadata, source.channels)
        groups = sorted({c.quantity for c in source.channels},
                        key=lambda q: (q != "force", q))
        rec, sinks = open_stream(args, blueprint(groups), default_rrd=default_rrd)
        run = LiveRun(rec, source.channels, quiet=args.quiet, decimation=args.decimation,
                      file_path=Path(args.file))
        service = _service_for(source.channels, source.sample_rate_hz, source.metadata,
                               identify, run, args)
        if not args.quiet:
            speed = "as fast as possible" if args.speed is None else f"at {args.speed:g}x"
            follow = ", following the file" if args.follow else ""
            print(f"replaying {args.file} {speed}{follow}; identification: {what}",
                  file=sys.stderr)
        t0 = time.monotonic()
        run.start_status()
        service.start(source)  # blocks are read in the assembler thread
        interrupted = False
        try:
            service.finish()
        except KeyboardInterrupt:  # stop reading; report what was identified so far
            interrupted = True
            service.close()
            source.close()
            try:
                service.finish(timeout=5.0)
            except Exception as exc:  # noqa: BLE001 - the closed source ends the assembler
                # with an error; what was identified before the interrupt is reported below
                logging.getLogger("fnsi_lab.replay").debug("after the interrupt: %s", exc)
        run.flush_signals()
        run.stop_status()
        wall = time.monotonic() - t0
        close_stream(rec, sinks)
    _finish_report(run, service, sinks, wall)
    if source.end_reason in ("timeout", "truncated"):
        print(f"note: the recording ended without its footer ({source.end_reason}); "
              f"`fnsi-lab recover {args.file} FIXED.mcap` makes it a clean, indexed file",
              file=sys.stderr)
    if args.web_wait and sinks.web_url:
        print(f"serving the web viewer for {args.web_wait:g} s more at {sinks.web_url}",
              file=sys.stderr)
        time.sleep(args.web_wait)
    if interrupted:
        print("fnsi-lab replay: interrupted", file=sys.stderr)
        return 130
    if source.end_reason == "damaged":
        print(f"fnsi-lab replay: error: {source.end_detail}", file=sys.stderr)
        return 2
    failure = identification_failure(service)
    if failure:
        print(f"fnsi-lab replay: error: identification failed: {failure}", file=sys.stderr)
        return 1
    return 0


# ---------------------------------------------------------------------------- live
def _cmd_live(args: argparse.Namespace) -> int:
    from fnsi_lab.daq.acquisition import Tap, recording_metadata, record_experiment
    from fnsi_lab.daq.config import load_experiment
    from fnsi_lab.daq.registry import make_source
    from fnsi_lab.viewer.blueprint import blueprint
    from fnsi_lab.viewer.cli import check_viewer_output, close_stream, open_stream

    if args.blas_threads > 0:
        limit_blas_threads(args.blas_threads)

    from fnsi_lab.outputs import check_output_path

    config = load_experiment(args.config)
    inputs = [args.config, config.file, args.ident]
    output = check_output_path(config.output if args.out is None else args.out,
                               force=args.force, inputs=inputs)
    # every output before any work: the .rrd (also the default next to the recording)
    rrd = check_viewer_output(args, str(output.with_suffix(".rrd")), inputs=[*inputs, output])
    html_path = _report_path(args, output, inputs=[*inputs, output, rrd])
    pace = None if args.fast else args.speed
    announce_simulator_compile(config.source.kind, enabled=not args.quiet)
    source = make_source(config, pace=pace) if pace is not None else make_source(config)
    metadata = recording_metadata(config, source)
    identify, what = make_identifier(args, metadata, source.channels)
    groups = sorted({c.quantity for c in source.channels}, key=lambda q: (q != "force", q))
    sizes = {g: sum(c.quantity == g for c in source.channels) for g in groups}
    units = {g: next((c.unit for c in source.channels if c.quantity == g and c.unit), "")
             for g in groups}
    rec, sinks = open_stream(args, blueprint(groups, group_sizes=sizes, group_units=units),
                             default_rrd=str(output.with_suffix(".rrd")))
    run = LiveRun(rec, source.channels, quiet=args.quiet, decimation=args.decimation,
                  file_path=output)
    service = _service_for(source.channels, source.sample_rate_hz, metadata, identify, run,
                           args)
    tap = Tap("ident", maxsize=args.queue_blocks)
    if not args.quiet:
        speed = "as fast as possible" if pace is None else f"at {pace:g}x real time"
        print(f"live: {config.name} ({config.source.kind}) {speed} -> {output}; "
              f"identification: {what}", file=sys.stderr)
    t0 = time.monotonic()
    run.start_status()
    service.start(tap)
    stop = threading.Event()
    report = record_experiment(config, output, realtime=pace is not None, taps=[tap],
                               stop=stop, source=source)
    service.finish()  # the tap was closed: the service ends after the last period
    run.flush_signals()
    run.stop_status()
    wall = time.monotonic() - t0
    close_stream(rec, sinks)
    print(report.summary())
    _finish_report(run, service, sinks, wall)
    if html_path is not None and not report.interrupted:
        _write_html_report(html_path, service, output, force=args.force)
    if args.web_wait and sinks.web_url:
        print(f"serving the web viewer for {args.web_wait:g} s more at {sinks.web_url}",
              file=sys.stderr)
        time.sleep(args.web_wait)
    if report.interrupted:
        print(f"fnsi-lab {args.command}: interrupted", file=sys.stderr)
        return 130
    failure = identification_failure(service)
    if failure:
        print(f"fnsi-lab {args.command}: error: identification failed: {failure}",
              file=sys.stderr)
        return 1
    return 0


def _report_path(args: argparse.Namespace, output: Path, *,
                 inputs: Any = ()) -> Path | None:
    """Where ``run`` writes its HTML report (next to the .rrd), checked before any work;
    ``--report ""`` is refused, not read as the default."""
    if not getattr(args, "html_report", False):
        return None
    from fnsi_lab.outputs import check_output_path

    rrd = Path(args.rrd) if getattr(args, "rrd", None) else output.with_suffix(".rrd")
    report = args.report if args.report is not None else rrd.with_suffix(".html")
    return check_output_path(report, force=args.force, option="--report", inputs=inputs)


def _write_html_report(path: Path, service: Any, recording: Path, *, force: bool) -> None:
    """The HTML report of the last identification update (``viewer.report``)."""
    from fnsi_lab.daq.recording.reader import open_recording
    from fnsi_lab.replay.identifiers import AutoIdentification
    from fnsi_lab.viewer.report_cli import write_report

    last = service.updates[-1] if service.updates else None
    if last is None or not isinstance(last.result, AutoIdentification):
        print(f"no HTML report: no identification to report ({path} not written)",
              file=sys.stderr)
        return
    with open_recording(recording) as rec:
        metadata = dict(rec.metadata)
    write_report(path, last.result.identification.to_json(), metadata, force=force,
                 title=f"fnsi-lab report: {recording.name}")
    print(f"HTML report written to {path}")


# ---------------------------------------------------------------------------- run
def _cmd_run(args: argparse.Namespace) -> int:
    """The main job: ``live`` as fast as the source and the identification allow."""
    args.fast = True
    return _cmd_live(args)


# ---------------------------------------------------------------------------- parser
def _common(p: argparse.ArgumentParser, harmonics: float = 1.0) -> None:
    from fnsi_lab.viewer.cli import add_viewer_arguments

    g = p.add_argument_group("identification")
    g.add_argument("--ident", type=opt.INPUT, metavar="IDENT.yaml",
                   help="identification config (basis functions, band, options)")
    g.add_argument("--orders", type=opt.ORDERS, default=None, metavar="FIRST:LAST",
                   help=f"model orders of the sweep: FIRST:LAST, FIRST:LAST:STEP or a list "
                        "4,6,8 (default: the --ident file's auto.orders, else "
                        f"{DEFAULT_ORDERS[0]}:{DEFAULT_ORDERS[-1]}, as fnsi-lab ident)")
    g.add_argument("--harmonics", type=opt.HARMONICS, default=harmonics, metavar="K",
                   help="without --ident: process the lines up to K times the highest excited "
                        "frequency, where the nonlinear distortion lives (5: the paper's "
                        f"5-250 Hz for a 5-50 Hz multisine; default {harmonics:g})")
    g.add_argument("--every", type=opt.EVERY, default=1, metavar="K",
                   help="re-identify after every K new steady-state periods (default 1)")
    g.add_argument("--method", choices=("auto", "frf"), default="auto",
                   help="auto: robust FNSI pipeline (default); frf: nonparametric FRF only")
    g.add_argument("--samples-per-period", type=opt.SAMPLES_PER_PERIOD, metavar="N",
                   help="period length when the recording has no excitation metadata")
    g.add_argument("--steady-tolerance", type=opt.STEADY_TOLERANCE, metavar="TOL",
                   help="also wait until two consecutive periods differ by less than TOL "
                        "(relative RMS) before identifying (default: only when the recording "
                        "does not give its transient periods, then 0.05)")
    add_viewer_arguments(p)
    p.add_argument("--decimation", type=opt.DECIMATION, default=1, metavar="D",
                   help="log every D-th sample of the signals to the viewer (default 1)")
    p.add_argument("--web-wait", type=opt.WEB_WAIT, default=0.0, metavar="S",
                   help="with --serve-web, keep serving S seconds after the run")
    p.add_argument("--blas-threads", type=opt.BLAS_THREADS, default=1, metavar="T",
                   help="OpenBLAS threads (default 1: identification runs next to "
                        "acquisition and the viewer; more threads oversubscribe small machines)")
    p.add_argument("--quiet", action="store_true", help="no status line")


def _experiment_arguments(p: argparse.ArgumentParser) -> None:
    """``--config`` and ``--out`` of the commands that run an experiment (run, live)."""
    p.add_argument("--config", type=opt.INPUT, metavar="EXP.yaml",
                   help="experiment YAML (default: the packaged simulated SmallSat)")
    p.add_argument("--out", metavar="FILE.mcap", help="recording (default: the config's output)")
    p.add_argument("--force", action="store_true",
                   help="replace existing output files (the recording and the .rrd)")


def register(subparsers: Any) -> None:
    """Add ``run``, ``live`` and ``replay``."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = subparsers.add_parser(
        "run", formatter_class=fmt,
        help="the whole chain, as fast as possible: acquire -> MCAP -> identify -> Rerun "
             "+ summary (default: simulated SmallSat)",
        description="Run an experiment as fast as its source allows (a simulated structure "
                    "runs far faster than real time), record it to MCAP, identify it with the "
                    "robust FNSI pipeline (information criterion over the order sweep, "
                    "stabilisation, MDI, spurious-pole removal) and save everything to a "
                    "Rerun recording; the result table (the paper's Table 2 layout, with "
                    "errors when the recording carries its truth) is printed at the end and "
                    "an offline HTML report (figures embedded) is written next to the .rrd. "
                    "The same as `fnsi-lab live --fast`, with the paper's order sweep 2..60 and its "
                    "processed band (--harmonics 5).",
        epilog="examples:\n"
               "  fnsi-lab run --out smallsat.mcap --rrd smallsat.rrd   # simulated SmallSat\n"
               "  fnsi-lab run --config lumped.yaml --rrd lumped.rrd    # packaged small model\n"
               "  fnsi-lab view smallsat.rrd                            # look at the result\n")
    _experiment_arguments(p)
    p.add_argument("--queue-blocks", type=opt.QUEUE_BLOCKS, default=1 << 16, metavar="B",
                   help="capacity of the identification queue in blocks (drop-oldest)")
    p.add_argument("--report", metavar="REPORT.html",
                   help="HTML report of the identification (default: next to the .rrd, "
                        "same name with .html)")
    p.add_argument("--no-report", dest="html_report", action="store_false",
                   help="do not write the HTML report")
    _common(p, harmonics=5.0)
    p.set_defaults(handler=_cmd_run, speed=None, html_report=True)

    p = subparsers.add_parser(
        "live", formatter_class=fmt,
        help="acquire -> MCAP -> identify as periods arrive -> Rerun (default: simulated SmallSat)",
        description="Run an experiment, record it to MCAP and identify it while it runs: "
                    "after each new steady-state period the robust FNSI pipeline runs on "
                    "all periods so far, and signals, FRFs, stabilisation diagram, "
                    "information criterion, MDI and coefficients go to Rerun. Acquisition "
                    "never waits for identification; when identification is slower, it "
                    "skips to the newest data (counted in the status line).",
        epilog="examples:\n"
               "  fnsi-lab live --rrd live.rrd              # simulated SmallSat, real time\n"
               "  fnsi-lab live --fast --spawn              # as fast as possible, native viewer\n"
               "  fnsi-lab live --config rig.yaml --ident rig-ident.yaml --serve-web\n")
    _experiment_arguments(p)
    p.add_argument("--speed", type=opt.SPEED, default=1.0, metavar="X",
                   help="pace a simulated source at X times real time (default 1)")
    p.add_argument("--fast", action="store_true", help="simulated sources: as fast as possible")
    p.add_argument("--queue-blocks", type=opt.QUEUE_BLOCKS, default=4096, metavar="B",
                   help="capacity of the identification queue in blocks (drop-oldest)")
    _common(p)
    p.set_defaults(handler=_cmd_live)

    p = subparsers.add_parser(
        "replay", formatter_class=fmt,
        help="replay an MCAP recording through the live identification and Rerun",
        description="Replay a recording block by block, as fast as possible or paced, "
                    "through the same identification service as `live`; with --follow, "
                    "keep reading a file that is still being written until its footer "
                    "arrives (or it stops growing for --follow-timeout seconds).",
        epilog="examples:\n"
               "  fnsi-lab replay smallsat.mcap --rrd replay.rrd\n"
               "  fnsi-lab replay smallsat.mcap --speed 10 --spawn\n"
               "  fnsi-lab replay growing.mcap --follow --connect   # a viewer already runs\n")
    p.add_argument("file", type=opt.INPUT, metavar="FILE.mcap")
    p.add_argument("--speed", type=opt.SPEED, metavar="X",
                   help="recorded seconds per wall second (default: as fast as possible)")
    p.add_argument("--follow", action="store_true", help="follow a file still being written")
    p.add_argument("--force", action="store_true", help="replace an existing .rrd file")
    p.add_argument("--follow-timeout", type=opt.FOLLOW_TIMEOUT, default=10.0, metavar="S",
                   help="with --follow, stop after S seconds without new data (default 10)")
    _common(p)
    p.set_defaults(handler=_cmd_replay)


__all__ = ["register", "make_identifier", "format_table", "LiveRun"]

