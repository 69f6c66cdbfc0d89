"""A simulated test whose drive runs on another clock than the acquisition.

The generator plays the multisine at ``fs_drive``; the DAQ samples force and responses at
``fs_acq = fs_drive (1 + e)``. The force the structure feels, read at acquisition sample n,
is the multisine evaluated at drive position ``n / (1 + e)`` (:meth:`Multisine.at`, exact:
a sum of cosines on the excited lines); the structure is integrated from rest on the
acquisition grid. Used to measure how much mismatch the identification tolerates and to
test :mod:`daq.periodicity`.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def simulate_clock_mismatch(source: Any, offset_ppm: float) -> np.ndarray:
    """Channels of every realization of a simulated experiment with a clock mismatch.

    Parameters
    ----------
    source : daq.sim.source.SimulatedSource
        The experiment (model, multisine, channels, quantities, noise-free).
    offset_ppm : float
        ``(fs_acq / fs_drive - 1) * 1e6``.

    Returns
    -------
    ndarray, shape (n_realizations, n_periods, N, n_channels)
        In the source's channel order (forces first), cut into N-sample acquisition periods.
    """
    from fnsi_lab.daq.sim.integrate import simulate

    ms = source.multisine
    n = ms.samples_per_period
    n_total = n * ms.n_periods
    model = source.model
    positions = np.arange(n_total) / (1.0 + offset_ppm * 1e-6)
    resp = [c for c in source.channels if not c.is_force]
    dofs = np.array([model.measured[c.name] for c in resp], dtype=np.int64)
    quantities = sorted({c.quantity for c in resp},
                        key=("displacement", "velocity", "acceleration").index)
    out = np.empty((ms.n_realizations, ms.n_periods, n, len(source.channels)))
    for r in range(ms.n_realizations):
        force = np.zeros((n_total, model.n_inputs))
        force[:, 0] = ms.at(positions, r)
        res = simulate(model, force, source.sample_rate_hz, oversample=source.options.oversample,
                       periodic=None, dofs=dofs, quantities=quantities,
                       passband=source.options.passband)
        cols, j = [], 0
        for c in source.channels:
            if c.is_force:
                cols.append(force[:, model.input_names.index(c.name)])
            else:
                cols.append(res.get(c.quantity)[:, j])
                j += 1
        out[r] = np.stack(cols, axis=1).reshape(ms.n_periods, n, -1)
    return out
