"""CAN bus source: python-can ``Bus`` (any interface) + a DBC file decoded with cantools.

A channel is one DBC signal: the DBC gives its scale, offset and unit, the experiment
YAML maps signals to channel names::

    source:
      kind: can
      options:
        interface: socketcan        # any python-can interface: pcan, vector, virtual...
        channel: can0
        bitrate: 1000000
        dbc: example_can.dbc        # relative to the YAML file's directory
        signals:                    # channel name -> Message.Signal
          F-NC2W-Z: Excitation.Force
          NC2W-Z: Response.Disp1
        counter: Counter            # optional sequence-counter signal (in every message)
        expected_rate_hz: 1000      # default: sample_rate_hz

How frames become rows
----------------------
One sample row holds one value of every channel. With a ``counter`` signal the frames
that carry the same counter value form a row, so a lost frame leaves NaN in exactly its
own channels and the row index (hence the time axis) stays right. Without a counter a
row closes when every mapped message has arrived once (or, with ``trigger``, when the
trigger message arrives), and a time gap between rows larger than 1.5 sample periods is
filled with NaN rows. Rows are cut into blocks of ``block_size``.

Reading is decoupled from decoding: a receive thread only calls ``bus.recv`` and appends
frames to a bounded queue (overflow counted as ``lost_frames``); :meth:`CanSource.read`
decodes in the caller's thread.

Everything abnormal is counted in ``stats.problems`` and emitted as an event for the
recording: ``error_frame``, ``bus_error`` / ``bus_reconnected`` (python-can raised, e.g.
bus-off or interface down), ``bus_state`` (ERROR_PASSIVE / BUS_OFF state changes),
``unknown_id``, ``decode_error``, ``missing_frames`` (counter gaps), ``rate_gap``
(time gaps), ``counter_repeat``, ``queue_overflow``, ``rate_mismatch`` / ``rate_ok``,
``no_frames`` (a mapped message never seen), ``gap`` (a jump too long to fill).
Frequent kinds are limited to one event per second of bus time; the event's
``suppressed`` field says how many were folded into it and the stats count them all.
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.source import Source
from fnsi_lab.daq.sources._rate import ReceiveThread, RowEmitter
from fnsi_lab.errors import ConfigError, SourceError
from fnsi_lab.validate import Section

try:  # the registry turns an ImportError into a ConfigError naming the package
    import can
    import cantools
    from cantools.database.errors import DecodeError
except ImportError as exc:  # pragma: no cover - both are declared dependencies
    raise ImportError(f"the CAN source needs python-can and cantools: {exc}",
                      name=exc.name) from exc

__all__ = ["CanSource", "CanSignal", "RAW_TOPIC", "resolve_dbc", "frame_to_dict"]

_PREFIX = "source.options"
#: MCAP topic of the raw frames (``record_raw: true``), JSON as :func:`frame_to_dict`.
RAW_TOPIC = "/daq/can_raw"


@dataclass(frozen=True)
class CanSignal:
    """Where a channel comes from.

    Attributes
    ----------
    channel : str
        Channel name (block column).
    message : str
        DBC message name.
    signal : str
        DBC signal name inside the message.
    unit : str
        Unit stated by the DBC ('' if none).
    scale, offset : float
        DBC factor and offset (physical = raw * scale + offset), kept for the metadata.
    """

    channel: str
    message: str
    signal: str
    unit: str
    scale: float
    offset: float


class _MessageSpec:
    """Decoding plan of one mapped DBC message (plain class: attribute access is hot)."""

    __slots__ = ("index", "name", "message", "signals", "columns", "counter", "modulus")

    def __init__(self, index: int, name: str, message: Any, signals: list[str],
                 columns: list[int], counter: str | None, modulus: int) -> None:
        self.index = index
        self.name = name
        self.message = message
        self.signals = signals
        self.columns = np.asarray(columns, dtype=np.intp)
        self.counter = counter
        self.modulus = modulus


def resolve_dbc(path: str, config_file: str | None) -> Path:
    """Find a DBC file: relative to the YAML's directory, else a file shipped in daq/data.

    Raises
    ------
    ConfigError
        If neither exists.
    """
    p = Path(path).expanduser()
    if not p.is_absolute():
        base = Path(config_file).resolve().parent if config_file else Path.cwd()
        p = base / p
    if p.is_file():
        return p
    shipped = Path(__file__).resolve().parent.parent / "data" / Path(path).name
    if shipped.is_file():
        return shipped
    raise ConfigError(f"DBC file {str(p)!r} not found", file=config_file,
                      field=f"{_PREFIX}.dbc",
                      fix="give a path relative to the experiment file's directory")


def frame_to_dict(msg: "can.Message") -> dict[str, Any]:
    """JSON-able form of a raw frame, for the ``/daq/can_raw`` topic."""
    return {"id": msg.arbitration_id, "extended": msg.is_extended_id, "dlc": msg.dlc,
            "data": bytes(msg.data).hex(), "error": msg.is_error_frame,
            "remote": msg.is_remote_frame, "fd": msg.is_fd,
            "channel": None if msg.channel is None else str(msg.channel)}


class CanSource(Source):
    """Sample blocks from DBC signals on a CAN bus.

    Parameters
    ----------
    channels : sequence of ChannelInfo
        Channel table (one column per entry of ``signals``).
    sample_rate_hz : float
        Nominal rate of one frame set (one row).
    database : cantools.database.can.Database
        The decoded DBC.
    signals : mapping of str to str
        Channel name -> ``"Message.Signal"``; must cover ``channels`` exactly.
    bus_kwargs : mapping
        Keyword arguments of ``can.Bus`` (``interface``, ``channel``, ``bitrate``...).
    block_size : int, optional
        Rows per block.
    counter : str or None, optional
        Name of a sequence-counter signal present in every mapped message (unsigned,
        factor 1, offset 0); frames with the same counter form one row.
    trigger : str or None, optional
        Message whose arrival closes a row (without ``counter``); default: a row closes
        when every mapped message has arrived once.
    expected_rate_hz : float or None, optional
        Rate the rows should come at (default ``sample_rate_hz``).
    rate_tolerance : float, optional
        Accepted relative rate deviation.
    rate_window_s : float, optional
        Bus time spanned by one rate check.
    queue_size : int, optional
        Frames the receive queue holds before it drops (and counts) new ones.
    record_raw : bool, optional
        Keep every received frame for :meth:`drain_raw_frames`.
    raw_queue_size : int, optional
        Raw frames kept between two drains (overflow counted as ``raw_frames_lost``).
    max_pending_rows : int, optional
        Rows kept open waiting for late frames before they are closed with NaN.
    max_gap_rows : int or None, optional
        Longest run of lost rows filled with NaN; a longer jump starts a new block at
        the new row index instead (default: 2 s of rows).
    reconnect_interval_s : float, optional
        Wait before reopening the bus after python-can raised.
    config_file : str or None, optional
        Experiment file, for messages.
    pace : float or None, optional
        Ignored: hardware delivers at its own pace.

    Notes
    -----
    The time of a row is the bus time stamp (``msg.timestamp``) of its first frame; a
    block's ``t0_ns`` is the time of its first row, ``first_sample`` its row index.
    """

    kind = "can"
    #: Hardware runs on its own clock: the acquisition must never block on the recorder.
    is_live = True

    def __init__(self, channels: Sequence[ChannelInfo], sample_rate_hz: float, *,
                 database: Any, signals: Mapping[str, str], bus_kwargs: Mapping[str, Any],
                 block_size: int = 100, counter: str | None = None,
                 trigger: str | None = None, expected_rate_hz: float | None = None,
                 rate_tolerance: float = 0.02, rate_window_s: float = 1.0,
                 queue_size: int = 100_000, record_raw: bool = False,
                 raw_queue_size: int = 200_000, max_pending_rows: int = 64,
                 max_gap_rows: int | None = None, reconnect_interval_s: float = 0.5,
                 config_file: str | None = None, pace: float | None = None) -> None:
        super().__init__(channels, sample_rate_hz, pace=None)
        self._file = config_file
        self._db = database
        self._bus_kwargs = dict(bus_kwargs)
        self._block_size = int(block_size)
        self._counter_name = counter
        self._expected_rate = float(expected_rate_hz or sample_rate_hz)
        self._queue_size = int(queue_size)
        self._record_raw = bool(record_raw)
        self._max_pending = int(max_pending_rows)
        self._max_gap = int(max_gap_rows if max_gap_rows is not None
                            else max(2 * self._block_size, 2 * self._expected_rate))
        self._reconnect_s = float(reconnect_interval_s)
        self.signal_map = self._plan(signals)
        self._trigger = self._find_trigger(trigger)
        self._n_msgs = len(self._specs)
        self._known_ids = {m.frame_id for m in database.messages}
        self._period_ns = 1e9 / self._expected_rate

        # receive side (thread): bounded frame queue + wake-up event
        self._bus: Any = None
        self._queue: deque[Any] = deque()
        self._wake = threading.Event()
        self._rx = ReceiveThread(self._receive_loop, "can-rx")
        self._stop_rx = self._rx.stop_event
        self._rx_overflow = 0          # written by the receive thread only
        self._reopen_failures = 0
        self._overflow_seen = 0
        self._raw: deque[tuple[int, dict[str, Any]]] = deque()
        self._raw_size = int(raw_queue_size)

        # decoding side (caller's thread)
        self._out = RowEmitter(self._emit_event, self.stats, len(self.channels),
                               self._block_size, self._expected_rate, rate_tolerance,
                               rate_window_s, self._max_gap)
        self._rows = self._out.rows
        self._limited = self._out.limited
        self._seen_unknown: set[int] = set()
        self._reset_assembly()

    # ------------------------------------------------------------------ configuration
    @classmethod
    def from_config(cls, config: Any, *, pace: float | None = None) -> "CanSource":
        """Build the source from an experiment (see the module docstring for the options).

        Raises
        ------
        ConfigError
            On missing or wrong options, an unreadable DBC, unknown messages or signals,
            or a channel table that does not match the signal map.
        """
        sec = Section(config.source.options, file=config.file, prefix=_PREFIX)
        interface = sec.string("interface", choices=sorted(can.interfaces.VALID_INTERFACES))
        channel = sec.raw("channel")
        if not isinstance(channel, (str, int)) or isinstance(channel, bool):
            raise sec.error("channel", f"expected a name or number, got {channel!r}",
                            fix="e.g. channel: can0 (socketcan) or PCAN_USBBUS1 (pcan)")
        bus_kwargs: dict[str, Any] = {"interface": interface, "channel": channel}
        bitrate = sec.integer("bitrate", None, minimum=1_000, maximum=8_000_000)
        if bitrate is not None:
            bus_kwargs["bitrate"] = bitrate
        extra = sec.raw("bus_options", {})
        if not isinstance(extra, Mapping):
            raise sec.error("bus_options", f"expected a mapping, got {type(extra).__name__}",
                            fix="e.g. bus_options: {fd: true, data_bitrate: 2000000}")
        clash = sorted(set(extra) & {"interface", "channel", "bitrate"})
        if clash:
            raise sec.error("bus_options", f"{plain.names(clash)} belong in source.options itself",
                            fix="move them one level up")
        bus_kwargs.update(extra)
        dbc_path = resolve_dbc(sec.string("dbc"), config.file)
        try:
            database = cantools.database.load_file(str(dbc_path), database_format="dbc")
        except Exception as exc:  # cantools raises several parser errors
            raise sec.error("dbc", f"cannot read DBC {str(dbc_path)!r}: {exc}",
                            fix="check the file with `python -m cantools dump FILE`") from None
        signals = sec.raw("signals")
        if not isinstance(signals, Mapping) or not signals or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in signals.items()):
            raise sec.error("signals", f"expected a mapping channel: Message.Signal, got {plain.value(signals)}",
                            fix="e.g. signals: {F-NC2W-Z: Excitation.Force}")
        kwargs = dict(
            counter=sec.string("counter", None),
            trigger=sec.string("trigger", None),
            expected_rate_hz=sec.number("expected_rate_hz", None, positive=True),
            rate_tolerance=sec.number("rate_tolerance", 0.02, positive=True, maximum=1.0),
            rate_window_s=sec.number("rate_window_s", 1.0, positive=True),
            queue_size=sec.integer("queue_size", 100_000, minimum=1),
            record_raw=sec.boolean("record_raw", False),
            raw_queue_size=sec.integer("raw_queue_size", 200_000, minimum=1),
            max_pending_rows=sec.integer("max_pending_rows", 64, minimum=1),
            max_gap_rows=sec.integer("max_gap_rows", None, minimum=0),
            reconnect_interval_s=sec.number("reconnect_interval_s", 0.5, positive=True),
        )
        sec.finish()
        channels = config.channels
        if not channels:
            raise ConfigError("the CAN source needs a channel table", file=config.file,
                              field="channels",
                              fix="list channels: with name and quantity, one per entry of "
                                  "source.options.signals")
        return cls(channels, config.sample_rate_hz, database=database, signals=signals,
                   bus_kwargs=bus_kwargs, block_size=config.block_size,
                   config_file=config.file, pace=pace, **kwargs)  # type: ignore[arg-type]

    def _error(self, key: str, message: str, fix: str | None = None) -> ConfigError:
        return ConfigError(message, file=self._file, field=f"{_PREFIX}.{key}", fix=fix)

    def _plan(self, signals: Mapping[str, str]) -> tuple[CanSignal, ...]:
        """Check the signal map against the DBC and the channel table; build the specs."""
        names = self.channel_names
        missing = [n for n in names if n not in signals]
        if missing:
            raise self._error("signals", f"channels {plain.names(missing)} have no DBC signal",
                              fix="add 'CHANNEL: Message.Signal' for each")
        extra = [n for n in signals if n not in names]
        if extra:
            raise self._error("signals", f"{plain.names(extra)} are not in the channel table",
                              fix="add them to channels: or remove them here")
        by_msg: dict[str, tuple[list[str], list[int]]] = {}
        plan = []
        for col, ch in enumerate(self.channels):
            ref = signals[ch.name]
            msg_name, dot, sig_name = ref.partition(".")
            if not dot:
                raise self._error(f"signals.{ch.name}", f"{ref!r} is not Message.Signal",
                                  fix="write e.g. Response.Disp1")
            try:
                msg = self._db.get_message_by_name(msg_name)
            except KeyError:
                raise self._error(f"signals.{ch.name}", f"no message {msg_name!r} in the DBC",
                                  fix=f"use one of {plain.names(sorted(m.name for m in self._db.messages))}") from None
            sig = next((s for s in msg.signals if s.name == sig_name), None)
            if sig is None:
                raise self._error(f"signals.{ch.name}",
                                  f"message {msg_name!r} has no signal {sig_name!r}",
                                  fix=f"use one of {plain.names([s.name for s in msg.signals])}")
            unit = sig.unit or ""
            if unit and unit != ch.unit:
                raise ConfigError(f"channel {ch.name!r} has unit {ch.unit!r} but DBC signal "
                                  f"{ref} is in {unit!r}", file=self._file, field="channels",
                                  fix=f"set unit: {unit} for {ch.name} (values are recorded "
                                      "in the DBC unit)")
            plan.append(CanSignal(ch.name, msg_name, sig_name, unit, float(sig.scale),
                                  float(sig.offset)))
            sigs, cols = by_msg.setdefault(msg_name, ([], []))
            sigs.append(sig_name)
            cols.append(col)
        self._specs: dict[int, _MessageSpec] = {}
        for i, (msg_name, (sigs, cols)) in enumerate(by_msg.items()):
            msg = self._db.get_message_by_name(msg_name)
            modulus = 0
            if self._counter_name is not None:
                sig = next((s for s in msg.signals if s.name == self._counter_name), None)
                if sig is None:
                    raise self._error("counter", f"message {msg_name!r} has no counter "
                                      f"signal {self._counter_name!r}",
                                      fix="every mapped message must carry the counter, "
                                          "or drop 'counter:'")
                if sig.is_signed or sig.scale != 1 or sig.offset != 0:
                    raise self._error("counter", f"{msg_name}.{sig.name} is not an unsigned "
                                      "integer counter (factor 1, offset 0)")
                modulus = 1 << sig.length
            if msg.frame_id in self._specs:
                raise self._error("signals", f"two mapped messages share id {msg.frame_id:#x}")
            self._specs[msg.frame_id] = _MessageSpec(i, msg_name, msg, sigs, cols,
                                                     self._counter_name, modulus)
        return tuple(plan)

    def _find_trigger(self, trigger: str | None) -> int | None:
        if trigger is None:
            return None
        if self._counter_name is not None:
            raise self._error("trigger", "'trigger' and 'counter' exclude each other",
                              fix="with a counter, frames with the same counter form a row")
        for spec in self._specs.values():
            if spec.name == trigger:
                return spec.index
        raise self._error("trigger", f"{trigger!r} is not one of the mapped messages",
                          fix=f"use one of {plain.names([s.name for s in self._specs.values()])}")

    # ------------------------------------------------------------------ life cycle
    def _open_bus(self) -> Any:
        try:
            return can.Bus(**self._bus_kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise SourceError(f"cannot open CAN bus {self._bus_kwargs}: {exc}") from exc

    def _start(self) -> None:
        if self._bus is None:
            self._bus = self._open_bus()
        self._rx.start()

    def _stop(self) -> None:
        self._rx.stop()

    def _close(self) -> None:
        if self._bus is not None:
            try:
                self._bus.shutdown()
            finally:
                self._bus = None

    # ------------------------------------------------------------------ receive thread
    def _receive_loop(self) -> None:
        """Move frames from the driver to the queue; report bus errors, never die on them.

        Kept minimal so the driver's buffer is emptied fast: no decoding here.
        """
        queue, wake, stop, limit = self._queue, self._wake, self._stop_rx, self._queue_size
        last_state = None
        next_state_poll = 0.0
        while not stop.is_set():
            bus = self._bus
            if bus is None:
                self._reopen()
                continue
            try:
                msg = bus.recv(0.05)
            except (can.CanError, OSError) as exc:
                # bus-off, interface down, adapter unplugged: report and reopen
                queue.append(("bus_error", time.time_ns(),
                              {"error": f"{type(exc).__name__}: {exc}"}))
                wake.set()
                try:
                    bus.shutdown()
                except Exception as shut_exc:  # noqa: BLE001 - the bus is gone anyway
                    logging.getLogger("fnsi_lab.daq").debug("CAN bus shutdown: %s", shut_exc)
                self._bus = None
                stop.wait(self._reconnect_s)
                continue
            if msg is not None:
                if len(queue) >= limit:
                    self._rx_overflow += 1
                else:
                    queue.append(msg)
                    if not wake.is_set():
                        wake.set()
            now = time.monotonic()
            if now >= next_state_poll:  # twice a second, busy bus or not
                next_state_poll = now + 0.5
                try:
                    state = bus.state
                except (NotImplementedError, can.CanError, OSError):
                    state = None
                if state is not None and state != last_state:
                    if last_state is not None or state != can.BusState.ACTIVE:
                        queue.append(("bus_state", time.time_ns(), {"state": state.name}))
                        wake.set()
                    last_state = state

    def _reopen(self) -> None:
        try:
            self._bus = can.Bus(**self._bus_kwargs)
        except Exception as exc:
            self._reopen_failures += 1
            if self._reopen_failures == 1:  # one event per outage, not one per attempt
                self._queue.append(("bus_reopen_failed", time.time_ns(),
                                    {"error": f"{type(exc).__name__}: {exc}"}))
                self._wake.set()
            self._stop_rx.wait(self._reconnect_s)
        else:
            self._queue.append(("bus_reconnected", time.time_ns(),
                                {"failed_attempts": self._reopen_failures}))
            self._reopen_failures = 0
            self._wake.set()

    # ------------------------------------------------------------------ reading
    def _read_block(self, timeout: float | None) -> Block | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        queue, rows = self._queue, self._rows
        while True:
            full = rows.pop()
            if full is not None:
                return self._make_block(full.data, full.first_sample, t0_ns=full.t0_ns)
            if self._rx_overflow != self._overflow_seen:
                n = self._rx_overflow - self._overflow_seen
                self._overflow_seen += n
                self.stats.count("lost_frames", n)
                self._limited("queue_overflow", time.time_ns(), n=n, frames_lost=n,
                              queue_size=self._queue_size)
            if queue:
                self._last_frame_s = time.monotonic()
                self._silence_reported = False
                # a bounded batch, so a block is returned soon after it fills
                for _ in range(min(len(queue), 4 * self._block_size * self._n_msgs + 16)):
                    self._handle(queue.popleft())
                continue
            self._wake.clear()
            if queue:
                continue
            if not self._rx.alive:
                return None
            self._check_silence()
            wait = 0.5 if deadline is None else deadline - time.monotonic()
            if wait <= 0:
                return None
            self._wake.wait(min(wait, 0.5))

    #: Seconds without any frame after which a silent bus is reported (once per silence).
    SILENCE_WARNING_S = 2.0

    def _check_silence(self) -> None:
        """Warn (event ``bus_silent`` + a logged warning) when no frame arrives at all."""
        last = getattr(self, "_last_frame_s", None)
        if last is None:
            self._last_frame_s = last = time.monotonic()
        silent = time.monotonic() - last
        if silent < self.SILENCE_WARNING_S or getattr(self, "_silence_reported", False):
            return
        self._silence_reported = True
        self._emit_event("bus_silent", seconds=round(silent, 1), bus=str(self._bus_kwargs))
        logging.getLogger("fnsi_lab.daq").warning(
            "warning: no CAN frame received for %.1f s on %s; check the wiring, termination, "
            "bitrate and that the sender is running", silent, self._bus_kwargs)

    def feed(self, msg: "can.Message") -> None:
        """Decode one frame now, bypassing the bus (replays, benchmarks, tests)."""
        self._handle(msg)

    def pop_block(self) -> Block | None:
        """A block completed by :meth:`feed`, or ``None``."""
        full = self._rows.pop()
        return None if full is None else self._make_block(full.data, full.first_sample,
                                                          t0_ns=full.t0_ns)

    def drain_raw_frames(self) -> list[tuple[str, int, dict[str, Any]]]:
        """Return and forget the raw frames received since the last call.

        Returns
        -------
        list of (str, int, dict)
            ``(RAW_TOPIC, time_ns, frame)`` with ``frame`` as :func:`frame_to_dict` gives
            it, ready for ``Recorder.write_json(topic, time_ns, frame)`` (what
            :func:`daq.acquisition.acquire` does). Empty unless ``record_raw`` is on.
        """
        out = []
        raw = self._raw
        while raw:
            t_ns, frame = raw.popleft()
            out.append((RAW_TOPIC, t_ns, frame))
        return out

    # ------------------------------------------------------------------ frame handling
    def _handle(self, msg: Any) -> None:
        if type(msg) is tuple:  # an event from the receive thread
            kind, t_ns, detail = msg
            self._emit_event(kind, time_ns=t_ns, **detail)
            return
        t_ns = int(msg.timestamp * 1e9)
        if self._record_raw:
            if len(self._raw) < self._raw_size:
                self._raw.append((t_ns, frame_to_dict(msg)))
            else:
                self.stats.count("raw_frames_lost")
                self._limited("raw_overflow", t_ns, size=self._raw_size)
        if msg.is_error_frame:
            self._limited("error_frame", t_ns, id=msg.arbitration_id,
                          data=bytes(msg.data).hex())
            return
        spec = self._specs.get(msg.arbitration_id)
        if spec is None or msg.is_remote_frame:
            if msg.is_remote_frame:
                self.stats.count("remote_frames")
            elif msg.arbitration_id in self._known_ids:
                self.stats.count("unmapped_frames")  # in the DBC, just not recorded
            else:
                self.stats.count("unknown_id_frames")
                new = msg.arbitration_id not in self._seen_unknown
                if new:
                    self._seen_unknown.add(msg.arbitration_id)
                    self._emit_event("unknown_id", time_ns=t_ns, id=msg.arbitration_id,
                                     dlc=msg.dlc, data=bytes(msg.data).hex())
            return
        try:
            decoded = spec.message.decode(msg.data, decode_choices=False)
        except (DecodeError, ValueError, KeyError, IndexError) as exc:
            self._limited("decode_error", t_ns, id=msg.arbitration_id, message=spec.name,
                          data=bytes(msg.data).hex(), error=str(exc))
            return
        values = [decoded[s] for s in spec.signals]
        if spec.counter is not None:
            self._add_counted(spec, t_ns, int(decoded[spec.counter]), values)
        else:
            self._add_set(spec, t_ns, values)

    # ------------------------------------------------------------------ row assembly
    def _reset_assembly(self) -> None:
        n = self._n_msgs
        # counter mode
        self._origin: int | None = None   # counter row of sample 0
        self._ref_row = 0
        self._ref_t = 0
        self._last_row: list[int | None] = [None] * n
        self._first_row: list[int | None] = [None] * n
        self._pending: dict[int, list[Any]] = {}
        self._next_row = 0
        self._started = False
        self._absent: set[int] = set()
        # set mode
        self._cur = np.full(len(self.channels), np.nan)
        self._cur_seen = [False] * n
        self._cur_count = 0
        self._cur_t = 0
        self._had_complete = False

    # -- counter mode: frames with the same (unwrapped) counter form a row
    def _add_counted(self, spec: _MessageSpec, t_ns: int, c: int, values: list[float]) -> None:
        m = spec.modulus
        if self._origin is None:
            self._origin = c
            self._ref_row, self._ref_t, self._next_row = c, t_ns, c
        # unwrap: the counter value nearest to the row the bus time predicts
        est = self._ref_row + int(round((t_ns - self._ref_t) / self._period_ns))
        row = est + ((c - est + m // 2) % m - m // 2)
        i = spec.index
        last = self._last_row[i]
        if last is not None:
            if row <= last:
                self._limited("counter_repeat", t_ns, message=spec.name, counter=c)
                return
            if row > last + 1:
                n = row - last - 1
                self.stats.count("lost_frames", n)
                self._limited("missing_frames", t_ns, message=spec.name,
                              expected=(last + 1) % m, got=c, frames=n)
        else:
            self._first_row[i] = row
        self._last_row[i] = row
        if i in self._absent:
            self._absent.discard(i)
        if row > self._ref_row:
            self._ref_row, self._ref_t = row, t_ns
        if row < self._next_row:
            self._limited("late_frame", t_ns, message=spec.name, counter=c)
            return
        p = self._pending.get(row)
        if p is None:
            p = self._pending[row] = [t_ns, np.full(len(self.channels), np.nan), 0]
        elif t_ns < p[0]:
            p[0] = t_ns
        p[1][spec.columns] = values
        p[2] += 1
        if not self._started and not self._start_rows():
            return
        self._drain_counted()

    def _start_rows(self) -> bool:
        """Start emitting once every message was seen: earlier rows are startup residue.

        Joining the bus mid-cycle gives rows that miss the messages sent before we
        listened; they are dropped (counted as ``startup_rows_discarded``). A message
        still unseen after ``max_pending_rows`` rows is reported (``no_frames``) and
        its channels stay NaN.
        """
        firsts = [r for r in self._first_row if r is not None]
        if len(firsts) < self._n_msgs:
            if self._ref_row - min(firsts) < self._max_pending:
                return False
            self._absent = {s.index for s in self._specs.values()
                            if self._first_row[s.index] is None}
            self._emit_event("no_frames", time_ns=self._ref_t,
                             messages=[s.name for s in self._specs.values()
                                       if s.index in self._absent])
            start = min(firsts)
        else:
            start = max(firsts)
        for r in [r for r in self._pending if r < start]:
            del self._pending[r]
            self.stats.count("startup_rows_discarded")
        self._started = True
        self._next_row = start
        self._origin = start
        return True

    def _drain_counted(self) -> None:
        n_present = self._n_msgs - len(self._absent)
        lasts = [r for k, r in enumerate(self._last_row) if k not in self._absent]
        final = min(lasts) if lasts and None not in lasts else self._next_row - 1
        final = max(final, self._ref_row - self._max_pending)
        pending = self._pending
        origin = self._origin or 0
        while True:
            row = self._next_row
            p = pending.get(row)
            if p is not None and (p[2] >= n_present or row <= final):
                del pending[row]
                if p[2] < self._n_msgs:
                    self.stats.count("incomplete_rows")
                self._out.emit(row - origin, p[0], p[1])
                self._next_row = row + 1
            elif p is None and row <= final:
                # no frame at all for this row: jump to the next row that has data
                target = min(min(pending, default=final + 1), final + 1)
                self.stats.count("incomplete_rows", target - row)
                self._next_row = target
                if target in pending or target <= final:
                    continue
                break
            else:
                break

    # -- set mode: a row closes when every mapped message arrived (or on the trigger)
    def _add_set(self, spec: _MessageSpec, t_ns: int, values: list[float]) -> None:
        i = spec.index
        if self._cur_seen[i]:
            if self._trigger is None:
                self._close_set(complete=False)
            else:
                self.stats.count("overwritten_frames")
        if self._cur_count == 0:
            self._cur_t = t_ns
        self._cur[spec.columns] = values
        if not self._cur_seen[i]:
            self._cur_seen[i] = True
            self._cur_count += 1
        if self._trigger is None:
            if self._cur_count == self._n_msgs:
                self._close_set(complete=True)
        elif i == self._trigger:
            self._close_set(complete=self._cur_count == self._n_msgs)

    def _close_set(self, complete: bool) -> None:
        t = self._cur_t
        if not self._had_complete and not complete:
            self.stats.count("startup_rows_discarded")  # joined the bus mid-cycle
        else:
            self._had_complete = True
            if not complete:
                self.stats.count("incomplete_rows")
                missing = [s.name for s in self._specs.values() if not self._cur_seen[s.index]]
                self.stats.count("lost_frames", len(missing))
                self._limited("missing_frames", t, messages=missing, n=len(missing))
            out = self._out
            if out.last_t is None:
                index = out.next_index
            else:
                steps = int(round((t - out.last_t) / self._period_ns))
                index = out.next_index + max(0, steps - 1)
                if steps > 1:
                    self.stats.count("lost_rows", steps - 1)
                    self._limited("rate_gap", t, rows=steps - 1,
                                  dt_s=(t - out.last_t) / 1e9)
            self._out.emit(index, t, self._cur)
        self._cur = np.full(len(self.channels), np.nan)
        self._cur_seen = [False] * self._n_msgs
        self._cur_count = 0

    # ------------------------------------------------------------------ metadata
    def describe(self) -> dict[str, Any]:
        """Base metadata plus the bus, the DBC (text and SHA-256) and the signal map."""
        out = super().describe()
        text = ""
        try:  # re-serialised: the DBC as cantools understood it
            text = self._db.as_dbc_string()
        except Exception as exc:  # noqa: BLE001 - cantools cannot write back every DBC
            logging.getLogger("fnsi_lab.daq").warning(
                "the DBC could not be re-serialised for the recording's metadata (%s); its "
                "SHA-256 and the signal map are still recorded", exc)
        out["source"]["can"] = {
            "bus": {k: v if isinstance(v, (str, int, float, bool)) or v is None else str(v)
                    for k, v in self._bus_kwargs.items()},
            "expected_rate_hz": self._expected_rate,
            "counter": self._counter_name,
            "signals": [asdict(s) for s in self.signal_map],
            "dbc_sha256": hashlib.sha256(text.encode()).hexdigest(),
            "dbc": text,
        }
        return out
