"""The diagnosis report: the ranking as a text table, and the HTML and markdown report
with its figures (the HTML body is shared with each step of the improve report).

Built with the reports' common toolkit, :mod:`lpvpc.report_html`. Each function takes the
result of :func:`lpvpc.diagnosis.diagnose.diagnose` (a :class:`lpvpc.diagnosis.diagnose.Diagnosis`) as ``diag``.
"""

from __future__ import annotations

import html
from pathlib import Path

from .candidates import _variant_text
from .signals import FORMS
from ..report_html import breakable as _breakable
from ..report_html import command_line_syntax
from ..report_html import escape as _e
from ..report_html import glossary as _glossary
from ..report_html import inline_figure as _html_img
from ..report_html import page as _html_page
from ..report_html import table as _table


def format_table(diag, n=None, syntax="python") -> str:
    """Plain-text ranking table of the candidates (the first ``n``, or all). ``syntax``: "cli"
    to name options in the reasons a candidate is not available as the command line spells
    them (``--structure fixed``), as ``lpvpc diagnose`` prints it; "python" as keywords."""
    lines = [f"{'rank':>4}  {'candidate':44} {'kind':8} {'pathway':9} {'gain (pp)':>9} {'p':>9}  significant"]
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        if not c.available:
            reason = command_line_syntax(c.reason) if syntax == "cli" else c.reason
            lines.append(f"{i:>4}  {c.effect:44} {c.kind:8} {c.pathway:9} {'-':>9} {'-':>9}  n/a: {reason}")
            continue
        name = c.effect + (" (" + ", ".join(f"{k}={v:g}" for k, v in c.variant.items()) + ")" if c.variant else "")
        name += " [between records]" if c.scope != "record" else ""
        lines.append(f"{i:>4}  {name:44} {c.kind:8} {c.pathway:9} {c.vaf_gain:>+9.3f} {c.p_value:>9.1e}  "
                     f"{'YES' if c.significant else 'no'}")
    return "\n".join(lines)


def candidates_html(diag, n=None, syntax="python") -> str:
    """The ranked candidates as an HTML table (significant ones first, in conditional order).
    A candidate's note (why it is not available, or what its refit found) takes a full-width
    row under it: as a ninth column it was squeezed to a word per line. ``syntax``: "cli" to
    name options as the command line spells them."""
    rows, notes = [], []
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        name = f"<code>{_e(c.effect)}</code>{_e(_variant_text(c.variant))}" + (" <em>(between records)</em>" if c.scope != "record" else "")
        if not c.available:
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), "–", "–", "–", "n/a"])
        else:
            cond = (f"{c.conditional_gain:+.3f}" + (f" (given {', '.join(c.given)})" if c.given else "")
                    if c.significant else "–")
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), f"{c.vaf_gain:+.3f}", _e(cond), f"{c.p_value:.1e}",
                         '<span class="pass">YES</span>' if c.significant else "no"])
        reason = command_line_syntax(c.reason) if (c.reason and syntax == "cli") else c.reason
        notes.append(_breakable(reason) if reason else "")
    return '<div class="wide">' + _table(["rank", "candidate", "kind", "pathway", "gain (pp)", "conditional gain (pp)",
                                          "p", "significant"], rows, left=(1, 2, 3, 5), notes=notes) + "</div>"


