"""``fnsi-lab view FILE.rrd`` and the viewer options shared by ``live`` and ``replay``.

Sinks (any combination): ``--rrd PATH`` saves, ``--spawn`` starts a native viewer,
``--connect URL`` streams to a running viewer, ``--serve-web`` serves the web viewer. On a
machine without a display ``--spawn`` falls back to saving (with a message), because a
headless spawn warns and blocks at exit.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fnsi_lab.arguments import CONNECT_URL, INPUT
from fnsi_lab.errors import DataFileError, FnsiLabError

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr  # imported where used: `fnsi-lab --help` must not load it

#: Default URL of a running viewer's gRPC proxy.
DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"
#: Application id of every fnsi-lab recording in Rerun.
APP_ID = "fnsi-lab"


class ViewerError(FnsiLabError, RuntimeError):
    """The viewer could not be started or reached."""


def has_display() -> bool:
    """True when a native window can be opened (X11/Wayland on Linux; always elsewhere)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def add_viewer_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--rrd``, ``--spawn``, ``--connect``, ``--serve-web`` and ``--web-port``."""
    g = parser.add_argument_group("viewer (Rerun)")
    g.add_argument("--rrd", metavar="PATH", help="save everything logged to this .rrd file")
    g.add_argument("--spawn", action="store_true",
                   help="start a native Rerun viewer (falls back to --rrd without a display)")
    g.add_argument("--connect", metavar="URL", nargs="?", const=DEFAULT_CONNECT_URL,
                   type=CONNECT_URL,
                   help=f"stream to a running viewer (default URL {DEFAULT_CONNECT_URL})")
    g.add_argument("--serve-web", action="store_true",
                   help="serve the web viewer (open the printed http address in a browser)")
    _add_server_arguments(g)


def tcp_port(text: str) -> int:
    """argparse type: a TCP port number, 1..65535."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is outside 1..65535")
    return port


def _add_server_arguments(g: Any) -> None:
    """``--web-port``, ``--grpc-port`` and ``--bind`` of ``--serve-web``."""
    g.add_argument("--web-port", type=tcp_port, default=9090, metavar="PORT",
                   help="HTTP port of --serve-web (default 9090; its gRPC port is 9876)")
    g.add_argument("--grpc-port", type=tcp_port, default=9876, metavar="PORT",
                   help="gRPC port of --serve-web (default 9876)")
    g.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="address the --serve-web servers listen on (default 127.0.0.1: this "
                        "machine only; 0.0.0.0 serves every network interface)")


def check_port_free(host: str, port: int, option: str) -> None:
    """Raise :class:`ViewerError` when ``host:port`` cannot be listened on (busy, bad address)."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
    except OSError as exc:
        busy = exc.errno in (98, 48, 10048)  # EADDRINUSE on Linux, macOS, Windows
        what = "is in use by another program" if busy else f"cannot be used ({exc.strerror})"
        raise ViewerError(f"{option} {port} on {host} {what} (fix: choose another port with "
                          f"{option}{', or stop the other server' if busy else ''})") from None


def check_server_ports(host: str, grpc_port: int, web_port: int) -> None:
    """The two ports of ``--serve-web``: different, and free on ``host`` (before any work)."""
    if grpc_port == web_port:
        raise ViewerError(f"--web-port {web_port} is also the --grpc-port: the two servers "
                          "need their own ports (fix: give different --web-port and "
                          "--grpc-port)")
    for port, option in ((grpc_port, "--grpc-port"), (web_port, "--web-port")):
        check_port_free(host, port, option)


def start_web_server(host: str, grpc_port: int, web_port: int,
                     timeout_s: float = 20.0) -> "subprocess.Popen[bytes]":
    """Start ``rerun --serve-web`` (gRPC proxy + web viewer) listening on ``host``.

    The Python SDK's in-process servers listen on every interface; the ``rerun`` executable
    takes ``--bind``, so the servers run there and the recording streams to them over gRPC.
    The process is terminated when this process exits.
    """
    import atexit
    import socket

    check_server_ports(host, grpc_port, web_port)
    exe = shutil.which("rerun")
    if exe is None:
        raise ViewerError("--serve-web needs the `rerun` executable of rerun-sdk on PATH "
                          "(fix: pip install rerun-sdk, or activate its environment)")
    # its own process group: `rerun` on PATH is a launcher whose child is the server, and
    # both must go when this process exits
    proc = subprocess.Popen([exe, "--serve-web", "--bind", host, "--port", str(grpc_port),
                             "--web-viewer-port", str(web_port)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    atexit.register(_stop_server, proc)
    probe = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    deadline = time.monotonic() + timeout_s
    while True:
        if proc.poll() is not None:
            raise ViewerError(f"`rerun --serve-web` exited at once (status {proc.returncode}) "
                              f"on {host} ports {grpc_port}/{web_port} (fix: check --bind and "
                              "the ports)")
        try:
            with socket.create_connection((probe, grpc_port), timeout=0.5):
                return proc
        except OSError:
            if time.monotonic() > deadline:
                _stop_server(proc)
                raise ViewerError(f"the web viewer server did not start within {timeout_s:g} s "
                                  f"(port {grpc_port})") from None
            time.sleep(0.1)


def _stop_server(proc: "subprocess.Popen[bytes]") -> None:
    """Stop the server's whole process group (the launcher and the server it started)."""
    import signal

    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        proc.poll()  # reap the launcher
        try:
            os.killpg(proc.pid, 0)  # anyone of the group left?
        except ProcessLookupError:
            return
        time.sleep(0.05)
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.poll()


