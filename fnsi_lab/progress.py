"""A dependency-free progress bar for long work (order sweeps, simulations, replays).

Writes to stderr; redraws in place on a terminal and prints a few plain lines otherwise
(CI logs stay short). Use as an iterator wrapper or call :meth:`Progress.update`.
"""

from __future__ import annotations

import sys
import time
from typing import IO, Iterable, Iterator, TypeVar

T = TypeVar("T")


class Progress:
    """Progress over ``total`` steps.

    Parameters
    ----------
    total : int
        Number of steps.
    label : str
        Text before the bar.
    enabled : bool
        False makes every call a no-op (``--quiet``).
    stream : file, optional
        Defaults to ``sys.stderr``.
    """

    def __init__(self, total: int, label: str = "", *, enabled: bool = True,
                 stream: IO[str] | None = None) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.done = 0
        self._t0 = time.monotonic()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_plain = -1

    def update(self, n: int = 1, note: str = "") -> None:
        """Advance by ``n`` steps."""
        self.done = min(self.done + n, self.total)
        if not self.enabled:
            return
        frac = self.done / self.total
        elapsed = time.monotonic() - self._t0
        if self._tty:
            width = 28
            bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
            self.stream.write(f"\r{self.label} [{bar}] {self.done}/{self.total} "
                              f"{elapsed:5.1f}s {note}\x1b[K")
            if self.done == self.total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            quarter = int(frac * 4)
            if quarter != self._last_plain:
                self._last_plain = quarter
                self.stream.write(f"{self.label}: {self.done}/{self.total} ({elapsed:.1f} s) {note}\n")
                self.stream.flush()

    def finish(self, note: str = "") -> None:
        """End a bar that stopped short of ``total`` (an iteration that converged early): the
        line is closed on a terminal, and the last count printed in a log."""
        if not self.enabled or not 0 < self.done < self.total:
            return
        elapsed = time.monotonic() - self._t0
        if self._tty:
            self.stream.write(f" {note}\n" if note else "\n")
        else:
            tail = f" {note}" if note else ""
            self.stream.write(f"{self.label}: {self.done} ({elapsed:.1f} s){tail}\n")
        self.stream.flush()

    def __call__(self, items: Iterable[T]) -> Iterator[T]:
        for item in items:
            yield item
            self.update()


#: Source kinds whose data come from the numba-compiled simulator (daq.sim).
SIMULATED_KINDS = ("simulated", "smallsat")


def announce_simulator_compile(source_kind: str, *, enabled: bool = True,
                               stream: IO[str] | None = None) -> None:
    """Print ``compiling the simulator (first run only)...`` when it is about to be compiled.

    For the command line: registers a notice with :func:`daq.sim.integrate.on_first_compile`
    that the kernel loader calls, once, when numba's on-disk cache does not hold the kernel
    yet (a fresh environment: ~3 s before the first block instead of ~0.4 s). Nothing for
    other sources (the simulator is then not imported).
    """
    if not enabled or source_kind not in SIMULATED_KINDS:
        return
    from fnsi_lab.daq.sim.integrate import COMPILE_SECONDS, on_first_compile

    out = stream or sys.stderr

    def notice() -> None:
        out.write(f"compiling the simulator (first run only, ~{COMPILE_SECONDS:.0f} s; "
                  "cached for later runs)...\n")
        out.flush()

    on_first_compile(notice)