def write_report(diag, data, folder, *, title="Diagnosis", syntax="cli") -> Path:
    """Report folder: ``report.html`` (self-contained: the answer first, then folded the
    ranked candidates, residual before/after the top candidate, where the model fails,
    signal dependence, a glossary), ``diagnosis.md`` (the same in markdown),
    ``diagnosis.json`` and the figures. Returns the path of report.html.

    ``syntax``: how the report names options: "cli" (the default: ``--structure fixed``, as
    the command line that writes most reports spells them) or "python" (keywords)."""
    from .. import plotting

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    diag.save(folder / "diagnosis.json")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(9.6, 10.5))
    plotting.plot_residual_diagnosis(diag, data, fig=fig)
    figs = folder / "residual.png"
    fig.savefig(figs, dpi=100)
    plt.close(fig)
    change = None
    first = next((c for c in diag.candidates if c.available and c.residual is not None), None)
    between = first is not None and first.scope != "record"  # fitted on the identification record: the model as it is
    before = diag.residual if between else diag.base_residual
    if first is not None and before is not None:
        fig, axes = plt.subplots(1, 2, figsize=(9.6, 3.2))
        plotting.plot_residual_change(data.time, data.torque, before, first.residual,
                                      labels=("model as it is" if between else "model (cross-validated)",
                                              f"+ {first.effect}" + (" (between records)" if between else "")),
                                      fs=data.fs, axes=axes)
        fig.tight_layout()
        change = folder / "residual_change.png"
        fig.savefig(change, dpi=100)
        plt.close(fig)
    _write_html(diag, folder / "report.html", title, figs, change, first, syntax)
    w = diag.where
    lines = [f"# {title}", "", f"Model `{diag.model_hash[:12]}` on `{diag.data_source}` ({diag.n_samples} samples at "
             f"{diag.fs:g} Hz): VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m; {diag.base_description()}.", "",
             "## Answer", "", diag.answer(), "", "## Candidates (held-out VAF gain)", "", "```", format_table(diag, syntax=syntax), "```", "",
             "Significant: p below alpha / number of candidates (alpha = "
             f"{diag.settings['alpha']}) and a gain of at least {diag.settings['min_gain']} pp.", "",
             "## Signal dependence (top 8)", "", "| signal | form | pathway | gain (pp) | p |", "|---|---|---|---|---|"]
    for d in diag.dependence[:8]:
        lines.append(f"| {d['signal']} | {FORMS[d['form']]} | {d['pathway']} | {d['vaf_gain']:+.3f} | {d['p_value']:.1e} |")
    lines += ["", "## Where the model fails", ""]
    for key in ("position", "velocity", "slow_movement", "time", "emg"):
        if key in w:
            lines += [f"### by {w[key]['by']}", "", "| bin | n | residual RMS (N m) | relative | VAF % |", "|---|---|---|---|---|"]
            lines += [f"| {b['bin']} | {b['n']} | {b['residual_rms']} | {b['relative_rms']} | {b['vaf']} |" for b in w[key]["bins"]]
            lines.append("")
    lines += ["### frequency bands", "", "| band (Hz) | unexplained fraction | share of residual power |", "|---|---|---|"]
    lines += [f"| {b['band_hz'][0]}-{b['band_hz'][1]} | {b['unexplained_fraction']} | {b['residual_power_share']} |" for b in w["frequency"]]
    lines += ["", "### events", ""]
    for k, e in w["events"].items():
        lines.append(f"- {e['description']} ({100 * e['fraction_of_samples']:.0f} % of samples): residual RMS "
                     f"{e['residual_rms_inside']} vs {e['residual_rms_outside']} N m elsewhere (ratio {e['ratio']})")
    wh = w["whiteness"]
    lines += ["", "### whiteness and cross-correlation", "",
              f"- residual autocorrelation outside +-2/sqrt(N) at {100 * wh['fraction_outside_2_over_sqrt_n']:.0f} % of lags "
              f"1..{wh['lags']} (Ljung-Box Q = {wh['ljung_box_q']}); {wh['note']}"]
    for k, c in w["cross_correlation"].items():
        lines.append(f"- with {k}: max |c| = {c['max_abs']} at lag {c['at_lag_s']:+.3f} s "
                     f"(99 % band +-{c['band_99']}{', OUTSIDE' if c['outside_band'] else ''})")
    lines += ["", f"![residual]({Path(figs).name})", ""]
    (folder / "diagnosis.md").write_text("\n".join(lines))
    return folder / "report.html"


def _next_step(diag, syntax="cli") -> str:
    """What to do next after this diagnosis (HTML)."""
    top = diag.top
    gap = any(flag for _, flag in diag.notes(weighed=True))
    if top is not None:
        if top.kind == "effect":
            how = (f"<code>lpvpc identify ... --effect {_e(top.effect)}</code>" if syntax == "cli" else
                   f"<code>LPVPCEstimator(effects=[{top.effect!r}])</code>")
            return (f"add <code>{_e(top.effect)}</code> to the model ({how}), or let "
                    f"{'<code>lpvpc improve</code>' if syntax == 'cli' else '<code>lpvpc.improve</code>'} add the "
                    f"significant effects one at a time and show what each changes.")
        setting = ", ".join(f"{k}={v:g}" for k, v in top.variant.items())
        return f"identify again with {_e(command_line_syntax(setting) if syntax == 'cli' else setting)}."
    if gap:
        return ("identify on a record more like this one (the model's parameters do not carry over to it; see the "
                "warning above).")
    return ("nothing to add: no effect of the catalog explains a meaningful part of what the model misses on these "
            "data. Validate it (FMU and co-simulation checks) with "
            + ("<code>lpvpc validate</code>." if syntax == "cli" else "<code>lpvpc.validate</code>."))


