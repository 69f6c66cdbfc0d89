"""FNSI's answer on a session, before any refinement: the model at a fixed order or the
robust automatic pipeline over an order sweep (:func:`fit_session`, its :class:`Fit`), and
the physical modes of an answer (:func:`answer_modes`).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, NamedTuple, Sequence

import numpy as np

from fnsi_lab.ident.coefficient_summaries import (coefficient_summaries, driving_points,
                                                  session_coefficient_spectra)
from fnsi_lab.ident.core.coefficients import spread_function
from fnsi_lab.ident.core.fnsi import (StateSpaceModel, SubspaceDecomposition, model_at_order,
                                      subspace_decomposition)
from fnsi_lab.ident.core.output_refit import refit_output_matrices
from fnsi_lab.ident.core.result import Mode
from fnsi_lab.ident.refine.output_error import OutputErrorFit
from fnsi_lab.ident.robust.auto_result import AutoResult
from fnsi_lab.ident.robust.nested import residual_weights
from fnsi_lab.ident.session import IdentSession

__all__ = ["Fit", "fit_session", "answer_modes"]


class Fit(NamedTuple):
    """FNSI's answer before the refinement, the coefficients and the nested test: the first
    fields of an :class:`Identification`."""

    model: StateSpaceModel
    method: str
    auto: AutoResult | None = None
    decomposition: SubspaceDecomposition | None = None


def fit_session(session: IdentSession, *, order: int | None, sweep: Sequence[int],
                reduce_at: int | None, max_order: int | None, block_rows: int | None,
                progress: Any = None) -> Fit:
    """FNSI at the fixed ``order``, or the robust pipeline over ``sweep``, on the session's data
    (no refinement, no coefficients yet)."""
    cfg = session.config
    block_rows = block_rows or cfg.block_rows
    dp = driving_points(session)
    if order is not None:
        max_order = max(int(order), max_order or cfg.max_order or int(order))
        t1 = time.perf_counter()
        if cfg.time_base == "auto" and session.data.output_quantity == "displacement":
            # band-limited or bilinear line map: the one that fits (ident.core.time_base)
            from fnsi_lab.ident.core.time_base import choose_time_base
            session.data, dec, model, choice = choose_time_base(
                session.data, int(order), max_order=max_order, block_rows=block_rows,
                weighted=session.weighted, d_zero=session.d_zero)
            session.evidence["time_base_choice"] = choice
        else:
            dec = subspace_decomposition(session.data, max_order=max_order,
                                         block_rows=block_rows, weighted=session.weighted)
            model = model_at_order(dec, session.data, int(order), d_zero=session.d_zero)
        session.timings_s["decomposition"] = time.perf_counter() - t1
        session.timings_s["model"] = time.perf_counter() - t1 - session.timings_s["decomposition"]
        return Fit(_refit(session, model), "order", decomposition=dec)
    else:
        from fnsi_lab.ident.robust.auto import identify_auto

        options = replace(cfg.auto, d_zero=session.d_zero, weighted=session.weighted,
                          block_rows=block_rows or cfg.auto.block_rows)
        basis = cfg.nonlinearities

        def coefficients(model: StateSpaceModel) -> list[dict] | None:
            return coefficient_summaries(session_coefficient_spectra(session, model),
                                         session) or None

        # the consistency gate reads the split between force and basis columns; a spline's
        # hinge slopes spread with the curve's shape instead, smallest at degenerate low
        # orders (three GVT levels with nonlinearities: auto: order 2, criterion 0.735,
        # against 0.150 at 19): the criterion alone orders a spline
        spread = (spread_function(session.data, basis, driving_point=dp)
                  if basis and dp is not None and not any(nl.kind == "spline" for nl in basis)
                  else None)
        sweep = _feasible_sweep(session, sweep, options.block_rows)
        t1 = time.perf_counter()
        res = identify_auto(session.data, options, orders=sweep, reduce_at=reduce_at,
                            progress=progress, coefficients=coefficients if basis else None,
                            spread=spread)
        session.timings_s["auto"] = time.perf_counter() - t1
        session.warnings.extend(res.confidence.get("warnings", []))  # e.g. order at sweep end
        return Fit(_refit(session, res.final_model), "auto", auto=res)


def _feasible_sweep(session: IdentSession, sweep: Sequence[int], block_rows: int | None
                    ) -> list[int]:
    """The sweep's orders that the record's lines can hold with the session's extended
    inputs (``2F >= i (m_e + p)`` with ``(i - 1) p >= n``: docs/ident.md, "Block rows"); the
    orders cut are said in a warning. A one-output record with a 12-knot spline (13
    extended inputs) holds orders up to 45 on the Silverbox's 323 lines, where the default
    sweep to 60 stopped the identification."""
    from fnsi_lab.ident.core.subspace import block_rows_for, default_output_rank

    data = session.data
    F, m_e, p_all = data.n_lines, data.n_extended_inputs, data.n_outputs

    def fits(n: int) -> bool:
        rank = default_output_rank(p_all, n, m_e)
        p = rank if rank is not None and rank < p_all else p_all
        i = int(block_rows) if block_rows else block_rows_for(data, n)
        return (i - 1) * p >= n and 2 * F >= i * (m_e + p)

    orders = sorted(int(n) for n in sweep)
    if not orders or fits(orders[-1]):
        return list(sweep)
    kept = [n for n in orders if fits(n)]
    if not kept:
        return list(sweep)       # the decomposition says why, with the fix
    session.warnings.append(
        f"order sweep cut at {kept[-1]} (asked up to {orders[-1]}): {F} lines hold no more "
        f"with {m_e} extended inputs (fewer basis columns, e.g. knots, or a wider band "
        "allow more)")
    return kept


def answer_modes(fit: Fit, output_error: OutputErrorFit | None = None) -> list[Mode]:
    """Physical modes of an answer, sorted by frequency: every mode of ``fit.model``, or for
    the robust pipeline those of its physical poles (the MDI table's; after an output-error
    refinement the same modes refined, or dropped)."""
    m = fit.model.poles.modes()
    keep = np.ones(m["frequency_hz"].size, bool)
    if fit.auto is not None:
        physical = [r["frequency_hz"] for r in fit.auto.mdi_table() if r["physical"]]
        if output_error is not None:   # the same modes, refined (or dropped)
            physical = [g for g in (output_error.refined_frequency(f)
                                    for f in physical) if g is not None]
        keep = np.array([any(abs(f - g) <= 1e-6 * max(g, 1e-12) for g in physical)
                         for f in m["frequency_hz"]], bool)
    return [Mode(frequency_hz=float(f), damping_ratio=float(z), stable=bool(s),
                 shape=np.asarray(m["mode_shapes"][:, k]))
            for k, (f, z, s, kp) in enumerate(zip(m["frequency_hz"], m["damping_ratio"],
                                                   m["stable"], keep)) if kp]


def _refit(session: IdentSession, model: StateSpaceModel) -> StateSpaceModel:
    """A linear model's ``C`` and ``D`` by least squares for its poles and ``B``
    (:mod:`ident.core.output_refit`), weighted as the nested test's residual.

    FNSI's poles are good and its ``C`` is not: on a linear beam record its linear answer
    predicted another realisation at -35..-43 dB where the record allows -49..-52; refit,
    -49..-55 (bench/RESULTS.md, "How far FNSI's linear model is from the data"). Linear
    models only: with basis columns the refit reads the *measured* motion's nonlinear
    forces, and the model simulated on its own motion got worse (the Bouc-Wen beam's 1 N
    Jenkins model: from 6 dB better than the linear fit on another level's record to 3 dB
    worse). A nonlinear configuration's linear fit (the nested test's yardstick) is refit.
    """
    if session.config.nonlinearities:
        return model
    weights = residual_weights(session.data)[0]
    return refit_output_matrices(model, session.data, weights, d_zero=session.d_zero)
