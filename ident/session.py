"""An identification's session: the configured channels of the data as frequency data.

:func:`prepare_session` selects the configured channels, fills a simulated recording's truth
(:func:`apply_recording_truth`), builds the frequency data (:mod:`ident.core.periodic`), places
spline knots on the measured motion and estimates the basis parameters left to the data
(:mod:`ident.refine.parameter_search`). The entry point (:mod:`ident.pipeline`) and the
localisation (:mod:`ident.locate`) both start from it.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.config import IdentConfig
from fnsi_lab.ident.errors import (DeadBasisError, IdentError, IdentWarning, NoExcitedLineError,
                                   NotIdentifiableError)
from fnsi_lab.ident.core.io import IdentInput, select_channels
from fnsi_lab.ident.refine.parameter_search import (DEFAULT_SEARCH_ORDER, ParameterSearchResult,
                                             estimate_basis_parameters, has_unknown_parameters)
from fnsi_lab.ident.core.periodic import FrequencyData, prepare_frequency_data, with_basis
from fnsi_lab.ident.core.spline import needs_knots, resolve_knots
from fnsi_lab.progress import Progress

__all__ = ["IdentSession", "prepare_session", "apply_recording_truth", "no_excited_line",
           "refused_search_evidence", "linear_answer_evidence"]


@dataclass
class IdentSession:
    """Everything prepared before an order is chosen.

    Attributes
    ----------
    config : IdentConfig
        The configuration actually used (truth values filled in for simulated recordings).
    input : IdentInput
        The selected channels.
    data : FrequencyData
        Spectra of the processed lines.
    weighted : bool
        Noise-weighted SVD and B, D least squares.
    d_zero : bool
        ``D = 0`` in the least squares.
    timings_s : dict
        Seconds per stage.
    parameter_search : ParameterSearchResult or None
        The estimate of the basis parameters left to the data (``clearances: auto``...);
        ``config.nonlinearities`` then hold the estimated values.
    warnings : list of str
        Everything a user should read about the data (steady state, truth mismatch...).
    evidence : dict
        Decisions taken from the data on the way (``time_base_choice``), copied to the JSON.
    refused_beside : tuple of str
        Elements the parameter search refused while searched beside another element with
        unknown parameters, which the search kept (:func:`ident.pipeline.identify_request`
        searches the first on its own when the kept ones leave no coefficient determined).
    """

    config: IdentConfig
    input: IdentInput
    data: FrequencyData
    weighted: bool
    d_zero: bool
    timings_s: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    evidence: dict = field(default_factory=dict)
    parameter_search: ParameterSearchResult | None = None
    cache: dict = field(default_factory=dict, repr=False)
    refused_beside: tuple[str, ...] = ()


def apply_recording_truth(cfg: IdentConfig, truth: Mapping | None) -> tuple[IdentConfig, list[str]]:
    """Fill missing ``truth`` coefficient values from a simulated recording's truth.

    Only the known coefficient values (for ``error_percent``) are taken; basis parameters
    (clearances, exponents) are never copied. Returns the updated config and warnings for
    clearances that differ from the truth (the basis would then not match the simulated
    element).
    """
    notes: list[str] = []
    if not truth or not isinstance(truth.get("nonlinearities"), list):
        return cfg, notes
    by_name = {t.get("name"): t for t in truth["nonlinearities"] if isinstance(t, dict)}
    nls = []
    for nl in cfg.nonlinearities:
        t = by_name.get(nl.name)
        if t is None:
            nls.append(nl)
            continue
        coefs = t.get("coefficients", {})
        keys = {"trilinear": ["neg", "pos"], "polynomial": ["k"], "quadratic_damping": ["c"],
                "coulomb": ["f"]}.get(nl.kind, list(coefs))
        if (nl.truth is None and all(k in coefs for k in keys)
                and len(keys) == len(nl.coefficient_names)):
            nl = replace(nl, truth=tuple(float(coefs[k]) for k in keys))
        given = [float(x) for x in t.get("clearances", [])]
        mine = {"trilinear": list(nl.clearances), "bilinear": [nl.clearance]}.get(nl.kind)
        if (mine is not None and given and not nl.unknown   # 'auto': estimated, compared later
                and all(isinstance(m, (int, float)) for m in mine)
                and not np.allclose(mine, given, rtol=1e-9, atol=0)):
            notes.append(f"nonlinearity {nl.name!r}: clearances {plain.names(mine)} differ from "
                         f"the recording's truth {plain.names(given)}")
        nls.append(nl)
    return replace(cfg, nonlinearities=tuple(nls)), notes


def prepare_session(inp: IdentInput, cfg: IdentConfig, *, search_order: int | None = None,
                    select_search_order: bool = False, progress: Any = None,
                    motion_for: Sequence[Nonlinearity] = (),
                    basis_oversample: int | None = None,
                    refused_as_linear: bool = False,
                    search: ParameterSearchResult | None = None) -> IdentSession:
    """Select the configured channels and build the frequency data.

    Basis parameters left to the data (``clearances: auto``, ``exponent: auto``...) are
    estimated here, before any identification (:mod:`ident.refine.parameter_search`), at
    ``search_order`` (default the config's ``order``, else 30); with
    ``select_search_order`` that is the largest order, and the information criterion
    picks the order of the search (docs/ident.md, "Unknown basis parameters").
    ``motion_for`` keeps the averaged motion of more elements' channels in ``data.motion``
    (:mod:`ident.locate` evaluates candidate locations on it); ``basis_oversample``
    overrides the config's.

    When the data cannot tell those parameters (the search refuses,
    :class:`ident.errors.NotIdentifiableError`), ``refused_as_linear`` leaves the elements
    with unknown parameters out instead of raising: the session is then the linear one (or
    keeps the fully given elements), and ``evidence["nonlinear_vs_linear"]`` says which
    elements were left out and why (docs/ident.md, "When the data cannot tell").
    ``search``: a search of these elements made before (a search result taking another
    minimum, :meth:`ParameterSearchResult.taking_alternative`): its basis is used and no
    search is run.

    Raises
    ------
    IdentError
        Channels missing, band outside the data, too few periods, ... (one line each).
    NotIdentifiableError
        A basis parameter the data cannot tell (without ``refused_as_linear``).
    """
    t0 = time.perf_counter()
    inp = select_channels(inp, outputs=cfg.outputs, inputs=[i.name for i in cfg.inputs] or None)
    for k, spec in enumerate(cfg.inputs):   # a misspelt driving point, basis or not
        if spec.driving_point is not None and spec.driving_point not in inp.output_channels:
            from fnsi_lab.ident.errors import ChannelError

            raise ChannelError(f"{cfg.file or 'config'}: inputs[{k}].driving_point "
                               f"{spec.driving_point!r} is not an output (outputs: "
                               f"{', '.join(inp.output_channels)})")
    cfg, truth_notes = apply_recording_truth(cfg, inp.truth)
    nyquist = inp.sample_rate_hz / 2
    if cfg.band_hz[1] > nyquist:  # the band's upper edge included: no line exists there
        where = "starts" if cfg.band_hz[0] >= nyquist else "ends"
        raise IdentError(f"band_hz {plain.band_hz(cfg.band_hz)} {where} above the Nyquist frequency "
                         f"{nyquist:g} Hz of the data (fs {inp.sample_rate_hz:g} Hz); "
                         f"lower band_hz to at most {nyquist:g} Hz")
    if cfg.output_quantity and inp.output_quantity and cfg.output_quantity != inp.output_quantity:
        # accelerations read as displacements give answers off by hundreds of percent
        where = inp.path or "the data"
        raise IdentError(f"{where}: the outputs are {inp.output_quantity} but the ident config "
                         f"says output_quantity: {cfg.output_quantity} (fix: make them agree, or "
                         "leave output_quantity out of the config)")
    quantity = cfg.output_quantity or inp.output_quantity or "displacement"
    unknown = has_unknown_parameters(cfg.nonlinearities)
    knots = needs_knots(cfg.nonlinearities)   # spline knot counts: placed on the motion
    def prepare(basis: Sequence[Nonlinearity]) -> FrequencyData:
        return prepare_frequency_data(
            u=inp.u, y=inp.y, sample_rate_hz=inp.sample_rate_hz,
            samples_per_period=inp.samples_per_period,
            basis=() if unknown or knots else basis,
            motion_for=(tuple(basis) if unknown or knots else ()) + tuple(motion_for),
            band_hz=cfg.band_hz,
            transient_periods=(cfg.transient_periods if cfg.transient_periods is not None
                               else inp.transient_periods),
            output_quantity=quantity, output_names=inp.output_channels,
            input_names=inp.input_channels, excited_lines=inp.excited_lines,
            highpass_hz=cfg.highpass_hz, steady_state_tolerance=cfg.steady_state_tolerance,
            steady_periods=cfg.steady_periods,
            time_base=cfg.time_base, bilinear_period_s=cfg.bilinear_period_s,
            basis_oversample=basis_oversample or cfg.basis_oversample,
            integration_min_snr=cfg.integration_min_snr or None)

    evidence: dict[str, Any] = {}
    left_out: list[str] = []   # elements the data cannot tell, when others are kept
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IdentWarning)
        try:
            data = prepare(cfg.nonlinearities)
        except DeadBasisError as exc:   # only with a given basis: no search follows
            never = _never_acting(cfg.nonlinearities, exc) if refused_as_linear else ()
            if not never:
                raise
            kept = tuple(nl for nl in cfg.nonlinearities if nl.name not in dict(never))
            evidence["nonlinear_vs_linear"] = refused_search_evidence(
                cfg.nonlinearities, kept, never, test="the measured motion")
            if kept:   # else the statement is the answer's own line
                left_out.append(evidence["nonlinear_vs_linear"]["statement"])
            cfg = replace(cfg, nonlinearities=kept)
            caught.clear()   # the first pass's warnings named the elements left out
            data = prepare(kept)
    if not np.any(data.excited):  # poles fitted to undriven lines would be no answer
        raise NoExcitedLineError(no_excited_line(data))
    weighted = cfg.weighting != "none"
    if cfg.weighting == "noise" and data.noise_cov is None:
        if data.n_periods >= 2:  # ident.core.periodic.floor_noise: the spread is no noise
            raise IdentError(
                "weighting: noise has nothing to weight with: the period-to-period spread of "
                "every output is below the resolution of a 24-bit record (noise-free data, "
                "e.g. a simulation); use auto or none")
        raise IdentError("weighting: noise needs at least 2 steady-state periods (use auto or none)")
    if knots:
        cfg = replace(cfg, nonlinearities=resolve_knots(cfg.nonlinearities, data.motion))
        if not unknown:
            data = with_basis(data, cfg.nonlinearities)
    timings = {"prepare": time.perf_counter() - t0}
    beside: list[str] = []
    if unknown and search is not None:   # searched before: its parameters, no search
        cfg = replace(cfg, nonlinearities=tuple(search.basis))
        data = with_basis(data, cfg.nonlinearities)
    elif unknown:  # the one place where 'auto' basis parameters become numbers
        t1 = time.perf_counter()
        bar = Progress(2, "basis parameters", enabled=bool(progress))
        search, kept, refusals, beside = _search_or_leave_out(
            data, cfg.nonlinearities, leave_out=refused_as_linear,
            order=int(search_order or cfg.order or DEFAULT_SEARCH_ORDER),
            d_zero=cfg.d_zero_for(quantity), weighted=weighted,
            select_order=select_search_order, progress=lambda note: bar.update(1, note=note))
        if refusals:
            evidence["nonlinear_vs_linear"] = refused_search_evidence(
                cfg.nonlinearities, kept, refusals)
            if kept:   # else the statement is the answer's own line
                left_out.append(evidence["nonlinear_vs_linear"]["statement"])
        cfg = replace(cfg, nonlinearities=kept)
        data = with_basis(data, kept)
        timings["parameter_search"] = time.perf_counter() - t1
    return IdentSession(config=cfg, input=inp, data=data, weighted=weighted,
                        d_zero=cfg.d_zero_for(quantity), parameter_search=search,
                        timings_s=timings, evidence=evidence, refused_beside=tuple(beside),
                        warnings=list(inp.notes) + truth_notes + left_out
                        + [str(w.message) for w in caught]
                        + (list(search.warnings) if search is not None else []))


def no_excited_line(data: FrequencyData) -> str:
    """One line naming the processed band and where the excitation is."""
    lo, hi = (float(x) for x in data.band_hz)
    exc = data.excitation or {}
    where = ""
    if exc.get("band_hz"):
        a, b = exc["band_hz"]
        where = f"; the excitation's {exc.get('n_excited')} lines lie in {a:.4g}-{b:.4g} Hz"
    return (f"no excited line in the processed band {lo:g}-{hi:g} Hz{where} "
            "(fix: an ident config band_hz that covers them)")


def _search_or_leave_out(data: FrequencyData, nonlinearities: Sequence[Nonlinearity], *,
                         leave_out: bool, **search: Any
                         ) -> tuple[ParameterSearchResult | None, tuple[Nonlinearity, ...],
                                    list[tuple[str, str]], list[str]]:
    """The parameter search; with ``leave_out``, an element the data cannot tell is left out
    and the search is run again on the others (a stop never touched at a low level leaves
    the friction element beside it to be searched alone).

    Returns
    -------
    search : ParameterSearchResult or None
        The last search, None when no element with unknown parameters is left.
    basis : tuple of Nonlinearity
        The elements kept, their parameters estimated.
    refusals : list of (element name, reason)
        One per element left out (every element with unknown parameters, when a refusal
        does not name one).
    beside : list of str
        The elements left out that were refused beside another element with unknown
        parameters, which the search kept (empty when one of them was kept alone,
        :func:`_searched_alone`).
    """
    pending = tuple(nonlinearities)
    refusals: list[tuple[str, str]] = []
    beside: list[str] = []   # refused while searched beside another unknown element
    while has_unknown_parameters(pending):
        try:
            found = estimate_basis_parameters(data, pending, **search)
            return found, tuple(found.basis), refusals, beside
        except NotIdentifiableError as refusal:
            if not leave_out:
                raise
            unknown = [nl.name for nl in pending if nl.unknown]
            drop = [refusal.element] if refusal.element in unknown else unknown
            if len(unknown) > len(drop):
                beside += drop
            refusals += [(name, str(refusal)) for name in drop]
            pending = tuple(nl for nl in pending if nl.name not in drop)
    alone = _searched_alone(data, nonlinearities, pending, beside, **search)
    if alone is not None:
        found, name = alone
        return found, tuple(found.basis), [r for r in refusals if r[0] != name], []
    return None, pending, refusals, []


def _searched_alone(data: FrequencyData, nonlinearities: Sequence[Nonlinearity],
                    given: Sequence[Nonlinearity], beside: Sequence[str], **search: Any
                    ) -> tuple[ParameterSearchResult, str] | None:
    """The search of the first element refused beside another (``beside``, in the order
    refused) that the data tell when it is searched alone with the ``given`` elements, and
    its name; None when every one is refused alone too.

    Why: in a joint search one element can take up what the other explains and leave it
    nothing to tell (aircraft-like GVT at 55 N, another realisation, a Jenkins element and a
    stop both left to the data: the stop's clearance went to the bottom of its interval,
    in contact all the time, a linear spring, and the slip to the top; the slip was refused
    first, then the stop alone: the answer was the linear fit, where the Jenkins element
    alone is kept). Only when nothing with unknown parameters is left: the elements the
    combined search kept stand as they are.
    """
    if any(nl.unknown for nl in given):
        return None
    for name in beside:
        element = next(nl for nl in nonlinearities if nl.name == name)
        try:
            found = estimate_basis_parameters(data, (*given, element), **search)
        except NotIdentifiableError:
            continue
        others = plain.names([n for n in beside if n != name] or
                             [nl.name for nl in nonlinearities if nl.unknown and nl.name != name],
                             quote=True)
        return replace(found, warnings=[
            *found.warnings, f"{name!r} was searched again on its own and kept: searched "
            f"beside {others}, its parameters were refused, and {others} was refused on its "
            "own too (docs/ident.md, \"When the data cannot tell a basis parameter\")"]), name
    return None


def _never_acting(basis: Sequence[Nonlinearity], exc: DeadBasisError
                  ) -> list[tuple[str, str]]:
    """``(element name, reason)`` of the elements all of whose basis functions are zero on
    the data (``exc.dead``); empty when an element is zero on one side only (a clearance
    given on one side that the motion never closes: the configuration is to be mended, not
    guessed)."""
    dead = set(exc.dead)
    never, partly = [], False
    for nl in basis:
        zero = [n for n in nl.coefficient_names if n in dead]
        if zero and len(zero) < len(nl.coefficient_names):
            partly = True
        elif zero:
            never.append((nl.name, f"nonlinearity {nl.name!r} never acts on this record: its "
                          f"basis functions {plain.names(zero, quote=True)} are identically "
                          "zero on the measured motion (a clearance larger than the motion, or "
                          "wrong channels)"))
    return [] if partly else never


def refused_search_evidence(requested: Sequence[Nonlinearity], kept: Sequence[Nonlinearity],
                            refusals: Sequence[tuple[str, str]], *,
                            test: str = "parameter search") -> dict[str, Any]:
    """The answer's ``nonlinear_vs_linear`` when the parameter search refused: which
    elements were left out and why, in the nested test's keys (docs/ident.md).

    Parameters
    ----------
    requested : sequence of Nonlinearity
        The configured elements.
    kept : sequence of Nonlinearity
        Those identified all the same.
    refusals : sequence of (element name, reason)
        The search's refusal of each element left out, one line each.
    test : str
        What refused them, in words (the ``test`` key).
    """
    reasons = dict(refusals)
    left_out = [nl for nl in requested if nl.name in reasons]
    names = ", ".join(repr(nl.name) for nl in left_out)
    rest = (f"the answer keeps {', '.join(repr(nl.name) for nl in kept)}"
            if kept else "the answer is the linear fit")
    statement = (f"not identifiable from these data: "
                 f"{'; '.join(dict.fromkeys(reasons.values()))}; {names} left out, {rest}")
    out: dict[str, Any] = (linear_answer_evidence(test, statement) if not kept
                           else {"test": test, "decision": None, "statement": statement})
    out["refused"] = [{"name": nl.name, "kind": nl.kind, "channels": dict(nl.channels),
                       "parameters": [u.parameter for u in nl.unknown],
                       "reason": reasons[nl.name]} for nl in left_out]
    return out


def linear_answer_evidence(test: str, statement: str) -> dict[str, Any]:
    """``nonlinear_vs_linear`` of an answer that is the linear fit without a nested test
    (``test``: what decided it, in words), in the nested test's keys (docs/ident.md)."""
    return {"test": test, "decision": "linear", "statement": statement,
            "residual_nonlinear": None, "residual_linear": None, "statistic": None,
            "p_value": None, "linear_modes": None}
