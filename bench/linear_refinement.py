"""How far is FNSI's linear model from the best linear model of the same data? (measurement)

FNSI (a subspace method) gives a consistent but not a least-squares model. This script takes
the linear model ``fnsi-lab ident`` identifies (the information criterion's order, and a
fixed higher order), and refines it on the same data as a prototype would: the poles by
Levenberg-Marquardt, kept stable (``|mu| < 1``), the residues and ``D`` by noise-weighted
least squares for given poles (variable projection; one force, so every residue is a
mode's output vector). It then predicts a record of another multisine realisation from its
measured force, as ``fnsi-lab validate`` does for a linear model, and compares with the
floor the data allow: the nonparametric FRF of the identified record applied to that force.

Since stop 39 the tool itself refits a linear answer's ``C`` and ``D`` for its poles
(``ident/core/output_refit.py``): "the tool's answer" then reads as "FNSI's poles, LS
residues" (weights smoothed over 8 lines, hence small differences); the table in
bench/RESULTS.md was measured before, with FNSI's own ``C``.

One force: the residue of a pole is its output vector times a scalar, so "FNSI's poles, LS
residues" is FNSI's ``A`` with ``C`` and ``D`` re-estimated by least squares (FNSI's own ``B``
and ``D`` are already the least-squares ones for its ``A`` and ``C``).

Printed per case: ``V`` (the noise-weighted squared residual per line and output, in noise
variances: 1 is a model that explains the record to its noise), the validation error (dB
below each output) of FNSI's model, of FNSI's poles with least-squares residues, of the
refined model and of the nonparametric floor, and the in-band physical modes before and after.
No product code uses this (bench/RESULTS.md, "How far FNSI's linear model is from the data").

Usage::

    python bench/linear_refinement.py --work DIR      # ~1 min: generates its records
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
import scipy.optimize as so  # noqa: E402
from scipy.special import expit  # noqa: E402

import fnsi_lab  # noqa: E402
from fnsi_lab.ident.core.fnsi import transfer_discrete  # noqa: E402
from fnsi_lab.ident.refine.modal import ModalModel  # noqa: E402

BENCH = Path(__file__).resolve().parent


def _generate(work: Path) -> list[tuple[str, Path, Path, Path]]:
    """(name, identified record, other realisation, config) per case, written once."""
    gvt_a, gvt_b = work / "gvt-a", work / "gvt-b"
    beam_a = work / "beam"
    runs = [([BENCH / "aircraft.py", "--out", gvt_a, "--levels", "12"],
             gvt_a / "aircraft-rms12.mcap"),
            ([BENCH / "aircraft.py", "--out", gvt_b, "--levels", "12", "--phase-seed", "10"],
             gvt_b / "aircraft-rms12.mcap"),
            ([BENCH / "independent_beam.py", "--out", beam_a, "--levels", "0.002"],
             beam_a / "beam-rms0.002.npz"),
            ([BENCH / "independent_beam.py", "--out", beam_a / "v", "--levels", "0.002",
              "--seed", "100"], beam_a / "v" / "beam-rms0.002.npz")]
    for args, made in runs:
        if not made.exists():
            subprocess.run([sys.executable, *map(str, args)], check=True,
                           stdout=subprocess.DEVNULL)
    return [("aircraft-like GVT, 12 N (joint stuck)", gvt_a / "aircraft-rms12.mcap",
             gvt_b / "aircraft-rms12.mcap", gvt_a / "aircraft-linear.yaml"),
            ("Bouc-Wen beam, 0.002 N (linear)", beam_a / "beam-rms0.002.npz",
             beam_a / "v" / "beam-rms0.002.npz", beam_a / "beam-linear.yaml")]


class PoleFit:
    """Variable projection over the poles of a one-force discrete-time model.

    ``Y[k, o] = (sum_poles R_o / (z_k - mu) + D_o) U[k]``: for given poles the residues and
    ``D`` solve a weighted linear least-squares problem per output; the poles, kept inside
    the unit circle by ``|mu| = 1 / (1 + exp(-x))``, are what Levenberg-Marquardt moves.
    """

    def __init__(self, z: np.ndarray, U: np.ndarray, Y: np.ndarray, weights: np.ndarray):
        self.z, self.U, self.Y, self.W = z, U, Y, weights      # (F,), (F,), (F, p), (F, p)

    def columns(self, pairs: np.ndarray, reals: np.ndarray, z: np.ndarray) -> np.ndarray:
        cols = []
        for q in pairs:   # residue x + j y of the pair: x (a + b) + y j (a - b)
            a, b = 1 / (z - q), 1 / (z - np.conj(q))
            cols += [a + b, 1j * (a - b)]
        cols += [1 / (z - q) for q in reals] + [np.ones_like(z)]
        return np.stack(cols, axis=1)

    def residues(self, pairs, reals) -> np.ndarray:
        """(n_columns, p) real coefficients of :meth:`columns` times the force."""
        A = self.columns(pairs, reals, self.z) * self.U[:, None]
        out = []
        for o in range(self.Y.shape[1]):
            Aw = A * self.W[:, o:o + 1]
            b = self.Y[:, o] * self.W[:, o]
            theta, *_ = np.linalg.lstsq(np.vstack([Aw.real, Aw.imag]),
                                        np.concatenate([b.real, b.imag]), rcond=None)
            out.append(theta)
        return np.stack(out, axis=1)

    def predict(self, pairs, reals, theta, z, U) -> np.ndarray:
        return (self.columns(pairs, reals, z) * U[:, None]) @ theta

    @staticmethod
    def unpack(x, n_pairs):
        radius = expit(x[:n_pairs])
        pairs = radius * np.exp(1j * x[n_pairs:2 * n_pairs])
        return pairs, np.tanh(x[2 * n_pairs:])

    @staticmethod
    def pack(pairs, reals):
        r = np.clip(np.abs(pairs), 1e-6, 1 - 1e-9)
        return np.concatenate([np.log(r / (1 - r)), np.angle(pairs),
                               np.arctanh(np.clip(reals, -1 + 1e-9, 1 - 1e-9))])

    def residual(self, x, n_pairs) -> np.ndarray:
        pairs, reals = self.unpack(x, n_pairs)
        theta = self.residues(pairs, reals)
        e = (self.Y - self.predict(pairs, reals, theta, self.z, self.U)) * self.W
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

    def misfit(self, pairs, reals) -> float:
        x = self.pack(pairs, reals)
        return float(np.sum(self.residual(x, pairs.size) ** 2) / self.Y.size)


def _error_db(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    return 10 * np.log10(np.sum(np.abs(measured - predicted) ** 2, axis=0)
                         / np.sum(np.abs(measured) ** 2, axis=0))


def _modes(pairs, data) -> list[tuple[float, float]]:
    """(frequency Hz, damping ratio) of the pairs in the band."""
    lo, hi = data.band_hz
    if data.time_base == "bilinear":
        lam = (2 / data.bilinear_period_s) * (pairs - 1) / (pairs + 1)
    else:
        lam = data.sample_rate_hz * np.log(pairs)
    f, zeta = np.abs(lam) / (2 * np.pi), -lam.real / np.abs(lam)
    return sorted((float(a), float(b)) for a, b in zip(f, zeta) if lo <= a <= hi and b > 0)


def _prediction(fit: PoleFit, pairs, reals, z, U) -> np.ndarray:
    """The outputs of the model with these poles and least-squares residues at lines ``z``."""
    return fit.predict(pairs, reals, fit.residues(pairs, reals), z, U)


def run_case(name, record, other, config, order) -> dict:
    ident = fnsi_lab.identify(str(record), str(config), **(
        {"order": order} if order else {"orders": "2:60"}))
    data, model = ident.session.data, ident.model
    m = data.n_inputs
    if m != 1 or data.n_realizations != 1:
        raise SystemExit(f"{name}: one force and one realisation only")
    modal = ModalModel.from_matrices(model.a_d, model.b_d, model.c_d, model.d_d)
    z, Y, U = np.asarray(data.z), np.asarray(data.Y), np.asarray(data.E[:, 0])
    var = np.asarray(data.noise_var)
    var = np.einsum("kpp->kp", var).real if var.ndim == 3 else var.real
    fit = PoleFit(z, U, Y, 1 / np.sqrt(var))
    pairs0, reals0 = modal.poles, modal.real_poles
    t0 = time.perf_counter()
    x0 = fit.pack(pairs0, reals0)
    sol = so.least_squares(fit.residual, x0, args=(pairs0.size,), method="lm",
                           max_nfev=100 * x0.size)
    seconds = time.perf_counter() - t0
    pairs1, reals1 = fit.unpack(sol.x, pairs0.size)
    # the other record's lines, processed as the identified one's
    val = fnsi_lab.identify(str(other), str(config), order=4).session.data
    z2, Y2, U2 = np.asarray(val.z), np.asarray(val.Y), np.asarray(val.E[:, 0])
    G = transfer_discrete(model, z2)[:, :, 0]
    floor = Y / U[:, None] * U2[:, None]
    out = {"name": name, "order": model.order, "seconds": seconds,
           # FNSI's unstable poles (none kept as modes) enter at the unit circle's edge
           "misfit": {"the tool's answer": float(np.mean(np.abs((Y - transfer_discrete(model, z)[:, :, 0]
                                                             * U[:, None]) * fit.W) ** 2)),
                      "FNSI's poles, LS residues": fit.misfit(pairs0, reals0),
                      "poles refined": float(np.sum(sol.fun ** 2) / Y.size)},
           "validation_db": {
               "the tool's answer": _error_db(Y2, G * U2[:, None]),
               "FNSI's poles, LS residues": _error_db(Y2, _prediction(fit, pairs0, reals0, z2, U2)),
               "poles refined": _error_db(Y2, _prediction(fit, pairs1, reals1, z2, U2)),
               "nonparametric floor": _error_db(Y2, floor)},
           "modes": {"fnsi": _modes(pairs0[np.abs(pairs0) < 1], data),
                     "refined": _modes(pairs1, data)},
           }
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", default="linear-refinement", help="folder for the records")
    a = p.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, "
          f"{os.cpu_count()} cores")
    for name, record, other, config in _generate(work):
        for order in (None, 40):
            r = run_case(name, record, other, config, order)
            label = "the criterion's order" if order is None else "fixed order"
            print(f"\n{name}, {label} {r['order']} (refinement {r['seconds']:.1f} s)")
            print("  V (noise variances): "
                  + ", ".join(f"{k} {v:.3g}" for k, v in r["misfit"].items()))
            for key, db in r["validation_db"].items():
                print(f"  validation on another realisation, {key:26s}: "
                      + " / ".join(f"{v:+.1f}" for v in db) + " dB")
            before, after = r["modes"]["fnsi"], r["modes"]["refined"]
            for label, modes in (("FNSI:   ", before), ("refined:", after)):
                print(f"  in-band poles {label} "
                      + ", ".join(f"{f:.4f} ({100 * z:.3f} %)" for f, z in modes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
