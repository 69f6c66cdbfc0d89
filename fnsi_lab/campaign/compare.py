"""Compare the runs of a campaign across force levels (docs/campaigns.md).

A nonlinear structure identified at several force levels should give the same underlying
linear system at every level (same natural frequencies, same underlying linear FRFs) and
the same nonlinear coefficients wherever the nonlinearity is active. This module turns the
campaign table and the runs' JSON results into:

- per coefficient and level: the mean over the runs, the spread of the estimate (the
  run's standard deviation of the real part over frequency, ``<name>:std``, averaged over
  the runs), the scatter between runs, and the stop's contact fraction;
- per natural frequency and level: the mean and the scatter between runs (modes of the
  runs matched to a reference run by nearest frequency);
- the underlying linear FRF of every run at one output (all inputs), and each run's RMS
  deviation from the campaign mean, relative to its RMS level;
- warnings where a coefficient is not identifiable at a level: its stop hardly ever
  closed (contact fraction below ``min_contact``), or its spread larger than
  ``max_relative_spread`` times its mean, or every run's own verdict is ``not
  identifiable``, or the identification failed.

Everything here is arrays and dicts; reading and writing happen in :mod:`.cli`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab.campaign.table import coefficient_names, physical_modes
from fnsi_lab.errors import ConfigError, DataFileError

#: Rows with these statuses carry a result.
_DONE = ("ok", "skipped")


@dataclass
class LevelValue:
    """One quantity at one force level.

    Attributes
    ----------
    level : float or None
        Force RMS (None: the input carried no level).
    runs : list of float
        The value of each run at this level.
    mean : float
        Mean over the runs.
    spread : float or None
        Coefficients: mean over the runs of their spread over frequency; natural
        frequencies: None.
    scatter : float or None
        Standard deviation between the runs (None with one run).
    contact : float or None
        Smallest contact fraction of the stop over the runs (None when not recorded).
    not_identifiable : str or None
        Coefficients: why the value cannot be trusted at this level (None: it can).
    """

    level: float | None
    runs: list[float]
    mean: float
    spread: float | None = None
    scatter: float | None = None
    contact: float | None = None
    not_identifiable: str | None = None


@dataclass
class RunFRF:
    """Underlying linear FRF of one run at one output.

    Attributes
    ----------
    file : str
    level : float or None
    frequency_hz : ndarray, shape (n_lines,)
    frf : complex ndarray, shape (n_lines, n_inputs)
    deviation : float
        RMS of ``frf`` minus the campaign mean (interpolated to this run's lines), over the
        RMS of the mean: 0 when every run gives the same underlying linear system.
    """

    file: str
    level: float | None
    frequency_hz: np.ndarray
    frf: np.ndarray
    deviation: float = float("nan")


@dataclass
class Comparison:
    """Everything ``fnsi-lab campaign`` shows (see the module docstring)."""

    levels: list[float | None]
    coefficients: dict[str, list[LevelValue]]
    frequencies: list[list[LevelValue]]
    damping: list[list[LevelValue]]
    reference_frequencies_hz: list[float]
    frfs: list[RunFRF]
    output: str | None
    inputs: list[str]
    warnings: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    #: The runs' ``units`` block (force, frf, coefficients {name: unit}; ident.core.units);
    #: empty for results written before units were recorded.
    units: dict = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """JSON-able form (complex FRFs as ``re``/``im``)."""
        def values(items: Sequence[LevelValue]) -> list[dict]:
            return [vars(v) for v in items]

        return {
            "levels": self.levels,
            "coefficients": {k: values(v) for k, v in self.coefficients.items()},
            "modes": [{"reference_frequency_hz": f, "frequency_hz": values(fr),
                       "damping_ratio": values(dr)}
                      for f, fr, dr in zip(self.reference_frequencies_hz, self.frequencies,
                                           self.damping)],
            "frf": {"output": self.output, "inputs": self.inputs,
                    "runs": [{"file": r.file, "level": r.level, "deviation": r.deviation,
                              "frequency_hz": r.frequency_hz,
                              "underlying_linear": {"re": r.frf.real, "im": r.frf.imag}}
                             for r in self.frfs]},
            "warnings": self.warnings,
            "failed": [{"file": f, "error": e} for f, e in self.failed],
            "units": self.units,
        }


# ---------------------------------------------------------------------------- helpers
def _level_key(level: Any) -> float | None:
    return None if level is None or not math.isfinite(float(level)) else float(level)


def _sort_levels(levels: Sequence[float | None]) -> list[float | None]:
    known = sorted({lv for lv in levels if lv is not None})
    return known + ([None] if any(lv is None for lv in levels) else [])


def _level_text(level: float | None) -> str:
    return "unknown level" if level is None else f"level {level:g}"


def _stats(values: Sequence[float]) -> tuple[float, float | None]:
    arr = np.asarray(values, float)
    return float(arr.mean()), (float(arr.std(ddof=1)) if arr.size > 1 else None)


def match_modes(reference_hz: Sequence[float], frequencies_hz: Sequence[float]) -> list[int | None]:
    """Index of the reference mode each frequency belongs to (None: no match).

    A frequency belongs to its nearest reference mode when it lies closer to it than half
    the gap to that mode's nearest neighbour (so two close modes are never confused); a
    reference mode takes at most one frequency (the nearest).
    """
    ref = np.asarray(reference_hz, float)
    out: list[int | None] = [None] * len(frequencies_hz)
    if ref.size == 0:
        return out
    gaps = np.abs(ref[:, None] - ref[None, :]) + np.diag(np.full(ref.size, np.inf))
    half_gap = 0.5 * gaps.min(axis=1) if ref.size > 1 else np.full(1, np.inf)
    best: dict[int, tuple[float, int]] = {}
    for i, f in enumerate(frequencies_hz):
        k = int(np.argmin(np.abs(ref - f)))
        d = abs(ref[k] - f)
        if d < half_gap[k] and (k not in best or d < best[k][0]):
            best[k] = (d, i)
    for k, (_, i) in best.items():
        out[i] = k
    return out


# ---------------------------------------------------------------------------- comparison
def _read_result(path: str, run: Any = None) -> dict[str, Any]:
    """One run's result JSON; a missing or damaged file is one line naming it and the fix."""
    fix = (f"run `fnsi-lab batch` again with --force to identify {run or 'that input'} anew"
           " (or delete the file)")
    try:
        result = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataFileError(f"{path}: result of {run or 'a run'} not found (fix: {fix})") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise DataFileError(f"{path}: not a readable result JSON ({reason}) (fix: {fix})"
                            ) from None
    if not isinstance(result, dict):
        raise DataFileError(f"{path}: not an identification result (fix: {fix})")
    return result


def _verdict(result: Mapping[str, Any] | None, name: str) -> tuple[str, str]:
    """A coefficient's verdict in one run's result and the first clause of its reason
    (``('', '')`` when the result does not give one)."""
    for c in (result or {}).get("coefficients") or []:
        if c.get("name") == name and c.get("verdict"):
            reason = str(c.get("verdict_reason") or "").split(";")[0].split(" (")[0]
            return str(c["verdict"]), reason or str(c["verdict"])
    return "", ""


def compare_campaign(rows: Sequence[Mapping[str, Any]], *, output: str | None = None,
                     driving_points: Mapping[str, str] | None = None,
                     max_relative_spread: float = 0.1, min_contact: float = 0.001,
                     results: Mapping[str, Mapping[str, Any]] | None = None) -> Comparison:
    """Compare the runs of a campaign table across force levels.

    Parameters
    ----------
    rows : sequence of dict
        The campaign table (:func:`fnsi_lab.campaign.table.read_table`), result paths
        absolute.
    output : str, optional
        Output channel of the FRF overlay; default the first input's driving point (from
        ``driving_points``), else the first output.
    driving_points : mapping, optional
        Input name -> driving-point output (the ident config's).
    max_relative_spread : float
        A coefficient whose spread exceeds this fraction of ``|mean|`` at a level is
        flagged as not identifiable there.
    min_contact : float
        A coefficient whose stop was closed less than this fraction of the time at a
        level is flagged (recordings of simulated structures carry the fraction).
    results : mapping, optional
        Result dicts by result path (default: read from the rows' ``result`` paths).

    Returns
    -------
    Comparison
    """
    done = [r for r in rows if r.get("status") in _DONE and r.get("result")]
    failed = [(str(r["file"]), str(r.get("error") or "")) for r in rows
              if r.get("status") == "error"]
    loaded = dict(results or {})
    for r in done:
        if r["result"] not in loaded:
            loaded[r["result"]] = _read_result(r["result"], r.get("file"))
    levels = _sort_levels([_level_key(r.get("force_rms")) for r in rows])
    warnings: list[str] = []

    # coefficients against level
    coefficients: dict[str, list[LevelValue]] = {}
    for name in coefficient_names(done):
        per_level = []
        for level in levels:
            at = [r for r in done if _level_key(r.get("force_rms")) == level
                  and r.get(name) is not None]
            if not at:
                continue
            mean, scatter = _stats([r[name] for r in at])
            spreads = [r[f"{name}:std"] for r in at if r.get(f"{name}:std") is not None]
            contacts = [r[f"{name}:contact"] for r in at if r.get(f"{name}:contact") is not None]
            value = LevelValue(level=level, runs=[float(r[name]) for r in at], mean=mean,
                               spread=float(np.mean(spreads)) if spreads else None,
                               scatter=scatter, contact=min(contacts) if contacts else None)
            per_level.append(value)
            verdicts = [_verdict(loaded.get(r["result"]), name) for r in at]
            if value.contact is not None and value.contact < min_contact:
                value.not_identifiable = (f"its stop is closed {100 * value.contact:.2g} % of "
                                          f"the time (< {100 * min_contact:g} %)")
            elif value.spread is not None and value.spread > max_relative_spread * abs(mean):
                value.not_identifiable = (f"spread {value.spread:.3g} is "
                                          f"{value.spread / max(abs(mean), 1e-300):.0%} of "
                                          f"|mean| {abs(mean):.3g} (> {max_relative_spread:.0%})")
            elif verdicts and all(v[0] == "not identifiable" for v in verdicts):
                # the identification said so itself (docs/ident.md: verdicts, nested test)
                value.not_identifiable = f"the result's verdict: {verdicts[0][1]}"
            if value.not_identifiable:
                warnings.append(f"{name} at {_level_text(level)}: not identifiable, "
                                f"{value.not_identifiable}")
        coefficients[name] = per_level
    for file, error in failed:
        level = next((_level_key(r.get("force_rms")) for r in rows if str(r["file"]) == file), None)
        warnings.append(f"{file} ({_level_text(level)}): identification failed: {error}")

    # natural frequencies against level, modes matched to the run with the most modes
    reference_hz: list[float] = []
    frequencies: list[list[LevelValue]] = []
    damping: list[list[LevelValue]] = []
    if done:
        modes_of = {r["result"]: [m for m in physical_modes(loaded[r["result"]])
                                  if m.get("frequency_hz") is not None] for r in done}
        ref_row = max(done, key=lambda r: (len(modes_of[r["result"]]),
                                           -(_level_key(r.get("force_rms")) or 0.0)))
        reference_hz = sorted(float(m["frequency_hz"]) for m in modes_of[ref_row["result"]])
        tracks: list[dict[float | None, list[tuple[float, float]]]] = [{} for _ in reference_hz]
        for r in done:
            modes = modes_of[r["result"]]
            for m, k in zip(modes, match_modes(reference_hz, [m["frequency_hz"] for m in modes])):
                if k is not None:
                    tracks[k].setdefault(_level_key(r.get("force_rms")), []).append(
                        (float(m["frequency_hz"]), float(m.get("damping_ratio") or float("nan"))))
        for track in tracks:
            f_values, z_values = [], []
            for level in levels:
                if level in track:
                    fs = [f for f, _ in track[level]]
                    zs = [z for _, z in track[level]]
                    f_mean, f_scatter = _stats(fs)
                    z_mean, z_scatter = _stats(zs)
                    f_values.append(LevelValue(level, fs, f_mean, scatter=f_scatter))
                    z_values.append(LevelValue(level, zs, z_mean, scatter=z_scatter))
            frequencies.append(f_values)
            damping.append(z_values)

    # underlying linear FRFs at one output
    frfs: list[RunFRF] = []
    inputs: list[str] = []
    chosen = output
    found_output = False
    for r in done:
        frf = loaded[r["result"]].get("frf") or {}
        if not frf.get("underlying_linear"):
            continue
        outputs = list(frf.get("outputs") or [])
        inputs = list(frf.get("inputs") or [])
        if chosen is None:
            dp = (driving_points or {}).get(inputs[0]) if inputs else None
            chosen = dp if dp in outputs else (outputs[0] if outputs else None)
        if chosen not in outputs:
            warnings.append(f"{r['file']}: no output {chosen!r} in its FRF (outputs: "
                            f"{', '.join(outputs[:8])}{'...' if len(outputs) > 8 else ''})")
            continue
        j = outputs.index(chosen)
        found_output = True
        h = (np.asarray(frf["underlying_linear"]["re"], float)
             + 1j * np.asarray(frf["underlying_linear"]["im"], float))[:, j, :]
        frfs.append(RunFRF(file=str(r["file"]), level=_level_key(r.get("force_rms")),
                           frequency_hz=np.asarray(frf["frequency_hz"], float), frf=h))
    if output is not None and not found_output and any(
            (loaded[r["result"]].get("frf") or {}).get("underlying_linear") for r in done):
        raise ConfigError(f"{output!r} is not an output of any run's FRF (outputs: "
                          f"{', '.join(outputs[:8])}{' ...' if len(outputs) > 8 else ''})",
                          field="--output", fix="give one of those outputs, or omit --output "
                                                "for the driving point")
    _frf_deviations(frfs)
    units = next((dict(loaded[r["result"]]["units"]) for r in done
                  if isinstance(loaded[r["result"]].get("units"), dict)), {})
    return Comparison(levels=levels, coefficients=coefficients, frequencies=frequencies,
                      damping=damping, reference_frequencies_hz=reference_hz, frfs=frfs,
                      output=chosen, inputs=inputs, warnings=warnings, failed=failed,
                      units=units)


def _frf_deviations(frfs: Sequence[RunFRF]) -> None:
    """Fill each run's relative RMS deviation from the mean FRF of all runs."""
    if len(frfs) < 2:
        return
    grid = frfs[0].frequency_hz

    def on_grid(r: RunFRF) -> np.ndarray:
        if r.frequency_hz.shape == grid.shape and np.allclose(r.frequency_hz, grid):
            return r.frf
        cols = [np.interp(grid, r.frequency_hz, r.frf[:, k].real)
                + 1j * np.interp(grid, r.frequency_hz, r.frf[:, k].imag)
                for k in range(r.frf.shape[1])]
        return np.stack(cols, axis=1)

    stack = np.stack([on_grid(r) for r in frfs])
    mean = stack.mean(axis=0)
    scale = np.sqrt(np.mean(np.abs(mean) ** 2))
    for r, h in zip(frfs, stack):
        r.deviation = float(np.sqrt(np.mean(np.abs(h - mean) ** 2)) / scale) if scale > 0 else float("nan")


def format_comparison(c: Comparison) -> str:
    """Plain-text summary: coefficients and frequencies per level, FRF agreement, warnings."""
    def level(lv: float | None) -> str:
        return "?" if lv is None else f"{lv:g}"

    lines = [f"campaign: {len(c.levels)} force level(s) "
             f"({', '.join(level(lv) for lv in c.levels)}), {len(c.failed)} failed run(s)"]
    for name, values in c.coefficients.items():
        lines.append(f"{name}:")
        for v in values:
            extra = (f" scatter {v.scatter:.3g}" if v.scatter is not None else "") + \
                    (f" contact {100 * v.contact:.3g} %" if v.contact is not None else "")
            spread = f"{v.spread:.3g}" if v.spread is not None else "-"
            lines.append(f"  level {level(v.level):>8}: {v.mean:.6g} ± {spread} "
                         f"({len(v.runs)} run(s)){extra}")
    if c.reference_frequencies_hz:
        lines.append("natural frequencies (Hz) per level:")
        head = "  " + " ".join(f"{level(lv):>10}" for lv in c.levels)
        lines.append(head)
        for values in c.frequencies:
            by_level = {v.level: v.mean for v in values}
            lines.append("  " + " ".join(f"{by_level[lv]:10.4f}" if lv in by_level else
                                         f"{'-':>10}" for lv in c.levels))
    if c.frfs:
        worst = max(c.frfs, key=lambda r: r.deviation if math.isfinite(r.deviation) else -1)
        lines.append(f"underlying linear FRFs at {c.output}: {len(c.frfs)} runs, largest "
                     f"deviation from their mean {100 * worst.deviation:.3g} % "
                     f"({Path(worst.file).name})" if math.isfinite(worst.deviation) else
                     f"underlying linear FRFs at {c.output}: {len(c.frfs)} run(s)")
    lines += [f"warning: {w}" for w in c.warnings]
    return "\n".join(lines)
