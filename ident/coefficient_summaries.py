"""The answer's nonlinear coefficients read on a session: the driving points, the
coefficient spectra ``c_a(w)`` of a model, the regressors' conditioning and per coefficient
the summary with its verdict (:mod:`ident.robust.verdict`).

Shared by the entry point (:mod:`ident.pipeline`), FNSI's fit (:mod:`ident.fit`), the
refinement (:mod:`ident.refinement`) and the answer (:mod:`ident.identification`).
"""

from __future__ import annotations

from typing import Any

from fnsi_lab.ident.core.coefficients import (CoefficientSpectra, coefficient_spread,
                                              nonlinear_coefficients, summarize_coefficients)
from fnsi_lab.ident.core.regressors import regressor_conditioning
from fnsi_lab.ident.core.fnsi import StateSpaceModel
from fnsi_lab.ident.robust.verdict import coefficient_verdict
from fnsi_lab.ident.session import IdentSession

__all__ = ["driving_points", "session_coefficient_spectra", "session_conditioning",
           "coefficient_summaries"]


def driving_points(session: IdentSession) -> Any:
    """Driving points for the coefficients: the config's, else the only output (None: unknown)."""
    cfg, data = session.config, session.data
    if any(cfg.driving_points.values()):
        return cfg.driving_points
    return data.output_names[0] if data.n_outputs == 1 else None


def session_coefficient_spectra(session: IdentSession,
                                model: StateSpaceModel) -> CoefficientSpectra | None:
    """``c_a(w)`` of ``model`` (None without basis functions).

    Raises NotIdentifiableError (one line) when the driving point is unknown."""
    basis = session.config.nonlinearities
    if not basis:
        return None
    return nonlinear_coefficients(model, session.data, basis,
                                  driving_point=driving_points(session))


def session_conditioning(session: IdentSession):
    """The regressors' conditioning of the session's current data (cached per data)."""
    cached = session.cache.get("conditioning")
    if cached is None or cached[0] is not session.data:
        cached = (session.data, regressor_conditioning(session.data))
        session.cache["conditioning"] = cached
    return cached[1]


def coefficient_summaries(spectra: CoefficientSpectra | None,
                          session: IdentSession | None = None) -> list[dict]:
    """Per coefficient the summary dict with its verdict (:mod:`ident.robust.verdict`)."""
    if spectra is None:
        return []
    summaries = [s.to_dict() for s in summarize_coefficients(spectra)]
    rho = coefficient_spread(spectra)
    cond = session_conditioning(session) if session is not None else None
    for a, c in enumerate(summaries):
        vif = None
        if cond is not None and c["name"] in cond.names:
            vif = float(cond.inflation[cond.names.index(c["name"])])
        v = coefficient_verdict(c, float(rho[a]), inflation=vif)
        c.update(v.to_dict())
    return summaries
