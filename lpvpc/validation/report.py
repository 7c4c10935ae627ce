"""The validation report: figures (PNG), ``report.html`` (one self-contained file, the PNGs
embedded as base64, no external resources, opens offline) and ``metrics.json``.

Units in every figure and table: time s, position rad, velocity rad/s, torque N m,
frequency Hz, VAF percent.

The page carries a small script that, once the page has loaded, marks every ``<img>``
with ``data-rendered="yes"|"no"`` (decoded with a non-zero natural width) and writes the
count into ``<p id="render-check" data-ok=.. data-total=..>``, so that a headless browser
can check that every figure rendered.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from lpvpc.io.outputs import write_text
from lpvpc.report_html import CSS as _CSS
from lpvpc.report_html import escape as _e
from lpvpc.report_html import glossary as _glossary
from lpvpc.report_html import figure_with_file as _img
from lpvpc.report_html import new_figure as _fig
from lpvpc.report_html import num as _num
from lpvpc.report_html import save_figure as _save
from lpvpc.report_html import table as _table
from lpvpc.models.summary import has_relaxed_stiffness, physiology_table_html, summary_positions
from lpvpc.models.uncertainty import NOT_DETERMINED

__all__ = ["write_report", "write_metrics", "FIGURES"]

#: file name -> (section, caption); the order of the report.
FIGURES = {
    "answer.png": "Elastic stiffness K and reflex gain over position, with their confidence bands (dots: the "
                  "positions of the table)",
    "fig4_intrinsic_gain.png": "Identified intrinsic gain over frequency and position, and the positions seen at "
                               "identification (Fig. 4; its value at 0 Hz is K, drawn with its band in the answer)",
    "fig5a_reflex_nonlinearity.png": "Identified reflex static nonlinearity at several positions with confidence "
                                     "bands, drawn where identification saw data (Fig. 5A)",
    "fig5b_reflex_irf.png": "Impulse response of the identified reflex dynamics (Fig. 5B)",
    "fig3_torque.png": "Measured and predicted perturbation torque with the intrinsic and reflex parts (Fig. 3)",
    "scheduling_range.png": "Held-out scheduling variable against the identified range",
    "error_by_position.png": "Error by position bin",
    "error_by_velocity.png": "Error by velocity bin",
    "error_over_time.png": "Error over time",
    "error_by_frequency.png": "Error by frequency",
    "worst_segments.png": "The worst segments of the record",
    "routes.png": "The prediction routes and the co-simulated actuator against the record",
}

_ROUTE_STYLE = {"numpy": ("C0", "offline (numpy)"), "fmu": ("C2", "FMU replay"), "cosim": ("C3", "co-simulation")}


def _json_default(o):
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _clean(o):
    """NaN/inf -> None (JSON has neither)."""
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def write_metrics(result) -> Path:
    """Write ``result.metrics`` to ``metrics.json`` in the report folder (non-finite numbers
    as null; units as the metrics state them: VAF %, torques N m, times s); returns the path."""
    path = Path(result.report_dir) / "metrics.json"
    write_text(path, json.dumps(_clean(result.metrics), indent=1, default=_json_default) + "\n")
    result.files["metrics"] = path
    return path


# --------------------------------------------------------------------------- figures


def _legend_above(ax, handles=None, ncol=4):
    """Legend in a row above the axes: never over the data (the figure's title goes in
    ``fig.suptitle``)."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    else:
        labels = [h.get_label() for h in handles]
    return ax.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=ncol, fontsize="small",
                     frameon=False, borderaxespad=0.0)


def _edge(x, resolution=0.0) -> str:
    """A bin edge for a tick label: 3 significant digits, signed, and never "-0.00"; edges
    within ``resolution`` of zero read "0" (in prose, 1 mrad/s: a hold's +2.03e-05 rad/s
    is a hold).

    >>> _edge(-0.0301), _edge(2.03e-05), _edge(2.03e-05, resolution=1e-3)
    ('-0.0301', '+2.03e-05', '0')
    """
    if abs(x) <= resolution or not math.isfinite(x):
        return "0" if abs(x) <= resolution else f"{x}"
    return f"{x:+.3g}"


def _window(n, fs, length=10.0, at=0.25):
    t0 = at * n / fs
    return (t0, min(t0 + length, n / fs))


