"""The offline HTML reports' building blocks: matplotlib figures as inline SVG, tables,
the style sheet and number formatting, shared by the identification report
(:mod:`viewer.report`), the distortion analysis (:mod:`viewer.distortion`) and the campaign
report (:mod:`fnsi_lab.campaign.report`).
"""

from __future__ import annotations

import html
import io
from typing import Any, Mapping, Sequence

__all__ = ["CSS", "fmt_g", "new_figure", "svg", "html_table", "kv_table", "figure_html"]


def fmt_g(x: Any, digits: int = 6) -> str:
    """``x`` to ``digits`` significant digits, ``-`` for None."""
    return "-" if x is None else f"{x:.{digits}g}"


def new_figure(width: float = 9.0, height: float = 4.0, rows: int = 1, sharex: bool = False):
    """A matplotlib figure of ``rows`` stacked axes (inches) and the list of its axes."""
    # matplotlib's object API, not pyplot: no backend or global figure state is touched
    # (the caller may be a notebook with its own backend), nothing to close afterwards
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=sharex, squeeze=False)
    return fig, [a[0] for a in axes]


def svg(fig: Any) -> str:
    """A matplotlib figure as inline SVG text."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    text = buf.getvalue()
    return text[text.index("<svg"):]  # drop the XML prolog and DOCTYPE: inline in HTML


#: The style sheet of the offline reports (identification, analysis, campaign).
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1000px;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}td,th{border:1px solid #ddd;padding:3px 8px;text-align:left}
th{background:#f3f3f3}figure{margin:1em 0}figure svg{max-width:100%;height:auto}
.note{color:#666;font-size:.85em}code{background:#f5f5f5;padding:0 3px}
.failed{border:2px solid #d55e00;background:#fff3ec;padding:.6em 1em}
"""


def html_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """An HTML table of dict rows (the first row's keys are the columns), text escaped."""
    if not rows:
        return "<p class='note'>none</p>"
    cols = list(rows[0])
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(r.get(c, '')))}</td>" for c in cols)
                   + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def kv_table(rows: Sequence[tuple[str, Any]]) -> str:
    """A two-column quantity/value HTML table."""
    return html_table([{"quantity": k, "value": v} for k, v in rows])


def figure_html(fig: Any, caption: str, fig_id: str) -> str:
    """A figure as inline SVG with its caption, or a note when there is none."""
    if fig is None:
        return f"<p class='note'>{html.escape(caption)}: not available in this result.</p>"
    return (f"<figure id='{fig_id}'>{svg(fig)}<figcaption class='note'>"
            f"{html.escape(caption)}</figcaption></figure>")
