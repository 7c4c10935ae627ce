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
           "save_figure", "GLOSSARY", "glossary", "command_line_syntax"]

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
.note{background:#f5f7fa;border-left:4px solid #9ab;padding:.5em 1em} section.answer{margin-bottom:1em}
section.answer h2{margin-top:.6em} p.lead{font-size:1.08em} details>summary{font-size:1.1em;padding:.3em 0;
border-bottom:1px solid #ddd} dl.gloss dt{font-weight:bold;margin-top:.5em} dl.gloss dd{margin-left:1.5em}
"""

#: Terms a report uses, in plain words (the reports link here instead of explaining
#: statistics in their main text). Term -> explanation.
GLOSSARY = {
    "VAF (variance accounted for)": "How much of the measured torque's variation the model reproduces, in percent: "
                                    "100 % is a perfect prediction, 0 % no better than the mean.",
    "RMSE": "Root-mean-square error: the typical size of the prediction error, in N m.",
    "held-out record": "Data the model was not fitted to (another trial, or a later stretch of the same session): "
                       "the honest judge of a model.",
    "95 % interval": "The range the value lies in with 95 % confidence, given these data. The stiffness and viscosity "
                     "intervals come from the least-squares fit with a covariance that respects correlated "
                     "residuals (HAC, heteroscedasticity and autocorrelation consistent); the reflex gain and threshold "
                     "intervals from refitting the reflex curve to many simulated copies of the data (parametric "
                     "bootstrap). Both are widened by a bound on the method's known bias.",
    "not determined by these data": "The interval spans most of the values the quantity could plausibly take: the "
                                    "data cannot tell it (for a reflex gain: cannot tell it from no reflex).",
    "identified range": "The positions (scheduling variable) the identification record covered; the model is "
                        "trusted inside it.",
    "FMU": "Functional Mock-up Unit: the model compiled for simulation tools (FMI standard).",
    "co-simulation": "The model FMU run in a loop with a simulated actuator that moves the ankle, as in a rig.",
    "causal form": "The model rewritten to use only past and present inputs, as a real-time loop needs.",
    "cross-validation": "Fitting on part of the data and scoring on the rest, in turn, so that every score is on "
                        "data the fit did not see.",
    "gain (pp)": "How many percentage points of held-out VAF a candidate adds.",
    "significant": "The gain is too large to be chance: its p-value (the probability of such a gain with no real "
                   "effect) is below the threshold, corrected for the number of candidates tried (Bonferroni), and "
                   "the gain is at least the minimum the report states.",
    "99 % band": "The range a correlation stays in by chance 99 % of the time when the residual does not depend on "
                 "that input.",
    "R²": "The share of one signal's variation another explains (0 to 1).",
}


def glossary(terms=None) -> str:
    """The glossary as a folded section with ``id="glossary"`` (``terms``: the keys of
    :data:`GLOSSARY` to include, default all), so that a report's main text can use plain
    words and link here for the precise ones.

    >>> glossary(["RMSE"]).startswith('<details id="glossary">')
    True
    """
    keys = list(GLOSSARY) if terms is None else [k for k in GLOSSARY if k in terms]
    items = "".join(f"<dt>{escape(k)}</dt><dd>{escape(GLOSSARY[k])}</dd>" for k in keys)
    return f'<details id="glossary"><summary>Glossary</summary><dl class="gloss">{items}</dl></details>'



#: The library names its fixes in Python (keywords); the command line and the reports it
#: writes show them as the options that do the same. Pattern -> replacement, in order.
CLI_SYNTAX = (
    (r"\bstructure='fixed'", "--structure fixed"),
    (r"\beffects=\(?'?(\w+)'?\)?", r"--effect \1"),
    (r"\beffects=", "--effect"),
    (r"channels=\{'(\w+)': COLUMN\}( \(--channel \w+=COLUMN\))?", r"--channel \1=COLUMN"),
    (r"\bchannel_skew=0 given\b", "--channel-skew-ms 0"),
    (r"\btarget_fs=None\b", "--fs 0"),
    (r"\btarget_fs=", "--fs "),
    (r"\bstationary=True\b", "--stationary"),
    (r"\bhigh_rate_reflex=True\b", "--high-rate-reflex"),
    (r"\bhigh_rate_reflex=False\b", "--model-rate-reflex"),
    (r"\bpt=PT\b", "--pt PT"),
    (r"\but=UT\b", "--ut UT"),
    (r"\bthe pt and ut arguments\b", "the --pt and --ut files"),
    # a keyword, not a field of a file ("conventions.torque_sign")
    (r"(?<![.\w])(position_unit|time_unit|torque_sign|velocity_order|intrinsic_order|reflex_order|state_order|"
     r"max_state_order|irf_lags|irf_length|reflex_delay|causal_lags|max_iter|relaxation_times|relaxation_order)"
     r"\b(='?([\w.+-]+)'?)?",
     lambda m: "--" + m.group(1).replace("_", "-") + (f" {m.group(3)}" if m.group(3) else "")),
    # a message that gave both syntaxes: once
    (r"\((--[^,()]+), \1\)", r"(\1)"),
    (r"(--[\w-]+ [^\s()]+) \(\1\)", r"\1"),  # "--torque-sign -1 (torque_sign=-1)": once
)


def command_line_syntax(text) -> str:
    """``text`` (a library message) with its Python keywords as command-line options: what
    the command line prints and the reports it writes show.

    >>> command_line_syntax("identify with structure='fixed' or the setting given")
    'identify with --structure fixed or the setting given'
    >>> command_line_syntax("pass position_unit='deg' if it is in degrees; or target_fs=None")
    'pass --position-unit deg if it is in degrees; or --fs 0'
    >>> command_line_syntax("read it as stationary (stationary=True, --stationary); conventions.torque_sign must be 1")
    'read it as stationary (--stationary); conventions.torque_sign must be 1'
    >>> command_line_syntax("identify again with --torque-sign -1 (torque_sign=-1)")
    'identify again with --torque-sign -1'
    """
    import re

    out = str(text)
    for pattern, repl in CLI_SYNTAX:
        out = re.sub(pattern, repl, out)
    return out


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
