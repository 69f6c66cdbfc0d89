"""Which periods of a record are in steady state (docs/ident.md, "Periods not in steady state").

A multisine test starts from rest: the first periods carry the free response of the
lightly damped modes, and a joint that settles (friction slip relaxing a bolt's preload)
makes the response drift for a while. Averaging such periods with the steady ones biases
every line, and their spread is taken for noise by the weighting. So, after the periods the
configuration names as transient (``transient_periods``), each remaining period is measured
against the *settled* part of the record, and the leading periods that stand out are left
out:

- ``deviation[j]``: the RMS difference between period ``j`` and the mean of the last half of
  the periods, relative to that mean's RMS, on the processed band's lines (where a ringing
  mode shows; broadband sensor noise would swamp it in the time domain), for the worst output
  channel (and realisation);
- ``floor``: the median deviation over that last half: what noise (or a response that
  differs from period to period without a trend, e.g. stick-slip) alone gives;
- a leading period is left out while its deviation exceeds both ``tolerance`` (default 1 %)
  and ``3 x floor``; the first period that passes ends the search (a transient decays), and
  at least half of the periods (at least 2) are always kept.

A record whose periods differ throughout without decaying keeps every period: the
difference is reported (``drift``), the averaging then treats it as noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PeriodSelection", "select_steady_periods", "STEADY_TOLERANCE"]

#: A leading period that differs by less than this (relative RMS, worst channel) from the
#: settled periods is kept whatever the noise: the existing records' numbers stay as they
#: were (the real Silverbox's periods differ by 0.6 % from period to period, noise; the
#: simulated SmallSat's by < 1e-6), while the aircraft-like GVT's second period, 3 % off
#: at 12 N (its 0.5 %-damped modes still ringing), is left out.
STEADY_TOLERANCE = 0.01


@dataclass(frozen=True)
class PeriodSelection:
    """The periods used and why.

    Attributes
    ----------
    first : int
        Index of the first period looked at (the configured transient periods before it).
    drift : ndarray, shape (P - 1,)
        Relative RMS difference between consecutive periods ``first + j`` and
        ``first + j + 1`` (worst output channel and realisation).
    deviation : ndarray, shape (P,)
        Relative RMS difference of each period from the mean of the last half.
    floor : float
        Median deviation over the last half (noise, or stick-slip without a trend).
    used : tuple of int
        Period indices used (0-based, in the whole record).
    dropped : tuple of int
        Periods left out as not steady (0-based, in the whole record).
    tolerance : float
    """

    first: int
    drift: np.ndarray
    deviation: np.ndarray
    floor: float
    used: tuple[int, ...]
    dropped: tuple[int, ...]
    tolerance: float

    @property
    def statement(self) -> str:
        """One line: which periods were used and why the others were not."""
        n_total = self.first + self.deviation.size
        first_used, last_used = self.used[0] + 1, self.used[-1] + 1
        used = (f"period {first_used} of {n_total} used" if first_used == last_used
                else f"periods {first_used}-{last_used} of {n_total} used")
        parts = [used]
        if self.first:
            parts.append(f"{self.first} configured as transient")
        if self.dropped:
            worst = float(np.max(self.deviation[np.asarray(self.dropped) - self.first]))
            parts.append(f"{len(self.dropped)} more left out as not steady (period"
                         f"{'s' if len(self.dropped) > 1 else ''} "
                         f"{', '.join(str(d + 1) for d in self.dropped)}: up to "
                         f"{100 * worst:.3g} % from the settled periods, whose own spread is "
                         f"{100 * self.floor:.2g} %)")
        if self.drift.size:
            last = float(self.drift[-1])
            parts.append(f"consecutive periods differ by {100 * last:.2g} % at the end"
                         + (" (no decay: averaged as noise)"
                            if last > self.tolerance and not self.dropped else ""))
        return "; ".join(parts)

    def to_dict(self) -> dict:
        """JSON-able (period numbers 1-based, as a user counts them)."""
        return {"used": [u + 1 for u in self.used], "dropped": [d + 1 for d in self.dropped],
                "transient": list(range(1, self.first + 1)),
                "drift_per_period": [float(x) for x in self.drift],
                "deviation": [float(x) for x in self.deviation], "floor": float(self.floor),
                "tolerance": self.tolerance, "statement": self.statement}


def _relative_rms(diff: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Worst channel and realisation of ``rms(diff) / rms(ref)`` over the lines.

    ``diff``, ``ref``: ``(R, ..., F, p)`` spectra; returns the leading middle axes."""
    num = np.sqrt(np.mean(np.abs(diff) ** 2, axis=-2))             # (R, ..., p)
    den = np.sqrt(np.mean(np.abs(ref) ** 2, axis=-2))
    rel = num / np.where(den > 0, den, 1.0)
    return np.max(rel, axis=(0, rel.ndim - 1))


def select_steady_periods(y: np.ndarray, first: int = 0, *, bins: np.ndarray | None = None,
                          tolerance: float = STEADY_TOLERANCE,
                          select: bool = True) -> PeriodSelection:
    """Measure the drift per period and choose the steady ones.

    Parameters
    ----------
    y : ndarray, shape (R, P_total, N, p)
        Outputs of every period of every realisation.
    first : int
        Periods before this one are transient by configuration (not looked at).
    bins : int ndarray, optional
        DFT bins (of one period) to compare on: the processed band, where a ringing mode
        shows and the broadband sensor noise does not swamp it (default every bin but DC).
    tolerance : float
        Relative RMS deviation below which a period counts as steady whatever the noise.
    select : bool
        False: measure only, keep every period from ``first`` on.

    Returns
    -------
    PeriodSelection
    """
    y = np.asarray(y, float)
    spectra = np.fft.rfft(y[:, first:], axis=2)                     # (R, P, bins, p)
    centred = spectra[:, :, np.asarray(bins, int)] if bins is not None else spectra[:, :, 1:]
    P = centred.shape[1]
    drift = (_relative_rms(np.diff(centred, axis=1), centred[:, 1:]) if P >= 2
             else np.zeros(0))
    half = max(P // 2, 1)
    ref = centred[:, P - half:].mean(axis=1, keepdims=True)
    deviation = _relative_rms(centred - ref, np.broadcast_to(ref, centred.shape))
    floor = float(np.median(deviation[P - half:])) if P >= 2 else 0.0
    n_drop = 0
    if select and P >= 3:
        limit = max(tolerance, 3.0 * floor)
        max_drop = P - max(2, (P + 1) // 2)
        while n_drop < max_drop and deviation[n_drop] > limit:
            n_drop += 1
    used = tuple(range(first + n_drop, first + P))
    dropped = tuple(range(first, first + n_drop))
    return PeriodSelection(first=first, drift=drift, deviation=deviation, floor=floor,
                           used=used, dropped=dropped, tolerance=tolerance)
