"""C and D by least squares for a model's poles (ident.core.output_refit)."""

from __future__ import annotations

import numpy as np

import fnsi_lab
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sim import lumped_model, simulate
from fnsi_lab.ident.core.output_refit import refit_output_matrices, state_response
from fnsi_lab.ident.core.state_space import transfer_discrete
from fnsi_lab.ident.robust.nested import residual_weights

FS, N, PERIODS = 1024.0, 4096, 6
LINEAR = {"band_hz": [3, 120], "transient_periods": 1, "refine": "none",
          "inputs": [{"name": "F", "driving_point": "X3"}], "nonlinearities": []}


def _chain(noise: float, seed: int = 3) -> dict:
    ms = multisine(N, FS, (3, 120), 5.0, n_periods=PERIODS + 1, seed=11)
    u = ms.signal[0][:, None]
    y = simulate(lumped_model("none"), u, FS, periodic=N,
                 quantities=("displacement",)).displacement
    y = y + noise * y.std(axis=0) * np.random.default_rng(seed).standard_normal(y.shape)
    return {"u": u, "y": y, "fs": FS, "N": N, "channels": np.array(["X1", "X2", "X3"]),
            "input_channels": np.array(["F"])}


def test_the_state_response_is_the_model_output_less_its_feedthrough():
    # C X(k) + D E(k) is the model's steady-state output, whichever way X is computed
    r = fnsi_lab.identify(_chain(0.0), {**LINEAR, "refine": "none"}, order=6)
    data, model = r.session.data, r.model
    X = state_response(model, data)
    np.testing.assert_allclose(X @ model.c_d.T + data.E_physical @ model.d_d.T,
                               model.steady_state_output(data), rtol=1e-9, atol=1e-15)


def test_noise_free_data_leave_an_exact_model_as_it_is():
    # the 3-DOF chain at its true order, noise-free: FNSI is exact, so is the refit (the
    # FRFs agree to the solver's precision)
    r = fnsi_lab.identify(_chain(0.0), LINEAR, order=6)
    data, model = r.session.data, r.model
    refit = refit_output_matrices(model, data, residual_weights(data)[0], d_zero=True)
    G0, G1 = (transfer_discrete(m, data.z)[:, :, 0] for m in (model, refit))
    assert np.max(np.abs(G1 - G0)) <= 1e-6 * np.max(np.abs(G0))
    np.testing.assert_allclose(np.sort_complex(refit.poles.eigenvalues),
                               np.sort_complex(model.poles.eigenvalues))


def test_the_refit_lowers_the_residual_and_keeps_the_poles():
    # 1 % output noise: FNSI's C carries the subspace's noise, the least-squares C, D for
    # the same poles leave a lower weighted residual, and the modes' frequencies and
    # damping do not move
    r = fnsi_lab.identify(_chain(0.01), {**LINEAR, "refine": "none"}, order=6)
    data = r.session.data
    w = residual_weights(data)[0]
    from fnsi_lab.ident.core.fnsi import model_at_order, subspace_decomposition

    fnsi = model_at_order(subspace_decomposition(data, max_order=6), data, 6, d_zero=True)
    refit = refit_output_matrices(fnsi, data, w, d_zero=True)

    def residual(m):
        return float(np.sum(w * np.abs(data.Y - m.steady_state_output(data)) ** 2))

    assert refit is not fnsi and residual(refit) < residual(fnsi)
    np.testing.assert_allclose(refit.poles.natural_frequency_hz, fnsi.poles.natural_frequency_hz)
    np.testing.assert_allclose(refit.poles.damping_ratio, fnsi.poles.damping_ratio)