@dataclass
class ViewerSinks:
    """What :func:`open_stream` set up (for messages and clean shutdown)."""

    rrd: str | None = None
    spawned: bool = False
    connected: str | None = None
    web_url: str | None = None
    grpc_url: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def any(self) -> bool:
        """True when at least one sink receives data."""
        return bool(self.rrd or self.spawned or self.connected or self.web_url)


def planned_rrd(args: argparse.Namespace, default_rrd: str | None = None) -> str | None:
    """The .rrd file :func:`open_stream` will write for these options (None: no file).

    ``--rrd ""`` is kept as given (the output check refuses it), never read as "the default".
    """
    rrd = getattr(args, "rrd", None)
    if rrd is not None:
        return rrd
    spawn = bool(getattr(args, "spawn", False))
    if not (spawn or getattr(args, "connect", None) or getattr(args, "serve_web", False)):
        return default_rrd or "fnsi-lab.rrd"  # a stream without a sink: saved instead
    if spawn and not has_display():  # no window: saved instead
        return default_rrd or "fnsi-lab.rrd"
    return None


def check_viewer_output(args: argparse.Namespace, default_rrd: str | None = None, *,
                        inputs: Any = ()) -> str | None:
    """Check the .rrd output of these options before any work (empty, an input, exists
    without --force, folder not writable: :func:`fnsi_lab.outputs.check_output_path`) and
    the ``--serve-web`` ports (different, free)."""
    from fnsi_lab.outputs import check_output_path

    if getattr(args, "serve_web", False):
        check_server_ports(getattr(args, "bind", "127.0.0.1") or "127.0.0.1",
                           args.grpc_port, args.web_port)
    rrd = planned_rrd(args, default_rrd)
    if rrd is None:
        return None
    if str(rrd).strip() and not Path(rrd).parent.is_dir():
        try:
            Path(rrd).parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataFileError(f"--rrd {rrd}: cannot create its folder ({exc.strerror}) "
                                "(fix: choose a writable place)") from None
    check_output_path(rrd, force=getattr(args, "force", False), option="--rrd",
                      inputs=inputs)
    return rrd


def open_stream(args: argparse.Namespace, blueprint: Any, *, recording_id: str | None = None,
                default_rrd: str | None = None) -> tuple[rr.RecordingStream, ViewerSinks]:
    """Create the recording stream and attach the sinks the options ask for.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_viewer_arguments`.
    blueprint : rerun.blueprint.Blueprint
        Sent as the default blueprint of every sink.
    recording_id : str, optional
        Rerun recording id (defaults to a random one).
    default_rrd : str, optional
        Where to save when no sink option was given, or ``--spawn`` is impossible and no
        ``--rrd`` was given.

    Returns
    -------
    (RecordingStream, ViewerSinks)
    """
    import rerun as rr

    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    sinks = ViewerSinks()
    given = getattr(args, "rrd", None)
    spawn = bool(getattr(args, "spawn", False))
    rrd = planned_rrd(args, default_rrd)
    if given is None and not (spawn or getattr(args, "connect", None)
                              or getattr(args, "serve_web", False)):
        # a stream without a sink keeps everything in memory: save instead
        sinks.notes.append(f"no viewer option given: saving to {rrd} (use --spawn, "
                           "--connect or --serve-web to watch live)")
    if spawn and not has_display():
        sinks.notes.append(f"no display: not spawning a viewer; saving to {rrd} "
                           f"(open it later with `rerun {rrd}` or `fnsi-lab view {rrd}`)")
        spawn = False
    sink_list: list[Any] = []
    if rrd is not None:
        check_viewer_output(args, default_rrd)
        try:
            sink_list.append(rr.FileSink(str(rrd)))
        except Exception as exc:  # noqa: BLE001 - the SDK raises plain exceptions
            raise DataFileError(f"--rrd {rrd}: cannot be written ({exc}) "
                                "(fix: choose a writable place)") from None
        sinks.rrd = str(rrd)
    if getattr(args, "connect", None):
        try:
            sink_list.append(rr.GrpcSink(args.connect))
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError for a bad URL
            raise ViewerError(f"--connect {args.connect}: {exc} (fix: give "
                              f"{DEFAULT_CONNECT_URL} or another viewer's address)") from None
        sinks.connected = args.connect
    if spawn:
        # spawn() starts the viewer and connects the stream to it; other sinks follow.
        rec.spawn(connect=not sink_list, default_blueprint=blueprint)
        if sink_list:
            sink_list.append(rr.GrpcSink(DEFAULT_CONNECT_URL))
        sinks.spawned = True
    if getattr(args, "serve_web", False):
        if sink_list:
            sinks.notes.append("--serve-web streams only to the web viewer; "
                               "other sinks are ignored")
        host = getattr(args, "bind", "127.0.0.1") or "127.0.0.1"
        start_web_server(host, args.grpc_port, args.web_port)
        shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
        grpc_url = f"rerun+http://{shown}:{args.grpc_port}/proxy"
        rec.set_sinks(rr.GrpcSink(grpc_url), default_blueprint=blueprint)
        sinks.grpc_url = grpc_url
        sinks.web_url = f"http://{shown}:{args.web_port}/?url={grpc_url}"
        sinks.notes.append(f"web viewer at {sinks.web_url}")
    elif sink_list:
        try:
            rec.set_sinks(*sink_list, default_blueprint=blueprint)
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError for a bad path
            rec.disconnect()
            raise DataFileError(f"cannot open the viewer sinks ({exc}) (fix: choose a "
                                "writable --rrd path or a reachable --connect URL)") from None
    return rec, sinks


