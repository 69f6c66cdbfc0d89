"""Multisine generator: flat on the excited lines, zero elsewhere, periodic, exact RMS, reproducible."""

import numpy as np
import pytest

from fnsi_lab.daq.multisine import excited_lines, multisine


def _spectrum(ms, r=0, p=0):
    n = ms.samples_per_period
    return np.fft.rfft(ms.signal[r, p * n:(p + 1) * n])


def test_flat_on_excited_lines_and_zero_elsewhere():
    ms = multisine(8192, 1000.0, (5.0, 50.0), 100.0, n_periods=2, seed=3)
    amp = np.abs(_spectrum(ms))
    lines = ms.excited_lines
    # Lines 5-50 Hz at 1000/8192 Hz spacing: ceil(5/0.1220703) = 41 ... floor(50/0.1220703) = 409.
    assert lines[0] == 41 and lines[-1] == 409 and lines.size == 369
    # Flat: every excited line has the same amplitude to float64 rounding (irfft/rfft round trip
    # of O(1e3)-sized values: relative spread ~1e-13, 1e-10 leaves margin without hiding a bug).
    assert np.ptp(amp[lines]) / amp[lines].mean() < 1e-10
    others = np.ones(amp.size, bool)
    others[lines] = False
    # Zero elsewhere: leakage would be O(1) of the line amplitude; rounding is ~1e-13.
    assert amp[others].max() < 1e-10 * amp[lines].mean()


def test_exactly_periodic_and_exact_rms():
    ms = multisine(1024, 500.0, (10.0, 100.0), 2.5, n_periods=4, n_realizations=3, seed=1)
    n = 1024
    for r in range(3):
        periods = ms.signal[r].reshape(4, n)
        assert np.array_equal(periods[0], periods[3])  # tiled: bit-identical periods
        assert abs(np.sqrt(np.mean(ms.signal[r] ** 2)) - 2.5) < 1e-12 * 2.5
    # realizations differ (independent phases)
    assert not np.allclose(ms.signal[0], ms.signal[1])


def test_reproducible_from_seed():
    a = multisine(2048, 1000.0, (5.0, 50.0), 1.0, seed=42)
    b = multisine(2048, 1000.0, (5.0, 50.0), 1.0, seed=42)
    c = multisine(2048, 1000.0, (5.0, 50.0), 1.0, seed=43)
    assert np.array_equal(a.signal, b.signal)
    assert not np.array_equal(a.signal, c.signal)


def test_schroeder_phases_lower_crest_factor_than_worst_case():
    ms = multisine(4096, 1000.0, (1.0, 200.0), 1.0, phases="schroeder")
    crest = np.abs(ms.signal).max() / 1.0
    # Schroeder multisines have crest factors near 1.7; equal phases would give sqrt(2 K) ~ 40.
    assert crest < 2.5
    assert np.ptp(np.abs(_spectrum(ms))[ms.excited_lines]) < 1e-9


def test_band_edges_on_lines_are_included_and_dc_nyquist_excluded():
    lines = excited_lines(100, 100.0, (0.0, 50.0))
    assert lines[0] == 1 and lines[-1] == 49  # DC and Nyquist (50 Hz) never excited
    assert list(excited_lines(100, 100.0, (2.0, 4.0))) == [2, 3, 4]


@pytest.mark.parametrize("kwargs", [dict(rms=0.0), dict(n_periods=0), dict(band=(300.0, 400.0))])
def test_bad_arguments_raise(kwargs):
    band = kwargs.pop("band", (5.0, 50.0))
    args = dict(rms=1.0)
    args.update(kwargs)
    with pytest.raises(ValueError):
        multisine(256, 500.0, band, **args)
