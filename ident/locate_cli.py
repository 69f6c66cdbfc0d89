"""``fnsi-lab locate``: where is the structure nonlinear (docs/discovery.md, "Localisation").

A thin layer over :func:`fnsi_lab.locate` (the one entry point, shared with the API and
``nonlinearities: auto``): parse the options, call it, print the ranking and write the JSON.
"""

from __future__ import annotations

import argparse
import sys

EXAMPLES = """\
examples:
  fnsi-lab locate test.mcap --config smallsat39 --json where.json
  fnsi-lab locate test.mcap --config ident.yaml --candidates pairs
  fnsi-lab locate data.npz --config ident.yaml --candidates my-candidates.yaml
  fnsi-lab locate gvt.mcap --config linear.yaml --form generic   # no stick-slip element tried
  fnsi-lab locate rms40.mcap rms55.mcap rms69.mcap --config linear.yaml   # levels together

Candidates: each channel to ground and each pair of channels measured in the same
direction (names ending -X, _Y, :+Z...; every pair when the names carry none): 'all'
(default), 'channels' or 'pairs'; or a YAML/JSON file with a list such as
  - {channels: {NC2W-Z: 1, NC2B-Z: -1}}
  - {channels: {IP1-Z: 1}}
Every candidate gets a generic restoring force (stop-like and polynomial terms in the
relative displacement, damping and friction terms in the relative velocity); a screen ranks
them all by how much of the linear model's residual it explains, then the best few are
re-ranked by a full FNSI with those columns at each (--knots adds a spline). With --form
jenkins every candidate gets instead a Jenkins element (a spring in series with a slider:
friction with memory, which no function of the present motion draws), its slip from the
data, ranked by the information criterion against the linear model's; --form auto (the
default) does that first when there are at most 10 candidates and keeps it when it locates
one (a test on other periods than the fit), else the generic columns. The config's
nonlinearities are not used (they are the question); its band, inputs, outputs and order are.
"""


def register(subparsers) -> None:
    """Add the ``locate`` subcommand to the ``fnsi-lab`` dispatcher."""
    from fnsi_lab.ident import locate as loc

    p = subparsers.add_parser(
        "locate", help="rank candidate locations of a nonlinearity by the distortion they explain",
        description="Localisation of nonlinear elements: each candidate location (a channel "
                    "to ground, a pair of channels, or a list) is scored by how much of the "
                    "measured distortion a generic nonlinear restoring force there explains, "
                    "with an F-test of that reduction against the linear model.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", metavar="INPUT", nargs="+",
                   help="recording (.mcap) or array file (.npz, .mat); several: records of one "
                        "structure (force levels) judged together")
    p.add_argument("--config", default=None, metavar="IDENT.yaml",
                   help="ident configuration (band, inputs, outputs, order; docs/ident.md); a "
                        "bare name such as smallsat39 picks a packaged example")
    p.add_argument("--candidates", default="all", metavar="all|channels|pairs|FILE",
                   help="candidate locations (default all: channels to ground and pairs)")
    p.add_argument("--order", type=int, default=None, metavar="N",
                   help="linear model order (default: the config's, else chosen by the "
                        "minimum-description-length criterion)")
    p.add_argument("--refine", type=int, default=loc.REFINE_TOP, metavar="K",
                   help=f"re-rank the screen's best K by a full FNSI with the generic "
                        f"columns at each (default {loc.REFINE_TOP}; 0: the screen alone, a "
                        "filter rather than a verdict)")
    p.add_argument("--knots", type=int, default=loc.REFINE_KNOTS, metavar="K",
                   help=f"spline knots added to the refinement's generic columns (default "
                        f"{loc.REFINE_KNOTS}: none; 24 tells nearly equal motions apart better "
                        "on many outputs, at 3x the time)")
    p.add_argument("--form", choices=("auto", "generic", "jenkins"), default="auto",
                   help="force offered at each candidate: generic columns, a Jenkins element "
                        "(stick-slip friction), or auto (default: with at most "
                        f"{loc.AUTO_STICK_SLIP_CANDIDATES} candidates the Jenkins element "
                        "first, the generic columns when it locates nothing; docs/discovery.md)")
    p.add_argument("--top", type=int, default=10, metavar="N",
                   help="candidates printed (default 10; the JSON has them all)")
    p.add_argument("--json", dest="json_out", default=None, metavar="OUT.json",
                   help="write the ranking as JSON ('-' for stdout)")
    p.add_argument("--force", action="store_true", help="replace an existing --json file")
    p.add_argument("--quiet", action="store_true", help="no summary on stdout")
    p.set_defaults(handler=run_locate)


