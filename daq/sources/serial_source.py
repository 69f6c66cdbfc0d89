"""Serial instrument source over pyserial: text lines (CSV-like) or fixed binary frames.

The port is opened with ``serial.serial_for_url``, so a device path (``/dev/ttyUSB0``,
``COM3``, a pty), ``loop://`` and ``socket://host:port`` all work::

    source:
      kind: serial
      options:
        url: /dev/ttyUSB0
        baudrate: 921600
        format: line                # or binary
        delimiter: ","              # line format; "whitespace" splits on any blank
        fields: [counter, F-NC2W-Z, NC2W-Z]   # what each column is; "_" skips one
        counter: counter            # optional sample counter (lost lines become NaN)
        scale: {F-NC2W-Z: 0.01}     # physical = raw * scale + offset
        offset: {NC2W-Z: 0.0}

Binary frames are ``sync`` bytes, a ``struct`` payload and an optional checksum over the
payload (``sum8``, ``xor8``, ``crc16`` = CRC-16/CCITT with init 0xFFFF, ``crc32``), in
the payload's byte order::

        format: binary
        sync: "A55A"                # hex
        struct: "<Hhh"              # one item per entry of fields
        fields: [counter, F-NC2W-Z, NC2W-Z]
        checksum: crc16

Robustness
----------
A receive thread reads bytes into a bounded queue (overflow counted as ``lost_bytes``)
and owns the port: when the device stops sending for ``stall_timeout_s`` it reports
``stall`` (and ``resumed`` when bytes come back); when pyserial raises (cable pulled,
USB adapter re-enumerated, TCP peer gone) it reports ``disconnected``, reopens the URL
every ``reconnect_interval_s`` and reports ``reconnected``. The parser, running in the
caller's thread, keeps partial lines across reads, resynchronises after garbage
(``bad_line``, ``resync``, ``bad_checksum``, ``overlong_line``) and drops the first line
after every (re)connection, which may be a tail. Without a counter a lost line cannot be
told from inserted garbage, so rows are numbered consecutively; with a counter, lost
samples become NaN rows and are counted (``lost_samples`` / ``missing_samples``).

Serial devices have no time stamps: a row is stamped with the host clock when its last
byte was read, so one block's ``t0_ns`` jitters by the USB latency (about 1 ms); the
rate check uses windows of ``rate_window_s`` (default 2 s) to average that out.
"""

from __future__ import annotations

import logging

import binascii
import struct
import threading
import time
import zlib
from collections import deque
from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.source import Source
from fnsi_lab.daq.sources._rate import ReceiveThread, RowEmitter
from fnsi_lab.errors import ConfigError, SourceError
from fnsi_lab.validate import Section

try:
    import serial
except ImportError as exc:  # pragma: no cover - pyserial is a declared dependency
    raise ImportError(f"the serial source needs pyserial: {exc}", name=exc.name) from exc

__all__ = ["SerialSource", "CHECKSUMS"]

_PREFIX = "source.options"
_SKIP = ("_", "")


def _sum8(data: bytes) -> int:
    return sum(data) & 0xFF


def _xor8(data: bytes) -> int:
    x = 0
    for b in data:
        x ^= b
    return x


#: checksum name -> (struct code, function over the payload bytes)
CHECKSUMS: dict[str, tuple[str, Callable[[bytes], int]]] = {
    "sum8": ("B", _sum8),
    "xor8": ("B", _xor8),
    "crc16": ("H", lambda d: binascii.crc_hqx(d, 0xFFFF)),
    "crc32": ("I", lambda d: zlib.crc32(d) & 0xFFFFFFFF),
}


