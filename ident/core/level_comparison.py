"""Several distortion analyses of one structure at different levels, compared: the
resonances followed from level to level, the outputs' noise and distortion levels side by
side (:func:`compare_levels`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.distortion_records import RecordAnalysis
from fnsi_lab.ident.core.resonances import Resonance

__all__ = ["compare_levels", "SAME_SHAPE_MAC"]

#: Two resonances of different levels are one only when their operating deflection shapes
#: (the BLA's columns at the resonance, over the outputs both records have) agree at least
#: this much (modal assurance criterion). Aircraft-like GVT, 12 -> 98 N: the tracked modes
#: keep 0.86-1.00 (9.85 -> 9.47 Hz: 0.86; 12.89 -> 12.55 Hz: 0.90) where the 7.17 Hz payload
#: mode against the 7.32 Hz reading at 84 and 98 N is 0.35 and 0.15: another mode, not a shift.
SAME_SHAPE_MAC = 0.8


def _mutual_nearest(a: Sequence[float], b: Sequence[float], cap: float,
                    allowed: np.ndarray | None = None) -> dict[int, int]:
    """Pairs (i in a -> j in b) that are each other's nearest frequency, within ``cap``
    (relative), among the pairs ``allowed`` (bool, ``(len(a), len(b))``; default all)."""
    if not a or not b:
        return {}
    dist = np.abs(np.subtract.outer(np.asarray(a, float), np.asarray(b, float)))
    if allowed is not None:
        dist = np.where(allowed, dist, np.inf)
    pairs = {}
    for i, fa in enumerate(a):
        j = int(np.argmin(dist[i]))
        if np.isfinite(dist[i, j]) and int(np.argmin(dist[:, j])) == i and \
                dist[i, j] <= cap * fa:
            pairs[i] = j
    return pairs


def _shape(rec: RecordAnalysis, frequency_hz: float, names: Sequence[str]) -> np.ndarray:
    """The record's BLA at its line nearest ``frequency_hz`` over the outputs ``names``, unit
    length: the resonance's operating deflection shape, ``(len(names),)`` complex."""
    k = int(np.argmin(np.abs(np.asarray(rec.frequency_hz) - frequency_hz)))
    cols = [[o.name for o in rec.outputs].index(n) for n in names]
    v = np.asarray(rec.frf)[k, cols]
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 0 else v


def _mac(a: np.ndarray, b: np.ndarray) -> float:
    """Modal assurance criterion of two unit-length shapes (1: the same shape)."""
    return float(abs(np.vdot(a, b)) ** 2)


def compare_levels(records: Sequence[RecordAnalysis], *, max_shift: float = 0.5) -> dict:
    """Several records of one structure at different levels, by increasing input RMS.

    Parameters
    ----------
    records : sequence of RecordAnalysis
        Same outputs (by name) expected; outputs missing from a record are left out.
    max_shift : float
        Resonances are followed from level to level: a resonance of the next level is the
        same one when each is the other's nearest and they differ by less than this
        fraction (a hardening stop can move a resonance by tens of percent). A resonance
        not found at one level (damped into its neighbours, or below the scatter of a
        ragged BLA) is followed on from where it was last seen. With two or more outputs
        in common, the two must also have the same operating deflection shape
        (:data:`SAME_SHAPE_MAC`).

    Returns
    -------
    dict
        ``order`` (record indices by level), ``input_rms``, ``resonances[]`` (per resonance
        of the lowest level, by frequency: ``frequency_hz``, ``damping_ratio``,
        ``shift_percent`` against the lowest level, ``resolution_hz`` (:class:`Resonance`)
        and ``mac``, the shape's agreement with the resonance's previous sighting, per
        level, None where it was not seen; ``first_level`` 0), ``resonances_appearing[]``
        (the same for resonances first seen above the lowest level, ``first_level`` the
        index of that level, the shift against it) and ``outputs[]`` (per output:
        ``output_db``, ``noise_db``, ``distortion_db``, ``odd_distortion_db``,
        ``even_distortion_db``, ``relative_distortion_db`` = distortion minus output, and
        ``nonlinear`` per level).
    """
    order = sorted(range(len(records)), key=lambda i: records[i].input_rms)
    recs = [records[i] for i in order]
    common = [o.name for o in recs[0].outputs
              if all(o.name in {x.name for x in r.outputs} for r in recs[1:])]
    tracks: list[list[Resonance | None]] = [[r] for r in recs[0].resonances]
    macs: list[list[float | None]] = [[None] for _ in tracks]
    # each track at its last sighting (resonance, record): a resonance lost at 40 N and back
    # at 98 N is the same one (aircraft-like GVT: otherwise 9.85 Hz at 12 N ended at 40 N and
    # its 98 N reading 9.48 Hz was taken for the 10.6 Hz mode's, a -10.6 % "shift")
    last = [(r, recs[0]) for r in recs[0].resonances]
    for level, rec in enumerate(recs[1:], start=1):
        now = [_shape(rec, q.frequency_hz, common) for q in rec.resonances]
        before = [_shape(seen, r.frequency_hz, common) for r, seen in last]
        mac = np.array([[_mac(b, shape) for shape in now]
                        for b in before]).reshape(len(last), len(rec.resonances))
        pairs = _mutual_nearest([r.frequency_hz for r, _ in last],
                                [q.frequency_hz for q in rec.resonances], max_shift,
                                allowed=mac >= SAME_SHAPE_MAC if len(common) >= 2 else None)
        for i, t in enumerate(tracks):
            j = pairs.get(i)
            t.append(None if j is None else rec.resonances[j])
            macs[i].append(None if j is None else float(mac[i, j]))
            if j is not None:
                last[i] = (rec.resonances[j], rec)
        for j in sorted(set(range(len(rec.resonances))) - set(pairs.values())):
            # first seen at this level (a mode that was too damped or too weak below)
            tracks.append([None] * level + [rec.resonances[j]])
            macs.append([None] * (level + 1))
            last.append((rec.resonances[j], rec))
    res_rows: list[tuple[int, dict]] = []    # (first level seen, row)
    for t, m in sorted(zip(tracks, macs), key=lambda tm: next(
            r.frequency_hz for r in tm[0] if r is not None)):
        first = next(k for k, r in enumerate(t) if r is not None)
        f0 = t[first].frequency_hz     # type: ignore[union-attr]
        res_rows.append((first, {
            "frequency_hz": [None if r is None else r.frequency_hz for r in t],
            "damping_ratio": [None if r is None else r.damping_ratio for r in t],
            "shift_percent": [None if r is None else 100.0 * (r.frequency_hz / f0 - 1.0)
                              for r in t],
            "resolution_hz": [None if r is None else r.resolution_hz for r in t],
            "mac": m, "first_level": first}))
    names = [o.name for o in recs[0].outputs]
    out_rows = []
    for name in names:
        row: dict = {"name": name}
        found = [next((o for o in rec.outputs if o.name == name), None) for rec in recs]
        per = [o for o in found if o is not None]
        if len(per) < len(found):
            continue
        for key in ("output_db", "noise_db", "distortion_db", "odd_distortion_db",
                    "even_distortion_db", "nonlinear"):
            row[key] = [getattr(o, key) for o in per]
        row["relative_distortion_db"] = [
            None if o.distortion_db is None else o.distortion_db - o.output_db for o in per]
        out_rows.append(row)
    return {"order": order, "input_rms": [r.input_rms for r in recs],
            "inputs": [r.path for r in recs],
            "resonances": [row for first, row in res_rows if first == 0],
            "resonances_appearing": [row for first, row in res_rows if first > 0],
            "outputs": out_rows}
