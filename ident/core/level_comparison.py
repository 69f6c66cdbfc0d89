"""Several distortion analyses of one structure at different levels, compared: the
resonances followed from level to level, the outputs' noise and distortion levels side by
side (:func:`compare_levels`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab.ident.core.distortion_records import RecordAnalysis
from fnsi_lab.ident.core.resonances import Resonance

__all__ = ["compare_levels"]


def _mutual_nearest(a: Sequence[float], b: Sequence[float], cap: float) -> dict[int, int]:
    """Pairs (i in a -> j in b) that are each other's nearest frequency, within ``cap``
    (relative)."""
    pairs = {}
    for i, fa in enumerate(a):
        if not b:
            break
        j = int(np.argmin([abs(fb - fa) for fb in b]))
        back = int(np.argmin([abs(b[j] - x) for x in a]))
        if back == i and abs(b[j] - fa) <= cap * fa:
            pairs[i] = j
    return pairs


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
        ragged BLA) is followed on from where it was last seen.

    Returns
    -------
    dict
        ``order`` (record indices by level), ``input_rms``, ``resonances[]`` (per resonance
        of the lowest level: ``frequency_hz``, ``damping_ratio``, ``shift_percent`` against
        the lowest level, per level; None where it was lost) and ``outputs[]`` (per output:
        ``output_db``, ``noise_db``, ``distortion_db``, ``odd_distortion_db``,
        ``even_distortion_db``, ``relative_distortion_db`` = distortion minus output, and
        ``nonlinear`` per level).
    """
    order = sorted(range(len(records)), key=lambda i: records[i].input_rms)
    recs = [records[i] for i in order]
    base = recs[0].resonances
    tracks: list[list[Resonance | None]] = [[r] for r in base]
    for rec in recs[1:]:
        # each track at its last sighting: a resonance lost at 40 N and back at 98 N is the
        # same one (aircraft-like GVT: otherwise 9.85 Hz at 12 N ended at 40 N and its 98 N
        # reading 9.48 Hz was taken for the 10.6 Hz mode's, a -10.6 % "shift")
        alive = [(i, next(r for r in reversed(t) if r is not None))
                 for i, t in enumerate(tracks)]
        pairs = _mutual_nearest([r.frequency_hz for _, r in alive],
                                [r.frequency_hz for r in rec.resonances], max_shift)
        matched = {alive[k][0]: rec.resonances[j] for k, j in pairs.items()}
        for i, t in enumerate(tracks):
            t.append(matched.get(i))
    res_rows = []
    for first, t in zip(base, tracks):
        f0 = first.frequency_hz
        res_rows.append({
            "frequency_hz": [None if r is None else r.frequency_hz for r in t],
            "damping_ratio": [None if r is None else r.damping_ratio for r in t],
            "shift_percent": [None if r is None else 100.0 * (r.frequency_hz / f0 - 1.0)
                              for r in t]})
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
            "inputs": [r.path for r in recs], "resonances": res_rows, "outputs": out_rows}