class SerialSource(Source):
    """Sample blocks from a serial instrument.

    Parameters
    ----------
    channels : sequence of ChannelInfo
        Channel table; every channel must appear in ``fields``.
    sample_rate_hz : float
        Rate of the instrument (one line or frame per sample).
    url : str
        Anything ``serial.serial_for_url`` opens.
    fields : sequence of str
        What each column (line) or struct item (binary) is: a channel name, the
        ``counter`` name, or ``"_"`` to skip it.
    format : {'line', 'binary'}, optional
    baudrate : int, optional
    serial_kwargs : mapping, optional
        More ``serial_for_url`` arguments (``bytesize``, ``parity``, ``stopbits``...).
    delimiter : str, optional
        Line format column separator; ``"whitespace"`` splits on runs of blanks.
    line_ending : str, optional
        Line terminator (``"\\n"`` also accepts ``"\\r\\n"``).
    encoding : str, optional
        Text encoding of lines.
    sync : bytes, optional
        Binary frame start marker.
    struct_format : str, optional
        ``struct`` format of the binary payload.
    checksum : {'none', 'sum8', 'xor8', 'crc16', 'crc32'}, optional
    counter : str or None, optional
        Field holding a sample counter.
    counter_modulus : int or None, optional
        Counter wrap-around (binary: default from the struct type; line: none).
    scale, offset : mapping of str to float, optional
        Per-channel ``physical = raw * scale + offset``.
    block_size : int, optional
    expected_rate_hz, rate_tolerance, rate_window_s : float, optional
        Rate check (default rate: ``sample_rate_hz``).
    read_timeout_s, stall_timeout_s, reconnect_interval_s : float, optional
        pyserial read timeout; silence reported as a stall; wait between reopen tries.
    max_line_bytes : int, optional
        A "line" longer than this is garbage: dropped up to the next line end.
    queue_bytes : int, optional
        Bytes the receive queue holds before it drops (and counts) new ones.
    max_gap_rows : int or None, optional
        Longest counter gap filled with NaN rows (default: 2 s of rows).
    config_file : str or None, optional
        Experiment file, for messages.
    pace : float or None, optional
        Ignored: the instrument delivers at its own pace.
    """

    kind = "serial"
    #: Hardware runs on its own clock: the acquisition must never block on the recorder.
    is_live = True

    def __init__(self, channels: Sequence[ChannelInfo], sample_rate_hz: float, *, url: str,
                 fields: Sequence[str | None], format: Literal["line", "binary"] = "line",
                 baudrate: int = 115200, serial_kwargs: Mapping[str, Any] | None = None,
                 delimiter: str = ",", line_ending: str = "\n", encoding: str = "ascii",
                 sync: bytes = b"", struct_format: str = "", checksum: str = "none",
                 counter: str | None = None, counter_modulus: int | None = None,
                 scale: Mapping[str, float] | None = None,
                 offset: Mapping[str, float] | None = None, block_size: int = 100,
                 expected_rate_hz: float | None = None, rate_tolerance: float = 0.02,
                 rate_window_s: float = 2.0, read_timeout_s: float = 0.05,
                 stall_timeout_s: float = 1.0, reconnect_interval_s: float = 0.5,
                 max_line_bytes: int = 4096, queue_bytes: int = 16 << 20,
                 max_gap_rows: int | None = None, config_file: str | None = None,
                 pace: float | None = None) -> None:
        super().__init__(channels, sample_rate_hz, pace=None)
        self._file = config_file
        self._url = url
        self._format = format
        self._serial_kwargs = {"baudrate": int(baudrate), **dict(serial_kwargs or {})}
        self._delimiter = None if delimiter == "whitespace" else delimiter
        self._eol = line_ending.encode(encoding)
        self._encoding = encoding
        self._read_timeout = float(read_timeout_s)
        self._stall_s = float(stall_timeout_s)
        self._reconnect_s = float(reconnect_interval_s)
        self._max_line = int(max_line_bytes)
        self._queue_bytes = int(queue_bytes)
        expected = float(expected_rate_hz or sample_rate_hz)
        self._expected_rate = expected
        self._plan_fields(list(fields), counter, scale or {}, offset or {})
        self._sync = bytes(sync)
        self._checksum = checksum
        if format == "binary":
            self._plan_binary(struct_format, checksum, counter_modulus)
        else:
            self._modulus = counter_modulus
        max_gap = int(max_gap_rows if max_gap_rows is not None
                      else max(2 * block_size, 2 * expected))
        self._out = RowEmitter(self._emit_event, self.stats, len(self.channels), block_size,
                               expected, rate_tolerance, rate_window_s, max_gap)
        self._limited = self._out.limited

        self._port: Any = None
        self._queue: deque[Any] = deque()
        self._queued_bytes = 0
        self._lock_q = threading.Lock()  # _queued_bytes is updated by two threads
        self._wake = threading.Event()
        self._rx = ReceiveThread(self._receive_loop, "serial-rx")
        self._stop_rx = self._rx.stop_event
        self._rx_lost = 0
        self._lost_seen = 0

        self._buf = bytearray()
        self._skip_line = True      # the first line after a (re)connect may be a tail
        self._discarding = False    # inside an overlong line, up to its end
        self._index = -1            # row index of the last row
        self._last_counter: int | None = None

    # ------------------------------------------------------------------ configuration
    def _error(self, key: str, message: str, fix: str | None = None) -> ConfigError:
        return ConfigError(message, file=self._file, field=f"{_PREFIX}.{key}", fix=fix)

    def _plan_fields(self, fields: list[str | None], counter: str | None,
                     scale: Mapping[str, float], offset: Mapping[str, float]) -> None:
        names = self.channel_names
        fields = ["_" if f is None else str(f) for f in fields]
        if not fields:
            raise self._error("fields", "no fields", fix="list what each column is")
        missing = [n for n in names if n not in fields]
        if missing:
            raise self._error("fields", f"channels {plain.names(missing)} are not among the fields",
                              fix="name every channel in fields (\"_\" skips a column)")
        known = set(names) | set(_SKIP) | ({counter} if counter else set())
        unknown = [f for f in fields if f not in known]
        if unknown:
            raise self._error("fields", f"{plain.names(unknown)} are neither channels nor the counter",
                              fix="use a channel name, the counter name, or \"_\" to skip")
        dup = sorted({f for f in fields if f not in _SKIP and fields.count(f) > 1})
        if dup:
            raise self._error("fields", f"{plain.names(dup)} appear twice")
        if counter is not None and counter not in fields:
            raise self._error("counter", f"counter {counter!r} is not one of the fields",
                              fix="add it to fields")
        for key, table in (("scale", scale), ("offset", offset)):
            bad = [k for k in table if k not in names]
            if bad:
                raise self._error(key, f"{plain.names(bad)} are not channels")
        self._fields = fields
        self._counter_pos = fields.index(counter) if counter else None
        pos = [fields.index(n) for n in names]
        self._pos = np.asarray(pos, dtype=np.intp)
        self._scale = np.array([float(scale.get(n, 1.0)) for n in names])
        self._offset = np.array([float(offset.get(n, 0.0)) for n in names])
        self._identity = bool(np.all(self._scale == 1.0) and np.all(self._offset == 0.0))

    def _plan_binary(self, fmt: str, checksum: str, modulus: int | None) -> None:
        if not self._sync:
            raise self._error("sync", "binary frames need sync bytes",
                              fix='e.g. sync: "A55A" (hex)')
        try:
            payload = struct.Struct(fmt)
        except struct.error as exc:
            raise self._error("struct", f"bad struct format {fmt!r}: {exc}",
                              fix='e.g. "<Hhh" (little-endian uint16, 2 x int16)') from None
        n_items = len(payload.unpack(bytes(payload.size)))
        if n_items != len(self._fields):
            raise self._error("fields", f"struct {fmt!r} has {n_items} items but "
                              f"{len(self._fields)} fields are named",
                              fix="one field name per struct item")
        order = fmt[0] if fmt and fmt[0] in "<>!=@" else "<"
        self._payload = payload
        if checksum == "none":
            self._ck: tuple[struct.Struct, Callable[[bytes], int]] | None = None
        else:
            code, fn = CHECKSUMS[checksum]
            self._ck = (struct.Struct(order + code), fn)
        self._frame_len = len(self._sync) + payload.size + (self._ck[0].size if self._ck else 0)
        if modulus is None and self._counter_pos is not None:
            code = fmt.lstrip("<>!=@").replace(" ", "")
            codes = [c for c in code if not c.isdigit()]
            ctype = codes[self._counter_pos] if len(codes) == n_items else ""
            size = struct.calcsize(ctype) if ctype in "BHILQ" and ctype else 0
            modulus = 1 << (8 * size) if size else None
        self._modulus = modulus

    @classmethod
    def from_config(cls, config: Any, *, pace: float | None = None) -> "SerialSource":
        """Build the source from an experiment (options: see the module docstring).

        Raises
        ------
        ConfigError
            On missing or wrong options, naming the field and the fix.
        """
        sec = Section(config.source.options, file=config.file, prefix=_PREFIX)
        url = sec.string("url")
        fmt = sec.string("format", "line", choices=("line", "binary"))
        kwargs: dict[str, Any] = {}
        extra = sec.raw("serial_options", {})
        if not isinstance(extra, Mapping):
            raise sec.error("serial_options", f"expected a mapping, got {type(extra).__name__}",
                            fix="e.g. serial_options: {parity: E, rtscts: true}")
        fields = sec.raw("fields", None)
        if fields is None:
            fields = [c.name for c in config.channels]
        if not isinstance(fields, list) or not all(isinstance(f, str) or f is None
                                                   for f in fields):
            raise sec.error("fields", f"expected a list of names, got {plain.value(fields)}",
                            fix='e.g. fields: [counter, F-NC2W-Z, "_", NC2W-Z]')
        tables = {}
        for key in ("scale", "offset"):
            table = sec.raw(key, {})
            if not isinstance(table, Mapping) or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool)
                    for v in table.values()):
                raise sec.error(key, f"expected channel: number pairs, got {plain.value(table)}")
            tables[key] = {str(k): float(v) for k, v in table.items()}
        if fmt == "binary":
            sync_hex = sec.string("sync")
            try:
                kwargs["sync"] = bytes.fromhex(sync_hex)
            except ValueError:
                raise sec.error("sync", f"{sync_hex!r} is not hex", fix='e.g. sync: "A55A"') from None
            kwargs["struct_format"] = sec.string("struct")
            kwargs["checksum"] = sec.string("checksum", "none",
                                            choices=("none", *CHECKSUMS))
        else:
            kwargs["delimiter"] = sec.string("delimiter", ",")
            kwargs["line_ending"] = sec.string("line_ending", "\n")
            kwargs["encoding"] = sec.string("encoding", "ascii")
            if not kwargs["delimiter"] or not kwargs["line_ending"]:
                raise sec.error("delimiter", "delimiter and line_ending must not be empty",
                                fix='use "whitespace" to split on blanks')
        kwargs.update(
            baudrate=sec.integer("baudrate", 115200, minimum=50),
            counter=sec.string("counter", None),
            counter_modulus=sec.integer("counter_modulus", None, minimum=2),
            expected_rate_hz=sec.number("expected_rate_hz", None, positive=True),
            rate_tolerance=sec.number("rate_tolerance", 0.02, positive=True, maximum=1.0),
            rate_window_s=sec.number("rate_window_s", 2.0, positive=True),
            read_timeout_s=sec.number("read_timeout_s", 0.05, positive=True),
            stall_timeout_s=sec.number("stall_timeout_s", 1.0, positive=True),
            reconnect_interval_s=sec.number("reconnect_interval_s", 0.5, positive=True),
            max_line_bytes=sec.integer("max_line_bytes", 4096, minimum=16),
            queue_bytes=sec.integer("queue_bytes", 16 << 20, minimum=1024),
            max_gap_rows=sec.integer("max_gap_rows", None, minimum=0),
        )
        sec.finish()
        if not config.channels:
            raise ConfigError("the serial source needs a channel table", file=config.file,
                              field="channels", fix="list channels: with name and quantity")
        return cls(config.channels, config.sample_rate_hz, url=url, fields=fields, format=fmt,
                   serial_kwargs=extra, scale=tables["scale"], offset=tables["offset"],
                   block_size=config.block_size, config_file=config.file, pace=pace,
                   **kwargs)

    # ------------------------------------------------------------------ life cycle
    def _open(self) -> Any:
        return serial.serial_for_url(self._url, timeout=self._read_timeout,
                                     **self._serial_kwargs)

    def _start(self) -> None:
        if self._port is None:
            try:
                self._port = self._open()
            except (serial.SerialException, OSError, ValueError) as exc:
                raise SourceError(f"cannot open serial port {self._url!r}: {exc}") from exc
        self._rx.start()

    def _stop(self) -> None:
        self._rx.stop()

    def _close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            finally:
                self._port = None

    @property
    def port(self) -> Any:
        """The open pyserial port (``None`` while disconnected); tests write to loop://."""
        return self._port

    # ------------------------------------------------------------------ receive thread
    def _post(self, kind: str, **detail: Any) -> None:
        """Hand an event to the parser thread, in order with the bytes around it."""
        self._queue.append((kind, time.time_ns(), detail))
        self._wake.set()

    def _receive_loop(self) -> None:
        """Read bytes, detect stalls and disconnections, reopen; no parsing here."""
        stop, queue, wake = self._stop_rx, self._queue, self._wake
        last_data = time.monotonic()
        stalled = False
        while not stop.is_set():
            port = self._port
            if port is None:
                try:
                    self._port = self._open()
                except (serial.SerialException, OSError, ValueError):
                    stop.wait(self._reconnect_s)
                    continue
                self._post("reconnected", url=self._url,
                           after_s=round(time.monotonic() - last_data, 3))
                last_data = time.monotonic()
                stalled = False
                continue
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, ValueError) as exc:
                self._post("disconnected", url=self._url, error=f"{type(exc).__name__}: {exc}")
                try:
                    port.close()
                except Exception as close_exc:  # noqa: BLE001 - the port is gone anyway
                    logging.getLogger("fnsi_lab.daq").debug("closing %s: %s", self._url,
                                                            close_exc)
                self._port = None
                stop.wait(self._reconnect_s)
                continue
            now = time.monotonic()
            if data:
                if stalled:
                    self._post("resumed", stalled_s=round(now - last_data, 3))
                    stalled = False
                last_data = now
                if self._queued_bytes + len(data) > self._queue_bytes:
                    self._rx_lost += len(data)
                    continue
                with self._lock_q:
                    self._queued_bytes += len(data)
                queue.append((time.time_ns(), data))
                if not wake.is_set():
                    wake.set()
            elif not stalled and now - last_data >= self._stall_s:
                stalled = True
                self._post("stall", silent_s=round(now - last_data, 3))

    # ------------------------------------------------------------------ reading
    def _read_block(self, timeout: float | None) -> Block | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        rows, queue = self._out.rows, self._queue
        while True:
            full = rows.pop()
            if full is not None:
                return self._make_block(full.data, full.first_sample, t0_ns=full.t0_ns)
            if self._rx_lost != self._lost_seen:
                n = self._rx_lost - self._lost_seen
                self._lost_seen += n
                self.stats.count("lost_bytes", n)
                self._limited("queue_overflow", time.time_ns(), bytes_lost=n)
            if queue:
                item = queue.popleft()
                if type(item[1]) is bytes:
                    with self._lock_q:
                        self._queued_bytes -= len(item[1])
                    self.feed(item[1], item[0])
                else:
                    self._on_port_event(*item)
                continue
            self._wake.clear()
            if queue:
                continue
            if not self._rx.alive:
                return None
            wait = 0.5 if deadline is None else deadline - time.monotonic()
            if wait <= 0:
                return None
            self._wake.wait(min(wait, 0.5))

    def pop_block(self) -> Block | None:
        """A block completed by :meth:`feed`, or ``None``."""
        full = self._out.rows.pop()
        return None if full is None else self._make_block(full.data, full.first_sample,
                                                          t0_ns=full.t0_ns)

    def _on_port_event(self, kind: str, t_ns: int, detail: dict[str, Any]) -> None:
        self._emit_event(kind, time_ns=t_ns, **detail)
        if kind in ("disconnected", "stall"):
            # what was half-read belongs to a line we will never see whole
            if kind == "disconnected":
                self._drop_partial(t_ns)
            self._out.restart_rate()
        elif kind == "reconnected":
            self._skip_line = True

    def _drop_partial(self, t_ns: int) -> None:
        if self._buf:
            self.stats.count("partial_bytes_dropped", len(self._buf))
            self._buf.clear()
        self._discarding = False

    # ------------------------------------------------------------------ parsing
    def feed(self, data: bytes, t_ns: int | None = None) -> None:
        """Parse bytes now, bypassing the port (benchmarks, tests, replays).

        Parameters
        ----------
        data : bytes
            The next bytes of the stream.
        t_ns : int, optional
            Arrival time (default: now).
        """
        if t_ns is None:
            t_ns = time.time_ns()
        self._buf += data
        if self._format == "line":
            self._parse_lines(t_ns)
        else:
            self._parse_frames(t_ns)

    def _parse_lines(self, t_ns: int) -> None:
        buf, eol = self._buf, self._eol
        start = 0
        while True:
            end = buf.find(eol, start)
            if end < 0:
                break
            line = bytes(buf[start:end])
            start = end + len(eol)
            if len(line) > self._max_line:
                self._limited("overlong_line", t_ns, bytes=len(line),
                              head=line[:40].decode(self._encoding, "replace"))
                continue
            if self._discarding:
                self._discarding = False  # the end of an overlong line: back in sync
                continue
            if self._skip_line:
                self._skip_line = False
                self.stats.count("startup_lines_discarded")
                continue
            self._parse_line(line, t_ns)
        if start:
            del buf[:start]
        if len(buf) > self._max_line:
            self._limited("overlong_line", t_ns, bytes=len(buf),
                          head=bytes(buf[:40]).decode(self._encoding, "replace"))
            buf.clear()
            self._discarding = True

    def _parse_line(self, line: bytes, t_ns: int) -> None:
        try:
            text = line.decode(self._encoding).strip()
            if not text:
                return
            parts = text.split(self._delimiter)
            if len(parts) != len(self._fields):
                raise ValueError(f"{len(parts)} fields, expected {len(self._fields)}")
            raw = [float(parts[i]) for i in self._pos]
            counter = None if self._counter_pos is None else int(parts[self._counter_pos])
        except (UnicodeDecodeError, ValueError) as exc:
            self._limited("bad_line", t_ns, line=line[:80].decode(self._encoding, "replace"),
                          error=str(exc)[:120])
            return
        self._add_row(t_ns, raw, counter)

    def _parse_frames(self, t_ns: int) -> None:
        buf, sync, flen = self._buf, self._sync, self._frame_len
        payload, ck = self._payload, self._ck
        ps, start = payload.size, 0
        skipped = 0
        while len(buf) - start >= flen:
            at = buf.find(sync, start)
            if at < 0:
                # keep a possible sync prefix at the end of the buffer
                keep = len(sync) - 1
                skipped += max(0, len(buf) - start - keep)
                start = max(start, len(buf) - keep)
                break
            if at > start:
                skipped += at - start
                start = at
            if len(buf) - start < flen:
                break
            p0 = start + len(sync)
            body = bytes(buf[p0:p0 + ps])
            if ck is not None:
                (got,) = ck[0].unpack_from(buf, p0 + ps)
                if got != ck[1](body):
                    # a false sync inside garbage or a corrupted frame: slide one byte
                    self._limited("bad_checksum", t_ns, frame=bytes(buf[start:start + flen]).hex())
                    start += 1
                    skipped += 1
                    continue
            if skipped:
                self._report_resync(t_ns, skipped)
                skipped = 0
            start += flen
            if self._skip_line:  # a frame cannot be a tail: nothing to skip
                self._skip_line = False
            items = payload.unpack(body)
            raw = [items[i] for i in self._pos]
            counter = None if self._counter_pos is None else int(items[self._counter_pos])
            self._add_row(t_ns, raw, counter)
        if skipped:
            self._report_resync(t_ns, skipped)
        if start:
            del buf[:start]

    def _report_resync(self, t_ns: int, skipped: int) -> None:
        self.stats.count("skipped_bytes", skipped)
        self._limited("resync", t_ns, skipped_bytes=skipped)

    # ------------------------------------------------------------------ rows
    def _add_row(self, t_ns: int, raw: list[float], counter: int | None) -> None:
        index = self._index + 1
        if counter is not None:
            last = self._last_counter
            if last is not None:
                m = self._modulus
                delta = (counter - last) % m if m else counter - last
                if delta == 0:
                    self._limited("counter_repeat", t_ns, counter=counter)
                    return
                if delta < 0 or delta > self._out.max_gap + 1:
                    # restarted instrument (or an outage too long to tell): start anew
                    self._emit_event("counter_reset", time_ns=t_ns, last=last, got=counter)
                elif delta > 1:
                    self.stats.count("lost_samples", delta - 1)
                    self._limited("missing_samples", t_ns, samples=delta - 1,
                                  expected=(last + 1) % m if m else last + 1, got=counter)
                    index = self._index + delta
            self._last_counter = counter
        values = np.asarray(raw, dtype=float)
        if not self._identity:
            values = values * self._scale + self._offset
        self._index = index
        self._out.emit(index, t_ns, values)

    # ------------------------------------------------------------------ metadata
    def describe(self) -> dict[str, Any]:
        """Base metadata plus the port and the frame layout."""
        out = super().describe()
        info: dict[str, Any] = {
            "url": self._url, "format": self._format,
            "serial": {k: v if isinstance(v, (str, int, float, bool)) or v is None else str(v)
                       for k, v in self._serial_kwargs.items()},
            "fields": self._fields, "expected_rate_hz": self._expected_rate,
            "scale": dict(zip(self.channel_names, self._scale.tolist())),
            "offset": dict(zip(self.channel_names, self._offset.tolist())),
        }
        if self._format == "binary":
            info.update(sync=self._sync.hex(), struct=self._payload.format,
                        checksum=self._checksum)
        else:
            info.update(delimiter=self._delimiter or "whitespace",
                        line_ending=self._eol.decode(self._encoding))
        out["source"]["serial"] = info
        return out
