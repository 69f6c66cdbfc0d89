"""A simulated test whose drive runs on another clock than the acquisition.

The generator plays the multisine at ``fs_drive``; the DAQ samples force and responses at
``fs_acq = fs_drive (1 + e)``. The force the structure feels, read at acquisition sample n,
is the multisine evaluated at drive position ``n / (1 + e)`` (exact: a sum of cosines on the
excited lines); the structure is integrated from rest on the acquisition grid. Used to
measure how much mismatch the identification tolerates and to test :mod:`daq.periodicity`.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.daq.multisine import Multisine


def multisine_at(ms: Multisine, positions: np.ndarray, realization: int = 0,
                 chunk: int = 4096) -> np.ndarray:
    """Evaluate a multisine between its samples.

    Parameters
    ----------
    ms : Multisine
    positions : ndarray, shape (n,)
        Fractional sample indices of the drive (``t * fs_drive``).
    realization : int
    chunk : int
        Positions evaluated at once (memory: ``chunk * n_lines`` values).

    Returns
    -------
    ndarray, shape (n,)
        ``sum_k a cos(2 pi k t / N + phi_k)``; equals ``ms.signal[realization]`` at integer
        positions (to rounding).
    """
    n = ms.samples_per_period
    lines = ms.excited_lines.astype(np.float64)
    amplitude = ms.rms * np.sqrt(2.0 / lines.size)
    phase = ms.phases_rad[realization]
    pos = np.asarray(positions, dtype=np.float64)
    out = np.empty(pos.size)
    for start in range(0, pos.size, chunk):
        # reduce modulo N first: keeps the cosine arguments small (accurate)
        t = np.mod(pos[start:start + chunk], n)
        out[start:start + chunk] = amplitude * np.cos(
            2 * np.pi * np.outer(t, lines) / n + phase).sum(axis=1)
    return out


def simulate_clock_mismatch(source, offset_ppm: float) -> np.ndarray:
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
        force[:, 0] = multisine_at(ms, positions, r)
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
