"""``fnsi-lab ident``: identify a nonlinear model from a recording or an array file.

A thin layer over :func:`fnsi_lab.identify` (the one entry point, shared with the live
service, batch campaigns and the benchmarks): parse the options, call it, print a summary
and write the JSON result.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fnsi_lab import plain
from fnsi_lab import arguments as opt
from fnsi_lab.ident.errors import IdentError

EXAMPLES = """\
examples:
  fnsi-lab ident test.mcap --config smallsat39 --auto --json result.json
  fnsi-lab ident test.mcap --config ident.yaml --order 10
  fnsi-lab ident data.npz --config ident.yaml --auto --orders 2:20
  fnsi-lab ident data.mat --config ident.yaml --order 6 --max-order 20
  fnsi-lab ident rms55.mcap --config joint.yaml --auto --validation rms40.mcap --validation rms69.mcap
  fnsi-lab ident rms40.mcap rms55.mcap rms69.mcap --config joint.yaml --auto   # one model

INPUT: an fnsi-lab MCAP recording, or .npz/.mat with u (n_samples, n_inputs),
y (n_samples, n_outputs), fs, optional N, channels, input_channels (see docs/ident.md).
Without --config: the excited band, the driving point where the recording's channel
table puts an output at the force's node and direction (else give it in the config:
inputs: [{name: F, driving_point: X}]), and for simulated recordings the basis functions
of the recording's truth. Gaps or exponents you do not know: 'clearances: auto' (or per side
[low, high]) and 'exponent: auto' in the YAML are estimated from the data first, printed
with their uncertainty and the model error against them (docs/ident.md).
"""


def add_ident_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``ident`` options to ``parser``."""
    parser.add_argument("input", type=opt.INPUT, metavar="INPUT", nargs="+",
                        help="recording (.mcap) or array file (.npz, .mat); several: records of "
                             "one structure (force levels), identified together")
    parser.add_argument("--config", type=opt.INPUT, default=None, metavar="IDENT.yaml",
                        help="ident configuration (band, channels, nonlinearities; docs/ident.md); "
                             "a bare name such as smallsat39 picks a packaged example")
    parser.add_argument("--order", type=opt.ORDER, default=None, metavar="N",
                        help="model order (overrides the config's 'order')")
    parser.add_argument("--max-order", type=opt.MAX_ORDER, default=None, metavar="N",
                        help="largest order of the decomposition (default: the order)")
    parser.add_argument("--block-rows", type=opt.BLOCK_ROWS, default=None, metavar="I",
                        help="block rows i (default from outputs and max order)")
    parser.add_argument("--json", dest="json_out", default=None, metavar="OUT.json",
                        help="write the result as JSON ('-' for stdout)")
    parser.add_argument("--suggest", default=None, metavar="OUT.yaml",
                        help="kind: spline elements (or nonlinearities: auto): write the config "
                             "with each replaced by the parametric form its curve suggests "
                             "('-' for stdout; docs/discovery.md)")
    parser.add_argument("--validation", type=opt.INPUT, action="append", default=None,
                        metavar="RECORD",
                        help="another record of the structure (e.g. the force level below "
                             "and the one above; repeat for several): the nonlinear terms are "
                             "kept only if the model predicts each at least as well as the "
                             "linear fit (docs/ident.md)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing --json / --suggest file")
    parser.add_argument("--quiet", action="store_true", help="no summary on stdout")
    parser.add_argument("--blas-threads", type=opt.BLAS_THREADS, default=1, metavar="T",
                        help="OpenBLAS threads (default 1: the many small solves of the order "
                             "sweep run 10-40x slower multi-threaded on a shared small machine)")
    g = parser.add_argument_group("robust pipeline (docs/robust.md)")
    g.add_argument("--auto", action="store_true",
                   help="choose the order (information criterion), classify poles (MDI + "
                        "stabilisation) and remove the spurious ones (model reduction)")
    g.add_argument("--orders", type=opt.ORDERS, default=None, metavar="FIRST:LAST",
                   help="order sweep of --auto: 2:60 (default, or the config's auto.orders), "
                        "2:60:2 or 4,6,8")
    g.add_argument("--reduce-at", type=opt.REDUCE_AT, default=None, metavar="N",
                   help="apply the MDI and the reduction at order N (default: the IC order)")


