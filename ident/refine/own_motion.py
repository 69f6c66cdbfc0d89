"""A nonlinear model's output matrices refit on its own simulated motion (docs/ident.md,
"The output matrices of a kept nonlinear answer").

FNSI's ``C`` carries the subspace's noise and bias; for a linear model ``C`` and ``D`` by
least squares for the model's poles close that gap (:mod:`ident.core.output_refit`). A
nonlinear model's extended input holds the basis columns, and on the *measured* motion they
carry its noise and the model's misfit: refit on them, the Bouc-Wen beam's 1 N Jenkins model
simulated 3 dB worse than before. Here the basis columns are those of the model's *own*
periodic steady state (the harmonic balance that ``fnsi-lab validate`` solves,
:func:`ident.refine.validation.balance_outputs`), so the refit lowers the figure of merit
that validate reports, the simulation error on the record:

    ``Y(k) ~ C X(k) + D E(k)``,  ``E = [P; H(delta_hat)]``,  ``X = (z I - A)^{-1} B E``

with ``delta_hat`` the model's own motion. A new ``C`` moves that motion where the basis
reads outputs, so this is a fixed point, not one least-squares problem, and the least
squares ignore that move: each round solves the balance again and keeps the new matrices
only if the simulated error falls (else half the step, then a quarter, then the same with
the nonlinear forces' feedthrough held); the rounds stop when one lowers it by less than
:data:`MIN_GAIN`. The poles, ``B`` and with them every mode's frequency and damping do not
move.

Where it helps and where it does not (bench/RESULTS.md, "Own-motion refit"): a slipping
joint's force is bounded by its slip force and moves little with a new ``C``; the
aircraft-like GVT's Jenkins + stop model at 84 N gains 0.6-2.7 dB on its own record in 4
rounds of 1-2 s, the independent Iwan joint's 20 N model 2-7 dB on a 6 N record no step
of the fit or of the choice read. A Duffing oscillator's cubic force grows fast with the
motion: from a ``C`` 2 % low no step lowers the error, and the start is kept. The refit
lowers the error on its own record by construction, so the pipeline keeps it only where
validation records show it predicts better (:mod:`ident.linear_comparison`).

Shapes: spectra ``(R, F, p)`` over realisations and compared lines, as
:class:`ident.refine.validation.SimulatedOutputs`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.frequency_data import FrequencyData
from fnsi_lab.ident.core.output_refit import (output_matrices_for, state_response_at,
                                              with_output_matrices)
from fnsi_lab.ident.core.state_space import StateSpaceModel
from fnsi_lab.ident.refine.validation import SimulatedOutputs, balance_outputs

__all__ = ["OwnMotionRefit", "refit_on_own_motion", "MAX_ROUNDS", "MIN_GAIN"]

#: Rounds (balance, least squares) at most: the GVT's Jenkins + stop model gained 22 %, 9 %,
#: 3 % and 0.1 % of its error energy in its four; the independent Iwan joint's 14 %, 6 %,
#: 11 %, 24 %, 8 %.
MAX_ROUNDS = 5
#: A round that lowers the summed relative error energy by less than this ends the refit
#: (0.04 dB: below any difference a validation table shows).
MIN_GAIN = 0.01
#: Fractions of the least-squares step tried in turn: a full step can move the motion the
#: basis reads enough to undo its gain (the Bouc-Wen beam's 1 N Jenkins model: +28 % error
#: energy at the full step, -10 % at half of it).
STEPS = (1.0, 0.5, 0.25)


@dataclass(frozen=True)
class OwnMotionRefit:
    """The outcome of :func:`refit_on_own_motion`.

    Attributes
    ----------
    model : StateSpaceModel
        The refit model; the start itself when ``applied`` is False.
    applied : bool
    rounds : int
        Rounds kept.
    error_db_before, error_db_after : tuple of float
        Per output, the simulation error on the record in dB below the output (the start's
        and the refit model's; equal when not applied).
    reason : str
        One line: what was done, or why not.
    """

    model: StateSpaceModel
    applied: bool
    rounds: int
    error_db_before: tuple[float, ...]
    error_db_after: tuple[float, ...]
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"applied": self.applied, "rounds": self.rounds,
                "error_db_before": list(self.error_db_before),
                "error_db_after": list(self.error_db_after), "reason": self.reason}


def _relative_error(sim: SimulatedOutputs) -> np.ndarray:
    """Per output, the simulation's error energy over the output's, shape (p,)."""
    assert sim.nonlinear is not None
    err = np.sum(np.abs(sim.measured - sim.nonlinear) ** 2, axis=(0, 1))
    ref = np.sum(np.abs(sim.measured) ** 2, axis=(0, 1))
    return err / np.where(ref > 0, ref, 1.0)


def _db(energy: np.ndarray) -> tuple[float, ...]:
    return tuple(float(10.0 * np.log10(max(e, 1e-300))) for e in energy)


def _least_squares_steps(model: StateSpaceModel, sim: SimulatedOutputs, d_zero: bool
                         ) -> list[tuple[np.ndarray, np.ndarray]]:
    """``C``, ``D`` by least squares for the extended input of ``sim`` (the model's motion):
    with every feedthrough column, then with the nonlinear forces' feedthrough held.

    The second is tried when no step along the first lowers the error: regressed on forces
    read on a motion that is not yet the refit model's, that feedthrough can run away (a
    Duffing answer with ``C`` 2 % low: 1.6e3 -> 1.5e5), while on the aircraft-like GVT it
    carries a third of the gain (the payload 98 N record: -9.3 dB with it, -8.6 without)."""
    assert sim.extended_input is not None and sim.z is not None
    R, F, p = sim.measured.shape
    z, E = np.tile(sim.z, R), sim.extended_input.reshape(R * F, -1)
    Y = sim.measured.reshape(R * F, p)
    m = model.n_inputs
    X = state_response_at(model, z, E)                           # both directions' states
    every = output_matrices_for(model, z, E, Y, d_zero=d_zero, states=X)
    c_d, d_u = output_matrices_for(model, z, E, Y - E[:, m:] @ model.d_d[:, m:].T,
                                   d_zero=d_zero, feedthrough=m, states=X)
    return [every, (c_d, np.concatenate([d_u, model.d_d[:, m:]], axis=1))]


def _descent(model: StateSpaceModel, sim: SimulatedOutputs, error: np.ndarray,
             basis: Sequence[Nonlinearity], record: FrequencyData,
             band_hz: tuple[float, float], d_zero: bool
             ) -> tuple[StateSpaceModel, SimulatedOutputs, np.ndarray] | None:
    """The first trial along :func:`_least_squares_steps` (:data:`STEPS` of each) whose
    simulation error on the record is below ``error``'s sum, with its simulation; None."""
    for c_d, d_d in _least_squares_steps(model, sim, d_zero):
        for step in STEPS:
            trial = with_output_matrices(model, model.c_d + step * (c_d - model.c_d),
                                         model.d_d + step * (d_d - model.d_d))
            trial_sim = balance_outputs(trial, basis, record, band_hz)
            if trial_sim.nonlinear is None:
                continue
            trial_error = _relative_error(trial_sim)
            if np.sum(trial_error) < np.sum(error):
                return trial, trial_sim, trial_error
    return None


def refit_on_own_motion(model: StateSpaceModel, basis: Sequence[Nonlinearity],
                        record: FrequencyData, band_hz: tuple[float, float], *,
                        d_zero: bool, max_rounds: int = MAX_ROUNDS,
                        min_gain: float = MIN_GAIN) -> OwnMotionRefit:
    """Refit ``C`` and ``D`` of a nonlinear model on its own steady state (module doc).

    Parameters
    ----------
    model : StateSpaceModel
        Extended inputs ``[p; h]`` in physical units.
    basis : sequence of Nonlinearity
        Its basis (same order as its nonlinear columns).
    record : FrequencyData
        The record it was identified on, prepared as ``fnsi-lab validate`` prepares one
        (:func:`ident.refine.validation.prediction_data`: every line the motion needs).
    band_hz : (float, float)
        The lines compared (the identified band).
    d_zero : bool
        Keep ``D = 0``.
    max_rounds, min_gain
        :data:`MAX_ROUNDS`, :data:`MIN_GAIN`.

    Returns
    -------
    OwnMotionRefit
        Not applied when the model has no steady state on the record or no round lowers
        its simulation error.
    """
    sim = balance_outputs(model, basis, record, band_hz)
    if sim.nonlinear is None:
        return OwnMotionRefit(model, False, 0, (), (), "not applied: the model has no "
                              "periodic steady state on its record")
    error = _relative_error(sim)
    before = _db(error)
    current, rounds = model, 0
    for _ in range(max_rounds):
        found = _descent(current, sim, error, basis, record, band_hz, d_zero)
        if found is None:   # no step lowers the error: the fixed point is reached (or
            break           # leads nowhere)
        trial, trial_sim, trial_error = found
        gain = 1.0 - np.sum(trial_error) / np.sum(error)
        current, sim, error, rounds = trial, trial_sim, trial_error, rounds + 1
        if gain < min_gain:
            break
    if rounds == 0:
        return OwnMotionRefit(model, False, 0, before, before, "not applied: no refit of the "
                              "output matrices lowers the model's simulation error on its "
                              "record")
    after = _db(error)
    return OwnMotionRefit(current, True, rounds, before, after,
                          f"C and D refit on the model's own motion in {rounds} round"
                          f"{'s' if rounds > 1 else ''}: its simulation error on its record "
                          f"{'/'.join(f'{v:.1f}' for v in before)} -> "
                          f"{'/'.join(f'{v:.1f}' for v in after)} dB")
