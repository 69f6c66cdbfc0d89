"""FRF values as plotted: magnitude in dB, phase in degrees, lines in frequency order.

Pure numpy, shared by the Rerun figures (:mod:`viewer.log`) and the HTML report
(:mod:`viewer.report`).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def magnitude_db(frf: Any) -> np.ndarray:
    """``20 log10 |H|``, with zeros mapped to -400 dB instead of -inf."""
    mag = np.abs(np.asarray(frf))
    with np.errstate(divide="ignore"):
        return np.where(mag > 0, 20.0 * np.log10(np.where(mag > 0, mag, 1.0)), -400.0)


def phase_deg(frf: Any) -> np.ndarray:
    """Phase in degrees in (-180, 180], NaN where it wraps (so a line breaks, not jumps).

    ``frf`` must be in frequency order along its first axis (see :func:`frequency_order`).
    """
    ph = np.degrees(np.angle(np.asarray(frf)))
    out = ph.astype(float).copy()
    jump = np.flatnonzero(np.abs(np.diff(ph, axis=0)) > 180.0)
    out[jump + 1] = np.nan
    return out


def frequency_order(frequency_hz: Any) -> np.ndarray:
    """Indices that sort the lines by frequency (stable).

    The lines of several realizations come one realization after the other; a curve drawn
    through them in that order would run back from the top of the band to its bottom.
    """
    return np.argsort(np.asarray(frequency_hz, dtype=float).ravel(), kind="stable")