def _shade_out_of_range(ax, t, outside, label=True):
    if not np.any(outside):
        return
    d = np.diff(np.concatenate([[0], outside.astype(int), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    for j, (a, b) in enumerate(zip(starts, stops)):
        ax.axvspan(t[a], t[min(b, len(t) - 1)], color="red", alpha=0.12, lw=0,
                   label="outside identified range" if (label and j == 0) else None)


def _draw_figures(folder: Path, m: dict, model, record, pred) -> dict:
    from lpvpc import plotting

    meas = record.measured
    fs, n = meas.fs, meas.n
    t = np.arange(n) / fs
    y = meas.torque
    lo, hi = model.scheduling_range
    outside = (meas.scheduling < lo) | (meas.scheduling > hi)
    cos = pred["cosim"]
    series = {"numpy": pred["numpy"].total, "fmu": pred["fmu"]["torque"], "cosim": cos.torque}
    paths = {}

    def out(name):
        p = folder / name
        paths[name] = p
        return p

    # Fig. 3
    fig = _fig(9, 6.5)
    win = _window(n, fs)
    axes = plotting.plot_torque_fit(t, y, pred["numpy"], fig=fig, window=win).axes
    sel = (t >= win[0]) & (t <= win[1])
    axes[0].plot(t[sel], cos.torque[sel], color="C3", lw=0.9, ls="--", label="co-simulation")
    _legend_above(axes[0])
    axes[0].set_title("")
    fig.suptitle(f"perturbation torque, {win[0]:.0f}-{win[1]:.0f} s of the held-out record "
                 f"(offline VAF {m['vaf']:.1f} %, co-simulation {m['vaf_cosim']:.1f} %)", fontsize="medium")
    _save(fig, out("fig3_torque.png"))

    # routes and actuator tracking
    fig = _fig(9, 6.5)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    win = _window(n, fs, length=4.0, at=0.4)
    sel = (t >= win[0]) & (t <= win[1])
    ax1.plot(t[sel], y[sel], color="0.6", lw=1.2, label="measured")
    for name, (c, label) in _ROUTE_STYLE.items():
        ax1.plot(t[sel], series[name][sel], color=c, lw=1.0, ls="-" if name != "cosim" else "--", label=label)
    ax1.set_ylabel("torque (N m)")
    _legend_above(ax1)
    fig.suptitle("prediction routes", fontsize="medium")
    ax2.plot(t[sel], 1e3 * meas.position[sel], color="0.6", lw=1.2, label="measured (decimated)")
    ax2.plot(t[sel], 1e3 * cos.model_inputs["position"][sel], color="C3", lw=1.0, ls="--",
             label="co-simulated actuators PT - UT (sampled)")
    ax2.set_ylabel("perturbation (mrad)")
    _legend_above(ax2)
    ax3.plot(t[sel], series["cosim"][sel] - series["fmu"][sel], color="C3", lw=1.0, label="co-simulation - FMU replay")
    # what the FMU's variant computes: the model-rate prediction, the headline's unless the reflex
    # sees the file's own rate (lpvpc.validation.routes.offline_routes)
    ref = ("numpy_model_rate" if "numpy_model_rate" in pred else "numpy") if cos.variant == "exact" else "numpy_causal"
    ax3.plot(t[sel], series["fmu"][sel] - pred[ref].total[sel], color="C2", lw=1.0,
             label=f"FMU replay - {'numpy' if ref == 'numpy_model_rate' else ref.replace('_', ' ')}")
    ax3.set_ylabel("difference (N m)")
    ax3.set_xlabel("time (s)")
    _legend_above(ax3)
    _save(fig, out("routes.png"))

    # the answer: K and the reflex gain over position, each on its own axis
    fig = _fig(9, 2.9)
    plotting.plot_stiffness_and_reflex(model, fig.subplots(1, 2), marks=summary_positions(model))
    _save(fig, out("answer.png"))

    # Figs. 4 and 5
    fig = _fig(7, 5)
    plotting.plot_intrinsic_gain(model, fig.gca())
    _save(fig, out("fig4_intrinsic_gain.png"))
    fig = _fig(7, 5)
    plotting.plot_reflex_nonlinearity(model, fig.gca())
    _save(fig, out("fig5a_reflex_nonlinearity.png"))
    fig = _fig(7, 5)
    plotting.plot_reflex_irf(model, fig.gca())
    _save(fig, out("fig5b_reflex_irf.png"))

    # scheduling range
    fig = _fig(9, 5)
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 1]})
    ax1.plot(t, meas.scheduling, color="C0", lw=0.8, label="held-out scheduling (UT position)")
    ax1.axhspan(lo, hi, color="C2", alpha=0.1, label="identified range")
    ax1.plot(np.where(outside, t, np.nan), np.where(outside, meas.scheduling, np.nan), color="red", lw=1.6,
             label=f"outside ({100 * m['out_of_range_fraction']:.1f} %)")
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("position rho (rad)")
    _legend_above(ax1, ncol=3)
    s = m["scheduling"]
    names = ["numpy", "fmu", "cosim"]
    inside_r = [s["in_range"][k]["rmse"] or 0.0 for k in names]
    out_r = [(s["out_of_range"][k]["rmse"] or 0.0) for k in names]
    xs = np.arange(len(names))
    ax2.bar(xs - 0.2, inside_r, 0.4, color="C2", label="inside")
    ax2.bar(xs + 0.2, out_r, 0.4, color="red", alpha=0.7, label="outside")
    ax2.set_xticks(xs, ["offline", "FMU", "cosim"])
    ax2.set_ylabel("RMSE (N m)")
    _legend_above(ax2, ncol=2)
    fig.suptitle("held-out scheduling against the identified range; error inside and outside", fontsize="medium")
    _save(fig, out("scheduling_range.png"))

    # error by position bin
    fa = m["failure_analysis"]

    def bars(ax, rows, xlabel, mark_outside=False):
        xs = np.arange(len(rows))
        w = 0.8 / len(_ROUTE_STYLE)
        for j, (name, (c, label)) in enumerate(_ROUTE_STYLE.items()):
            ax.bar(xs + (j - 1) * w, [r[f"rmse_{name}"] or 0.0 for r in rows], w, color=c, label=label)
        twin = ax.twinx()
        line, = twin.plot(xs, [r["rms_measured"] or 0.0 for r in rows], "k.:", lw=0.8,
                          label="RMS measured torque (right axis)")
        twin.set_ylabel("RMS measured torque (N m)")
        twin.set_ylim(bottom=0)
        if mark_outside:
            for x, r in zip(xs, rows):
                if r["hi"] <= lo + 1e-12 or r["lo"] >= hi - 1e-12:
                    ax.axvspan(x - 0.5, x + 0.5, color="red", alpha=0.12, lw=0)
        ax.set_xticks(xs, [_edge(r["lo"]) + "\n" + _edge(r["hi"]) for r in rows], fontsize="x-small")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("RMSE (N m)")
        _legend_above(ax, ax.get_legend_handles_labels()[0] + [line])

    fig = _fig(9, 4.5)
    bars(fig.gca(), fa["by_position"], "position bin rho (rad); shaded: outside the identified range",
         mark_outside=True)
    fig.suptitle("error by position (scheduling) bin", fontsize="medium")
    _save(fig, out("error_by_position.png"))

    fig = _fig(9, 7)
    a1, a2 = fig.subplots(2, 1)
    bars(a1, fa["by_ut_velocity"], "movement velocity bin (UT velocity, rad/s; equal-count bins)")
    fig.suptitle("error by velocity bin", fontsize="medium")
    bars(a2, fa["by_perturbation_velocity"], "perturbation (stretch) velocity bin (rad/s; edges at the 50, 80 and "
                                             "95th percentiles of |velocity|)")
    _save(fig, out("error_by_velocity.png"))

    ot = fa["over_time"]
    fig = _fig(9, 4)
    ax = fig.gca()
    for name, (c, label) in _ROUTE_STYLE.items():
        ax.plot(ot["t_centre"], ot[f"rmse_{name}"], color=c, marker=".", lw=1.0, label=label)
    ax.plot(ot["t_centre"], ot["rms_measured"], "k:", lw=0.8, label="RMS measured torque")
    _shade_out_of_range(ax, t, outside)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"RMSE per {ot['window']:g} s (N m)")
    ax.set_ylim(bottom=0)
    ax.set_xlim(0, t[-1])
    _legend_above(ax, ncol=3)
    fig.suptitle("error over time", fontsize="medium")
    _save(fig, out("error_over_time.png"))

    from .compare import error_spectrum

    spec = error_spectrum(y, series, fs)
    fig = _fig(9, 4.5)
    ax = fig.gca()
    f = spec["f"]
    ax.semilogy(f[1:], spec["measured"][1:], color="0.5", lw=1.2, label="measured torque")
    for name, (c, label) in _ROUTE_STYLE.items():
        ax.semilogy(f[1:], spec[name][1:], color=c, lw=1.0, label=f"error, {label}")
    for r in fa["by_frequency"][1:]:
        ax.axvline(r["lo"], color="0.8", lw=0.6)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("power spectral density (N² m²/Hz)")
    ax.set_xlim(0, fs / 2)
    _legend_above(ax)
    fig.suptitle("error by frequency (band edges as vertical lines)", fontsize="medium")
    _save(fig, out("error_by_frequency.png"))

    segs = fa["worst_segments"]
    fig = _fig(9, 2.4 * len(segs) + 0.5)
    axes = np.atleast_1d(fig.subplots(len(segs), 1))
    for ax, sgm in zip(axes, segs):
        sl = slice(sgm["i0"], sgm["i1"])
        tt = t[sl]
        ax.plot(tt, y[sl], color="0.55", lw=1.3, label="measured")
        for name, (c, label) in _ROUTE_STYLE.items():
            ax.plot(tt, series[name][sl], color=c, lw=1.0, ls="--" if name == "cosim" else "-", label=label)
        rho = meas.scheduling[sl]
        flag = " - OUTSIDE the identified range" if np.any((rho < lo) | (rho > hi)) else ""
        ax.set_title(f"{sgm['start']:.1f}-{sgm['stop']:.1f} s: offline RMSE {sgm['rmse']:.2f} N m, "
                     f"rho {rho.min():+.3f}..{rho.max():+.3f} rad{flag}", fontsize="small")
        ax.set_ylabel("torque (N m)")
    _legend_above(axes[0])
    axes[0].set_title(axes[0].get_title(), fontsize="small", pad=22)
    axes[-1].set_xlabel("time (s)")
    _save(fig, out("worst_segments.png"))
    return paths


