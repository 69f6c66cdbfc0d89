"""One vocabulary for what became of each pole of the MDI order (its "fate").

The robust pipeline (``ident.robust.auto``) decides per pole in several steps: candidates are the
stable in-band poles; the MDI threshold splits them; stabilisation rescues some below it
and vetoes some above it; a kept pole that does not stand out of the model's residual in
its bandwidth is dropped as not detectable; a near-undamped pole at a mains harmonic is
dropped as hum; the output-error refinement may leave out one mode of a split pair. The
terminal, the JSON (``mdi[].fate``), the HTML report and the viewer all name these
decisions with the words below, and draw each one distinctly.

Pure functions over the JSON's ``mdi`` rows and ``confidence`` lists (so an old result file
gets its fates too).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

__all__ = ["FATES", "FATE_ORDER", "pole_fates", "result_fates", "fate_label",
           "fate_caption"]

#: fate -> (short label, explanation). Order: kept first, then the reasons for dropping.
FATES: dict[str, tuple[str, str]] = {
    "physical": ("physical", "above the MDI threshold, stabilised and detectable: a mode"),
    "rescued": ("physical (stabilisation)",
                "below the MDI threshold but kept: fully stable across orders"),
    "split": ("split mode, left out",
              "one pole of a close pair fitting the same mode twice, left out (by the "
              "robust pipeline or the output-error refinement)"),
    "spurious": ("spurious by MDI", "below the MDI threshold: removed as spurious"),
    "not_detectable": ("not detectable",
                       "above the MDI threshold but dropped: it does not stand out of the "
                       "model's residual in its bandwidth"),
    "not_stabilised": ("not stabilised",
                       "above the MDI threshold but dropped: new at this order"),
    "mains_hum": ("mains hum", "dropped: near-undamped at a 50/60 Hz harmonic"),
    "no_evidence": ("no physical evidence",
                    "physical for the nonlinear model's classification, left out of the "
                    "answer: an isolated mode with a negative modal mass at the driving point or "
                    "at the element"),
    "unstable": ("unstable", "negative damping: not a candidate"),
    "out_of_band": ("out of band", "outside the processed band: not a candidate"),
}
FATE_ORDER: tuple[str, ...] = tuple(FATES)


def _near(f: float, freqs: Sequence[float], rel: float = 1e-6) -> bool:
    return any(abs(f - g) <= rel * max(abs(f), 1e-12) for g in freqs)


def pole_fates(mdi_rows: Sequence[Mapping[str, Any]], confidence: Mapping[str, Any] | None,
               left_out_hz: Sequence[float] = (),
               no_evidence_hz: Sequence[float] = ()) -> list[str]:
    """The fate of each pole of the MDI table.

    Parameters
    ----------
    mdi_rows : sequence of mapping
        The JSON's ``mdi`` rows (``frequency_hz``, ``in_band``, ``stable``, ``physical``).
    confidence : mapping or None
        The JSON's ``confidence`` (its lists ``below_residual``, ``vetoed_not_stabilised``,
        ``rescued_by_stabilisation``, ``mains_hum``, ``duplicate_modes``, frequencies in Hz).
    left_out_hz : sequence of float
        Frequencies of the split modes the output-error refinement left out
        (``output_error.left_out[].frequency_hz``); matched within 0.5 %.
    no_evidence_hz : sequence of float
        Frequencies of a kept nonlinear answer's modes without physical evidence
        (``nonlinear_vs_linear.modes.left_out[].frequency_hz``, :mod:`ident.robust.mode_support`).

    Returns
    -------
    list of str
        One key of :data:`FATES` per row.
    """
    conf = confidence or {}
    below = conf.get("below_residual") or []
    vetoed = conf.get("vetoed_not_stabilised") or []
    rescued = conf.get("rescued_by_stabilisation") or []
    hum = conf.get("mains_hum") or []
    duplicate = conf.get("duplicate_modes") or []
    out = []
    for r in mdi_rows:
        f = float(r["frequency_hz"])
        if r.get("physical"):
            if _near(f, left_out_hz, 5e-3):
                fate = "split"
            elif _near(f, no_evidence_hz):
                fate = "no_evidence"
            else:
                fate = "rescued" if _near(f, rescued) else "physical"
        elif not r.get("in_band", True):
            fate = "out_of_band"
        elif not r.get("stable", True):
            fate = "unstable"
        elif _near(f, below):
            fate = "not_detectable"
        elif _near(f, vetoed):
            fate = "not_stabilised"
        elif _near(f, hum):
            fate = "mains_hum"
        elif _near(f, duplicate):
            fate = "split"
        else:
            fate = "spurious"
        out.append(fate)
    return out


def result_fates(result: Mapping[str, Any]) -> list[str]:
    """:func:`pole_fates` of a result dict (the JSON): its ``mdi`` rows, ``confidence``,
    the refinement's ``left_out`` split modes and the added modes the nested test left out
    (``nonlinear_vs_linear.modes.left_out``)."""
    left = [float(m["frequency_hz"]) for m in
            ((result.get("output_error") or {}).get("left_out") or [])
            if m.get("frequency_hz") is not None]
    nested = result.get("nonlinear_vs_linear") or {}
    gone = ([float(m["frequency_hz"]) for m in ((nested.get("modes") or {}).get("left_out")
                                                  or []) if m.get("frequency_hz") is not None]
            if nested.get("decision") == "nonlinear" else [])
    return pole_fates(result.get("mdi") or [], result.get("confidence"), left, gone)


def fate_label(fate: str) -> str:
    """Short label of a fate (``not detectable``)."""
    return FATES.get(fate, (fate, ""))[0]


def fate_caption(fates: Sequence[str] = FATE_ORDER) -> str:
    """One sentence per fate present, for a figure caption or a legend note."""
    present = [f for f in FATE_ORDER if f in set(fates)]
    return "; ".join(f"{FATES[f][0]}: {FATES[f][1]}" for f in present) + "."