def print_ranking(loc, top: int = 10, out=None) -> None:
    """The ranking as text: one line per candidate."""
    out = out or sys.stdout
    t = loc.timings_s
    if loc.linear_criterion is not None:
        _print_stick_slip(loc, top, out)
        return
    print(f"{len(loc.candidates)} candidates, linear model order {loc.order}, "
          f"{'noise-weighted' if loc.weighted else 'unweighted (no noise estimate)'}; "
          f"screen {t.get('screen', 0):.2f} s, FNSI refinement of the best {loc.refined} "
          f"({'generic columns' + (f' + {loc.refine_knots}-knot spline' if loc.refine_knots else '')}) "
          f"{t.get('refine', 0):.2f} s", file=out)
    if loc.linear_misfit is not None:
        print(f"linear model's residual: {loc.linear_misfit:.3g} noise variances per value"
              + ("" if loc.linear_misfit < 3 else " (far above the noise: the tests compare "
                 "against model error, see docs/discovery.md)"), file=out)
    print(f"  {'rank':>4}  {'location':28s} {'stage':6s} {'score':>8s} {'-log10 p':>9s} "
          f"{'RSS/best':>9s}  verdict", file=out)
    for i, c in enumerate(loc.candidates[:top], 1):
        print(f"  {i:4d}  {c.name:28s} {c.stage:6s} {c.score:8.4f} {c.significance:9.1f} "
              f"{c.rss_ratio_to_best:9.3f}  {c.verdict}", file=out)
    best = loc.located
    if best is None:
        print("no location explains the distortion beyond the noise", file=out)
    else:
        print(f"located: {best.name} (channels {_vector(best.channels)}); characterise it "
              "with kind: spline there (docs/discovery.md)", file=out)
    for w in loc.warnings:
        print(f"  warning: {w}", file=out)


def _vector(channels) -> str:
    """A location vector as ``wing +1, payload -1``."""
    return ", ".join(f"{k} {v:+g}" for k, v in dict(channels).items())


def _print_stick_slip(loc, top: int, out) -> None:
    """The Jenkins ranking (``--form jenkins``, or ``auto`` when it located one): one line per
    candidate, the criterion against the linear model's."""
    print(f"{len(loc.candidates)} candidates, each with a Jenkins element (slip from the data), "
          f"ranked by the information criterion (mdl) against the linear model's "
          f"{loc.linear_criterion:.4g} (order {loc.order}); "
          f"{loc.timings_s.get('stick_slip', 0):.2f} s", file=out)
    print(f"  {'rank':>4}  {'location':28s} {'slip':>10s} {'criterion':>10s} {'vs linear':>10s}"
          "  verdict", file=out)
    for i, c in enumerate(loc.candidates[:top], 1):
        crit = (1 - c.score) * loc.linear_criterion
        slip = f"{c.slip:10.3g}" if c.slip is not None else f"{'-':>10s}"
        ratio = f"{loc.linear_criterion / crit:9.3g}x" if crit > 0 and c.slip is not None else f"{'-':>10s}"
        print(f"  {i:4d}  {c.name:28s} {slip} {crit if c.slip is not None else float('nan'):10.4g} "
              f"{ratio}  {c.verdict}" + ("" if not c.note else f" ({c.note})" if c.slip is not None
                                          else " (slip search refused: see the JSON's note)"),
              file=out)
    best = loc.located
    if best is None:
        print("nothing located (the verdicts and notes above say why)", file=out)
    else:
        print(f"located: {best.name} (channels {_vector(best.channels)}); a stick-slip "
              "element there explains the distortion far better than the linear model, which "
              "locates the nonlinearity but does not prove friction (a hardening spring is "
              "located so too): kind: spline there shows its shape, kind: jenkins, slip: auto "
              "tests a joint that sticks and slips (docs/discovery.md)", file=out)
    for w in loc.warnings:
        print(f"  warning: {w}", file=out)


def run_locate(args: argparse.Namespace) -> int:
    """Handler of ``fnsi-lab locate``; returns the exit status."""
    import fnsi_lab
    from fnsi_lab.blas import limit_blas_threads
    from fnsi_lab.outputs import check_output_path, write_json

    if args.json_out not in (None, "-"):
        check_output_path(args.json_out, force=args.force, option="--json",
                          inputs=[*args.input, args.config])
    limit_blas_threads(1)
    show = not args.quiet and args.json_out != "-"
    progress = (lambda note: print(f"  {note}", file=sys.stderr)) if show else None
    source = args.input[0] if len(args.input) == 1 else list(args.input)
    loc = fnsi_lab.locate(source, args.config, candidates=args.candidates,
                          order=args.order, refine=args.refine, knots=args.knots,
                          form=args.form, progress=progress)
    if show:
        print_ranking(loc, args.top)
    write_json(loc.to_json(), args.json_out, force=True)
    return 0