# --------------------------------------------------------------------------- HTML

_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    var good = imgs[i].complete && imgs[i].naturalWidth > 0 && imgs[i].naturalHeight > 0;
    imgs[i].setAttribute('data-rendered', good ? 'yes' : 'no');
    if (good) { ok++; }
  }
  var el = document.getElementById('render-check');
  el.setAttribute('data-ok', String(ok));
  el.setAttribute('data-total', String(imgs.length));
  el.textContent = ok + ' of ' + imgs.length + ' figures rendered in this browser.';
});
"""


def _physiology_sentence(model) -> str:
    rho = np.array(model.scheduling_range)
    K = model.elastic_stiffness(rho)
    g, _ = model.reflex_gain_threshold(rho)
    g_ok = model.reflex_determined(rho)[0]  # a gain the data do not determine is not quoted (as in the table)
    gain = [f"{x:.1f} N m s/rad" if ok else NOT_DETERMINED for x, ok in zip(g, g_ok)]
    if model.one_position:  # a stationary trial's model: nothing varies with position
        return (f"At the one operating position of its identification, {rho[0]:+.2f} rad (+ = dorsiflexion), the "
                f"elastic stiffness is {K[0]:.0f} N m/rad and the reflex gain "
                f"{'is ' + NOT_DETERMINED if not g_ok[0] else gain[0]}.")
    trend = "rises" if K[1] > K[0] else "falls"
    reflex = (f"the reflex gain goes from {g[0]:.1f} to {g[1]:.1f} N m s/rad over the same range" if all(g_ok) else
              f"the reflex gain is {gain[0]} at {rho[0]:+.2f} rad and {gain[1]} at {rho[1]:+.2f} rad")
    return (f"Elastic stiffness {trend} from {K[0]:.0f} N m/rad at {rho[0]:+.2f} rad to {K[1]:.0f} N m/rad at "
            f"{rho[1]:+.2f} rad (+ = dorsiflexion); {reflex}.")


def _physiology_table(model, level=0.95) -> str:
    """Elastic stiffness, viscosity, reflex gain and threshold at the command line's
    positions, with their ``level`` confidence intervals when the model carries them, and
    the note on them (HTML)."""
    return "".join(_physiology_parts(model, level))


def _physiology_parts(model, level=0.95) -> tuple:
    """(table HTML, note HTML) of :func:`_physiology_table`: the table opens the report, the
    note is folded. The table is the one the diagnosis and improve reports show
    (:func:`lpvpc.models.summary.physiology_table_html`); the note is this report's text on it
    (what the brackets mean, the VAF interval, the reflex's bias, the stress relaxation)."""
    if model.has_intervals:
        v_lo, v_hi = model.vaf_interval()
        note = (f"In brackets: {level:.0%} confidence intervals (<a href=\"#glossary\">glossary</a>); "
                f"a value whose interval spans most of its plausible range reads \"{NOT_DETERMINED}\". "
                f"Identification VAF {model.fit.get('vaf', float('nan')):.2f} % ({v_lo:.2f}–{v_hi:.2f} %). "
                f"The intervals allow for the method's known bias; K is the stiffness over the perturbation's "
                f"amplitude (slightly above the slope of a curved torque-angle relation). {_reflex_bias_note(model)} "
                f"On the virtual subject the 95 % intervals held the truth 91-100 % of the time (the user guide's "
                f"page on confidence intervals). In a model with stress relaxation the K interval is the "
                f"short-range stiffness's.")
    else:
        note = _no_intervals_note(model)
    if has_relaxed_stiffness(model):
        chosen = "stress_relaxation" in (((model.fit or {}).get("structure_selection") or {}).get("effects")
                                         or {}).get("chosen", ())
        from lpvpc.models.effects import model_relaxation_times

        how = "was chosen by the structure's cross-validation" if chosen else "was asked for (--effect)"
        times = " and ".join(f"{t:g}" for t in model_relaxation_times(model))
        note += (f" Stress relaxation {how} (the position averaged over {times} s): right after a displacement the "
                 "joint resists with the short-range stiffness; held for seconds, part of that torque relaxes and the "
                 "relaxed stiffness remains. The short-range stiffness trades with that time, which a record hardly "
                 "determines" + ("; its interval counts the neighbouring times." if chosen else
                                 ": with an effect asked for, the interval does not count that."))
    return physiology_table_html(model, level), f"<p class=\"small\">{note}</p>"


def _no_intervals_note(model) -> str:
    """Why a model has no confidence intervals: what is true of it, and what would give them."""
    if model.effects:
        return ("No confidence intervals in this model file: it has "
                f"{', '.join(fe.name for fe in model.effects)} and was identified by an lpvpc that computed intervals "
                "for models without effects only, or its intervals could not be computed (identification warned "
                "why). Re-identifying gives them. The estimates are shown.")
    return ("No confidence intervals in this model file: they could not be computed from the "
            "identification data (identification warned why), or the file predates intervals in lpvpc (re-identifying "
            "gives them then). The estimates are shown.")


def _caption(name, model) -> str:
    """A figure's caption, without the confidence bands the figure does not draw."""
    text = FIGURES[name]
    if not model.has_intervals:
        text = text.replace(", its confidence band", "").replace(" with confidence bands", "")
    return text


def _reflex_bias_note(model) -> str:
    """Where the reflex nonlinearity was seen: from 100 Hz files its threshold is biased."""
    fs_v = model.nonlinearity_fs
    if model.reflex_threshold_biased:
        return (f"The reflex was seen on {fs_v:g} Hz velocity, too slow for its threshold: the threshold is "
                f"reported as not determined by these data and the gain's interval allows for the smoothing "
                f"(from 1 kHz files, <code>--high-rate-reflex</code> identifies it on the 1 kHz velocity; "
                f"see the user guide's page on reflex intervals).")
    return (f"The reflex curve was identified on the {fs_v:g} Hz delayed velocity; its gain and threshold intervals "
            f"come from refitting it to many simulated copies of the data.")


#: Out-of-range RMSE above this multiple of the in-range RMSE is flagged (red): the model's
#: continuation beyond its range is then worse than its fit, which changes where it may be used.
OUT_OF_RANGE_WORSE = 1.25


def _out_of_range_worse(outside: dict, inside: dict) -> bool:
    """Whether the prediction outside the identified range is clearly worse than inside.

    >>> _out_of_range_worse({"rmse": 0.262}, {"rmse": 0.259}), _out_of_range_worse({"rmse": 0.5}, {"rmse": 0.26})
    (False, True)
    """
    o, i = outside.get("rmse"), inside.get("rmse")
    if o is None or i is None or not (math.isfinite(o) and math.isfinite(i)) or i <= 0:
        return False
    return o > OUT_OF_RANGE_WORSE * i


def _next_step(m: dict, model) -> str:
    """What to do next, from the validation's own findings (HTML)."""
    prov = m["provenance"]
    s = m["scheduling"]
    if not m["pass"]:
        return ("a software check failed (see <i>Software checks</i> below): the FMU or the co-simulation does not "
                "reproduce the model; do not use the FMU until it passes.")
    if s["flagged"] and not model.one_position and _out_of_range_worse(s["out_of_range"]["numpy"],
                                                                       s["in_range"]["numpy"]):
        return (f"identify on a record that covers [{s['heldout_range'][0]:+.3f}, {s['heldout_range'][1]:+.3f}] rad "
                "before using the model at the positions outside its range.")
    files = prov["data_files"]
    data = (f"{files['data']['path']}" if "data" in files else
            f"--pt {files['pt']['path']} --ut {files['ut']['path']}" if "ut" in files else f"--pt {files['pt']['path']}")
    cmd = (f"<code>lpvpc diagnose {_e(prov['model_file'])} {_e(data)} --report diagnosis</code>"
           if prov.get("command_line") else "<code>lpvpc.diagnose(model, heldout)</code>")
    return (f"the model is ready to use (its FMU: <code>{_e(prov['model_fmu']['path'])}</code>). To see what it "
            f"misses and which physical effect would explain the rest: {cmd}.")


def _worst_bin(rows, key="rmse_numpy"):
    rows = [r for r in rows if r.get(key) is not None and r["n"] > 0]
    return max(rows, key=lambda r: r[key]) if rows else None


def _html(m: dict, figs: dict, model) -> str:
    pf = lambda ok: '<span class="pass">pass</span>' if ok else '<span class="fail">FAIL</span>'  # noqa: E731
    c = m["cosim"]
    s = m["scheduling"]
    fa = m["failure_analysis"]
    prov = m["provenance"]
    ag = m["route_agreement"]
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
             f"<title>lpvpc validation report</title><style>{_CSS}</style></head><body>"]
    parts.append("<h1>Validation report</h1>")
    files = prov["data_files"]
    on = (f"<code>{_e(files['data']['path'])}</code> (PT - UT)" if "data" in files else
          f"<code>{_e(files['pt']['path'])}</code> / <code>{_e(files['ut']['path'])}</code>")
    parts.append(f"<p class=\"small\">model <code>{_e(prov['model_hash'][:12])}</code> on {on}, {m['n_samples']} "
                 f"samples at {m['fs']:g} Hz ({m['duration_s']:.1f} s); {_e(prov['date'])}</p>")
    context = []  # how the records were read: opens the prediction details
    if "data" in files:  # the two trials the co-simulation drives, rebuilt: say so before any figure
        context.append("<p class=\"small\">The record is one PT - UT file: the actuators are driven with its "
                     "scheduling position (UT) and the scheduling plus the perturbation position (PT). Its UT torque "
                     "is not in the file, so the co-simulation loads the PT actuator with the model's torque "
                     "only.</p>")

    skew = float(model.conventions.get("channel_skew_s", 0.0) or 0.0)
    if skew:  # the records were lined up as at identification (lpvpc.identification.channel_skew): say so before any figure
        context.append(f"<p class=\"small\">Channel skew: the rig's torque channel lags its position channel by "
                     f"{skew * 1e3:.2f} ms (found or given at identification, recorded in the model); these records' "
                     f"position was delayed by it at the file's rate before every comparison below. The FMU applies "
                     f"no delay: in a loop it answers the true angle at once.</p>")

    # A scientist reads the physiology first, then how well the model predicts and where it
    # fails, then the software checks; provenance last.
    top, physiology, prediction, software = [], [], [], []
    overall = m["pass"]
    software.append(f"<p class=\"what\">The same model through every route a user can take: offline numpy, the "
                    f"CasADi function, the FMU replaying the measured positions and the FMU co-simulated with the "
                    f"actuator; overall result: {'pass' if overall else 'FAIL'}.</p>")
    rows = []
    for name in ("numpy", "numpy_model_rate", "numpy_causal", "casadi", "casadi_exact", "fmu", "actuator_replay", "cosim", "cosim_unloaded"):
        r = m["routes"].get(name)
        if r:
            rows.append([f"<code>{name}</code>", _num(r["vaf"]), _num(r["rmse"], "{:.3f}"), _e(r["description"])])
    software.append(_table(["route", "VAF (%)", "RMSE (N m)", "what"], rows, left=(0, 3)))
    rows = [[_e(ch["name"]), _num(ch["value"], "{:.4g}"), _num(ch["threshold"], "{:.4g}"), pf(ch["pass"])]
            for ch in m["checks"]]
    software.append(_table(["check", "value", "threshold", "result"], rows))
    if s["flagged"] and model.one_position:  # a stationary trial's model: how far the record is from its position
        o = s["out_of_range"]["numpy"]
        away = 1e3 * s["max_excursion"]
        top.append(f"<p class=\"flag\"><b>Away from the identified position:</b> the model was identified at one "
                   f"operating position, {s['identified_range'][0]:+.3f} rad, and does not vary with position; the "
                   f"held-out record's scheduling variable lies up to {away:.1f} mrad from it "
                   f"([{s['heldout_range'][0]:+.3f}, {s['heldout_range'][1]:+.3f}] rad). Where the ankle differs "
                   f"from that position, the model cannot follow. Offline RMSE {_num(o['rmse'], '{:.3f}')} N m, "
                   f"VAF {_num(o['vaf'])} %.</p>")
    elif s["flagged"]:
        o, i = s["out_of_range"]["numpy"], s["in_range"]["numpy"]
        worse = _out_of_range_worse(o, i)
        text = (f"{100 * s['out_of_range_fraction']:.2f} % of the held-out samples ({o['n']}) lie outside the "
                f"identified range [{s['identified_range'][0]:+.3f}, {s['identified_range'][1]:+.3f}] rad (held-out "
                f"range [{s['heldout_range'][0]:+.3f}, {s['heldout_range'][1]:+.3f}] rad), where the model is "
                f"{model.beyond_range}. Offline RMSE there {_num(o['rmse'], '{:.3f}')} N m against "
                f"{_num(i['rmse'], '{:.3f}')} N m inside (VAF {_num(o['vaf'])} % vs {_num(i['vaf'])} %)")
        if worse:  # the one case that changes what the reader may do with the model
            top.append(f"<p class=\"flag\"><b>Outside the identified range the model predicts worse:</b> {text}. "
                       f"Do not use it there without identifying on a record that covers those positions.</p>")
        else:
            top.append(f"<p class=\"small\">{100 * s['out_of_range_fraction']:.2f} % of the held-out samples lie "
                       f"outside the identified range; the model predicts them as well as the rest (RMSE "
                       f"{_num(o['rmse'], '{:.3f}')} N m there, {_num(i['rmse'], '{:.3f}')} N m inside; details under "
                       f"<i>Prediction</i>).</p>")

    # Fig. 3
    prediction.append("<h3>Measured and predicted torque (Fig. 3)</h3>")
    prediction.append("<p class=\"what\">A 10-s window of the held-out perturbation torque with the offline prediction "
                 "split into its intrinsic and reflex parts, and the co-simulated torque dashed.</p>")
    prediction.append(_img(figs["fig3_torque.png"], FIGURES["fig3_torque.png"]))

    # routes
    software.append("<h3>Prediction routes and co-simulation</h3>")
    d = ag["cosim_vs_fmu_replay"]
    fmu_key = "fmu_vs_numpy" if "fmu_vs_numpy" in ag else "fmu_vs_numpy_causal"
    software.append(f"<p class=\"what\">The CasADi and FMU routes reproduce the numpy prediction to "
                 f"{max(ag['casadi_vs_numpy_causal']['max_relative_difference'], ag[fmu_key]['max_relative_difference']):.1e} "
                 f"of the torque scale, while the co-simulation, which adds the actuator and the loop, is "
                 f"{abs(d['vaf_difference']):.2f} VAF points {'below' if d['vaf_difference'] >= 0 else 'above'} "
                 f"the FMU replay.</p>")
    rows = []
    for key in ("casadi_vs_numpy_causal", fmu_key, "casadi_exact_vs_numpy"):
        a = ag[key]
        rows.append([f"<code>{key}</code>", _num(a["max_relative_difference"], "{:.2e}"),
                     _num(a["rmse_difference"], "{:.2e}"), pf(a["pass"])])
    rows.append(["<code>numpy_causal_vs_numpy</code> (causal form vs identified)",
                 _num(ag["numpy_causal_vs_numpy"]["max_relative_difference"], "{:.2e}"), "–",
                 f"VAF {ag['numpy_causal_vs_numpy']['vaf_difference']:+.2f} points"])
    rows.append(["<code>cosim_vs_fmu_replay</code> (physical)", _num(d["max_relative_difference"], "{:.2e}"),
                 _num(d["rmse_difference"], "{:.3f}"), f"VAF {-d['vaf_difference']:+.2f} points"])
    software.append(_table(["routes", "max |a-b| / max |b|", "RMS difference (N m)", f"tolerance {ag['tolerance']:.0e}"], rows))
    tr = c["tracking"]
    cal = c["calibration"]
    le = c["load_effect"]
    st = c["settings"]
    txt = (f"The actuators were driven by {_e(c['command_source'])}. ")
    if c.get("model_fmu_variant") == "exact":
        lat = c['model_fmu_latency_samples']
        txt += (f"The model FMU is the exact variant (the identified two-sided model): it needs {lat} future "
                f"positions, so its torque comes {lat} samples late. The replay and the co-simulation shift it back by "
                f"{lat} samples for comparison; in the loop, however, it loads the actuator {lat} samples late. The "
                f"latency-free causal FMU meant for closed loop reaches {m['vaf_causal']:.2f} % offline (validate it "
                f"with --fmu-variant causal). ")
    if cal.get("done"):
        txt += (f"The servo was calibrated on the record: bandwidth {cal['servo_bandwidth']:.2f} Hz, damping "
                f"{cal['servo_damping']:.3f} (FMU defaults {cal['defaults']['servo_bandwidth']:g} Hz, "
                f"{cal['defaults']['servo_damping']:g}); position fit VAF {cal['vaf']:.3f} %"
                + (" — <b>poor: the co-simulation tests the actuator model as much as the ankle model</b>" if cal["poor"] else "")
                + ". ")
    else:
        txt += f"No servo calibration ({_e(cal.get('reason', ''))}). "
    txt += (f"The co-simulated perturbation position matches the measured one with VAF "
            f"{tr['perturbation_position_vaf']:.3f} % (RMS difference {tr['perturbation_position_rmse_mrad']:.3f} mrad). ")
    if le:
        txt += (f"Load effect, measured by repeating the run unloaded: the load changes the perturbation position by "
                f"at most {le['perturbation_position_max_mrad']:.3f} mrad (RMS {100 * le['perturbation_position_rms_relative']:.2f} % "
                f"of the perturbation) and vaf_cosim by {le['vaf_change']:+.3f} points. ")
    if st.get("band_limit_command"):
        txt += (f"The commands were band-limited to the model's band before driving the actuators, so the model in "
                f"the loop sees no aliasing (replaying the co-simulated actuator positions, decimated once more, "
                f"gives {m['vaf_actuator_replay']:.2f} %).")
    else:
        txt += (f"The model FMU replaying the co-simulated actuator positions after recording them at the actuator "
                f"rate and decimating them like the measured data gives {m['vaf_actuator_replay']:.2f} %: the "
                f"difference to vaf_cosim ({m['vaf_actuator_replay'] - m['vaf_cosim']:+.2f} points) is what feeding "
                f"the {m['fs']:g} Hz model sampled, not anti-aliased, positions in the loop costs.")
    software.append(f"<p>{txt}</p>")
    software.append(_img(figs["routes.png"], FIGURES["routes.png"]))
    rows = [[f"<code>{_e(x['to'])}</code>", _e(x["from"])] for x in c["connections"]]
    software.append("<p>Connections (by variable name):</p>" + _table(["input", "connected from"], rows, left=(0, 1)))
    rows = [["communication step (model sample period)", f"{c['communication_step_s'] * 1e3:g} ms"],
            ["actuator step (command fed at every step)" if st["command_rate"] == "actuator"
             else "actuator step (command held over each model step)", f"{c['step_actuator_s'] * 1e3:g} ms"],
            ["coupling of the load torque",
             "one-step delay (torque of the previous model step)" if st["coupling"] == "delay"
             else f"iterated with FMU state rollback to {st['iterate_tol']:g} N m "
                  f"(mean {c['iterations']['mean']:.2f}, max {c['iterations']['max']} iterations)"],
            ["model velocity / acceleration", "central differences of the perturbation position at the model rate"
             if st["derivatives"] == "central" else "the actuators' velocity and acceleration outputs"],
            ["load torque", _e(st["load"])],
            ["actuator parameters", _e(", ".join(f"{k} = {v:.6g}" for k, v in c["actuator_parameters"].items()) or "defaults")],
            ["stepping time", f"{c['stepping_seconds']:.2f} s ({c['real_time_factor']:.0f}x real time)"]]
    software.append(_table(["co-simulation set-up", ""], rows, left=(0, 1)))
    if c.get("ssp"):
        software.append(f"<p>The same set-up (both FMUs, connections by variable name, the parameters above, start and "
                     f"stop time) is in <code>{_e(c['ssp'])}</code> (SSP 1.0) for other co-simulation tools; the "
                     f"signals this master computes or takes from the record are inputs of the system there.</p>")

    # physiology
    physiology.append("<h3>Intrinsic stiffness (Fig. 4)</h3>")
    K = model.elastic_stiffness(np.array(model.scheduling_range))
    span = (f"at its one operating position ({model.scheduling_range[0]:+.2f} rad) the elastic stiffness is "
            f"{K[0]:.0f} N m/rad" if model.one_position else
            f"the elastic stiffness K(rho) goes from {K[0]:.0f} N m/rad at {model.scheduling_range[0]:+.2f} rad to "
            f"{K[1]:.0f} N m/rad at {model.scheduling_range[1]:+.2f} rad")
    physiology.append(f"<p class=\"what\">The intrinsic gain of the identified model over frequency and position; "
                      f"{span}.</p>")
    physiology.append(_img(figs["fig4_intrinsic_gain.png"], _caption("fig4_intrinsic_gain.png", model)))
    physiology.append("<h3>Reflex pathway (Fig. 5)</h3>")
    physiology.append(f"<p class=\"what\">The reflex static nonlinearity (steady torque for a constant delayed stretch "
                 f"velocity) {'at its one operating position' if model.one_position else 'at five positions'}"
                 f"{', with confidence bands' if model.has_intervals else ''}, and the "
                 f"impulse response of the reflex dynamics (order "
                 f"{model.state_order}, delay {1e3 * model.delay / model.fs:.0f} ms).</p>")
    physiology.append(_img(figs["fig5a_reflex_nonlinearity.png"], _caption("fig5a_reflex_nonlinearity.png", model)))
    physiology.append(_img(figs["fig5b_reflex_irf.png"], FIGURES["fig5b_reflex_irf.png"]))

    # scheduling range
    prediction.append("<h3>Scheduling range</h3>")
    o = s["out_of_range"]
    prediction.append(f"<p class=\"what\">The held-out record spans [{s['heldout_range'][0]:+.3f}, {s['heldout_range'][1]:+.3f}] rad "
                 f"against the identified [{s['identified_range'][0]:+.3f}, {s['identified_range'][1]:+.3f}] rad; "
                 f"{100 * s['out_of_range_fraction']:.2f} % of it lies outside, where the error is shown separately."
                 + (" The model was identified at one operating position and does not vary with position: it "
                    "answers every position as it does that one." if model.one_position else "") + "</p>")
    rows = []
    for k, label in (("numpy", "offline"), ("fmu", "FMU replay"), ("cosim", "co-simulation")):
        i_, o_ = s["in_range"][k], o[k]
        rows.append([label, str(i_["n"]), _num(i_["vaf"]), _num(i_["rmse"], "{:.3f}"), str(o_["n"]), _num(o_["vaf"]),
                     _num(o_["rmse"], "{:.3f}")])
    prediction.append(_table(["route", "n inside", "VAF inside (%)", "RMSE inside (N m)", "n outside", "VAF outside (%)",
                         "RMSE outside (N m)"], rows))
    prediction.append(_img(figs["scheduling_range.png"], FIGURES["scheduling_range.png"]))

    # where it fails
    prediction.append("<h3>Where the model fails</h3>")
    wb = _worst_bin(fa["by_position"])
    if wb:
        prediction.append(f"<p class=\"what\">By position: the offline error is largest between {wb['lo']:+.3f} and "
                     f"{wb['hi']:+.3f} rad (RMSE {wb['rmse_numpy']:.3f} N m against an RMS torque of "
                     f"{wb['rms_measured']:.2f} N m there).</p>")
    prediction.append(_img(figs["error_by_position.png"], FIGURES["error_by_position.png"]))
    wv, wp = _worst_bin(fa["by_ut_velocity"]), _worst_bin(fa["by_perturbation_velocity"])
    if wv and wp:
        prediction.append(f"<p class=\"what\">By velocity: the error is largest for movement velocities "
                     f"{_edge(wv['lo'], 1e-3)}..{_edge(wv['hi'], 1e-3)} rad/s (RMSE {wv['rmse_numpy']:.3f} N m) and for "
                     f"perturbation velocities {_edge(wp['lo'], 1e-3)}..{_edge(wp['hi'], 1e-3)} rad/s "
                     f"(RMSE {wp['rmse_numpy']:.3f} N m).</p>")
    prediction.append(_img(figs["error_by_velocity.png"], FIGURES["error_by_velocity.png"]))
    ot = fa["over_time"]
    j = int(np.argmax(ot["rmse_numpy"]))
    prediction.append(f"<p class=\"what\">Over time: the offline RMSE per {ot['window']:g} s window ranges from "
                 f"{min(ot['rmse_numpy']):.3f} to {max(ot['rmse_numpy']):.3f} N m, worst around t = "
                 f"{ot['t_centre'][j]:.1f} s (out-of-range periods shaded).</p>")
    prediction.append(_img(figs["error_over_time.png"], FIGURES["error_over_time.png"]))
    bands = fa["by_frequency"]
    worst_band = min((b for b in bands if b["power_measured"] > 0 and b["vaf_numpy"] is not None),
                     key=lambda b: b["vaf_numpy"], default=None)
    if worst_band:
        prediction.append(f"<p class=\"what\">By frequency: the model explains least of the torque between "
                     f"{worst_band['lo']:g} and {worst_band['hi']:g} Hz (band VAF {worst_band['vaf_numpy']:.1f} % "
                     f"offline, {_num(worst_band['vaf_cosim'], '{:.1f}')} % co-simulated).</p>")
    total_p = sum(b["power_measured"] for b in bands) or 1.0
    rows = [[f"{b['lo']:g}–{b['hi']:g}", f"{100 * b['power_measured'] / total_p:.1f}", _num(b["vaf_numpy"], "{:.1f}"),
             _num(b["vaf_fmu"], "{:.1f}"), _num(b["vaf_cosim"], "{:.1f}")] for b in bands]
    prediction.append(_table(["band (Hz)", "share of torque power (%)", "band VAF offline (%)", "FMU (%)", "cosim (%)"], rows))
    prediction.append(_img(figs["error_by_frequency.png"], FIGURES["error_by_frequency.png"]))
    segs = fa["worst_segments"]
    prediction.append(f"<p class=\"what\">The {len(segs)} two-second segments with the largest offline error, measured and "
                 f"predicted torque overlaid; the worst starts at {segs[0]['start']:.1f} s "
                 f"(RMSE {segs[0]['rmse']:.3f} N m).</p>")
    prediction.append(_img(figs["worst_segments.png"], FIGURES["worst_segments.png"]))

    if "whole_joint" in m and WHOLE_JOINT_FIGURE in figs:
        prediction.append(_whole_joint_section(m["whole_joint"], figs[WHOLE_JOINT_FIGURE]))

    table_html, table_note = _physiology_parts(model)
    checks = '<span class="pass">pass</span>' if overall else '<span class="fail">FAIL</span>'
    parts.append('<section class="answer" id="answer"><h2>Answer</h2>')
    parts.append(f"<p class=\"lead\">On the held-out record the model explains <b>{m['vaf']:.2f} %</b> of the "
                 f"torque (VAF; RMSE {m['rmse']:.3f} N m); {m['vaf_fmu']:.2f} % as an FMU and {m['vaf_cosim']:.2f} % "
                 f"co-simulated with the actuator. Software checks: {checks}. The physiology at the positions "
                 f"<code>lpvpc identify</code> prints, 95 % intervals in brackets "
                 f"(<a href=\"#glossary\">glossary</a>):</p>")
    parts.append(table_html)
    parts.append(_img(figs["answer.png"], _caption("answer.png", model)))
    parts += top
    parts.append(f"<p><b>Next:</b> {_next_step(m, model)}</p>")
    parts.append("</section>")
    parts.append("<details><summary>Physiology in detail: the intervals, the intrinsic gain map (Fig. 4) and the "
                 "reflex (Fig. 5)</summary>")
    parts.append(f"<p class=\"what\">{_e(_physiology_sentence(model))}</p>")
    parts.append(table_note)
    parts += physiology
    parts.append("</details>")
    parts.append("<details><summary>Prediction in detail: measured and predicted torque (Fig. 3), the scheduling "
                 "range, where the model fails</summary>")
    parts += context
    parts += prediction
    parts.append("</details>")
    parts.append(f"<details><summary>Software checks ({'pass' if overall else 'FAIL'}): routes, FMU and "
                 f"co-simulation</summary>")
    parts += software
    parts.append("</details>")

    # provenance
    parts.append("<details><summary>Provenance: what was validated, with what, and when</summary>")
    v = prov["versions"]
    rows = [["date (UTC)", _e(prov["date"])],
            ["model file", _e(prov["model_file"])],
            ["model hash (sha256 of equations and coefficients)", f"<code>{_e(prov['model_hash'])}</code>"],
            ["hash of the model's identification data", f"<code>{_e(prov['model_data_hash'])}</code>"],
            *[[f"{label} file (sha256)", f"{_e(prov['data_files'][role]['path'])}<br>"
                                         f"<code>{_e(prov['data_files'][role]['sha256'])}</code>"]
              for role, label in (("pt", "PT"), ("ut", "UT"), ("data", "PT - UT")) if role in prov["data_files"]],
            ["held-out data hash (PT-UT at the model rate)", f"<code>{_e(prov['data_hash'])}</code>"],
            ["record", f"{prov['record_samples']} samples at {prov['record_fs']:g} Hz"
                       + (f" (resampled from the files' {prov['record_fs_file']:g} Hz)" if prov.get("record_fs_file") else "")
                       + "; position unit "
                       f"{_e(prov['position_unit'])}, torque sign {_e(prov['torque_sign'])}"],
            ["model FMU (sha256)", f"{_e(prov['model_fmu']['path'])} (FMI {prov['model_fmu']['fmi_version']}.0"
                                   f"{', given' if prov['model_fmu']['given'] else ', exported for this report'})"
                                   f"<br><code>{_e(prov['model_fmu']['sha256'])}</code>"],
            ["actuator FMU (sha256)", f"{_e(prov['actuator_fmu']['path'])} (FMI {prov['actuator_fmu']['fmi_version']}.0)"
                                      f"<br><code>{_e(prov['actuator_fmu']['sha256'])}</code>"],
            ["step sizes", f"model {prov['step_sizes']['model_s']:g} s, actuator {prov['step_sizes']['actuator_s']:g} s, "
                           f"communication {prov['step_sizes']['communication_s']:g} s"],
            ["tolerances", _e(", ".join(f"{k} {val}" for k, val in prov["tolerances"].items()))],
            ["package versions", _e(", ".join(f"{k} {val}" for k, val in v.items()))],
            ["platform", _e(prov["platform"])],
            ["command line", f"<code>{_e(prov['command_line'] or '(library call)')}</code>"]]
    parts.append(_table(["", ""], rows, left=(0, 1)))
    parts.append("</details>")
    parts.append(_glossary())
    parts.append('<p id="render-check" class="small" data-ok="" data-total="">figure check pending '
                 '(needs JavaScript)</p>')
    parts.append(f"<script>{_SCRIPT}</script></body></html>")
    return "\n".join(parts)


