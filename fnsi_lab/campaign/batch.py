"""Identify many inputs as independent Dask tasks: plan, run, resume.

One task per input calls the one public entry point :func:`fnsi_lab.identify` and writes
that input's JSON result (the dict ``fnsi-lab ident --json`` writes, plus a ``campaign``
section: content hashes, worker, force level, contact fractions); it returns one row of
the campaign table (:mod:`fnsi_lab.campaign.table`). Tasks never raise: an input that
fails becomes a row with ``status='error'`` and its one-line reason, so one bad file never
stops the others.

Resuming: an input is skipped when its result file exists and records the same input
content hash (SHA-256 of the file) and the same configuration hash (config text, order
choice, software version). Nothing else is trusted: a renamed input with the same content
is still skipped, an edited config re-runs everything.

Scheduling (``client``): ``None`` runs the tasks one after the other in this process (the
serial baseline); otherwise a :class:`distributed.Client` (a local cluster of processes, or
a running ``dask scheduler``). Workers read the inputs and write the results themselves,
so on a real cluster both must be on a file system every worker sees.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from fnsi_lab import __version__
from fnsi_lab.errors import ConfigError, DataFileError, FnsiLabError
from fnsi_lab.outputs import atomic_output, dumps
from fnsi_lab.campaign.table import PlannedInput

#: File types an input may have (what :func:`fnsi_lab.identify` reads).
INPUT_SUFFIXES = (".mcap", ".npz", ".mat")

#: Key of the campaign section added to each per-input JSON result.
CAMPAIGN_KEY = "campaign"


class SchedulerError(FnsiLabError, ConnectionError):
    """The Dask scheduler cannot be reached, or no worker joined it."""


@dataclass(frozen=True)
class BatchSpec:
    """What every task of one campaign shares (see :func:`make_spec`).

    Attributes
    ----------
    config : str
        Absolute path of the ident configuration (remote workers read it too).
    config_sha256 : str
        Hash of the config text, the order choice and the software version.
    order : int or None
        Fixed model order (None with ``auto``).
    orders : str or None
        Order sweep of the robust pipeline (None: the config's, else 2:60).
    crc_check : bool
        Check the recordings' CRCs (``--no-crc-check`` turns it off in every worker; it
        does not change a result, so it is not part of the hash).
    """

    config: str
    config_sha256: str
    order: int | None = None
    orders: str | None = None
    crc_check: bool = True

    @property
    def auto(self) -> bool:
        """True for the robust automatic pipeline."""
        return self.order is None

    def identify(self, path: str) -> Any:
        """:func:`fnsi_lab.identify` of one input, called as ``fnsi-lab ident`` calls it."""
        import fnsi_lab

        if self.auto:
            return fnsi_lab.identify(path, self.config, orders=self.orders)
        return fnsi_lab.identify(path, self.config, order=self.order)


# ---------------------------------------------------------------------------- planning
def expand_inputs(patterns: Sequence[str]) -> list[Path]:
    """Input files from paths, folders and glob patterns, in order, without duplicates.

    A folder stands for its ``.mcap``/``.npz``/``.mat`` files (sorted); a pattern (``*``,
    ``?``, ``[``) for its matches (sorted).

    Raises
    ------
    DataFileError
        A path that does not exist, or a pattern or folder with no input file in it.
    """
    import glob

    found: list[Path] = []
    for pattern in patterns:
        if any(ch in pattern for ch in "*?["):
            matches = [Path(p) for p in sorted(glob.glob(pattern, recursive=True))
                       if Path(p).is_file()]
            if not matches:
                raise DataFileError(f"{pattern}: no file matches (fix: check the pattern; "
                                    "quote it so the shell does not expand it first)")
        elif Path(pattern).is_dir():
            matches = sorted(p for p in Path(pattern).iterdir()
                             if p.is_file() and p.suffix.lower() in INPUT_SUFFIXES)
            if not matches:
                raise DataFileError(f"{pattern}: folder has no {'/'.join(INPUT_SUFFIXES)} "
                                    "file (fix: give the recordings' folder)")
        elif Path(pattern).is_file():
            matches = [Path(pattern)]
        else:
            raise DataFileError(f"{pattern}: no such file (fix: check the path)")
        found.extend(matches)
    unique: dict[Path, Path] = {}
    for p in found:
        unique.setdefault(p.resolve(), p)
    return list(unique.values())


def file_sha256(path: str | os.PathLike[str], chunk_bytes: int = 1 << 20) -> str:
    """SHA-256 hex digest of a file's content (read in 1 MB chunks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(chunk_bytes):
            digest.update(chunk)
    return digest.hexdigest()


def make_spec(config: str, *, order: int | None = None, auto: bool = False,
              orders: str | None = None) -> BatchSpec:
    """Validate the ident configuration once and hash the campaign settings.

    Parameters
    ----------
    config : str
        YAML path or packaged name (``smallsat39``).
    order : int, optional
        Fixed model order; without it and without ``auto``, the config's ``order``.
    auto : bool
        Robust automatic pipeline (information criterion, MDI, reduction).
    orders : str, optional
        Its order sweep (``2:60``).

    Raises
    ------
    ConfigError
        Invalid config, or no order chosen (same messages as ``fnsi-lab ident``).
    """
    import fnsi_lab
    from fnsi_lab.arguments import check_order_options

    # the same rules as `fnsi-lab ident`, before any input is read or any table written
    checked = check_order_options(order=order, orders=orders)
    order = checked["order"]
    cfg = fnsi_lab.load_config(config)
    path = Path(cfg.file).resolve()
    if not auto:
        order = order if order is not None else cfg.order
        if order is None:
            raise ConfigError("no model order", file=str(config), field="order",
                              fix="give --order N or --auto (or 'order:' in the config)")
    else:
        order = None
    choice = {"order": order} if order is not None else {"auto": True, "orders": orders}
    digest = hashlib.sha256(path.read_bytes())
    digest.update(json.dumps({**choice, "software_version": __version__},
                             sort_keys=True).encode())
    return BatchSpec(config=str(path), config_sha256=digest.hexdigest(), order=order,
                     orders=orders)


def plan_inputs(inputs: Sequence[Path], results_dir: Path) -> list[PlannedInput]:
    """Hash every input and name its result file ``<results_dir>/<stem>.json``.

    Inputs sharing a stem (``a/run1.mcap``, ``b/run1.mcap``) get the first 8 hex digits
    of their content hash appended, so no result overwrites another.
    """
    stems: dict[str, int] = {}
    for p in inputs:
        stems[p.stem] = stems.get(p.stem, 0) + 1
    planned = []
    for p in inputs:
        sha = file_sha256(p)
        name = p.stem if stems[p.stem] == 1 else f"{p.stem}-{sha[:8]}"
        planned.append(PlannedInput(path=p, sha256=sha, result_path=results_dir / f"{name}.json"))
    return planned


def check_result_paths(planned: Sequence[PlannedInput], *, force: bool = False) -> None:
    """Refuse (before any work) a result path holding a file this command did not write.

    A JSON result of an earlier ``fnsi-lab batch`` (it carries the ``campaign``
    section) is this command's own state, replaced when its input or config changed, like
    the campaign table; any other file (a user's ``lumped.json``) needs ``force``.

    Raises
    ------
    OutputExistsError
        Naming the file, its input and the fix.
    """
    from fnsi_lab.outputs import OutputExistsError

    if force:
        return
    for item in planned:
        if not item.result_path.exists():
            continue
        try:
            with open(item.result_path, encoding="utf-8") as fh:
                ours = isinstance(json.load(fh).get(CAMPAIGN_KEY), dict)
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise OutputExistsError(
                f"--results {item.result_path}: file exists and is not a result of fnsi-lab "
                f"batch (the result of {item.path} goes there); nothing was written (fix: "
                "give another --results folder, or add --force to replace it)")


def previous_result(item: PlannedInput, spec: BatchSpec) -> dict | None:
    """The stored result of ``item`` when it was made from the same content and config."""
    try:
        with open(item.result_path, encoding="utf-8") as fh:
            result = json.load(fh)
    except (OSError, ValueError):
        return None
    meta = result.get(CAMPAIGN_KEY) if isinstance(result, dict) else None
    if (isinstance(meta, dict) and meta.get("input_sha256") == item.sha256
            and meta.get("config_sha256") == spec.config_sha256):
        return result
    return None


# ---------------------------------------------------------------------------- one task
def recording_context(path: str | os.PathLike[str],
                      nonlinearities: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:
    """Force level and per-coefficient contact fractions a recording carries.

    Parameters
    ----------
    path : path-like
        The input; only fnsi-lab recordings (``.mcap``) carry these (array files: ``{}``).
    nonlinearities : sequence of dict
        The ``nonlinearities`` of its JSON result (``name``, ``channels``,
        ``coefficients``), to match with the elements of the recording's truth.

    Returns
    -------
    dict
        ``force_rms`` (the multisine RMS, unit of the force channel) and
        ``contact_fraction`` (coefficient name -> fraction of the steady-state time its
        stop was closed; simulated structures only), each present only when known.
    """
    if Path(path).suffix.lower() != ".mcap":
        return {}
    from fnsi_lab.daq.recording.reader import open_recording

    with open_recording(path) as rec:
        excitation, truth = rec.excitation or {}, rec.truth or {}
    out: dict[str, Any] = {}
    if isinstance(excitation.get("rms"), (int, float)):
        out["force_rms"] = float(excitation["rms"])
    if isinstance(truth.get("contact_fraction"), dict):
        out["contact_fraction"] = contact_by_coefficient(
            nonlinearities, truth.get("nonlinearities") or [], truth["contact_fraction"])
    return out


def contact_by_coefficient(nonlinearities: Sequence[Mapping[str, Any]],
                           truth_elements: Sequence[Mapping[str, Any]],
                           contact_fraction: Mapping[str, float]) -> dict[str, float]:
    """Contact fraction of the stop behind each identified coefficient.

    An identified element is the truth element of the same name, else the one acting on
    the same channels with proportional weights (the config may name it differently).
    Its coefficient ``<name>:neg`` is the stop ``<truth name>.neg``; an element with a
    single stop (bilinear) gives that stop to its one coefficient.
    """
    out: dict[str, float] = {}
    for nl in nonlinearities:
        element = _matching_element(nl, truth_elements)
        if element is None:
            continue
        stops = {k.split(".", 1)[1]: float(v) for k, v in contact_fraction.items()
                 if k.split(".", 1)[0] == element["name"] and "." in k}
        for coefficient in nl.get("coefficients") or []:
            side = coefficient.split(":", 1)[1] if ":" in coefficient else None
            if side in stops:
                out[coefficient] = stops[side]
            elif len(stops) == 1:
                out[coefficient] = next(iter(stops.values()))
    return out


def _matching_element(nl: Mapping[str, Any], elements: Sequence[Mapping[str, Any]]
                      ) -> Mapping[str, Any] | None:
    for element in elements:
        if element.get("name") == nl.get("name"):
            return element
    mine = {str(k): float(v) for k, v in (nl.get("channels") or {}).items()}
    for element in elements:
        theirs = {str(k): float(v) for k, v in (element.get("channels") or {}).items()}
        if mine and set(mine) == set(theirs):
            ratios = [theirs[k] / mine[k] for k in mine if mine[k]]
            if ratios and all(abs(r - ratios[0]) <= 1e-9 * abs(ratios[0]) for r in ratios):
                return element
    return None


def _worker_address() -> str:
    """Address of the Dask worker running this task ('local' outside Dask)."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return "local"


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 500 else text[:497] + "..."


def identify_task(item: PlannedInput, spec: BatchSpec) -> dict[str, Any]:
    """Identify one input and write its JSON result; runs on a Dask worker.

    Never raises for a bad input: the returned row then has ``status='error'``.

    Returns
    -------
    dict
        One campaign-table row (:func:`fnsi_lab.campaign.table.result_row`).
    """
    from fnsi_lab.blas import limit_blas_threads
    from fnsi_lab.campaign.table import error_row, result_row

    from fnsi_lab.daq.recording.reader import set_default_crc_check

    # one BLAS thread per worker: the workers already fill the cores
    limit_blas_threads(1)
    set_default_crc_check(spec.crc_check)  # the worker may be another process
    worker = _worker_address()
    t0 = time.perf_counter()
    try:
        result = spec.identify(str(item.path)).to_json()
        result[CAMPAIGN_KEY] = {
            "input": str(item.path), "input_sha256": item.sha256,
            "config": spec.config, "config_sha256": spec.config_sha256,
            "order_choice": "auto" if spec.auto else spec.order, "orders": spec.orders,
            "worker": worker, "wall_time_s": time.perf_counter() - t0,
            **recording_context(item.path, result.get("nonlinearities") or [])}
        with atomic_output(item.result_path) as fh:
            fh.write(dumps(result, indent=2) + "\n")
    except Exception as exc:  # noqa: BLE001 - any failure of one input is that input's error
        row = error_row(item, worker=worker, error=f"{type(exc).__name__}: {_one_line(exc)}")
        try:  # the level of a failed run still places it in the comparison
            row["force_rms"] = recording_context(item.path).get("force_rms")
        except Exception as ctx_exc:  # noqa: BLE001 - an unreadable input has no level
            logging.getLogger("fnsi_lab.campaign").debug("%s: no level (%s)", item.path, ctx_exc)
        return row
    return result_row(result, item, status="ok")


# ---------------------------------------------------------------------------- the campaign
@dataclass
class BatchCounts:
    """Task counts shown by the progress bar."""

    total: int
    done: int = 0
    failed: int = 0
    skipped: int = 0
    running: int = 0

    def note(self) -> str:
        """``done 3, failed 1, running 2, skipped 4``."""
        text = f"done {self.done}, failed {self.failed}, running {self.running}"
        return text + (f", skipped {self.skipped}" if self.skipped else "")


def find_done(planned: Sequence[PlannedInput], spec: BatchSpec,
              previous_rows: Mapping[str, Mapping[str, Any]] | None = None
              ) -> dict[int, dict[str, Any]]:
    """Rows (``status='skipped'``) of the inputs identified before with the same config.

    Parameters
    ----------
    planned : sequence of PlannedInput
    spec : BatchSpec
    previous_rows : mapping, optional
        Rows of the previous campaign table (same config hash) by input hash: an input
        whose row is there and whose result file still exists is skipped without reading
        its JSON result (resuming a large campaign then costs one hash per input).
        Otherwise the result file itself is checked (:func:`previous_result`).

    Returns
    -------
    dict
        Index in ``planned`` -> row.
    """
    from fnsi_lab.campaign.table import result_row

    done = {}
    for i, item in enumerate(planned):
        known = (previous_rows or {}).get(item.sha256)
        if (known is not None and known.get("status") in ("ok", "skipped")
                and "force_unit" in known   # a table of before the unit columns: re-read
                and known.get("result") and Path(known["result"]).resolve()
                == item.result_path.resolve() and item.result_path.is_file()):
            done[i] = {**known, "file": str(item.path), "status": "skipped"}
            continue
        previous = previous_result(item, spec)
        if previous is not None:
            done[i] = result_row(previous, item, status="skipped")
    return done


def run_batch(planned: Sequence[PlannedInput], spec: BatchSpec, *, client: Any = None,
              done: Mapping[int, dict[str, Any]] | None = None,
              on_row: Callable[[dict[str, Any], BatchCounts], None] | None = None
              ) -> list[dict[str, Any]]:
    """Identify every planned input not done before and return the rows.

    Parameters
    ----------
    planned : sequence of PlannedInput
        From :func:`plan_inputs`; their result folder must exist.
    spec : BatchSpec
    client : distributed.Client or None
        Where the tasks run; None runs them one after the other in this process.
    done : mapping, optional
        :func:`find_done` of these inputs (computed here when not given).
    on_row : callable, optional
        Called with each finished or skipped row and the counts (progress display).

    Returns
    -------
    list of dict
        One row per input, in the order of ``planned``.
    """
    rows = dict(find_done(planned, spec) if done is None else done)
    counts = BatchCounts(total=len(planned), skipped=len(rows))
    if on_row is not None:
        for i in sorted(rows):
            on_row(rows[i], counts)
    todo = [i for i in range(len(planned)) if i not in rows]

    def finished(i: int, row: dict[str, Any]) -> None:
        rows[i] = row
        counts.done += 1
        counts.failed += row["status"] == "error"
        if on_row is not None:
            on_row(row, counts)

    if client is None:
        for n, i in enumerate(todo):
            row = identify_task(planned[i], spec)
            counts.running = 1 if n + 1 < len(todo) else 0  # the next one starts now
            finished(i, row)
    elif todo:
        for i, row in _run_on_cluster(client, [planned[i] for i in todo], todo, spec, counts):
            finished(i, row)
    return [rows[i] for i in range(len(planned))]


def _run_on_cluster(client: Any, items: Sequence[PlannedInput], indices: Sequence[int],
                    spec: BatchSpec, counts: BatchCounts) -> Iterable[tuple[int, dict[str, Any]]]:
    """Submit one task per item; yield ``(index, row)`` as tasks finish, in any order."""
    from distributed import as_completed

    from fnsi_lab.campaign.table import error_row

    futures = {}
    for i, item in zip(indices, items):
        # pure=False: a re-run after a fix must run again even with the same arguments
        future = client.submit(identify_task, item, spec, pure=False,
                               key=f"identify-{item.path.stem}-{item.sha256[:8]}-{i}")
        futures[future] = (i, item)
    slots = max(sum(client.nthreads().values()), 1)
    pending = len(futures)
    counts.running = min(pending, slots)
    try:
        for future in as_completed(futures, raise_errors=False):
            i, item = futures[future]
            pending -= 1
            counts.running = min(pending, slots)
            if future.status == "finished":
                row = future.result()
            else:  # the task itself never raises: the worker died or the task was lost
                exc = future.exception()
                row = error_row(item, worker="", error=f"{type(exc).__name__}: {_one_line(exc)}")
            yield i, row
    finally:
        client.cancel(list(futures))


#: Worker preload module: the worker processes leave SIGINT to the command.
_WORKER_SETUP = "fnsi_lab.campaign.worker_setup"


def _start_forkserver_ignoring_sigint() -> None:
    """Have multiprocessing's fork server ignore SIGINT in the workers it forks.

    The local cluster's workers are forked from it (``forkserver`` start method); it imports
    :mod:`fnsi_lab.campaign._forkserver_sigint` before serving, so they ignore a Ctrl-C
    sent to the terminal's process group from their first instruction: none dies half-way
    through its start-up or a task with a traceback; the command alone handles it and
    closes the cluster. A fork server this process started before (other code) keeps its
    settings: its workers ignore SIGINT from their Dask preload
    (:mod:`fnsi_lab.campaign.worker_setup`), once started.
    """
    import multiprocessing
    import signal
    import threading
    from multiprocessing import forkserver

    module = "fnsi_lab.campaign._forkserver_sigint"
    # first, and without '__main__' (the workers need only fnsi_lab): the server ignores
    # SIGINT before it imports anything else
    others = [m for m in getattr(forkserver._forkserver, "_preload_modules", None) or []
              if m not in ("__main__", module)]
    multiprocessing.set_forkserver_preload([module, *others])
    if threading.current_thread() is not threading.main_thread():
        forkserver.ensure_running()
        return
    # the server inherits an ignored SIGINT through its exec: no Ctrl-C interrupts its own
    # start-up either (here ignored only while it is spawned, about 0.1 s)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _local_cluster(n_workers: int) -> Iterator[Any]:
    """A LocalCluster of ``n_workers`` one-thread worker processes; closed on exit.

    Its workers ignore SIGINT (:func:`_start_forkserver_ignoring_sigint`). A Ctrl-C or
    SIGTERM while it starts is held until it has started (1-4 s), then it is closed and the
    interrupt raised: a cluster stopped half-way leaves workers that die with tracebacks.
    """
    from distributed import LocalCluster

    _start_forkserver_ignoring_sigint()
    with _interrupts_held() as held:
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL)
    if held():
        _quiet_shutdown()
        cluster.close()
        raise KeyboardInterrupt
    with cluster:
        yield cluster


@contextlib.contextmanager
def _interrupts_held() -> Iterator[Callable[[], bool]]:
    """SIGINT and SIGTERM recorded, not raised, inside the block (main thread only);
    yields a function telling whether one came."""
    import signal
    import threading

    came: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda signum, frame: came.append(signum))
                for sig in signals}
    try:
        yield lambda: bool(came)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _quiet_shutdown() -> None:
    """After Ctrl-C: the cluster closes with its workers mid-task; what Dask logs about the
    closing connections (CommClosedError, CancelledError) is not news to the user, and a
    second Ctrl-C must not interrupt that close (tracebacks from its atexit handler): both
    are undone by :func:`_interrupt_state` when the cluster is gone."""
    import signal
    import threading

    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _interrupt_state() -> Iterator[None]:
    """Restore what :func:`_quiet_shutdown` changed (SIGINT handler, log levels) on exit."""
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    handler = signal.getsignal(signal.SIGINT) if main else None
    levels = {name: logging.getLogger(name).level for name in ("distributed", "tornado",
                                                                "asyncio")}
    try:
        yield
    finally:
        if main and handler is not None:
            signal.signal(signal.SIGINT, handler)
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _refuses(scheduler: str, probe_s: float = 3.0) -> None:
    """Raise :class:`ConnectionRefusedError` at once when nothing listens at the scheduler's
    ``tcp://host:port``: Dask's client retries a refused connection until its whole timeout
    (30 s measured for ``tcp://127.0.0.1:9``) before saying so. Anything else (no answer
    within ``probe_s``, another scheme, no port) is left to the client and its timeout."""
    from urllib.parse import urlsplit

    parts = urlsplit(scheduler)
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        return
    if parts.scheme != "tcp" or not host or not port:
        return
    try:
        socket.create_connection((host, port), timeout=probe_s).close()
    except ConnectionRefusedError:
        raise
    except OSError:
        return


@contextlib.contextmanager
def dask_client(scheduler: str = "local", workers: int | None = None, *,
                connect_timeout_s: float = 30.0) -> Iterator[Any]:
    """A :class:`distributed.Client` for the campaign, closed on exit.

    Parameters
    ----------
    scheduler : str
        ``'local'``: start a :class:`distributed.LocalCluster` of ``workers`` processes
        with one thread each (and stop it on exit); ``'serial'``: no Dask, yields None
        (tasks run in this process); otherwise the address of a running scheduler
        (``tcp://host:8786``), whose workers are left running.
    workers : int, optional
        Local cluster: number of worker processes (default: the CPU count). Running
        scheduler: wait until this many workers have joined (default: one).
    connect_timeout_s : float
        How long to wait for the scheduler and its workers.

    Raises
    ------
    SchedulerError
        The scheduler cannot be reached or not enough workers join in time.
    """
    if scheduler == "serial":
        yield None
        return
    from distributed import Client, LocalCluster

    if scheduler == "local":
        import dask

        n = int(workers or os.cpu_count() or 1)
        # One thread per worker process: the identification holds the GIL between its many
        # small solves. No dashboard (bokeh is not a dependency). Dask's worker defaults
        # cost an identification 1.5-2.5x its time (measured, docs/campaigns.md): the
        # statistical profiler samples the task's thread every 10 ms, and
        # MALLOC_TRIM_THRESHOLD_ turns off glibc's adaptive mmap threshold, so every large
        # temporary array is mapped, zero-filled and unmapped again.
        # Ctrl-C in a terminal reaches the worker processes too: they ignore it (a preload)
        # and the cluster is closed quietly from here (no worker tracebacks, exit 130).
        with _interrupt_state(), \
                dask.config.set({"distributed.worker.profile.enabled": False,
                              "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                              "distributed.worker.preload": [_WORKER_SETUP],
                              "distributed.worker.multiprocessing-method": "forkserver"}), \
                _local_cluster(n) as cluster, Client(cluster) as client:
            try:
                yield client
            except KeyboardInterrupt:
                _quiet_shutdown()
                raise
        return
    try:
        _refuses(scheduler)
        client = Client(scheduler, timeout=f"{connect_timeout_s}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerError(f"--scheduler {scheduler}: cannot connect ({_one_line(exc)}) "
                             "(fix: start 'dask scheduler' and 'dask worker ADDRESS', or use "
                             "--scheduler local)") from None
    with client:
        try:
            client.wait_for_workers(int(workers or 1), timeout=connect_timeout_s)
        except TimeoutError:
            raise SchedulerError(f"--scheduler {scheduler}: fewer than {workers or 1} "
                                 f"worker(s) joined within {connect_timeout_s:g} s (fix: start "
                                 f"'dask worker {scheduler}')") from None
        yield client
