"""Software trigger for any source: recording starts when a channel crosses a level.

Like a scope (or LDAQ's trigger): a *level* and a *slope* on one channel, with
*pre-trigger samples* kept from before the crossing. :class:`TriggeredSource` wraps any
:class:`~daq.source.Source`; until the crossing it only keeps the last ``pre_samples``
rows, then it delivers those rows and everything after, with ``first_sample`` counted
from the first delivered row (so periods are cut from the trigger). The trigger settings
go to the recording's ``trigger`` metadata record and the crossing itself (sample, time,
value) is a ``trigger`` event on ``/fnsi_lab/events``.

Configured in the experiment YAML::

    trigger: {channel: F-NC2W-Z, level: 20.0, slope: rising, pre_samples: 500}
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from fnsi_lab import plain
from fnsi_lab.daq.block import Block
from fnsi_lab.daq.source import Source, SourceEvent
from fnsi_lab.errors import ConfigError

SLOPES = ("rising", "falling", "either")


@dataclass(frozen=True)
class TriggerConfig:
    """When recording starts.

    Attributes
    ----------
    channel : str
        Channel name watched.
    level : float
        Threshold, in the channel's unit.
    slope : {'rising', 'falling', 'either'}
        Rising: previous sample below the level, this one at or above it; falling: the
        reverse.
    pre_samples : int
        Samples kept from before the crossing (fewer if the source had not delivered them).
    """

    channel: str
    level: float
    slope: Literal["rising", "falling", "either"] = "rising"
    pre_samples: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (the recording's ``trigger`` metadata)."""
        return {"channel": self.channel, "level": self.level, "slope": self.slope,
                "pre_samples": self.pre_samples}


def find_crossing(x: np.ndarray, level: float, slope: str, previous: float | None = None) -> int | None:
    """Index of the first sample that completes a crossing of ``level``.

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
        Samples of the watched channel (NaN never crosses).
    level : float
    slope : {'rising', 'falling', 'either'}
    previous : float, optional
        The sample before ``x[0]`` (from the previous block); None: ``x[0]`` cannot trigger.

    Returns
    -------
    int or None
        ``i`` such that ``x[i-1] < level <= x[i]`` (rising) or ``x[i-1] > level >= x[i]``
        (falling); None when there is no crossing.
    """
    x = np.asarray(x, dtype=np.float64)
    prev = np.concatenate([[np.nan if previous is None else previous], x[:-1]])
    with np.errstate(invalid="ignore"):
        rising = (prev < level) & (x >= level)
        falling = (prev > level) & (x <= level)
    hit = rising if slope == "rising" else falling if slope == "falling" else rising | falling
    idx = np.flatnonzero(hit)
    return int(idx[0]) if idx.size else None


