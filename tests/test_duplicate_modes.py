"""One mode fitted twice by two poles is reported once (ident.robust.auto._duplicate_modes).

Case that found it: the independent Iwan-joint chain at 3 N (bench/independent_joint.py),
whose linear ``--auto`` answer listed 6.678 and 6.683 Hz with the same shape for one mode at
6.682 Hz. Here the poles are built, so the expected answer is known exactly.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.ident.robust import mdi as mdi_mod
from fnsi_lab.ident.robust.auto import _duplicate_modes
from fnsi_lab.ident.robust.pole_fate import pole_fates


def _poles(modes):
    """``(f_hz, zeta, shape, gain)`` per mode -> lam (2q,), c_hat (p, 2q), b_hat (2q, 1)."""
    lam, cols, rows = [], [], []
    for f, z, shape, gain in modes:
        w = 2 * np.pi * f
        p = -z * w + 1j * w * np.sqrt(1 - z * z)
        v = np.asarray(shape, complex)
        lam += [p, np.conj(p)]
        cols += [v, np.conj(v)]
        rows += [[gain], [np.conj(gain)]]
    return np.array(lam), np.stack(cols, axis=1), np.array(rows, complex)


def _duplicates(modes):
    lam, c_hat, b_hat = _poles(modes)
    md = mdi_mod.modal_dominancy(lam, c_hat, b_hat, (1.0, 20.0))
    physical = np.ones(md.frequency_hz.size, bool)
    dup = _duplicate_modes(md, c_hat, physical, md.mdi)
    return md, dup


def test_the_weaker_of_two_same_shape_poles_is_left_out():
    shape = [1.0, 0.6, -0.4]
    md, dup = _duplicates([(6.678, 0.0072, shape, 0.1), (6.683, 0.0080, shape, 1.0),
                           (11.7, 0.0095, [1.0, -0.8, 0.2], 1.0)])
    assert dup.sum() == 1
    # the weaker one (smaller MDI) goes, the mode it doubled stays
    (i,) = np.flatnonzero(dup)
    assert abs(md.frequency_hz[i] - 6.678) < 1e-9
    assert md.mdi[i] < md.mdi[np.argmin(np.abs(md.frequency_hz - 6.683))]


def test_close_modes_of_other_shapes_or_damping_are_kept():
    # the same frequencies with orthogonal shapes: two modes (a symmetric structure)
    _, dup = _duplicates([(6.678, 0.0072, [1.0, 0.6, -0.4], 1.0),
                          (6.683, 0.0080, [0.6, -1.0, 0.0], 1.0)])
    assert not dup.any()
    # 1 % apart (five times the 0.2 % tolerance): two modes
    _, dup = _duplicates([(6.60, 0.0072, [1.0, 0.6, -0.4], 1.0),
                          (6.666, 0.0080, [1.0, 0.6, -0.4], 1.0)])
    assert not dup.any()
    # damping 3x apart: not one mode
    _, dup = _duplicates([(6.678, 0.004, [1.0, 0.6, -0.4], 1.0),
                          (6.683, 0.012, [1.0, 0.6, -0.4], 1.0)])
    assert not dup.any()


def test_a_left_out_duplicate_is_named_a_split_mode():
    rows = [{"frequency_hz": 6.678, "in_band": True, "stable": True, "physical": False},
            {"frequency_hz": 6.683, "in_band": True, "stable": True, "physical": True}]
    assert pole_fates(rows, {"duplicate_modes": [6.678]}) == ["split", "physical"]
