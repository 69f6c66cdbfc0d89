"""``fnsi-lab report RESULT.json | REC.mcap --out report.html``: the HTML report command.

Loading (:func:`load_report_input`) and writing (:func:`write_report`) are separate from the
page itself (:mod:`viewer.report`), so ``fnsi-lab run`` writes the same report from the
identification it has just made.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from fnsi_lab import arguments as opt
from fnsi_lab.errors import ConfigError, DataFileError


def load_report_input(source: str | Path, *, config: str | None = None, orders: str | None = None,
                      recording: str | None = None, harmonics: float = 1.0,
                      progress: bool = False) -> tuple[dict, dict | None]:
    """The identification JSON and the recording metadata behind a report.

    Parameters
    ----------
    source : path
        ``RESULT.json`` (``fnsi-lab ident --json``) or a recording ``REC.mcap``, identified
        here with the robust pipeline (``config``, ``orders``).
    config, orders : str, optional
        With a recording: identification config and order sweep (see
        :func:`fnsi_lab.identify`).
    recording : path, optional
        Recording whose metadata the report shows (default: the JSON's ``input`` when it is
        an existing ``.mcap``, or ``source`` itself).
    harmonics : float
        With a recording and no config: process the lines up to ``harmonics`` times the
        highest excited frequency (``fnsi-lab run`` uses 5; 1: the excited band).
    progress : bool
        Progress bar over the order sweep.

    Returns
    -------
    (dict, dict or None)
        The result JSON and the recording metadata.

    Raises
    ------
    DataFileError
        Missing or unreadable file, another command's JSON (locate, validate, analyse), or
        an unsupported file type.
    """
    import json

    src = Path(source)
    if not src.is_file():
        raise DataFileError(f"{src}: no such file; give a result .json (fnsi-lab ident --json) "
                            "or a recording .mcap")
    suffix = src.suffix.lower()
    if suffix == ".json":
        try:
            result = json.loads(src.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataFileError(f"{src}: not a readable JSON result ({exc}); write one with "
                                "`fnsi-lab ident REC.mcap --auto --json RESULT.json`") from None
        from fnsi_lab.result_kind import json_kind, not_an_ident_result

        if isinstance(result, dict) and json_kind(result) not in ("ident", None):
            raise DataFileError(str(not_an_ident_result(result, str(src))))  # locate, validate...
        if not isinstance(result, dict) or "order" not in result:
            raise DataFileError(f"{src}: not an identification result (no 'order'); write one "
                                "with `fnsi-lab ident REC.mcap --auto --json RESULT.json`")
        inp = str(result.get("input") or "")
        if recording is None and inp.lower().endswith(".mcap") and Path(inp).is_file():
            recording = inp
    elif suffix == ".mcap":
        result = _identify_recording(src, config, orders, harmonics, progress).to_json()
        recording = recording or str(src)
    else:
        raise DataFileError(f"{src}: unsupported file type {suffix!r}; give a result .json or "
                            "a recording .mcap")
    metadata = None
    if recording is not None:
        from fnsi_lab.daq.recording.reader import open_recording

        with open_recording(recording) as rec:
            metadata = dict(rec.metadata)
    return result, metadata


def _identify_recording(path: Path, config: str | None, orders: str | None,
                        harmonics: float, progress: bool) -> Any:
    """The robust pipeline on a recording; without a config, the same default as ``live``
    and ``run`` (excited band, the truth's basis, the driving point from the channel table)."""
    import fnsi_lab

    if config is not None:
        return fnsi_lab.identify(path, config, orders=orders, progress=progress)
    from fnsi_lab.daq.recording.reader import open_recording
    from fnsi_lab.ident.pipeline import default_config
    from fnsi_lab.inputs import load_input
    from fnsi_lab.replay.identifiers import driving_point

    with open_recording(path) as rec:
        outs, ins = rec.output_channels, rec.input_channels
        dp = outs[driving_point(outs, ins)].name if outs and ins else None
    inp = load_input(path)
    cfg = default_config(inp, harmonics=harmonics, driving_point=dp)
    return fnsi_lab.identify(inp, cfg, orders=orders, progress=progress)


def write_report(path: str | Path, result: dict, metadata: dict | None = None, *,
                 force: bool = False, title: str | None = None,
                 output: str | None = None) -> Path:
    """Render :func:`viewer.report.render_report` and write it atomically to ``path``.

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``force`` is False.
    ConfigError
        ``output`` is not an output channel of the result.
    """
    from fnsi_lab.outputs import atomic_output, check_output_path
    from fnsi_lab.viewer.report import render_report

    path = check_output_path(path, force=force)
    outputs = (result.get("frf") or {}).get("outputs") or []
    if output is not None and output not in outputs:
        raise ConfigError(f"--output {output!r} is not an output of this result",
                          field="--output", fix=f"one of {', '.join(outputs[:8])}"
                          + (" ..." if len(outputs) > 8 else ""))
    page = render_report(result, metadata, title=title or f"fnsi-lab report: {path.stem}",
                         output=output)
    with atomic_output(path) as fh:
        fh.write(page)
    return path


def _cmd_report(args: argparse.Namespace) -> int:
    from fnsi_lab.outputs import check_output_path

    src = Path(args.source)
    # --out "" is refused by the check, not read as "the default"
    out = args.out if args.out is not None else src.with_suffix(".html")
    out = check_output_path(out, force=args.force,  # before a long identification
                            inputs=[args.source, args.config, args.recording])
    result, metadata = load_report_input(src, config=args.config, orders=args.orders,
                                         recording=args.recording, harmonics=args.harmonics,
                                         progress=not args.quiet)
    write_report(out, result, metadata, force=args.force, title=args.title, output=args.output)
    print(f"report written to {out} (one file, opens offline in any browser)")
    from fnsi_lab.viewer.report import failure_reason

    failure = failure_reason(result)
    if failure:  # the page says so too; a script must not take it for a result
        print(f"fnsi-lab report: error: {src}: identification failed: {failure}; {out} was "
              "written and says so", file=sys.stderr)
        return 1
    return 0


def register(subparsers: Any) -> None:
    """Add the ``report`` subcommand."""
    p = subparsers.add_parser(
        "report", help="one self-contained HTML report of an identification",
        description="Write one HTML file (figures embedded, opens offline) with what a test "
                    "report needs: summary (the paper's Table 2 layout), mode table, "
                    "stabilisation diagram, information criterion, MDI per pole, coefficient "
                    "spectra with their statistics, measured / model / underlying-linear FRF "
                    "and the recording's metadata. From a result JSON, or from a recording "
                    "identified here with the robust pipeline.",
        epilog="examples:\n"
               "  fnsi-lab report result.json --out report.html   # from fnsi-lab ident --json\n"
               "  fnsi-lab report smallsat.mcap                   # identify, then smallsat.html\n"
               "  fnsi-lab report run.mcap --config rig.yaml --orders 2:40 --out run.html\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", type=opt.INPUT, metavar="RESULT.json|REC.mcap",
                   help="identification result (fnsi-lab ident --json) or a recording")
    p.add_argument("--out", metavar="REPORT.html",
                   help="output file (default: the source with .html)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--config", type=opt.INPUT, metavar="IDENT.yaml",
                   help="with a recording: identification config (default: the recording's "
                        "excited band and, for simulations, its truth's basis functions)")
    p.add_argument("--orders", type=opt.ORDERS, metavar="FIRST:LAST",
                   help="with a recording: order sweep (default the config's, else 2:60)")
    p.add_argument("--harmonics", type=opt.HARMONICS, default=1.0, metavar="K",
                   help="with a recording and no config: process the lines up to K times the "
                        "highest excited frequency (5 as `fnsi-lab run`; default 1: the "
                        "excited band)")
    p.add_argument("--recording", metavar="REC.mcap",
                   help="with a JSON: recording whose metadata to show (default: the JSON's "
                        "input when it is a recording)")
    p.add_argument("--output", metavar="CHANNEL",
                   help="output channel of the FRF figure (default: the driving point)")
    p.add_argument("--title", help="report title")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=_cmd_report)


__all__ = ["load_report_input", "write_report", "register"]