WHOLE_JOINT_FIGURE = "whole_joint.png"


def _draw_whole_joint(folder: Path, tr: dict) -> Path:
    t = tr["time"]
    t0, t1 = _window(len(t), 1.0 / (t[1] - t[0]))
    sel = (t >= t0) & (t < t1)
    fig = _fig(9, 5.2)
    ax1 = fig.add_subplot(2, 1, 1)
    ax2 = fig.add_subplot(2, 1, 2, sharex=ax1)
    ax1.plot(t[sel], tr["angle"][sel], color="0.3", lw=1.0, label="joint angle (PT)")
    ax1.plot(t[sel], tr["operating_angle"][sel], color="C1", lw=1.2, label="operating angle (causal low-pass)")
    ax1.set_ylabel("angle (rad)")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.plot(t[sel], tr["measured"][sel], color="0.3", lw=1.0, label="measured total torque (PT)")
    ax2.plot(t[sel], tr["predicted"][sel], color="C0", lw=1.0, label="whole-joint model")
    ax2.plot(t[sel], tr["quasi_static"][sel], color="C1", lw=1.0, ls="--", label="quasi-static part")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("torque (N m)")
    ax2.legend(loc="upper right", fontsize=8)
    path = folder / WHOLE_JOINT_FIGURE
    _save(fig, path)
    return path


