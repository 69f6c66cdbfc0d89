"""The identified model in the JSON result, and back: what ``fnsi-lab validate`` simulates.

An ``ident --json`` result carries, next to the answer, everything needed to rebuild the
nonlinear model without the data it came from (docs/validate.md):

``state_space``
    the answer's discrete-time matrices of the extended input ``e = [p; h]``
    (``a`` (n, n), ``b`` (n, m_e), ``c`` (p, n), ``d`` (p, m_e), ``B``/``D`` in physical
    basis units), ``sample_rate_hz``, ``n_inputs``, ``input_names`` (extended),
    ``output_names``, ``time_base``, ``bilinear_period_s``;
``processing``
    how a record is turned into the model's frequency data (``transient_periods``,
    ``highpass_hz``, ``basis_oversample``, ``integration_min_snr``,
    ``steady_state_tolerance``, ``steady_periods``, ``samples_per_period``);
``nonlinearities``
    the basis as used (already in the result; ``velocity_scale`` added for Coulomb, the
    placed ``knots`` and ``velocity_knots`` for splines).

Pure functions over dicts and numpy arrays.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.fnsi import StateSpaceModel, make_model

__all__ = ["state_space_json", "processing_json", "model_from_json", "basis_from_json"]


def state_space_json(model: StateSpaceModel) -> dict[str, Any]:
    """The model's DT matrices and time base as a JSON-able dict (see the module doc)."""
    return {"a": np.asarray(model.a_d).tolist(), "b": np.asarray(model.b_d).tolist(),
            "c": np.asarray(model.c_d).tolist(), "d": np.asarray(model.d_d).tolist(),
            "order": int(model.order), "sample_rate_hz": float(model.sample_rate_hz),
            "n_inputs": int(model.n_inputs), "input_names": list(model.input_names),
            "output_names": list(model.output_names), "time_base": model.time_base,
            "bilinear_period_s": model.bilinear_period_s}


def processing_json(config: Any, transient_periods: int | None,
                    samples_per_period: int) -> dict[str, Any]:
    """The record-to-frequency-data settings of an identification (see the module doc)."""
    return {"transient_periods": transient_periods, "samples_per_period": int(samples_per_period),
            "highpass_hz": config.highpass_hz, "basis_oversample": int(config.basis_oversample),
            "integration_min_snr": config.integration_min_snr,
            "steady_state_tolerance": float(config.steady_state_tolerance),
            "steady_periods": str(getattr(config, "steady_periods", "auto"))}


def _matrix(d: Mapping[str, Any], key: str, shape: tuple[int | None, int | None],
            where: str) -> np.ndarray:
    try:
        a = np.asarray(d[key], dtype=float)
    except KeyError:
        raise IdentError(f"{where}: state_space.{key} is missing (fix: re-run ident --json "
                         "with this version)") from None
    except (TypeError, ValueError):
        raise IdentError(f"{where}: state_space.{key} is not a matrix of numbers") from None
    if a.ndim == 1 and a.size == 0:
        a = a.reshape(shape[0] or 0, shape[1] or 0)
    if a.ndim != 2 or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        raise IdentError(f"{where}: state_space.{key} has shape {' x '.join(map(str, a.shape))}, expected "
                         f"{' x '.join('n' if s is None else str(s) for s in shape)}")
    return a


def model_from_json(result: Mapping[str, Any], where: str = "result") -> StateSpaceModel:
    """Rebuild the answer's :class:`StateSpaceModel` from a result's ``state_space``.

    Raises
    ------
    IdentError
        The key is missing (a result written before it existed) or malformed: one line
        naming ``where`` and the field.
    """
    ss = result.get("state_space")
    if not isinstance(ss, Mapping):
        raise IdentError(f"{where}: no 'state_space' in the result (written by an older "
                         "fnsi-lab; fix: run fnsi-lab ident --json again)")
    try:
        n_inputs = int(ss["n_inputs"])
        fs = float(ss["sample_rate_hz"])
        time_base = str(ss["time_base"])
    except (KeyError, TypeError, ValueError) as exc:
        raise IdentError(f"{where}: state_space lacks a valid {exc}") from None
    order = int(ss.get("order", len(ss.get("a") or [])))
    a = _matrix(ss, "a", (order, order), where)
    b = _matrix(ss, "b", (order, None), where)
    c = _matrix(ss, "c", (None, order), where)
    d = _matrix(ss, "d", (c.shape[0], b.shape[1]), where)
    return make_model(a, b, c, d, sample_rate_hz=fs, n_inputs=n_inputs,
                      input_names=tuple(ss.get("input_names") or ()),
                      output_names=tuple(ss.get("output_names") or ()), time_base=time_base,
                      bilinear_period_s=ss.get("bilinear_period_s"))


def basis_from_json(items: Sequence[Mapping[str, Any]] | None,
                    where: str = "result") -> tuple[Nonlinearity, ...]:
    """The basis of a result's ``nonlinearities`` (every parameter as identified).

    Raises
    ------
    IdentError
        An element lacks a field it needs.
    """
    out = []
    for i, el in enumerate(items or ()):
        try:
            kind = str(el["kind"])
            kw: dict[str, Any] = {"name": str(el["name"]), "kind": kind,
                                  "channels": dict(el["channels"]),
                                  "offset": float(el.get("offset") or 0.0)}
            if kind == "trilinear":
                kw["clearances"] = tuple(float(g) for g in el["clearances"])
            elif kind == "bilinear":
                kw.update(clearance=float(el["clearances"][0]), side=str(el.get("side", "pos")))
            elif kind == "polynomial":
                kw.update(exponent=float(el.get("exponent", 3.0)), signed=bool(el.get("signed")),
                          argument=str(el.get("argument", "displacement")))
            elif kind == "coulomb":
                kw["velocity_scale"] = float(el.get("velocity_scale", 1e-3))
            elif kind == "jenkins":
                kw["slip"] = float(el["slip"])
            elif kind == "spline":
                kw.update(knots=tuple(float(k) for k in el.get("knots") or ()),
                          velocity_knots=tuple(float(k) for k in el.get("velocity_knots") or ()))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise IdentError(f"{where}: nonlinearities[{i}] lacks a valid {exc}") from None
        out.append(Nonlinearity(**kw))
    return tuple(out)
