"""Which DFT lines a multisine excites, found from the measured drive (user data).

Recordings made by ``fnsi-lab acquire`` carry their excited lines; arrays from elsewhere may
not. A plain power threshold on the drive spectrum counts everything above it, and the
drive of a real test carries more than the multisine: mains hum (50/60 Hz and harmonics,
not on the DFT grid, so it leaks onto neighbouring lines) and the noise floor of the
generator. On the Silverbox measurement (odd multisine, 8192-sample periods) a threshold at
1e-4 of the largest line counted 1351 lines where 1342 were excited: the hum at 50 and
150 Hz was counted as excitation.

:func:`detect_excited_lines` uses what a multisine is: lines of equal design on a regular
grid (every line, odd lines, or every ``s``-th line from an offset) filling a band.

1. candidates: lines whose power exceeds ``threshold`` times the median power of the
   strongest lines (robust to one large hum line, unlike the maximum);
2. grid: the coarsest grid ``k = offset (mod step)``, step 1..8, that holds at least
   ``grid_fraction`` of the candidates (odd multisines: step 2, offset 1); candidates off
   the grid are not excitation;
3. runs: candidates on the grid form runs (gaps of at most two grid steps); runs shorter
   than ``min_run`` lines are not a band (hum landing on the grid outside the band), nor
   are runs shorter than ``4 min_run`` whose peak sits at a mains harmonic and stands
   ``mains_ratio`` above their median (the leakage skirt of strong hum), nor is a run
   whose median power is ``faint_ratio`` (10 dB) below that of the longest run and that
   lies more than a tenth of that run's width away from it: such a run is the measured
   force's own distortion beyond the band (nearer, it is the band going on after a force
   drop-out at a resonance) (a lightly damped mode above the band, seen through the
   shaker-structure interaction: 20-30 dB below the multisine's level, above the 30 dB
   threshold, on a beam with a hysteretic joint, bench/RESULTS_beam.md);
4. mains: a candidate within ``mains_zone`` lines of a multiple of 50 or 60 Hz whose power
   departs by more than ``mains_ratio`` from the median of its run's lines within 20 grid
   steps (outside that zone) is hum (leakage at a band edge, or hum on top of a design
   line).

Pure numpy; spectra ``(n_lines, n_channels)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ExcitationGrid", "detect_excited_lines", "best_grid", "MAINS_HZ"]

#: Mains frequencies whose harmonics are never taken for excitation on their own.
MAINS_HZ: tuple[float, ...] = (50.0, 60.0)


@dataclass(frozen=True)
class ExcitationGrid:
    """Excited lines found in a drive spectrum, with what was rejected and why.

    Attributes
    ----------
    lines : int ndarray
        Excited DFT bins of one period.
    step, offset : int
        Grid ``k = offset (mod step)``: (1, 0) full multisine, (2, 1) odd multisine.
    n_candidates : int
        Lines above the power threshold.
    off_grid, isolated, mains : int ndarray
        Candidates rejected because they are off the grid, without excited neighbours, or at
        a mains harmonic without excited neighbours on both sides.
    faint : int ndarray
        Candidates in a run of grid lines whose median power is ``faint_ratio`` below the
        longest run's, away from it (distortion in the measured force, not a designed band).
    source : str
        ``'detected'`` here; ``'given'`` when the caller supplied the lines.
    """

    lines: np.ndarray
    step: int = 1
    offset: int = 0
    n_candidates: int = 0
    off_grid: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    isolated: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    mains: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    source: str = "detected"
    faint: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @property
    def kind(self) -> str:
        """``'full'``, ``'odd'``, or ``'every STEP-th line from OFFSET'``."""
        if self.step == 1:
            return "full"
        if self.step == 2 and self.offset == 1:
            return "odd"
        return f"every {self.step}th line from {self.offset}"

    def to_dict(self, sample_rate_hz: float, samples_per_period: int) -> dict:
        """JSON-able summary (rejected lines as frequencies in Hz)."""
        df = float(sample_rate_hz) / int(samples_per_period)
        return {"source": self.source, "grid": self.kind, "step": int(self.step),
                "offset": int(self.offset), "n_excited": int(self.lines.size),
                "band_hz": ([round(float(self.lines.min()) * df, 6),
                             round(float(self.lines.max()) * df, 6)] if self.lines.size
                            else None),
                "n_candidates": int(self.n_candidates),
                "rejected_off_grid_hz": [round(float(k) * df, 6) for k in self.off_grid],
                "rejected_isolated_hz": [round(float(k) * df, 6) for k in self.isolated],
                "rejected_mains_hz": [round(float(k) * df, 6) for k in self.mains],
                "rejected_faint_hz": [round(float(k) * df, 6) for k in self.faint]}


def best_grid(cand: np.ndarray, grid_fraction: float, max_step: int) -> tuple[int, int]:
    """Coarsest (step, offset) holding ``grid_fraction`` of the candidate bins."""
    best = (1, 0)
    for step in range(2, max_step + 1):
        counts = np.bincount(cand % step, minlength=step)
        off = int(np.argmax(counts))
        if counts[off] >= grid_fraction * cand.size:
            best = (step, off)
    return best


def detect_excited_lines(drive_power: np.ndarray, sample_rate_hz: float,
                         samples_per_period: int, *, threshold: float = 1e-3,
                         grid_fraction: float = 0.9, max_step: int = 8,
                         min_run: int = 8, mains_hz: tuple[float, ...] = MAINS_HZ,
                         mains_zone: float = 3.0, mains_ratio: float = 4.0,
                         faint_ratio: float = 0.1) -> ExcitationGrid:
    """Excited lines of a multisine from the power spectrum of the measured drive.

    Parameters
    ----------
    drive_power : ndarray, shape (N // 2 + 1,) or (N // 2 + 1, n_inputs)
        ``|U(k)|^2`` of one period (averaged over periods and realisations; summed over the
        inputs when 2-D), bins 0..N/2.
    sample_rate_hz : float
    samples_per_period : int
        ``N``.
    threshold : float
        Candidates exceed ``threshold`` times the median power of the strongest 10 % of
        the lines (the multisine level, whatever a few hum lines do). 1e-3 (30 dB) is far
        below any multisine design's spread of line amplitudes and far above a generator's
        noise floor.
    grid_fraction : float
        The grid must hold this fraction of the candidates.
    max_step : int
        Coarsest grid tried.
    min_run : int
        Fewest grid lines of a run of candidates that counts as an excited band.
    mains_hz : tuple of float
        Mains frequencies (their harmonics are checked).
    mains_zone : float
        Lines within this many lines of a mains harmonic are checked (hum off the DFT grid
        leaks onto a few lines on each side).
    mains_ratio : float
        Such a line is hum when its power differs from the local design level (its run's
        lines within 20 grid steps, outside the zone) by more than this factor (a flat or
        smooth design has neighbours within a few dB).
    faint_ratio : float
        A run whose median power is below this fraction of the longest run's median is not
        excitation (0.1: 10 dB; the force's distortion beyond the band sits 20-30 dB below).

    Returns
    -------
    ExcitationGrid
    """
    pw = np.asarray(drive_power, float)
    if pw.ndim == 2:
        pw = pw.sum(axis=1)
    N = int(samples_per_period)
    k_all = np.arange(pw.size)
    valid = (k_all > 0) & (k_all < N / 2)
    if not np.any(pw[valid] > 0):
        return ExcitationGrid(lines=np.zeros(0, int))
    vals = np.sort(pw[valid])[::-1]
    level = float(np.median(vals[:max(1, vals.size // 10)]))
    cand = k_all[valid & (pw > threshold * level)]
    if cand.size == 0:
        return ExcitationGrid(lines=np.zeros(0, int))
    step, offset = best_grid(cand, grid_fraction, max_step)
    on = cand % step == offset
    off_grid, cand = cand[~on], cand[on]
    # runs of grid lines (a gap of at most 2 grid steps continues a run: random-odd designs
    # leave one line of three out); short runs are not a multisine band
    gaps = np.diff(cand) > 2 * step
    run_id = np.concatenate([[0], np.cumsum(gaps)])
    run_size = np.bincount(run_id)
    keep = run_size[run_id] >= min_run
    isolated, cand, run_id = cand[~keep], cand[keep], run_id[keep]
    # a run far below the longest run's level, and far from it, is the force's distortion
    # beyond the band, not a band. Near it (a gap under a tenth of the longest run's width)
    # it is the same band after a force drop-out: a shaker's force falls by tens of dB at a
    # lightly damped driving-point resonance and may stay 10 dB lower above it (a 3-line
    # drop-out before a band 13 dB lower had lost that band, silently)
    faint_run = np.zeros(cand.size, bool)
    if cand.size:
        run_ids = np.unique(run_id)
        longest = run_ids[int(np.argmax([np.sum(run_id == r) for r in run_ids]))]
        main = cand[run_id == longest]
        reference = float(np.median(pw[main]))
        near = max(0.1 * float(main[-1] - main[0]), 2.0 * step)
        for rid in run_ids:
            sel = run_id == rid
            run = cand[sel]
            gap = max(float(run[0] - main[-1]), float(main[0] - run[-1]), 0.0)
            faint_run[sel] = (float(np.median(pw[run])) < faint_ratio * reference
                              and gap > near)
    faint, cand, run_id = cand[faint_run], cand[~faint_run], run_id[~faint_run]
    df = float(sample_rate_hz) / N
    # a short run peaked at a mains harmonic is the hum's own leakage skirt, not a band
    hum_run = np.zeros(cand.size, bool)
    for rid in np.unique(run_id):
        sel = run_id == rid
        run = cand[sel]
        if run.size >= 4 * min_run:
            continue
        k_pk = run[int(np.argmax(pw[run]))]
        at_mains = any(h >= 1 and abs(k_pk * df - h * f_m) <= mains_zone * df
                       for f_m in mains_hz for h in (round(k_pk * df / f_m),))
        if at_mains and pw[k_pk] > mains_ratio * float(np.median(pw[run])):
            hum_run[sel] = True
    # mains harmonics inside a run: hum leaks onto the lines next to it; a line there whose
    # power departs from its run's level by more than ``mains_ratio`` is hum, not design
    keep = ~hum_run
    for i, k in enumerate(cand):
        if hum_run[i]:
            continue
        near = any(h >= 1 and abs(k * df - h * f_m) <= mains_zone * df
                   for f_m in mains_hz for h in (round(k * df / f_m),))
        if near:
            # the design level there: the same run's lines within 20 grid steps that are
            # clear of the harmonic's zone (shaped designs vary along the band)
            run = cand[run_id == run_id[i]]
            local = run[(np.abs(run - k) <= 20 * step) & (np.abs(run - k) > mains_zone)]
            ref = float(np.median(pw[local if local.size else run]))
            keep[i] = ref / mains_ratio <= pw[k] <= ref * mains_ratio
    mains, cand = cand[~keep], cand[keep]
    return ExcitationGrid(lines=cand.astype(int), step=step, offset=offset,
                          n_candidates=int(np.sum(on) + off_grid.size), off_grid=off_grid,
                          isolated=isolated, mains=mains, faint=faint)