def register(subparsers) -> None:
    """Add the ``ident`` subcommand to the ``fnsi-lab`` dispatcher."""
    p = subparsers.add_parser(
        "ident", help="identify a nonlinear model (FNSI) from a recording or array file",
        description="Frequency-domain nonlinear subspace identification (FNSI): one QR and "
                    "one SVD, the model at the requested order (--order) or the robust "
                    "automatic pipeline (--auto), its poles and the nonlinear coefficients.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_ident_arguments(p)
    p.set_defaults(handler=run_ident)


def _print_summary(res: dict, out=None) -> None:
    """Summary of a fixed-order result (the JSON dict)."""
    out = out or sys.stdout
    print(f"order {res['order']} (block rows {res['block_rows']}, "
          f"{'weighted' if res['weighted'] else 'unweighted'}, {res['n_lines']} lines, "
          f"relative model error {res['relative_model_error']:.3g})", file=out)
    nvl = res.get("nonlinear_vs_linear") or {}
    if nvl.get("decision") == "linear" and nvl.get("linear_modes") is not None:
        print("  poles of the nonlinear model (not the answer: its modes are the linear fit's, "
              "see 'nonlinear vs linear' below):", file=out)
    for i, pl in enumerate(res["poles"], 1):
        st = "" if pl["stable"] else "  UNSTABLE"
        print(f"  mode {i:2d}: {pl['frequency_hz']:10.4f} Hz  damping {100 * pl['damping_ratio']:7.3f} %{st}",
              file=out)
    for c in res["coefficients"]:
        err = (f"  error {c['value_error_percent']:+.3f} %"
               if c.get("value_error_percent") is not None else "")
        unit = f" {c['unit']}" if c.get("unit") else ""
        print(f"  {c['name']}: value {c['value']:.6g}{unit}{err} (LS; mean Re "
              f"{c['mean_real']:.6g}, std {c['std_real']:.3g}, log10|Re/Im| "
              f"{c['log10_re_im']:.2f}){verdict_text(c)}", file=out)
    for w in res["warnings"]:
        print(f"  warning: {w}", file=out)


def verdict_text(coefficient: dict, *, reason: bool = True) -> str:
    """``'  [identified]'`` or ``'  [weak: reason]'`` for a coefficient dict (docs/ident.md)."""
    v = coefficient.get("verdict")
    if not v:
        return ""
    why = coefficient.get("verdict_reason")
    return f"  [{v}: {why}]" if reason and why and v != "identified" else f"  [{v}]"


def objective_sketch(values, objective, width_levels: str = "_.-=+*#") -> str:
    """One-line text plot of an objective profile (log scale, low = good).

    Parameters
    ----------
    values, objective : array_like, shape (n_points,)
        Parameter values (sorted) and the relative model error at each.

    Returns
    -------
    str
        ``'0.0912 _.-=#... 4.47'``: one character per point, the lowest ``_``.
    """
    v = np.log10(np.maximum(np.asarray(objective, float), 1e-300))
    ok = np.isfinite(v)
    if not ok.any():
        return ""
    lo, hi = float(v[ok].min()), float(v[ok].max())
    span = hi - lo if hi > lo else 1.0
    n = len(width_levels) - 1
    chars = "".join(width_levels[int(round(n * (x - lo) / span))] if np.isfinite(x) else "?"
                    for x in v)
    return f"{values[0]:.4g} {chars} {values[-1]:.4g}"


def _print_parameter_summary(res: dict, out=None) -> None:
    """Basis parameters estimated from the data (the JSON dict's ``nonlinearities``)."""
    out = out or sys.stdout
    search = res.get("parameter_search")
    if not search:
        return
    misfit = search.get("noise_misfit")
    fit = (f"; residual {misfit:.3g}x the noise" if misfit is not None and np.isfinite(misfit)
           else "")
    print(f"basis parameters from the data (order {search['order']}, "
          f"{search['n_evaluations']} fits, {search['timings_s']['total']:.2f} s{fit}):", file=out)
    oe = res.get("output_error") or {}
    refined = ({(p["name"], p["parameter"]): p for p in oe.get("parameters") or []}
               if oe.get("applied") else {})
    for nl in res["nonlinearities"]:
        for par, ob in (nl.get("objective") or {}).items():
            side = 0 if par in ("g_neg", "clearance") else 1
            own = par in ("exponent", "offset", "slip")     # stored under its own name
            value = nl[par] if own else nl["clearances"][side]
            std = (nl.get(f"{par}_std") if own
                   else (nl.get("clearance_std") or [None, None])[side])
            unc = f" +- {std:.2g}" if std is not None and np.isfinite(std) else ""
            if (nl["name"], par) in refined:
                unc += (f" (output-error refinement; the search gave "
                        f"{refined[(nl['name'], par)]['start']:.6g})")
            err = ""
            errs = nl.get("clearance_error_percent")
            if errs and not own:
                e = errs[0 if par in ("g_neg", "clearance") else 1]
                err = f" (error {e:+.3f} % vs the recording's truth)" if e is not None else ""
            print(f"  {nl['name']} {par} = {value:.6g}{unc}{err}", file=out)
            what = ("noise-weighted model error, corrected for the motion noise,"
                    if ob.get("noise_corrected") else ob.get("quantity") or "model error")
            profile = np.array([np.nan if v is None else v for v in ob["relative_model_error"]],
                               float)   # null: no opinion at that value (JSON has no NaN)
            low = f"{np.nanmin(profile):.3g}" if np.isfinite(profile).any() else "-"
            print(f"    {what} vs {par}: {objective_sketch(ob['values'], profile)}"
                  f"  (min {low})", file=out)


def _print_refinement(res: dict, out=None) -> None:
    """The output-error refinement (the JSON dict's ``output_error``): whether it ran, how it
    went, and the answer it gave."""
    out = out or sys.stdout
    oe = res.get("output_error")
    if not oe:
        return
    if not oe.get("applied"):
        print(f"output-error refinement: not run ({oe.get('reason') or 'no reason recorded'})",
              file=out)
        return
    dropped = oe.get("dropped_modes_hz") or []
    left_out = oe.get("left_out") or []
    print(f"output-error refinement (docs/ident.md): misfit {oe['misfit_start']:.3g} -> "
          f"{oe['misfit']:.3g} noise variances in {oe['iterations']} steps"
          + (f"; modes it dropped: {', '.join(f'{f:.4g} Hz' for f in dropped)}" if dropped
             else "")
          + ("; split modes left out: " + ", ".join(
              f"{m['frequency_hz']:.4g} Hz (would explain {m['evidence']:.2g} of "
              f"{m['threshold']} noise variances)" for m in left_out) if left_out else "")
          + "; the answer:", file=out)
    for c in res["coefficients"]:
        err = (f"  error {c['value_error_percent']:+.3f} %"
               if c.get("value_error_percent") is not None else "")
        unit = f" {c['unit']}" if c.get("unit") else ""
        print(f"  {c['name']}: value {c['value']:.6g}{unit}{err}{verdict_text(c)}", file=out)


def _print_output_refit(res: dict, out=None) -> None:
    """The kept nonlinear answer's output matrices refit on its own motion (the JSON's
    ``output_refit``; docs/ident.md): one line when it ran."""
    refit = res.get("output_refit")
    if not refit:
        return
    print(f"output matrices (docs/ident.md, own-motion refit): {refit['reason']}",
          file=out or sys.stdout)


def _print_auto_summary(res: Any, out=None, warnings: list | tuple = (),
                        refined: bool = False, units: dict | None = None,
                        fates: list | None = None, result_json: dict | None = None) -> None:
    """Summary of a robust-pipeline result (:class:`~fnsi_lab.ident.robust.auto_result.AutoResult`);
    ``refined``: the answer is the output-error refinement's (printed after); ``units``:
    the JSON's ``units`` block (coefficient units); ``fates``: each MDI row's fate
    (:mod:`ident.robust.pole_fate`, the JSON's ``mdi[].fate``); ``result_json``: the result,
    whose ``coefficients`` and ``nonlinear_vs_linear`` decide what is printed as the answer
    (the terminal never says another value or verdict than the file)."""
    out = out or sys.stdout
    coefficient_units = (units or {}).get("coefficients") or {}
    ic = res.information_criterion
    band = ic.band if isinstance(ic.band, str) else plain.band_hz(ic.band)
    print(f"information criterion ({ic.criterion}, band {band}): order {res.selected_order}; "
          f"{int(np.sum(~ic.stable))} of {ic.orders.size} orders unstable", file=out)
    print(f"MDI at order {res.mdi_order} ({res.options.mdi_norm}, band "
          f"{plain.band_hz(res.modal_dominancy.band_hz)}): "
          f"confidence {res.confidence['level']}", file=out)
    print("  " + res.confidence["statement"], file=out)
    gone = (((result_json or {}).get("nonlinear_vs_linear") or {}).get("modes") or {}).get(
        "left_out") or []
    if gone:   # the count above is the nonlinear model's; the answer lists fewer
        print(f"  {len(gone)} of them left out of the answer's modes, without physical "
              "evidence (" + ", ".join(f"{m['frequency_hz']:.4g} Hz" for m in gone)
              + "; nonlinear vs linear below)", file=out)
    from fnsi_lab.ident.robust.pole_fate import fate_label, pole_fates

    rows = res.mdi_table()
    fates = fates or pole_fates(rows, res.confidence)
    for row, fate in zip(rows, fates):
        if not row["in_band"]:
            continue
        print(f"  {row['frequency_hz']:9.3f} Hz  {100 * row['damping_ratio']:6.2f} %  "
              f"MDI {row['mdi_h2']:9.3g}  {row['stabilisation'] or '':9s} "
              f"{fate_label(fate)}", file=out)
    if res.reduced is not None:
        print(f"reduced model: order {res.reduced.order}", file=out)
    answer = "reduced" if res.final == "reduced" else "full"
    doc = result_json or {}
    linear = (doc.get("nonlinear_vs_linear") or {}).get("decision") == "linear"
    statement = str((doc.get("nonlinear_vs_linear") or {}).get("statement") or "")
    final = {c["name"]: c for c in doc.get("coefficients") or []}
    which = f"the {answer} model at order {res.final_model.order}" + (
        f" ({res.final_reason or 'the reduction did not make the coefficients more consistent'})"
        if res.reduced is not None and answer == "full" else "")
    if linear:
        kept = f"its nonlinear model: {which}" if doc.get("coefficients") else \
            "no nonlinear element kept"
        print(f"answer: the linear fit at order {doc.get('order')} ({kept}; nonlinear vs "
              "linear below)", file=out)
    else:
        print(f"answer: {which}", file=out)
    rows = [("selected", "selected")]
    if res.mdi_order != res.selected_order or answer == "full":
        rows.append((f"order {res.mdi_order}" if res.mdi_order != res.selected_order
                     else "full", "full"))
    rows.append(("reduced", "reduced"))
    printed: list[list] = []
    for label, key in rows:
        values = [c["value"] for c in res.coefficients.get(key) or []]
        if key != answer and values in printed:
            continue                         # the same model under another name
        printed.append(values)
        for c in res.coefficients.get(key) or []:
            err = (f"  error {c['value_error_percent']:+.3f} %"
                   if c.get("value_error_percent") is not None else "")
            mark = ""
            if key == answer:
                if not refined or linear:   # the file's own value and verdict (refined:
                    c = {**c, **{k: v for k, v in final.get(c["name"], {}).items()   # below)
                                 if k in ("value", "verdict", "verdict_reason")}}
                mark = (" <- the nonlinear model's (the answer is the linear fit)" if linear
                        else " <- answer")
                if linear:
                    c = {**c, "verdict_reason": _once(c.get("verdict_reason"), statement)}
            if mark and refined and not linear:
                mark = " <- FNSI's answer, refined below"
            unit = coefficient_units.get(c["name"], "")
            unit = f" {unit}" if unit else ""
            verdict = verdict_text(c, reason=bool(mark))
            if linear and not mark and verdict:   # not the file's verdict: the answer's is
                verdict = verdict[:-1] + " on its own]"
            print(f"  {label} {c['name']}: value {c['value']:.6g}{unit}{err} (LS; mean Re "
                  f"{c['mean_real']:.6g}, std {c['std_real']:.3g}){mark}{verdict}", file=out)
    for w in warnings:
        print(f"  warning: {w}", file=out)


def _once(reason: str | None, statement: str) -> str | None:
    """A coefficient's verdict reason without the nested test's statement in front (the
    summary prints that statement once, under "nonlinear vs linear"; the JSON keeps it)."""
    if not reason or not statement or not reason.startswith(statement):
        return reason
    return "not kept, see nonlinear vs linear below" + reason[len(statement):]


def _print_nested(res: dict, out=None) -> None:
    """The nonlinear answer against the linear fit (the JSON dict's ``nonlinear_vs_linear``)."""
    out = out or sys.stdout
    nvl = res.get("nonlinear_vs_linear")
    if not nvl:
        return
    print(f"nonlinear vs linear: {nvl['statement']}", file=out)
    before = nvl.get("before_reduction")
    if before:
        print(f"  the model before the reduction (order {before['order']}), tested too: "
              f"{before['statement']}", file=out)
    if nvl.get("linear_modes") is None:
        return
    modes = nvl["linear_modes"]
    print(f"  linear fit (order {nvl['order_linear']}): {len(modes)} modes "
          + ", ".join(f"{m['frequency_hz']:.4g} Hz ({100 * m['damping_ratio']:.2g} %)"
                      for m in modes), file=out)


def run_ident(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab ident``; returns the exit status."""
    import fnsi_lab
    from fnsi_lab.outputs import check_output_path, write_json

    # every option before any work: their relations (--max-order >= --order), the output
    opt.check_order_options(order=args.order, max_order=args.max_order,
                            block_rows=args.block_rows, reduce_at=args.reduce_at, prefix="--")
    if args.json_out != "-":  # '' is refused there, not taken for "no file"
        if args.json_out is not None:
            check_output_path(args.json_out, force=args.force, option="--json",
                              inputs=[*args.input, args.config, *(args.validation or [])])
    if args.auto and args.order is not None:
        raise IdentError("--order and --auto: give one (--auto chooses the order; --orders "
                         "FIRST:LAST limits its sweep)")
    suggest = getattr(args, "suggest", None)
    if suggest is not None and suggest != "-":
        if args.json_out not in (None, "-") and (
                Path(suggest).resolve() == Path(args.json_out).resolve()):
            raise IdentError(f"--suggest and --json both name {suggest}: one file cannot hold "
                             "the YAML and the JSON (fix: give two names)")
        check_output_path(suggest, force=args.force, option="--suggest",
                          inputs=[*args.input, args.config, *(args.validation or [])])
    if suggest == "-" and args.json_out == "-":
        raise IdentError("--suggest - and --json -: only one of them can go to stdout")
    if getattr(args, "blas_threads", 0) and args.blas_threads > 0:
        from fnsi_lab.blas import limit_blas_threads

        limit_blas_threads(args.blas_threads)
    config = fnsi_lab.load_config(args.config) if args.config is not None else None
    source = args.input[0] if len(args.input) == 1 else list(args.input)
    if suggest is not None and not (config is not None and (
            config.nonlinearities_auto or any(nl.kind == "spline"
                                              for nl in config.nonlinearities))):
        raise IdentError("--suggest needs a kind: spline element (or nonlinearities: auto) in "
                         "the config: nothing to suggest from (fix: drop --suggest or add one; "
                         "docs/discovery.md)")
    if not args.auto:
        order = args.order if args.order is not None else (config.order if config else None)
        if order is None:
            raise IdentError("no model order: give --order N (or 'order:' in the config), "
                             "or --auto for the robust pipeline")
        result = fnsi_lab.identify(source, config, order=order, max_order=args.max_order,
                                   block_rows=args.block_rows, validation=args.validation)
    else:
        show = not args.quiet and args.json_out != "-" and suggest != "-"
        result = fnsi_lab.identify(source, config, orders=args.orders or None,
                                   reduce_at=args.reduce_at, block_rows=args.block_rows,
                                   progress=show, validation=args.validation)
    res = result.to_json()
    if not args.quiet and args.json_out != "-" and suggest != "-":
        if (res.get("periods") or {}).get("statement"):
            print(f"periods: {res['periods']['statement']}")
        _print_parameter_summary(res)
        refined = bool((res.get("output_error") or {}).get("applied"))
        if result.auto is not None:
            _print_auto_summary(result.auto, warnings=res["warnings"], refined=refined,
                                result_json=res,
                                units=res.get("units"),
                                fates=[r.get("fate") for r in res.get("mdi") or []] or None)
        else:
            _print_summary(res)
        _print_refinement(res)
        _print_nested(res)
        _print_output_refit(res)
        _print_curves(res)
    write_json(res, args.json_out, force=True)
    if suggest is not None:   # after the result: a suggestion never costs the JSON
        _write_suggestion(res, suggest)
    return 0


def _print_curves(res: dict, out=None) -> None:
    """``kind: spline`` results: each curve in a few numbers and the suggested config."""
    out = out or sys.stdout
    loc = res.get("localisation")
    if loc and loc.get("candidates"):   # nonlinearities: auto
        best = loc["candidates"][0]
        sig = best.get("significance")   # None (JSON null) for a Jenkins element's ranking
        word = "located" if best.get("verdict") == "located" else "nothing located; best"
        print(f"nonlinearities: auto: {word} {best['name']} ({best['verdict']}, score "
              f"{best['score']:.3g}" + (f", -log10 p {sig:.1f}" if sig is not None else "")
              + f"; {len(loc['candidates'])} candidates, form {loc.get('form', 'generic')}: "
              "the JSON's localisation)", file=out)
    curves = [c["curve"] for c in res.get("coefficients", []) if c.get("curve")]
    if not curves:
        return
    for c in curves:
        f, sd = np.asarray(c["force"], float), np.asarray(c["std"], float)
        i = int(np.argmax(np.abs(f)))
        print(f"{c['element']} ({c['argument']}): force curve over {c['x'][0]:.4g} .. "
              f"{c['x'][-1]:.4g}, largest {f[i]:.4g} +- {sd[i]:.2g} at {c['x'][i]:.4g} "
              f"({len(c['knots'])} knots; the curve and its band: coefficients[].curve)",
              file=out)
    for sgg in res.get("suggestions", []):
        print(f"  suggested form of {sgg['element']} ({sgg['argument']}): {sgg['kind']}"
              + "".join(f", {k} {_short(sgg[k])}" for k in ("clearances", "clearance", "side",
                                                   "exponent", "velocity_scale", "slip")
                          if k in sgg)
              + (f", coefficients {_short(sgg['values'])}" if "values" in sgg else "")
              + (f" ({sgg['reason']})" if "reason" in sgg else ""), file=out)
    text = (res.get("suggested_config") or {}).get("yaml")
    if text:
        print("suggested config (paste, or write it with --suggest OUT.yaml):", file=out)
        for line in text.splitlines():
            print(f"    {line}", file=out)


def _short(value: Any) -> str:
    """A suggestion's parameter in 4 significant digits (lists element-wise)."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _write_suggestion(res: dict, path: str) -> None:
    """Write the suggested config (YAML) of a spline identification."""
    from fnsi_lab.outputs import atomic_output

    text = (res.get("suggested_config") or {}).get("yaml")
    if not text:   # nonlinearities: auto located nothing: no element, no shape to suggest
        print(f"--suggest: nothing written to {path}: no element to suggest a form for "
              "(nonlinear vs linear above)", file=sys.stderr)
        return
    if path == "-":
        sys.stdout.write(text)
        return
    with atomic_output(path) as fh:
        fh.write(text)
