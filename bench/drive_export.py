"""The default experiment's drive in every export format: size, time, read-back fidelity.

    python bench/drive_export.py

For each format the drive (SmallSat: 6 periods of 8192 samples at 1 kHz, 0.01 V/N) is
written with ``daq.drive.write_drive``, read back with the third-party reader of that
format (scipy.io.wavfile, npTDMS, numpy) and compared with the design: largest error
relative to full scale, periodicity (every period bit-identical to the first) and the
power off the excited lines.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fnsi_lab.daq.config import load_experiment
from fnsi_lab.daq.drive import design_drive, off_line_power_db, read_drive, write_drive


def main() -> int:
    import nptdms  # noqa: F401  (imports outside the timings)
    import scipy.io.wavfile  # noqa: F401

    config = load_experiment(None)
    definition, signal = design_drive(config.excitation, config.sample_rate_hz,
                                      volts_per_newton=0.01)
    designed = signal.reshape(-1)
    n = config.excitation.samples_per_period
    peak = float(np.max(np.abs(designed)))
    print("| format | size | write | read | max error / full scale | bit-periodic | off-line power |")
    print("|---|---:|---:|---:|---:|---|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, kwargs in (("drive.wav", {"wav_encoding": "float32"}),
                             ("drive24.wav", {"wav_encoding": "pcm24"}),
                             ("drive.csv", {}), ("drive.npy", {}), ("drive.tdms", {})):
            path = Path(tmp) / name
            t0 = time.perf_counter()
            done = write_drive(path, definition, signal, **kwargs)
            t1 = time.perf_counter()
            back = read_drive(path, done)
            t2 = time.perf_counter()
            label = name.split(".")[1] + (" pcm24" if "24" in name else
                                          " float32" if name.endswith(".wav") else "")
            periodic = bool(np.all(back.reshape(-1, n) == back[:n]))
            err = float(np.max(np.abs(back - designed))) / peak
            print(f"| {label} | {path.stat().st_size / 1e3:.0f} kB | {1e3 * (t1 - t0):.0f} ms "
                  f"| {1e3 * (t2 - t1):.0f} ms | {err:.1e} | {periodic} "
                  f"| {off_line_power_db(back, n, definition.excited_lines):.0f} dB |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