def close_stream(rec: rr.RecordingStream, sinks: ViewerSinks, *, wait_web_s: float = 0.0) -> None:
    """Flush and disconnect; with a web viewer, keep serving ``wait_web_s`` seconds first."""
    rec.flush()
    if sinks.web_url and wait_web_s > 0:
        time.sleep(wait_web_s)
    rec.disconnect()


# ---------------------------------------------------------------------------- rrd reading
def _rrd_reader(path: str | Path) -> Any:
    """A ``rerun.chunk.RrdReader`` of ``path``, without the reader's warning about files
    written without a footer (every file our recorders stream; it printed a source line
    before our own message on a damaged file)."""
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer/manifest.*")
        return RrdReader(str(path))


def rrd_entities(path: str | Path) -> dict[str, int]:
    """Entity path -> number of rows (static and temporal) in an .rrd file.

    Raises
    ------
    DataFileError
        The file is missing or not an .rrd.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFileError(f"{path}: no such file")
    try:
        store = _rrd_reader(path).stream().collect()
    except Exception as exc:  # the reader raises plain exceptions on bad files
        raise DataFileError(f"{path}: not a readable .rrd file ({exc})") from None
    counts: dict[str, int] = {}
    for chunk in store.stream():
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def signal_groups(entities: Any) -> tuple[str, ...]:
    """The channel groups of a recording, from its ``/signals/<group>`` entity paths.

    In the order ``live``/``replay`` give them to the blueprint (force first, then by name),
    so ``view --serve-web``/``--connect`` shows one signal view per group of the file (an
    accelerometer run has a ``signals: acceleration`` view, not an empty displacement one).
    Without signals, the default groups of :func:`viewer.blueprint.blueprint`.
    """
    from fnsi_lab.viewer import paths

    prefix = paths.SIGNALS + "/"
    found = {str(e)[len(prefix):] for e in entities
             if str(e).startswith(prefix) and "/" not in str(e)[len(prefix):]}
    found.discard("")
    if not found:
        return ("force", "displacement")
    return tuple(sorted(found, key=lambda q: (q != "force", q)))


def rrd_text(path: str | Path, entity: str) -> str | None:
    """The last TextDocument text logged at ``entity`` in an .rrd file, if any."""

    store = _rrd_reader(path).stream().collect()
    text = None
    for chunk in store.stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if "TextDocument:text" in batch.schema.names:
            values = batch.column("TextDocument:text").to_pylist()
            if values:
                last = values[-1]
                text = last[0] if isinstance(last, list) else last
    return text


def signal_layout(path: str | Path) -> tuple[dict[str, int], dict[str, str]]:
    """Channels per signal group and the group's unit, from the series names an .rrd holds
    (``viewer.log.log_signal_styles`` names a channel ``NC2W-Z [mm]``): the blueprint
    arguments ``group_sizes`` and ``group_units`` of the recording's own layout."""

    from fnsi_lab.viewer import paths

    prefix = paths.SIGNALS + "/"
    sizes: dict[str, int] = {}
    units: dict[str, str] = {}
    for chunk in _rrd_reader(path).stream().collect().stream():
        entity = str(chunk.entity_path)
        if not entity.startswith(prefix) or "/" in entity[len(prefix):]:
            continue
        batch = chunk.to_record_batch()
        if "SeriesLines:names" not in batch.schema.names:
            continue
        names = [n for row in batch.column("SeriesLines:names").to_pylist() if row
                 for n in (row if isinstance(row, list) else [row])]
        group = entity[len(prefix):]
        sizes[group] = len(names)
        found = {n.rsplit("[", 1)[1].rstrip("]") for n in names if n.endswith("]") and "[" in n}
        if len(found) == 1:
            units[group] = found.pop()
    return sizes, units