def _whole_joint_section(w: dict, fig: Path) -> str:
    rows = [["total torque of the PT trial", _num(w["vaf_total"]), _num(w["vaf_total_fmu"])],
            ["perturbation part (whole-joint PT minus UT) vs measured PT minus UT", _num(w["vaf_perturbation"]), ""],
            ["two-input model on the measured split (reference)", _num(w["vaf_two_input"]), ""],
            ["quasi-static curve at the UT angle vs the UT torque", _num(w["vaf_quasi_static_ut"]), ""]]
    return "\n".join([
        "<h2>Whole-joint model</h2>",
        f"<p class=\"what\">Joint angle in, total torque out: the quasi-static torque-angle curve (order "
        f"{w['quasi_static_order']}, fitted to the identification UT trial) at the operating angle (first-order "
        f"causal low-pass, {w['cutoff_hz']:g} Hz) plus the LPV parallel cascade of the angle minus it. Its CasADi "
        f"step and FMU (FMI {w['fmi_version']}.0) return the torque of {w['latency_samples']} samples earlier "
        f"({w['latency_s'] * 1000:g} ms, removed here); they agree with numpy to {w['casadi_vs_numpy']:.1e} and "
        f"{w['fmu_vs_numpy']:.1e} (max |difference| / max |torque|).</p>",
        _table(["VAF (%)", "numpy", "FMU"], rows),
        _img(fig, "The whole-joint model on the PT trial: angle, operating angle and total torque"),
    ])


