"""The one entry point of the distortion analysis (``fnsi-lab analyse``, ``fnsi_lab.analyse``).

:func:`analyse_inputs` takes periodic inputs (:class:`ident.core.io.IdentInput`, one per record)
and an optional ident config, picks the input channel and the outputs, drops the transient
periods, finds the excited lines when the record does not carry them, and calls
:func:`ident.core.distortion.analyse_arrays` per record; several records are then compared by
level (:func:`ident.core.distortion.compare_levels`). Arrays only: files are read at the edge
(:mod:`fnsi_lab.inputs`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.core.distortion import (DEFAULT_ALPHA, RecordAnalysis, analyse_arrays,
                                       compare_levels)
from fnsi_lab.ident.errors import IdentDataError
from fnsi_lab.ident.core.excitation import detect_excited_lines
from fnsi_lab.ident.core.io import IdentInput, select_channels

__all__ = ["DistortionReport", "analyse_inputs", "analyse_input"]

#: Version of the JSON layout of ``fnsi-lab analyse --json`` (docs/discovery.md).
JSON_VERSION = 1


@dataclass
class DistortionReport:
    """Records analysed, and their comparison by level when there are several.

    Attributes
    ----------
    records : list of RecordAnalysis
        In the order given.
    levels : dict or None
        :func:`ident.core.distortion.compare_levels` (two records or more).
    timings_s : dict
    """

    records: list[RecordAnalysis]
    levels: dict | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def to_json(self, spectra: bool = False) -> dict:
        """The JSON of ``fnsi-lab analyse --json`` (layout in docs/discovery.md)."""
        return {"kind": "distortion analysis", "version": JSON_VERSION,
                "records": [r.to_dict(spectra) for r in self.records],
                "levels": self.levels, "notes": list(self.notes),
                "timings_s": dict(self.timings_s)}


def _input_channel(inp: IdentInput, cfg: IdentConfig | None) -> str:
    names = inp.input_channels
    if cfg is not None and cfg.inputs:
        return cfg.inputs[0].name
    if len(names) == 1:
        return names[0]
    power = np.mean(inp.u ** 2, axis=(0, 1, 2))
    driven = [n for n, pw in zip(names, power) if pw > 1e-6 * power.max()]
    if len(driven) == 1:
        return driven[0]
    raise IdentDataError(f"{inp.path}: {len(names)} input channels ({plain.names(names)}): the analysis "
                         "takes one; name it in the config, e.g. 'inputs: [{name: "
                         f"{names[0]}}}]'")


def analyse_input(inp: IdentInput, cfg: IdentConfig | None = None, *,
                  band_hz: tuple[float, float] | None = None, alpha: float = DEFAULT_ALPHA,
                  keep_spectra: bool = True) -> RecordAnalysis:
    """Distortion analysis of one record (see :func:`analyse_inputs`)."""
    outputs = cfg.outputs if cfg is not None else None
    name = _input_channel(inp, cfg)
    inp = select_channels(inp, outputs=outputs, inputs=[name])
    point = cfg.inputs[0].driving_point if cfg is not None and cfg.inputs else None
    if cfg is not None and point is not None and point not in inp.output_channels:
        raise IdentDataError(f"{cfg.file or 'config'}: inputs[0].driving_point {point!r} is not "
                             f"an output of {inp.path} (outputs: "
                             f"{', '.join(inp.output_channels)})")
    transient = (cfg.transient_periods if cfg is not None and cfg.transient_periods is not None
                 else inp.transient_periods) or 0
    P = inp.u.shape[1]
    if transient >= P:
        raise IdentDataError(f"{inp.path}: transient_periods={transient} leaves none of the "
                             f"{P} periods; lower transient_periods in the config")
    u = inp.u[:, transient:, :, 0]
    y = inp.y[:, transient:]
    N = inp.samples_per_period
    lines = inp.excited_lines
    if lines is None or np.asarray(lines).size == 0:
        U = np.fft.rfft(u, axis=2) / N
        lines = detect_excited_lines((np.abs(U) ** 2).mean(axis=(0, 1)), inp.sample_rate_hz,
                                     N).lines
        if lines.size == 0:
            raise IdentDataError(f"{inp.path}: no multisine found in input {name!r}: give "
                                 "'excited_lines' in the file or the drive channel")
    rec = analyse_arrays(u, y, inp.sample_rate_hz, np.asarray(lines), input_name=name,
                         output_names=inp.output_channels, band_hz=band_hz, path=inp.path,
                         alpha=alpha, keep_spectra=keep_spectra)
    note = first_period_note(y, transient)
    if note:
        rec.notes.append(note)
    return rec


def first_period_note(y: np.ndarray, transient: int) -> str | None:
    """A note when the first analysed period departs from the others like a transient.

    ``y`` (R, P, N, p): each period's RMS difference from the mean of the other periods;
    with ``P >= 4`` the first one is flagged when it exceeds three times the largest of the
    others (noise alone spreads them evenly), since its leftover transient is counted as
    noise and distortion.
    """
    R, P = y.shape[:2]
    if P < 4:
        return None
    dev = np.empty(P)
    for p in range(P):
        rest = np.delete(y, p, axis=1).mean(axis=1)
        dev[p] = float(np.sqrt(np.mean((y[:, p] - rest) ** 2)))
    if dev[0] > 3 * dev[1:].max():
        ratio = dev[0] / np.median(dev[1:])
        return (f"the first analysed period differs from the others {ratio:.0f}x more than "
                f"they do among themselves: a transient? (transient_periods is {transient}; "
                "raise it in the config)")
    return None


def analyse_inputs(inputs: Sequence[IdentInput], cfg: IdentConfig | None = None, *,
                   band_hz: tuple[float, float] | None = None, alpha: float = DEFAULT_ALPHA,
                   keep_spectra: bool = True) -> DistortionReport:
    """Distortion analysis of one or several records of one structure.

    Parameters
    ----------
    inputs : sequence of IdentInput
        Periodic records ``u`` (R, P, N, m), ``y`` (R, P, N, p).
    cfg : IdentConfig, optional
        Used for ``inputs[0].name`` (the drive), ``outputs`` (subset and order) and
        ``transient_periods`` (else each record's own, else 0). Its ``band_hz`` is the
        identification band, not the analysed one (the distortion reaches beyond it).
    band_hz : (float, float), optional
        Analysed band (default: lowest excited line to three times the highest, at most
        0.45 fs).
    alpha : float
        Family-wise false-alarm probability of a record's "nonlinear" verdicts.
    keep_spectra : bool
        Keep per-line levels for the plots.

    Returns
    -------
    DistortionReport
    """
    t0 = time.perf_counter()
    records = [analyse_input(inp, cfg, band_hz=band_hz, alpha=alpha, keep_spectra=keep_spectra)
               for inp in inputs]
    notes = []
    outputs = [tuple(o.name for o in r.outputs) for r in records]
    common = set(outputs[0]).intersection(*map(set, outputs[1:]))
    same = bool(common) and all(r.input_channel == records[0].input_channel for r in records)
    if len(records) >= 2 and not same:   # levels of one structure share their channels
        notes.append("not compared by level: the records do not share their drive and any "
                     "output (" + "; ".join(f"{r.path}: {', '.join(o)} / {r.input_channel}"
                                            for r, o in zip(records, outputs)) + ")")
    elif len(records) >= 2 and any(set(o) != common for o in outputs):
        # a record with an extra channel (a sensor added between levels): compared on the
        # outputs they share
        extra = "; ".join(f"{r.path}: {', '.join(n for n in o if n not in common)}"
                          for r, o in zip(records, outputs) if set(o) != common)
        notes.append(f"compared by level on the outputs all records have "
                     f"({', '.join(n for n in outputs[0] if n in common)}); left out of the "
                     f"comparison: {extra}")
    levels = compare_levels(records) if len(records) >= 2 and same else None
    return DistortionReport(records=records, levels=levels,
                            timings_s={"analysis": time.perf_counter() - t0}, notes=notes)