class TriggeredSource(Source):
    """Deliver the blocks of ``inner`` from a trigger crossing on (minus pre-trigger rows).

    Parameters
    ----------
    inner : Source
        Any source; started, stopped and closed with this one.
    trigger : TriggerConfig

    Notes
    -----
    Realization indices and time stamps (``t0_ns``) are the inner source's; only
    ``first_sample`` of the triggered realization is shifted so that the first delivered
    row is sample 0. Attributes this class does not define (``multisine``,
    ``truth_attachments``, ``drain_raw_frames``...) are the inner source's.
    """

    def __init__(self, inner: Source, trigger: TriggerConfig) -> None:
        names = [c.name for c in inner.channels]
        if trigger.channel not in names:
            raise ConfigError(f"trigger channel {trigger.channel!r} is not a channel of the source",
                              field="trigger.channel", fix=f"use one of {plain.names(names)}")
        if trigger.slope not in SLOPES:
            raise ConfigError(f"unknown slope {trigger.slope!r}", field="trigger.slope",
                              fix=f"use one of {plain.names(SLOPES)}")
        if trigger.pre_samples < 0:
            raise ConfigError("pre_samples must be >= 0", field="trigger.pre_samples")
        super().__init__(inner.channels, inner.sample_rate_hz)
        self.inner = inner
        self.trigger = trigger
        self.kind = inner.kind  # type: ignore[misc]
        self._column = names.index(trigger.channel)
        self._pre: deque[Block] = deque()  # recent blocks, at least pre_samples rows
        self._previous: float | None = None
        self._offset: int | None = None  # first_sample of the first delivered row
        self._realization: int | None = None
        #: The crossing, once it happened: sample, time_ns, value, pre_samples kept.
        self.triggered: dict[str, Any] | None = None

    # ------------------------------------------------------------------ delegation
    def __getattr__(self, name: str) -> Any:
        if name == "inner":  # not yet set (during __init__)
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def is_live(self) -> bool:
        """Live when the wrapped source is (paced or without a natural end)."""
        return getattr(self.inner, "_pace", None) is not None or getattr(self.inner, "is_live", False)

    def _start(self) -> None:
        self.inner.start()

    def _stop(self) -> None:
        self.inner.stop()

    def _close(self) -> None:
        self.inner.close()

    def drain_events(self) -> list[SourceEvent]:
        """The inner source's events, then this trigger's."""
        return self.inner.drain_events() + super().drain_events()

    def describe(self) -> dict[str, Any]:
        """The inner source's metadata plus ``trigger`` (the settings)."""
        return {**self.inner.describe(), "trigger": self.trigger.to_dict()}

    def describe_at_start(self) -> dict[str, Any]:
        """What the recording stores when it opens: the inner source's, plus ``trigger``."""
        at_start = getattr(self.inner, "describe_at_start", self.inner.describe)
        return {**at_start(), "trigger": self.trigger.to_dict()}

    # ------------------------------------------------------------------ reading
    def _read_block(self, timeout: float | None) -> Block | None:
        block = self.inner.read(timeout)
        self.stats.lost_blocks = self.inner.stats.lost_blocks
        self.stats.problems = self.inner.stats.problems
        if block is None:
            if self.inner.finished:
                self._mark_finished()
            return None
        if self._offset is not None:
            if block.realization != self._realization:
                return self._rewrap(block, block.first_sample)
            return self._rewrap(block, block.first_sample - self._offset)
        return self._watch(block)

    def _rewrap(self, block: Block, first_sample: int, data: np.ndarray | None = None,
                t0_ns: int | None = None) -> Block:
        out = self._make_block(block.data if data is None else data, first_sample,
                               t0_ns=block.t0_ns if t0_ns is None else t0_ns,
                               realization=block.realization)
        if self.inner.finished:
            self._mark_finished()
        return out

    def _watch(self, block: Block) -> Block | None:
        """Look for the crossing in ``block``; return the first delivered block if found."""
        if self._pre and self._pre[-1].realization != block.realization:
            self._pre.clear()
            self._previous = None
        column = block.data[:, self._column]
        hit = find_crossing(column, self.trigger.level, self.trigger.slope, self._previous)
        self._previous = float(column[-1]) if block.n_samples else self._previous
        if hit is None:
            self._pre.append(block)
            while self._pre and sum(b.n_samples for b in self._pre) - self._pre[0].n_samples \
                    >= self.trigger.pre_samples:
                self._pre.popleft()
            if self.inner.finished:
                self._mark_finished()  # the source ended without a trigger
            return None
        # rows kept: the tail of the buffered blocks (contiguous ones only) + this block
        kept: list[np.ndarray] = [block.data]
        first = block.first_sample
        t0 = block.t0_ns
        want = self.trigger.pre_samples - hit
        for prev in reversed(self._pre):
            if want <= 0 or prev.first_sample + prev.n_samples != first:
                break
            take = min(want, prev.n_samples)
            kept.insert(0, prev.data[prev.n_samples - take:])
            first -= take
            t0 = prev.t0_ns + int(round((prev.n_samples - take) * 1e9 / self.sample_rate_hz))
            want -= take
        data = np.concatenate(kept, axis=0)
        start_in_data = (block.first_sample - first) + hit - self.trigger.pre_samples
        start_in_data = max(start_in_data, 0)
        data = data[start_in_data:]
        first += start_in_data
        t0 += int(round(start_in_data * 1e9 / self.sample_rate_hz))
        self._pre.clear()
        self._offset = first
        self._realization = block.realization
        trigger_sample = block.first_sample + hit
        trigger_ns = block.t0_ns + int(round(hit * 1e9 / self.sample_rate_hz))
        self.triggered = {"channel": self.trigger.channel, "level": self.trigger.level,
                          "slope": self.trigger.slope, "source_sample": int(trigger_sample),
                          "sample": int(trigger_sample - first), "time_ns": int(trigger_ns),
                          "value": float(block.data[hit, self._column]),
                          "pre_samples": int(trigger_sample - first),
                          "realization": int(block.realization)}
        # an event for the recording, not a problem: not counted in stats.problems
        self._events.append(SourceEvent(time_ns=trigger_ns, kind="trigger", detail={
            k: v for k, v in self.triggered.items() if k != "time_ns"}))
        return self._rewrap(block, 0, data=data, t0_ns=t0)


def parse_trigger(sec: Any) -> TriggerConfig:
    """The ``trigger:`` section of an experiment (a :class:`fnsi_lab.validate.Section`)."""
    slope = sec.string("slope", "rising", choices=SLOPES)
    config = TriggerConfig(channel=sec.string("channel"), level=sec.number("level"),
                           slope=slope,  # type: ignore[arg-type]
                           pre_samples=sec.integer("pre_samples", 0, minimum=0))
    sec.finish()
    return config
