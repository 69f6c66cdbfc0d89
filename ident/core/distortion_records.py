"""The records of a distortion analysis (:func:`ident.core.distortion.analyse_arrays`): one
test window (:class:`Evidence`), one output's levels and verdict (:class:`OutputAnalysis`),
one record's analysis (:class:`RecordAnalysis`), each with its JSON form.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fnsi_lab.ident.core.bla import LineSets
from fnsi_lab.ident.core.resonances import Resonance

__all__ = ["Evidence", "OutputAnalysis", "RecordAnalysis"]


@dataclass(frozen=True)
class Evidence:
    """One test window of one output.

    ``kind`` is ``'odd'``, ``'even'``, ``'mixed'`` (detection lines) or ``'realisations'``;
    ``band_hz`` the window's span, ``frequency_hz`` its centre; ``level_db`` the power
    measured there (noise included), ``noise_db`` the noise, ``output_db`` the output near
    it (excited lines in the window, else the band's), ``p_value`` the probability of a
    ratio this large from noise alone; ``significant`` against the record's corrected level.
    """

    kind: str
    frequency_hz: float
    band_hz: tuple[float, float]
    level_db: float
    noise_db: float
    output_db: float
    p_value: float
    significant: bool = False
    in_band: bool = True

    def to_dict(self) -> dict:
        return {"kind": self.kind, "frequency_hz": self.frequency_hz,
                "band_hz": list(self.band_hz), "level_db": self.level_db,
                "noise_db": self.noise_db, "output_db": self.output_db,
                "p_value": self.p_value, "significant": self.significant,
                "in_excited_band": self.in_band}


@dataclass
class OutputAnalysis:
    """Levels, per-line spectra and the verdict of one output.

    Levels are ``10 log10`` of mean powers over the lines of the analysed band, in dB re
    one output unit (DFT / N of a period average): ``output_db`` on the excited lines,
    ``noise_db`` the variance of the period average (every band line but the mains zones),
    ``odd_distortion_db``
    / ``even_distortion_db`` what the odd / even detection lines hold (noise included: equal
    to ``noise_db`` without distortion; with realisations and no odd detection line, the
    realisations' spread on the excited lines of an odd multisine), ``distortion_db`` every
    detection line, or the realisations' spread (total distortion). ``None``: not measurable
    with this excitation.
    """

    name: str
    output_db: float
    noise_db: float
    odd_distortion_db: float | None
    even_distortion_db: float | None
    distortion_db: float | None
    verdict: str
    nonlinear: bool | None
    evidence: list[Evidence] = field(default_factory=list)
    spectra: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dict(self, spectra: bool = False) -> dict:
        out = {"name": self.name, "output_db": self.output_db, "noise_db": self.noise_db,
               "odd_distortion_db": self.odd_distortion_db,
               "even_distortion_db": self.even_distortion_db,
               "distortion_db": self.distortion_db, "verdict": self.verdict,
               "nonlinear": self.nonlinear,
               "evidence": [e.to_dict() for e in self.evidence if e.significant][:5]}
        if spectra:
            out["spectra"] = {k: np.asarray(v).tolist() for k, v in self.spectra.items()}
        return out


@dataclass
class RecordAnalysis:
    """The analysis of one record (:func:`analyse_arrays`)."""

    path: str
    input_channel: str
    input_rms: float
    sample_rate_hz: float
    samples_per_period: int
    n_realizations: int
    n_periods: int
    lines: LineSets
    noise_source: str
    outputs: list[OutputAnalysis]
    resonances: list[Resonance]
    frequency_hz: np.ndarray          # (n_excited,) excited lines of the band
    frf: np.ndarray                   # (n_excited, p) BLA
    frf_noise_var: np.ndarray         # (n_excited, p)
    frf_total_var: np.ndarray | None  # (n_excited, p), R >= 2
    alpha: float
    n_tests: int
    timings_s: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def band_hz(self) -> tuple[float, float]:
        df = self.sample_rate_hz / self.samples_per_period
        return float(self.lines.band.min() * df), float(self.lines.band.max() * df)

    def to_dict(self, spectra: bool = False) -> dict:
        df = self.sample_rate_hz / self.samples_per_period
        exc = self.lines.excited
        inside = np.arange(exc.min(), exc.max() + 1)
        if self.lines.parity:
            grid = ("odd with odd detection lines" if np.any(~np.isin(inside[inside % 2 == 1],
                                                                        exc)) else "odd")
        else:
            grid = "full" if np.all(np.isin(inside, exc)) else "sparse (not all odd)"
        return {
            "input": self.path, "input_channel": self.input_channel,
            "input_rms": self.input_rms, "sample_rate_hz": self.sample_rate_hz,
            "samples_per_period": self.samples_per_period,
            "n_realizations": self.n_realizations, "n_periods": self.n_periods,
            "excitation": {"grid": grid, "n_excited": int(exc.size),
                           "excited_band_hz": [float(exc.min() * df), float(exc.max() * df)],
                           "n_odd_detection": int(self.lines.odd.size),
                           "n_even_detection": int(self.lines.even.size),
                           "n_mixed_detection": int(self.lines.mixed.size)},
            "analysis_band_hz": list(self.band_hz), "noise_source": self.noise_source,
            "alpha": self.alpha, "n_tests": self.n_tests,
            "outputs": [o.to_dict(spectra) for o in self.outputs],
            "resonances": [r.to_dict() for r in self.resonances],
            "notes": list(self.notes), "timings_s": dict(self.timings_s),
            **({"bla": self.bla_dict()} if spectra else {})}

    def bla_dict(self) -> dict:
        """The BLA per excited line: ``frequency_hz`` (F,), ``re``/``im`` (F, p), and the
        variances of one realisation's FRF ``noise_var`` and ``total_var`` (F, p; null when
        not measured)."""
        return {"frequency_hz": self.frequency_hz.tolist(), "outputs": [o.name for o in
                                                                        self.outputs],
                "re": self.frf.real.tolist(), "im": self.frf.imag.tolist(),
                "noise_var": self.frf_noise_var.tolist(),
                "total_var": None if self.frf_total_var is None else self.frf_total_var.tolist()}
