"""``fnsi-lab ident``: identify a nonlinear model from a recording or an array file.

Structure (so the robust pipeline can extend the same parser and handler):

- :func:`add_ident_arguments` adds the core options, then calls
  ``ident.auto.add_cli_arguments(parser)`` if that function exists (``--auto``,
  ``--orders``, ``--reduce-at``...);
- :func:`run_ident` builds an :class:`IdentSession` (config, input, frequency data) with
  :func:`prepare_session`, then gives ``ident.auto.run_cli(args, session)`` the first word
  if it exists (it returns an exit code, or None to fall through to the plain ``--order``
  path below);
- :func:`identify_order` and :func:`result_to_json` are the plain path's building blocks.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fnsi_lab.ident.coefficients import CoefficientSummary, nonlinear_coefficients, summarize_coefficients
from fnsi_lab.ident.config import IdentConfig, load_ident_config
from fnsi_lab.ident.errors import IdentError, IdentWarning
from fnsi_lab.ident.fnsi import (StateSpaceModel, SubspaceDecomposition, model_at_order,
                        steady_state_output, subspace_decomposition)
from fnsi_lab.ident.io import IdentInput, load_input, select_channels
from fnsi_lab.ident.periodic import FrequencyData, prepare_frequency_data

EXAMPLES = """\
examples:
  fnsi-lab ident test.mcap --config ident.yaml --order 10
  fnsi-lab ident data.npz --config ident.yaml --order 6 --json result.json
  fnsi-lab ident data.mat --config ident.yaml --order 6 --max-order 20

INPUT: an fnsi-lab MCAP recording, or .npz/.mat with u (n_samples, n_inputs),
y (n_samples, n_outputs), fs, optional N, channels, input_channels (see docs/ident.md).
"""


def _robust_module():
    """``ident.auto`` if it exists (robust pipeline hooks), else None."""
    try:
        return importlib.import_module("fnsi_lab.ident.auto")
    except ModuleNotFoundError as exc:
        if exc.name == "fnsi_lab.ident.auto":
            return None
        raise


def add_ident_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``ident`` options to ``parser`` (core, then the robust pipeline's hook)."""
    parser.add_argument("input", metavar="INPUT", help="recording (.mcap) or array file (.npz, .mat)")
    parser.add_argument("--config", required=True, metavar="IDENT.yaml",
                        help="ident configuration (band, channels, nonlinearities; docs/ident.md); "
                             "a bare name such as smallsat39 picks a packaged example")
    parser.add_argument("--order", type=int, default=None, metavar="N",
                        help="model order (overrides the config's 'order')")
    parser.add_argument("--max-order", type=int, default=None, metavar="N",
                        help="largest order of the decomposition (default: the order)")
    parser.add_argument("--block-rows", type=int, default=None, metavar="I",
                        help="block rows i (default from outputs and max order)")
    parser.add_argument("--json", dest="json_out", default=None, metavar="OUT.json",
                        help="write the result as JSON ('-' for stdout)")
    parser.add_argument("--quiet", action="store_true", help="no summary on stdout")
    parser.add_argument("--blas-threads", type=int, default=1, metavar="T",
                        help="OpenBLAS threads (default 1: the many small solves of the order "
                             "sweep run 10-40x slower multi-threaded on a shared small machine)")
    mod = _robust_module()
    hook = getattr(mod, "add_cli_arguments", None) if mod is not None else None
    if hook is not None:
        hook(parser)