# ---------------------------------------------------------------------------- view command
def _cmd_view(args: argparse.Namespace) -> int:
    from fnsi_lab.viewer import paths

    counts = rrd_entities(args.file)
    opens = not args.list and not (args.spawn or args.connect or args.serve_web)
    if opens:  # no option: open it, natively where a display exists, else in a browser
        if has_display() and shutil.which("rerun"):
            args.spawn = True
        else:
            args.serve_web = True
            print("no display: serving the web viewer instead of a window (use --list to "
                  "print what the file holds)", file=sys.stderr)
    if args.list or not opens:
        print(f"{args.file}: {len(counts)} entities, {sum(counts.values())} rows")
    if args.list:
        for entity in sorted(counts):
            if not entity.startswith("/__"):
                print(f"  {entity:<48} {counts[entity]:>8} rows")
        summary = rrd_text(args.file, paths.SUMMARY)
        if summary:
            print()
            print(summary.rstrip())
        return 0
    if args.spawn:
        exe = shutil.which("rerun")
        if exe is None:
            raise ViewerError("the `rerun` viewer executable is not on PATH",)
        if not has_display():
            print(f"no display: cannot open a window; copy {args.file} to a machine with one "
                  f"and run `rerun {args.file}`, or use --serve-web", file=sys.stderr)
            return 0
        subprocess.Popen([exe, str(args.file)], start_new_session=True)
        print(f"opening {args.file} in the Rerun viewer (a window)", file=sys.stderr)
        return 0
    if args.connect or args.serve_web:
        import rerun as rr

        from fnsi_lab.viewer.blueprint import blueprint

        args.rrd = None
        sizes, units = signal_layout(args.file)
        rec, sinks = open_stream(args, blueprint(signal_groups(counts), group_sizes=sizes,
                                                 group_units=units))
        rr.send_chunks(_rrd_reader(args.file).stream().collect(), recording=rec)
        for note in sinks.notes:
            print(note, file=sys.stderr)
        if sinks.web_url:
            # stdout: the one line a user (or a script) needs
            print(f"serving {args.file} at {sinks.web_url} (open it in a browser; Ctrl-C "
                  "to stop)", flush=True)
            try:
                while True:
                    time.sleep(3600)
            except KeyboardInterrupt:
                pass
            # Ctrl-C: the file was sent long ago; a bounded flush, so that stopping never
            # waits on a viewer connection. A second interrupt while it runs (rerun's flush
            # can surface the first one again: exit 130 once in CI) loses nothing either.
            try:
                rec.flush(timeout_sec=5.0)
                rec.disconnect()
            except KeyboardInterrupt:
                pass
            return 0
        close_stream(rec, sinks)
    return 0


def register(subparsers: Any) -> None:
    """Add the ``view`` subcommand."""
    p = subparsers.add_parser(
        "view", help="open a saved Rerun recording (.rrd) in the viewer",
        description="Open an .rrd file in the Rerun viewer: a native window where a display "
                    "exists, else the web viewer served on this machine (the URL is printed; "
                    "Ctrl-C stops it). --list prints what the file holds instead.",
        epilog="examples:\n"
               "  fnsi-lab view run.rrd                 # a window, or the web viewer's URL\n"
               "  fnsi-lab view run.rrd --list          # entities and the summary, no viewer\n"
               "  fnsi-lab view run.rrd --spawn         # the native viewer\n"
               "  fnsi-lab view run.rrd --serve-web     # http://127.0.0.1:9090 in a browser\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=INPUT, metavar="FILE.rrd", help="a recording saved with --rrd")
    p.add_argument("--list", action="store_true",
                   help="print the entities and the identification summary, open nothing")
    p.add_argument("--spawn", action="store_true", help="open it in the native Rerun viewer")
    p.add_argument("--connect", metavar="URL", nargs="?", const=DEFAULT_CONNECT_URL,
                   type=CONNECT_URL,
                   help="send it to a running viewer")
    p.add_argument("--serve-web", action="store_true", help="serve it to a web browser")
    _add_server_arguments(p)
    p.set_defaults(handler=_cmd_view)


__all__ = ["add_viewer_arguments", "open_stream", "close_stream", "ViewerSinks", "ViewerError",
           "has_display", "rrd_entities", "rrd_text", "signal_groups", "register", "APP_ID"]
