"""The HTML report toolkit shared by the validate, diagnose and improve reports.

One look (the style sheet), one way to escape text, format numbers, lay out tables and
inline figures, and one way to draw a figure outside pyplot: each report builds its own
sections from these, so the three reports read alike and a change of style is made once.
Every page is self-contained (figures inlined as base64 PNG, no external files).
"""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

__all__ = ["CSS", "escape", "num", "table", "figure_with_file", "inline_figure", "breakable", "page", "new_figure",
           "save_figure"]

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:2em auto;max-width:980px;
color:#222;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.25em;margin-top:1.8em;border-bottom:1px solid #ddd}
p.what{color:#333;font-style:italic} table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right} th{background:#f3f3f3}
td.l,th.l{text-align:left} td:not(.l){white-space:nowrap} h3{font-size:1.08em;margin-top:1.4em} .pass{color:#176b1a;font-weight:bold} .fail{color:#b00020;font-weight:bold}
.flag{background:#fff3f3;border-left:4px solid #d33;padding:.5em 1em} figure{margin:1em 0}
figure img{max-width:100%;height:auto;border:1px solid #eee} figcaption{font-size:.9em;color:#555}
code{background:#f6f6f6;padding:0 .2em} details{margin:1em 0} summary{cursor:pointer;font-weight:bold} .small{font-size:.85em;color:#555}
"""


def escape(x) -> str:
    """``x`` as HTML text.

    >>> escape("K < 100 N m/rad")
    'K &lt; 100 N m/rad'
    """
    return html.escape(str(x))


def num(x, fmt="{:.2f}") -> str:
    """A number for a table cell; None and non-finite floats read as a dash.

    >>> num(97.456), num(float("nan")), num(0.001234, "{:.1e}")
    ('97.46', '–', '1.2e-03')
    """
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return fmt.format(x)


def table(header, rows, left=(0,), notes=None) -> str:
    """HTML table; ``left``: indices of left-aligned (text) columns, the others are numbers.
    ``notes``: per row, HTML for a full-width row under it (empty: none), for text too long
    for a column.

    >>> table(["signal", "gain (pp)"], [["EMG", "+0.31"]])
    '<table><tr><th class="l">signal</th><th class="">gain (pp)</th></tr><tr><td class="l">EMG</td><td class="">+0.31</td></tr></table>'
    """
    h = "".join(f'<th class="{"l" if i in left else ""}">{escape(c)}</th>' for i, c in enumerate(header))
    body = ""
    for k, r in enumerate(rows):
        body += "<tr>" + "".join(f'<td class="{"l" if i in left else ""}">{c}</td>' for i, c in enumerate(r)) + "</tr>"
        if notes and notes[k]:
            body += f'<tr class="note"><td></td><td class="l small" colspan="{len(header) - 1}">{notes[k]}</td></tr>'
    return f"<table><tr>{h}</tr>{body}</table>"


def figure_with_file(path: Path, caption: str) -> str:
    """A PNG inlined as a figure whose caption names its file under ``figures/`` (the
    validate report, which also keeps its figures as files).

    >>> import tempfile
    >>> png = Path(tempfile.mkdtemp()) / "torque.png"
    >>> fig = new_figure(4, 3)
    >>> _ = fig.add_subplot().plot([0, 1], [0, 1])
    >>> save_figure(fig, png)
    >>> html_ = figure_with_file(png, "Measured and predicted torque")
    >>> html_.startswith('<figure><img src="data:image/png;base64,'), "figures/torque.png" in html_
    (True, True)
    """
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{escape(caption)}" data-file="{escape(path.name)}">'
            f"<figcaption>{escape(caption)} (<code>figures/{escape(path.name)}</code>)</figcaption></figure>")


def inline_figure(path: Path, caption: str) -> str:
    """A PNG inlined as a figure with its caption (the diagnose and improve reports).

    >>> import tempfile
    >>> png = Path(tempfile.mkdtemp()) / "residual.png"
    >>> save_figure(new_figure(4, 3), png)
    >>> inline_figure(png, "Residual").endswith("<figcaption>Residual</figcaption></figure>")
    True
    """
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def breakable(text) -> str:
    """Escaped text that may wrap inside its long words (candidate names in notes), so that a
    table keeps to the page's width instead of scrolling sideways.

    >>> breakable("position_dependent_reflex_delay")
    '<span class="brk">position_dependent_reflex_delay</span>'
    """
    return f'<span class="brk">{html.escape(str(text))}</span>'


def page(title, body) -> str:
    """A self-contained HTML page in the validate report's style (images inline).

    >>> page("Diagnosis", "<h1>Diagnosis</h1>").startswith('<!DOCTYPE html><html lang="en">')
    True
    """
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><meta name="viewport" '
            f'content="width=device-width, initial-scale=1"><title>{html.escape(title)}</title>'
            f'<style>{CSS}.wide{{overflow-x:auto}}.brk{{overflow-wrap:anywhere}}</style></head><body>{body}</body></html>\n')


def new_figure(*size):
    """A figure outside pyplot (no global state, no GUI backend: renders with Agg); size in
    inches.

    >>> new_figure(9, 4).get_size_inches().tolist()
    [9.0, 4.0]
    """
    from matplotlib.figure import Figure

    return Figure(figsize=size)


def save_figure(fig, path):
    """Save ``fig`` as the reports do: tight layout, 100 dpi.

    >>> import tempfile
    >>> png = Path(tempfile.mkdtemp()) / "empty.png"
    >>> save_figure(new_figure(2, 2), png)
    >>> png.read_bytes()[:4]
    b'\\x89PNG'
    """
    fig.tight_layout()
    fig.savefig(path, dpi=100)
