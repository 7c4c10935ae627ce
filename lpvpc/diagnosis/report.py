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
from ..report_html import escape as _e
from ..report_html import inline_figure as _html_img
from ..report_html import page as _html_page
from ..report_html import table as _table


def format_table(diag, n=None) -> str:
    """Plain-text ranking table of the candidates."""
    lines = [f"{'rank':>4}  {'candidate':44} {'kind':8} {'pathway':9} {'gain (pp)':>9} {'p':>9}  significant"]
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        if not c.available:
            lines.append(f"{i:>4}  {c.effect:44} {c.kind:8} {c.pathway:9} {'-':>9} {'-':>9}  n/a: {c.reason}")
            continue
        name = c.effect + (" (" + ", ".join(f"{k}={v:g}" for k, v in c.variant.items()) + ")" if c.variant else "")
        lines.append(f"{i:>4}  {name:44} {c.kind:8} {c.pathway:9} {c.vaf_gain:>+9.3f} {c.p_value:>9.1e}  "
                     f"{'YES' if c.significant else 'no'}")
    return "\n".join(lines)


def candidates_html(diag, n=None) -> str:
    """The ranked candidates as an HTML table (significant ones first, in conditional order).
    A candidate's note (why it is not available, or what its refit found) takes a full-width
    row under it: as a ninth column it was squeezed to a word per line."""
    rows, notes = [], []
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        name = f"<code>{_e(c.effect)}</code>{_e(_variant_text(c.variant))}"
        if not c.available:
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), "–", "–", "–", "n/a"])
        else:
            cond = (f"{c.conditional_gain:+.3f}" + (f" (given {', '.join(c.given)})" if c.given else "")
                    if c.significant else "–")
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), f"{c.vaf_gain:+.3f}", _e(cond), f"{c.p_value:.1e}",
                         '<span class="pass">YES</span>' if c.significant else "no"])
        notes.append(_breakable(c.reason) if c.reason else "")
    return '<div class="wide">' + _table(["rank", "candidate", "kind", "pathway", "gain (pp)", "conditional gain (pp)",
                                          "p", "significant"], rows, left=(1, 2, 3, 5), notes=notes) + "</div>"


def write_report(diag, data, folder, *, title="Diagnosis") -> Path:
    """Report folder: ``report.html`` (self-contained: the answer, the ranked candidates,
    residual before/after the top candidate, where the model fails, signal dependence),
    ``diagnosis.md`` (the same in markdown), ``diagnosis.json`` and the figures. Returns
    the path of report.html."""
    from .. import plotting

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    diag.save(folder / "diagnosis.json")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 7))
    plotting.plot_residual_diagnosis(diag, data, fig=fig)
    figs = folder / "residual.png"
    fig.savefig(figs, dpi=100)
    plt.close(fig)
    change = None
    first = next((c for c in diag.candidates if c.available and c.residual is not None), None)
    if first is not None and diag.base_residual is not None:
        fig, axes = plt.subplots(1, 2, figsize=(12, 3.6))
        plotting.plot_residual_change(data.time, data.torque, diag.base_residual, first.residual,
                                      labels=("model (cross-validated)", f"+ {first.effect}"), fs=data.fs, axes=axes)
        fig.tight_layout()
        change = folder / "residual_change.png"
        fig.savefig(change, dpi=100)
        plt.close(fig)
    _write_html(diag, folder / "report.html", title, figs, change, first)
    w = diag.where
    lines = [f"# {title}", "", f"Model `{diag.model_hash[:12]}` on `{diag.data_source}` ({diag.n_samples} samples at "
             f"{diag.fs:g} Hz): VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m; {diag.base_description()}.", "",
             "## Answer", "", diag.answer(), "", "## Candidates (held-out VAF gain)", "", "```", format_table(diag), "```", "",
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


def diagnosis_html(diag, figs=None, change=None, first=None, *, level=2) -> str:
    """The body of a diagnosis (used by the diagnose report and by each step of the improve
    report)."""
    h = f"h{level}"
    c = diag.coverage
    parts = [f"<p>Model <code>{_e(diag.model_hash[:12])}</code> on <code>{_e(diag.data_source)}</code>: "
             f"{diag.n_samples} samples at {diag.fs:g} Hz ({c.get('duration_s', 0):.1f} s, "
             f"{100 * c.get('covered_fraction_of_range', 1):.0f} % of the identified range); VAF {diag.vaf:.2f} %, "
             f"RMSE {diag.rmse:.4g} N m; design <b>{_e(diag.design)}</b>: "
             f"{_e(diag.base_description())}.</p>",
             f"<{h}>Answer</{h}>", f"<p class=\"what\">{_e(diag.answer())}</p>"]
    for note in diag.notes():
        parts.append(f'<p class="flag">{_e(note)}</p>')
    parts += [f"<{h}>Candidates, ranked</{h}>",
              "<p class=\"small\">Gain: held-out VAF gain over the base (pp). Significant candidates are ranked by "
              "what each adds given the ones above it (conditional gain); a candidate is significant when its p-value "
              f"is below {diag.settings['alpha']} / number of candidates and its gain at least "
              f"{diag.settings['min_gain']} pp.</p>", candidates_html(diag)]
    if change is not None:
        parts.append(_html_img(change, f"Held-out residual of the model (cross-validated base) and with "
                                       f"{first.effect} added: before and after, over time and as spectra"))
    if diag.dependence:
        rows = [[_e(d["signal"]), _e(FORMS[d["form"]]), _e(d["pathway"]), f"{d['vaf_gain']:+.3f}", f"{d['p_value']:.1e}",
                 "–" if "leak" not in d else f"{d['leak']:.2f}"] for d in diag.dependence[:8]]
        parts += [f"<{h}>Which signal the residual depends on (top 8)</{h}>",
                  '<div class="wide">' + _table(["signal", "form", "pathway", "gain (pp)", "p",
                                                 "R² by reflex drive"], rows, left=(0, 1, 2)) + "</div>"]
    if figs is not None:
        parts += [f"<{h}>Where the model fails</{h}>",
                  _html_img(figs, "Residual over time, by position and velocity, by frequency band, its "
                                  "cross-correlation with the input, and the candidates' gains")]
    return "\n".join(parts)


def _write_html(diag, path, title, figs, change, first):
    body = f"<h1>{html.escape(title)}</h1>" + diagnosis_html(diag, figs, change, first)
    Path(path).write_text(_html_page(title, body))