def register(subparsers) -> None:
    """Add the ``ident`` subcommand to the ``fnsi-lab`` dispatcher."""
    p = subparsers.add_parser(
        "ident", help="identify a nonlinear model (FNSI) from a recording or array file",
        description="Frequency-domain nonlinear subspace identification (FNSI): one QR and "
                    "one SVD, the model at the requested order, its poles and the nonlinear "
                    "coefficients (signed reciprocity).",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_ident_arguments(p)
    p.set_defaults(handler=run_ident)


@dataclass
class IdentSession:
    """Everything prepared before choosing an order (the robust pipeline starts here)."""

    config: IdentConfig
    input: IdentInput
    data: FrequencyData
    weighted: bool
    d_zero: bool
    timings_s: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def decomposition(self, max_order: int, block_rows: int | None = None) -> SubspaceDecomposition:
        """One QR + one SVD up to ``max_order`` (timed into ``timings_s['decomposition']``)."""
        t0 = time.perf_counter()
        dec = subspace_decomposition(self.data, max_order=max_order,
                                     block_rows=block_rows or self.config.block_rows,
                                     weighted=self.weighted)
        self.timings_s["decomposition"] = time.perf_counter() - t0
        return dec


def apply_recording_truth(cfg: IdentConfig, truth: dict | None) -> tuple[IdentConfig, list[str]]:
    """Fill missing ``truth`` values from a simulated recording's truth (same element name).

    Returns the updated config and warnings for clearances that differ from the truth (the
    basis would then not match the simulated element).
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
        if nl.truth is None and all(k in coefs for k in keys) and len(keys) == len(nl.coefficient_names):
            nl = replace(nl, truth=tuple(float(coefs[k]) for k in keys))
        g = [float(x) for x in t.get("clearances", [])]
        mine = {"trilinear": list(nl.clearances), "bilinear": [nl.clearance]}.get(nl.kind)
        if mine is not None and g and not np.allclose(mine, g, rtol=1e-9, atol=0):
            notes.append(f"nonlinearity {nl.name!r}: clearances {mine} differ from the "
                         f"recording's truth {g}")
        nls.append(nl)
    return replace(cfg, nonlinearities=tuple(nls)), notes


def _config_path(name: str) -> Path:
    """``name`` as given, or the packaged example of that name when no such file exists."""
    path = Path(name)
    if not path.exists() and path.parent == Path("."):
        from fnsi_lab.ident.config import packaged_config

        try:
            return packaged_config(name)
        except IdentError:
            return path      # let the loader report the missing file
    return path


def prepare_session(args: argparse.Namespace) -> IdentSession:
    """Load the config and INPUT, select channels, build :class:`FrequencyData`."""
    t0 = time.perf_counter()
    cfg = load_ident_config(_config_path(args.config))
    inp = load_input(args.input, samples_per_period=cfg.samples_per_period)
    inp = select_channels(inp, outputs=cfg.outputs,
                          inputs=[i.name for i in cfg.inputs] or None)
    cfg, truth_notes = apply_recording_truth(cfg, inp.truth)
    t1 = time.perf_counter()
    quantity = cfg.output_quantity or inp.output_quantity or "displacement"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IdentWarning)
        data = prepare_frequency_data(
            u=inp.u, y=inp.y, sample_rate_hz=inp.sample_rate_hz,
            samples_per_period=inp.samples_per_period, basis=cfg.nonlinearities,
            band_hz=cfg.band_hz,
            transient_periods=(cfg.transient_periods if cfg.transient_periods is not None
                               else inp.transient_periods),
            output_quantity=quantity, output_names=inp.output_channels,
            input_names=inp.input_channels, excited_lines=inp.excited_lines,
            highpass_hz=cfg.highpass_hz, steady_state_tolerance=cfg.steady_state_tolerance,
            time_base=cfg.time_base, bilinear_period_s=cfg.bilinear_period_s,
            basis_oversample=cfg.basis_oversample,
            integration_min_snr=cfg.integration_min_snr or None)
    t2 = time.perf_counter()
    weighted = cfg.weighting != "none"
    if cfg.weighting == "noise" and data.noise_cov is None:
        raise IdentError("weighting: noise needs at least 2 steady-state periods (use auto or none)")
    return IdentSession(config=cfg, input=inp, data=data, weighted=weighted,
                        d_zero=cfg.d_zero_for(quantity),
                        timings_s={"load": t1 - t0, "prepare": t2 - t1},
                        warnings=truth_notes + [str(w.message) for w in caught])


def identify_order(session: IdentSession, decomp: SubspaceDecomposition, order: int
                   ) -> tuple[StateSpaceModel, list[CoefficientSummary]]:
    """Model at ``order`` and its coefficient summaries (empty without nonlinearities)."""
    t0 = time.perf_counter()
    model = model_at_order(decomp, session.data, order, d_zero=session.d_zero)
    t1 = time.perf_counter()
    summaries: list[CoefficientSummary] = []
    if session.config.nonlinearities:
        spectra = nonlinear_coefficients(model, session.data, session.config.nonlinearities,
                                         driving_point=session.config.driving_points or None)
        summaries = summarize_coefficients(spectra)
    session.timings_s["model"] = t1 - t0
    session.timings_s["coefficients"] = time.perf_counter() - t1
    return model, summaries


def _finite(x: Any) -> Any:
    """JSON-safe float (NaN/inf -> None)."""
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def poles_to_json(model: StateSpaceModel) -> list[dict]:
    """Modes sorted by frequency: frequency_hz, damping_ratio, stable."""
    md = model.poles.modes()
    return [{"frequency_hz": _finite(f), "damping_ratio": _finite(z), "stable": bool(s)}
            for f, z, s in zip(md["frequency_hz"], md["damping_ratio"], md["stable"])]


def result_to_json(session: IdentSession, decomp: SubspaceDecomposition, model: StateSpaceModel,
                   summaries: list[CoefficientSummary]) -> dict:
    """The JSON result of the plain ``--order`` path."""
    data = session.data
    y_hat = steady_state_output(model, data)
    rel = float(np.sum(np.abs(data.Y - y_hat) ** 2) / np.sum(np.abs(data.Y) ** 2))
    p = model.poles
    return {
        "input": str(session.input.path), "config": session.config.file,
        "order": model.order, "block_rows": decomp.block_rows, "weighted": decomp.weighted,
        "d_zero": session.d_zero, "band_hz": list(data.band_hz), "time_base": data.time_base,
        "n_lines": data.n_lines, "n_excited_lines": int(data.excited.sum()),
        "n_periods": data.n_periods, "n_realizations": data.n_realizations,
        "outputs": list(data.output_names), "inputs": list(data.input_names),
        "output_quantity": data.output_quantity,
        "steady_state_error": _finite(data.steady_state_error),
        "stable": model.stable,
        "n_nyquist_poles": int(p.nyquist.sum()), "n_real_poles": int(p.real.sum()),
        "relative_model_error": _finite(rel),
        "singular_values": [_finite(s) for s in decomp.singular_values[:max(2 * model.order, 10)]],
        "poles": poles_to_json(model),
        "coefficients": [{k: (_finite(v) if isinstance(v, (float, int)) and not isinstance(v, bool)
                              else v) for k, v in s.to_dict().items() if k != "band"}
                         | {"band": {k: _finite(v) for k, v in s.band.items()}}
                         for s in summaries],
        "warnings": list(session.warnings),
        "timings_s": {k: round(float(v), 6) for k, v in session.timings_s.items()},
    }


def _print_summary(res: dict, out=None) -> None:
    out = out or sys.stdout
    print(f"order {res['order']} (block rows {res['block_rows']}, "
          f"{'weighted' if res['weighted'] else 'unweighted'}, {res['n_lines']} lines, "
          f"relative model error {res['relative_model_error']:.3g})", file=out)
    for i, pl in enumerate(res["poles"], 1):
        st = "" if pl["stable"] else "  UNSTABLE"
        print(f"  mode {i:2d}: {pl['frequency_hz']:10.4f} Hz  damping {100 * pl['damping_ratio']:7.3f} %{st}",
              file=out)
    for c in res["coefficients"]:
        err = f"  error {c['error_percent']:+.3f} %" if c.get("error_percent") is not None else ""
        print(f"  {c['name']}: mean {c['mean_real']:.6g} (std {c['std_real']:.3g}, "
              f"log10|Re/Im| {c['log10_re_im']:.2f}), LS {c['ls_value']:.6g}{err}", file=out)
    for w in res["warnings"]:
        print(f"  warning: {w}", file=out)


def write_json(obj: dict, target: str | None) -> None:
    """Write ``obj`` to ``target`` ('-' = stdout)."""
    if not target:
        return
    text = json.dumps(obj, indent=2, allow_nan=False)
    if target == "-":
        print(text)
        return
    try:
        Path(target).write_text(text + "\n", encoding="utf-8")
    except OSError as exc:
        raise IdentError(f"cannot write {target}: {exc}") from None


def run_ident(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab ident``; returns the exit status."""
    t0 = time.perf_counter()
    if getattr(args, "blas_threads", 0) and args.blas_threads > 0:
        from fnsi_lab.blas import limit_blas_threads

        limit_blas_threads(args.blas_threads)
    session = prepare_session(args)
    mod = _robust_module()
    hook = getattr(mod, "run_cli", None) if mod is not None else None
    if hook is not None:
        status = hook(args, session)
        if status is not None:
            return int(status)
    order = args.order if args.order is not None else session.config.order
    if order is None:
        raise IdentError("no model order: give --order N (or 'order:' in the config)")
    max_order = max(order, args.max_order or session.config.max_order or order)
    decomp = session.decomposition(max_order, args.block_rows)
    model, summaries = identify_order(session, decomp, order)
    session.timings_s["total"] = time.perf_counter() - t0
    res = result_to_json(session, decomp, model, summaries)
    if not args.quiet and args.json_out != "-":
        _print_summary(res)
    write_json(res, args.json_out)
    return 0