def diagnosis_html(diag, figs=None, change=None, first=None, *, level=2, syntax="cli") -> str:
    """The body of a diagnosis: the answer first (fit on these data, what is missing, the
    model's stiffness and reflex with their intervals when ``diag.model`` is known, what to
    do next), the details folded below. ``syntax``: "cli" (options as the command line
    spells them) or "python" (keywords)."""
    h = f"h{level}"
    c = diag.coverage
    outside = c.get("outside_fraction", 0) or 0
    parts = [f"<p class=\"small\">Model <code>{_e(diag.model_hash[:12])}</code> on <code>{_e(diag.data_source)}</code>: "
             f"{diag.n_samples} samples at {diag.fs:g} Hz ({c.get('duration_s', 0):.1f} s); its positions reach "
             f"{100 * c.get('covered_fraction_of_range', 1):.0f} % of the identified range"
             + (f", and {100 * outside:.1f} % of its samples lie beyond that range (left out of every score)"
                if outside > 0 else "") + ".</p>",
             f'<section class="answer" id="answer"><{h}>Answer</{h}>',
             f"<p class=\"lead\">On these data the model explains <b>{diag.vaf:.2f} %</b> of the torque (VAF; RMSE "
             f"{diag.rmse:.3g} N m). {_e(diag.answer())}</p>"]
    for note, flag in diag.notes(weighed=True):
        if flag:
            parts.append(f'<p class="flag">{_e(note)}</p>')
    model = getattr(diag, "model", None)
    if model is not None:
        from ..models.summary import physiology_table_html

        parts.append("<p>The model's physiology at the positions <code>lpvpc identify</code> prints, 95 % intervals "
                     "in brackets (<a href=\"#glossary\">glossary</a>):</p>")
        parts.append(physiology_table_html(model))
    if change is not None and diag.top is not None:
        parts.append(_html_img(change, _change_caption(first)))
    parts.append(f"<p><b>Next:</b> {_next_step(diag, syntax)}</p></section>")
    quiet = [n for n, flag in diag.notes(weighed=True) if not flag]
    n_sig = len(diag.significant)
    cand = candidates_html(diag, syntax=syntax)
    parts += [f"<details><summary>Candidates, ranked ({n_sig} significant)</summary>",
              f"<p class=\"small\">Design: {_e(diag.base_description())}. Gain: how much held-out VAF a candidate "
              f"adds (percentage points). A candidate is significant when its gain is too large to be chance (below "
              f"{diag.settings['alpha']} / number of candidates) and at least {diag.settings['min_gain']} points; "
              f"significant candidates are ranked by what each adds given the ones above it (conditional gain). See "
              f"the <a href=\"#glossary\">glossary</a>."
              + (" A candidate marked <em>between records</em> was fitted on the identification record and scored "
                 "on this one: its gain is what the change of its signal's level between the two records explains, "
                 "its conditional gain what it adds over the model as it is."
                 if any(c.scope != "record" for c in diag.candidates) else "") + "</p>", cand]
    parts += [f'<p class="note">{_e(n)}</p>' for n in quiet]
    if change is not None and diag.top is None:
        parts.append(_html_img(change, _change_caption(first)))
    parts.append("</details>")
    if figs is not None:
        parts += ["<details><summary>Where the model fails: residual over time, by position, velocity and frequency, "
                  "against the inputs</summary>",
                  _html_img(figs, "Residual over time, by position and velocity, by frequency band, its "
                                  "correlation with the inputs (each divided by its own 99 % band: inside +-1 is "
                                  "chance), and the candidates' gains"), "</details>"]
    if diag.dependence:
        rows = [[_e(d["signal"]), _e(FORMS[d["form"]]), _e(d["pathway"]), f"{d['vaf_gain']:+.3f}", f"{d['p_value']:.1e}",
                 "–" if "leak" not in d else f"{d['leak']:.2f}"] for d in diag.dependence[:8]]
        parts += ["<details><summary>Which signal the residual depends on (top 8)</summary>",
                  '<div class="wide">' + _table(["signal", "form", "pathway", "gain (pp)", "p",
                                                 "R² by reflex drive"], rows, left=(0, 1, 2)) + "</div>",
                  "</details>"]
    return "\n".join(parts)


def _change_caption(first) -> str:
    if first.scope != "record":
        return (f"Residual of the model as it is and with {first.effect} added (fitted on the identification "
                f"record, scored on this one): before and after, over time and as spectra")
    return (f"Held-out residual of the model (cross-validated base) and with {first.effect} added: before and "
            f"after, over time and as spectra")


def _write_html(diag, path, title, figs, change, first, syntax="cli"):
    body = f"<h1>{html.escape(title)}</h1>" + diagnosis_html(diag, figs, change, first, syntax=syntax) + _glossary()
    Path(path).write_text(_html_page(title, body))
