"""What a fitted model says about the ankle, in lines a person reads and in a dict a program
takes further: the identified physiology (K(theta), viscosity, the reflex gain and threshold,
with "not determined" where the data do not determine them), the structure chosen and its
cross-validation, and both stiffnesses of a model with stress relaxation.

``lpvpc identify`` prints these lines; :meth:`lpvpc.LPVPCModel.summary <lpvpc.models.model.LPVPCModel.summary>` returns them.
The physiology table the validation, diagnosis and improve reports open with is built here
too (``physiology_table_html``), once for all three, so that a value reads the same in each
report and as the command line prints it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .uncertainty import NOT_DETERMINED
from .reflex_uncertainty import SLOPE_TOLERANCE

__all__ = ["ModelSummary"]


@dataclass(frozen=True)
class ModelSummary:
    """A model's summary: ``lines`` (text, as ``lpvpc identify`` prints them) and ``values``
    (the same figures as numbers: SI units, None where not determined).

    Examples
    --------
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> summary = identify(pair_trials(sim.pt, sim.ut), structure="fixed").summary()
    >>> any(line.startswith("VAF:") for line in summary.lines), len(summary.values["stiffness"])
    (True, 5)
    """

    lines: list = field(default_factory=list)
    values: dict = field(default_factory=dict)

    def __str__(self) -> str:
        return "\n".join(self.lines)

    def to_dict(self) -> dict:
        """``values``, for JSON."""
        return dict(self.values)


def summarize(model) -> ModelSummary:
    """The summary of ``model`` (:class:`ModelSummary`)."""
    fit = model.fit or {}
    vaf_c = f" (causal form for closed loop: {fit['vaf_causal']:.2f} %)" if "vaf_causal" in fit else ""
    lines = skew_lines(model)
    if "vaf" in fit:
        lines.append(f"VAF:         {fit['vaf']:.2f} % on the identification data{vaf_c}")
    bic = fit.get("stationary_delay_bic")  # a stationary trial's delay, chosen by BIC among candidates
    by_bic = (f" (chosen by BIC among {', '.join(f'{1e3 * float(c):g}' for c in bic)} ms; IRF half-width the same)"
              if bic else "")
    lines.append(f"reflex:      state order {model.state_order}, delay {model.delay / model.fs * 1000:.0f} ms{by_bic}")
    lines += physiology_lines(model) + selection_lines(fit.get("structure_selection")) + relaxation_lines(model)
    return ModelSummary(lines, physiology_values(model))


def skew_lines(model) -> list:
    """The channel skew the model's record was lined up by, or what the fit's scan found."""
    choice = (model.fit or {}).get("channel_skew")
    skew = (model.conventions or {}).get("channel_skew_s", 0.0)
    if skew:
        how = (f"found by the fit's scan: removes {100 * choice['residual_reduction']:.1f} % of the residual variance"
               if choice else "given")
        return [f"skew:        torque channel {skew * 1e3:+.2f} ms behind position ({how}); position delayed by it at "
                f"the file's rate (recorded in the model: every record it reads is lined up the same)"]
    if choice and choice["chosen_s"]:  # found, but the skew was given as none
        return [f"skew:        none applied (channel_skew=0 given); the fit's scan finds the torque channel "
                f"{choice['chosen_s'] * 1e3:+.2f} ms behind position (lining up would remove "
                f"{100 * choice['residual_reduction']:.1f} % of the residual variance)"]
    if choice:
        return [f"skew:        none (the fit's scan: lining up by {choice['estimate_s'] * 1e3:+.2f} ms would remove "
                f"{100 * choice['residual_reduction']:.1f} % of the residual variance"
                + (", at the end of the candidates: a misfit, not a skew)"
                   if choice["estimate_s"] in (choice["candidates_s"][0], choice["candidates_s"][-1])
                   else ", too little to line up)")]
    return []


def summary_positions(model) -> np.ndarray:
    """The positions (rad) a summary reports: five across the identified range, its ends
    included (one for a stationary trial's model).

    The one choice of positions for every place that reports the physiology (the command
    line's summary, the validation, diagnosis and improve reports), so that a number printed
    by one can be found in the others."""
    lo, hi = model.scheduling_range
    return np.linspace(lo, hi, 5) if hi - lo > 1e-6 else np.array([lo])


def physiology_values(model) -> dict:
    """The identified physiology at :func:`summary_positions`, as numbers (None: not determined)."""
    rho = summary_positions(model)
    gain, thr = model.reflex_gain_threshold(rho)
    g_ok, th_ok = model.reflex_determined(rho)
    fit = model.fit or {}
    return {
        "scheduling": rho.tolist(),
        "stiffness": model.elastic_stiffness(rho).tolist(),
        "viscosity": model.viscosity(rho).tolist(),
        "reflex_gain": [float(g) if ok else None for g, ok in zip(gain, g_ok)],
        "reflex_threshold": [float(t) if ok else None for t, ok in zip(thr, th_ok)],
        "reflex_threshold_biased": bool(model.reflex_threshold_biased),
        "reflex_state_order": int(model.state_order),
        "reflex_delay_s": float(model.delay / model.fs),
        "vaf": fit.get("vaf"),
        "vaf_causal": fit.get("vaf_causal"),
        "channel_skew_s": float((model.conventions or {}).get("channel_skew_s", 0.0) or 0.0),
        "effects": [fe.name for fe in model.effects],
    }


def selection_lines(sel) -> list:
    """Lines of the structure selection (--structure cv): the chosen structure and a short CV table."""
    if not sel:
        return []
    if "skipped" in sel:
        effects = effects_cv_lines(sel.get("effects"))
        head = (f"structure:   basis orders and IRF as given (not selected: {sel['skipped']}); the effects "
                f"selected by CV (next line)" if effects else f"structure:   as given (not selected: {sel['skipped']})")
        return ([head] + effects
                + effects_cv_lines(sel.get("relaxation_term"), "relaxation:  forced on, its term by CV:"))
    short = {"irf_length": "L", "intrinsic_order": "intr", "reflex_order": "refl", "velocity_order": "vel",
             "reflex_delay": "delay", "elastic_curvature": "curv", "scheduling_extrapolation": "beyond range"}

    def text(s):
        return ", ".join(f"{short.get(k, k)} {1e3 * v:g} ms" if k in ("irf_length", "reflex_delay") else
                         f"{short.get(k, k)} {v}" for k, v in s.items())

    def effects(row):  # the allowed effects a row switches on (lpvpc.identification.identify: on/off candidates)
        return "" if "effects" not in row else f", effects {'+'.join(row['effects']) or 'none'}"

    chosen_effects = sel["effects"]["chosen"] if sel.get("effects") else None
    lines = [f"structure:   chosen by {sel['method']}: {text(sel['chosen'])}"
             + ("" if chosen_effects is None else f", effects {'+'.join(chosen_effects) or 'none'}"),
             f"             {'CV VAF %':>9} " + (f"{'later %':>8} " if "chosen_forward_vaf" in sel else "")
             + f"{'params':>6}  structure"]
    for row in sel["table"][:4]:  # the chosen, the best and the next: a few lines
        mark = "*" if row["settings"] == sel["chosen"] and row.get("effects", chosen_effects or []) == (
            chosen_effects or []) else " "
        later = f"{row['forward_vaf']:8.2f} " if "chosen_forward_vaf" in sel and "forward_vaf" in row else (
            f"{'':8} " if "chosen_forward_vaf" in sel else "")
        lines.append(f"           {mark} {row['cv_vaf']:9.2f} {later}{row['n_params']:6d}  {text(row['settings'])}"
                     f"{effects(row)}")
    orders = sel.get("state_order", {})
    if orders.get("cv_vaf"):
        lines.append(f"             reflex state order by CV: {orders['chosen']} (BIC {orders['bic']}; CV VAF % "
                     + ", ".join(f"order {k}: {v:.2f}" for k, v in orders["cv_vaf"].items()) + ")"
                     + (f"; with the effects, BIC's: {orders['with_effects']}" if "with_effects" in orders else ""))
    path = sel.get("reflex_path")
    if path:  # data that keep their file's higher rate: which velocity the reflex nonlinearity sees
        lines.append(f"             reflex nonlinearity by CV: {path['label']} (CV VAF % "
                     + ", ".join(f"{r['label']}: {r['cv_vaf']:.2f}" for r in path["table"]) + ")"
                     + (f"; {path['fallback']}" if path.get("fallback") else ""))
    return lines + effects_cv_lines(sel.get("effects"))


def effects_cv_lines(entry, head="effects cv: ") -> list:
    """Lines of the allowed effects' choice (lpvpc.identification.identify: on/off candidates of the selection),
    or of a forced stress relaxation's term (``head``)."""
    if not entry or not entry.get("allowed"):
        return []
    cv = entry.get("cv", {})

    def term(c):  # an effect with several terms (stress relaxation's averaging times): the one shown
        if "variant" not in c:
            return ""
        others = sorted(((v, x) for v, x in c["variants"].items() if v != c["variant"]), key=lambda t: -t[1])[:2]
        return (f", term {c['variant']} of {len(c['variants'])} (next: "
                + ", ".join(f"{v} {x:.2f}" for v, x in others) + ")")

    return [f"{head} {n} {'chosen' if n in entry['chosen'] else 'not chosen'} (CV VAF % on "
            f"{cv[n]['cv_vaf_on']:.2f}, off {cv[n]['cv_vaf_off']:.2f}{term(cv[n])}, reflex dynamics of a fit with "
            f"it; +{cv[n]['n_params']} parameters)" for n in entry["allowed"] if n in cv]


def relaxation_lines(model) -> list:
    """Both elastic stiffnesses of a model with stress relaxation, labelled, with units."""
    entry = (model.fit or {}).get("stiffness")
    if not entry:
        return []
    def why(x, k):  # a relaxed stiffness outside (0, short-range]: which side, in words
        return ("" if k <= 0 else "above the short-range: not relaxation; " if x > k else "below zero; " if x <= 0
                else "")

    def at(e):
        ok = e.get("determined", [True] * len(e["values"]))
        return ", ".join(f"{x:.1f} at {p:+.3f}" if good else
                         f"{x:.1f} ({why(x, k)}not determined by these data) at {p:+.3f}"
                         for x, p, good, k in zip(e["values"], entry["scheduling"], ok, entry["short_range"]["values"]))

    return [f"stiffness:   {e['label']}: {at(e)} {e['unit']}" for e in (entry["short_range"], entry["relaxed"])]


def physiology_lines(model) -> list:
    """Lines of the identified physiology: K(theta) at five positions, viscosity, reflex gain
    and threshold at the ends of the range, basis orders (what a user checks first)."""
    rho = summary_positions(model)
    K, B = model.elastic_stiffness(rho), model.viscosity(rho)
    gain, thr = model.reflex_gain_threshold(rho[[0, -1]])
    at = lambda v, r: ", ".join(f"{x:.1f} at {p:+.3f}" for x, p in zip(v, r))  # noqa: E731
    bias = (f" (threshold biased: rectifier seen on {model.nonlinearity_fs:g} Hz velocity)"
            if model.reflex_threshold_biased else "")
    s = model.settings
    g_ok, th_ok = model.reflex_determined(rho[[0, -1]])  # where an interval spans most of the plausible range
    gain = [f"{g:.2f}" if ok else NOT_DETERMINED for g, ok in zip(gain, g_ok)]
    thr = [f"{t:.3f}" if ok else NOT_DETERMINED for t, ok in zip(thr, th_ok)]
    if len(rho) == 1:  # a stationary trial: one operating point, one value each
        viscosity = f"B {B[0]:.2f} N m s/rad"
        g_text = f"{gain[0]} N m s/rad" if g_ok[0] else gain[0]  # (no unit after "not determined")
        reflex = f"{g_text}; threshold " + (f"{thr[0]} rad/s{bias}" if th_ok[0] else f"{NOT_DETERMINED}{bias}")
    else:
        viscosity = f"B {B.min():.2f}..{B.max():.2f} N m s/rad"
        if g_ok.all():
            reflex = f"{gain[0]} at {rho[0]:+.3f} .. {gain[-1]} at {rho[-1]:+.3f} N m s/rad"
        else:  # units on the numbers only ("not determined ... at -0.412 .. 14.01 at +0.197 N m s/rad" misread)
            reflex = ", ".join(f"{g} N m s/rad at {r:+.3f} rad" if ok else f"{g} at {r:+.3f} rad"
                               for g, ok, r in zip(gain, g_ok, rho[[0, -1]]))
        reflex += "; threshold " + (f"{NOT_DETERMINED}{bias}" if not th_ok.any() else f"{thr[0]} .. {thr[-1]} rad/s{bias}")
    return [
        f"stiffness:   K(theta) {at(K, rho)} N m/rad",
        f"viscosity:   {viscosity}",
        f"reflex gain: {reflex}",
    ] + gain_slope_lines(model) + [
        f"orders:      IRF lags {model.lags[0]}..{model.lags[-1]}, basis orders in position {s.get('intrinsic_order')} "
        f"(intrinsic), {s.get('reflex_order')} (reflex), velocity {s.get('velocity_order')}",
    ]


def gain_slope_lines(model, level=0.95) -> list:
    """The reflex gain's change with position (:func:`lpvpc.models.reflex_uncertainty.reflex_gain_slope`)
    as one line, its interval always given: the two ends the ``reflex gain`` line prints
    suggest a slope, and the data often bound its sign but not its size. Empty for a model of
    one operating position or without intervals.

    >>> from lpvpc import identify, pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> gain_slope_lines(identify(pair_trials(sim.pt, sim.ut)))[0].startswith("gain slope:  ")
    True
    """
    text = _gain_slope_text(model, level)
    return [] if text is None else [f"gain slope:  {text}"]


def _gain_slope_text(model, level=0.95):
    """The slope, its interval and whether its size is determined, in words (the one text of
    :func:`gain_slope_lines` and :func:`gain_slope_html`); None for a model of one operating
    position or without intervals."""
    from .reflex_uncertainty import reflex_gain_slope

    if len(summary_positions(model)) < 2 or not model.has_intervals:
        return None
    sl = reflex_gain_slope(model, level)
    text = (f"{sl['slope']:+.1f} N m s/rad per rad over position ({100 * level:g} % interval "
            f"{sl['lower']:+.1f}..{sl['upper']:+.1f})")
    return text if sl["determined"] else f"{text}: its size {NOT_DETERMINED} to within {100 * SLOPE_TOLERANCE:g} %"


def physiology_table_html(model, level=0.95) -> str:
    """The physiology table every report opens with: elastic stiffness K, viscosity B,
    reflex gain and threshold at the positions the command line prints.

    The one builder of the table in the validation, diagnosis and improve reports, so that a
    value reads the same in each of them and as ``lpvpc identify`` prints it
    (:func:`summary_positions`).

    Parameters
    ----------
    model : lpvpc.LPVPCModel
        The fitted model.
    level : float
        Confidence level of the intervals in brackets.

    Returns
    -------
    str
        HTML: the table, then the gain slope line (:func:`gain_slope_html`).

    Notes
    -----
    Each value has its ``level`` interval in brackets when the model carries intervals. A
    value whose interval spans most of its plausible range reads "not determined by these
    data"; for the reflex gain and threshold that is also the rule of
    :meth:`lpvpc.LPVPCModel.reflex_determined <lpvpc.models.model.LPVPCModel.reflex_determined>`,
    which the summary lines and the figures follow, so no report quotes a gain another
    calls undetermined. A model with stress relaxation has two elastic stiffnesses: the K
    column is then the short-range one and a relaxed-stiffness column follows it
    (:func:`relaxed_stiffness_cells`).
    """
    from ..report_html import table
    from .effects import RELAXED_LABEL, SHORT_RANGE_LABEL

    rho = summary_positions(model)
    K, B = model.elastic_stiffness(rho), model.viscosity(rho)
    G, th = model.reflex_gain_threshold(rho)
    has = model.has_intervals
    ci = {}
    if has:
        ci = {"K": model.elastic_stiffness_interval(rho, level), "B": model.viscosity_interval(rho, level),
              "G": model.reflex_gain_interval(rho, level), "th": model.reflex_threshold_interval(rho, level)}
    g_ok, th_ok = model.reflex_determined(rho, level)
    ok = {"G": g_ok, "th": th_ok}

    def cell(key, est, i, fmt):
        if (has and not ci[key].determined[i]) or (key in ok and not ok[key][i]):
            return f"<em>{NOT_DETERMINED}</em>"
        if not has:
            return fmt.format(est[i])
        return (f"{fmt.format(est[i])} <span class=\"small\">({fmt.format(ci[key][0][i])}–"
                f"{fmt.format(ci[key][1][i])})</span>")

    rows = [[f"{r:+.3f} ({np.degrees(r):+.0f}°)", cell("K", K, i, "{:.1f}"), cell("B", B, i, "{:.2f}"),
             cell("G", G, i, "{:.2f}"), cell("th", th, i, "{:.2f}")] for i, r in enumerate(rho)]
    head = ["position (rad)", "elastic stiffness K (N m/rad)", "viscosity B (N m s/rad)", "reflex gain (N m s/rad)",
            "reflex threshold (rad/s)"]
    if has_relaxed_stiffness(model):  # both stiffnesses, each labelled as the summary's lines are
        head[1:2] = [f"{SHORT_RANGE_LABEL}, K (N m/rad)", f"{RELAXED_LABEL} (N m/rad)"]
        for row, relaxed in zip(rows, relaxed_stiffness_cells(model, rho, level)):
            row.insert(2, relaxed)
    return table(head, rows) + gain_slope_html(model, level)


def has_relaxed_stiffness(model) -> bool:
    """Whether ``model`` has stress relaxation, hence a relaxed stiffness besides the
    short-range one (the physiology table's extra column, the reports' note on it)."""
    return any(fe.name == "stress_relaxation" for fe in getattr(model, "effects", None) or ())


def relaxed_stiffness_cells(model, rho, level=0.95) -> list:
    """The relaxed-stiffness column of :func:`physiology_table_html`: one HTML cell per
    position ``rho`` (rad) of a model with stress relaxation.

    Each cell is the relaxed stiffness (:func:`lpvpc.models.effects.relaxation_stiffnesses`),
    with its ``level`` interval in brackets when the model carries intervals and stress
    relaxation is its one effect (:func:`lpvpc.models.uncertainty.relaxed_stiffness_interval`;
    beside another effect there is none). Outside (0, short-range] the value is the slow
    averages extrapolated beyond the record's holds, the rule of the model file's
    ``fit.stiffness`` entry (:func:`lpvpc.models.effects.relaxation_stiffness_entry`): it is
    shown, marked not determined by these data, as the summary line shows it.
    """
    from .effects import relaxation_stiffnesses
    from .uncertainty import relaxed_stiffness_interval

    short, relaxed = relaxation_stiffnesses(model, rho)
    band = None
    if model.has_intervals:
        try:
            band = relaxed_stiffness_interval(model, rho, level)[1:]
        except ValueError:  # another effect beside stress relaxation: no interval for it
            band = None
    cells = []
    for i, (k, s) in enumerate(zip(relaxed, short)):
        ci_k = "" if band is None else f" <span class=\"small\">({band[0][i]:.1f}–{band[1][i]:.1f})</span>"
        cells.append(f"{k:.1f}{ci_k}" if 0.0 < k <= s else f"{k:.1f} <em>({NOT_DETERMINED})</em>")
    return cells


def gain_slope_html(model, level=0.95) -> str:
    """The gain slope :func:`gain_slope_lines` prints, as a small paragraph under a report's
    physiology table (empty when there is no line).

    >>> from lpvpc import identify, pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> gain_slope_html(identify(pair_trials(sim.pt, sim.ut))).startswith('<p class="small">Reflex gain slope:')
    True
    """
    from html import escape

    text = _gain_slope_text(model, level)
    return "" if text is None else f'<p class="small">Reflex gain slope: {escape(text)}</p>'