def write_report(result, *, model, record, predictions) -> dict:
    """Draw the figures into ``report_dir/figures`` and write ``report_dir/report.html``;
    returns {"report": path, "figures": {name: path}}. ``predictions``: "numpy" (the
    headline prediction), "numpy_causal", "fmu", "cosim", and optionally "numpy_model_rate"
    (the model-rate prediction when it differs from the headline), "unloaded",
    "actuator_replay" and "whole_joint"."""
    folder = Path(result.report_dir) / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    figs = _draw_figures(folder, result.metrics, model, record, predictions)
    if predictions.get("whole_joint") is not None:
        figs[WHOLE_JOINT_FIGURE] = _draw_whole_joint(folder, predictions["whole_joint"])
    page = _html(result.metrics, figs, model)
    path = Path(result.report_dir) / "report.html"
    write_text(path, page)
    result.metrics["files"] = {"report": "report.html", "metrics": "metrics.json",
                               "figures": [f"figures/{n}" for n in figs]}
    if result.metrics["cosim"].get("ssp"):
        result.metrics["files"]["ssp"] = result.metrics["cosim"]["ssp"]
    if result.metrics["cosim"].get("portable_ssp"):
        result.metrics["files"]["portable_ssp"] = result.metrics["cosim"]["portable_ssp"]
    return {"report": path, "figures": figs}
