"""The improve loop: fit, diagnose on held-out data, add the top significant effect (or
change the setting the diagnosis names), refit, until nothing significant is left.

Units: torque N m, VAF % (gains in percentage points).

Each rung of the ladder is a real refit of the extended model on the identification
record (:class:`lpvpc.identification.identify.LPVPCEstimator` with ``effects=...``), evaluated on the
held-out record, which is also the record the diagnosis cross-validates on. Because the
held-out record guides the choice of effects, its final VAF is slightly optimistic as an
estimate for a third record (the choice is among few candidates; the gains it reports
are cross-validated within the record). A refit that does not improve the held-out VAF
stops the loop and is reported, not kept.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .diagnose import Diagnosis, diagnose, format_table
from .candidates import _variant_text
from ..models.effects import CATALOG, reads_activation, signals_from_data, with_model_activation
from ..identification.identify import LPVPCEstimator, WarmStart
from ..linalg import on_one_blas_thread
from ..models.model import vaf
from ..progress import report

MAX_STEPS = 6
NO_GAIN = 0.02  # pp: a refit that gains less than this on held-out data is not kept


@dataclass
class Rung:
    """One model of the ladder."""

    index: int
    label: str
    change: dict  # {} (base), {"effect": name} or {"setting": {name: value}}
    settings: dict
    effects: tuple
    model: object
    heldout_vaf: float
    heldout_rmse: float
    fit_vaf: float
    residual: np.ndarray
    diagnosis: Diagnosis | None = None
    fit_time: float = 0.0
    diagnosis_time: float = 0.0
    kept: bool = True

    def __repr__(self):
        kept = "" if self.kept else ", not kept"
        return f"Rung({self.index}: {self.label!r}, held-out VAF {self.heldout_vaf:.2f} %{kept})"

    def to_dict(self) -> dict:
        top = self.diagnosis.top if self.diagnosis is not None else None
        return {
            "step": self.index, "label": self.label, "change": self.change, "kept": self.kept,
            "effects": list(self.effects), "settings": {k: v for k, v in self.settings.items()},
            "heldout_vaf": round(self.heldout_vaf, 3), "heldout_rmse": round(self.heldout_rmse, 6),
            "fit_vaf": round(self.fit_vaf, 3), "fit_time_s": round(self.fit_time, 3),
            "diagnosis_time_s": round(self.diagnosis_time, 3), "model_hash": self.model.model_hash,
            "top_significant": None if top is None else {"effect": top.effect, "vaf_gain": round(top.vaf_gain, 3),
                                                         "variant": top.variant},
        }


@dataclass
class Ladder:
    """The steps :func:`improve` took, from the base model to the last one kept.

    Parameters
    ----------
    rungs : list of Rung
        Every step in order (step 0 the base model); a step that did not raise the held-out
        VAF is kept in the list with ``kept`` False.
    stopped : str
        Why the loop ended (no significant candidate left, no held-out gain, the step limit).

    Attributes
    ----------
    kept : list of Rung
        The steps kept.
    final : Rung
        The last step kept: the improved model (``final.model``) and its held-out VAF.
    """

    rungs: list = field(default_factory=list)
    stopped: str = ""

    @property
    def kept(self) -> list:
        return [r for r in self.rungs if r.kept]

    def __repr__(self):
        if not self.rungs:
            return "Ladder(empty)"
        first, last = self.rungs[0], self.final
        return (f"Ladder({len(self.rungs)} steps, held-out VAF {first.heldout_vaf:.2f} -> {last.heldout_vaf:.2f} %; "
                f"final: {last.label!r})")

    @property
    def final(self) -> Rung:
        return self.kept[-1]

    def table(self) -> str:
        lines = [f"{'step':>4}  {'model':44} {'held-out VAF':>12} {'RMSE (N m)':>11}  next (top significant candidate)"]
        for r in self.rungs:
            top = r.diagnosis.top if r.diagnosis is not None else None
            nxt = "-" if not r.kept else ("none" if top is None else
                                         f"{top.effect}{_variant_text(top.variant)} (+{top.vaf_gain:.2f} pp)")
            mark = "" if r.kept else "  [not kept: no held-out gain]"
            lines.append(f"{r.index:>4}  {r.label[:44]:44} {r.heldout_vaf:>10.2f} % {r.heldout_rmse:>11.4f}  {nxt}{mark}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"format": "lpvpc-improve", "steps": [r.to_dict() for r in self.rungs], "stopped": self.stopped,
                "final": {"effects": list(self.final.effects), "settings": self.final.settings,
                          "heldout_vaf": round(self.final.heldout_vaf, 3)},
                "units": {"heldout_vaf": "%", "heldout_rmse": "N m"}}


def physiology(model, rho) -> dict:
    """Elastic stiffness K (N m/rad) and reflex gain (N m s/rad) of a model at positions
    ``rho`` (rad): what a step of the ladder changes in the physiology it reports."""
    rho = np.asarray(rho, dtype=float)
    return {"K": model.elastic_stiffness(rho), "reflex_gain": model.reflex_gain_threshold(rho)[0]}


def _ladder_positions(ladder: Ladder) -> np.ndarray:
    """The positions (rad) the ladder reports: the ones ``lpvpc identify`` prints for the
    base model (:func:`lpvpc.models.summary.summary_positions`; one for a stationary trial)."""
    from ..models.summary import summary_positions

    return summary_positions(ladder.rungs[0].model)


def _evaluate(model, data):
    pred = model.predict(data, warn=False, signals=signals_from_data(data))  # as every door predicts the record
    r = np.asarray(data.torque) - pred.total
    return vaf(data.torque, pred.total), float(np.sqrt(np.mean(r**2))), r


@on_one_blas_thread
def improve(ident, heldout, *, settings=None, max_steps=MAX_STEPS, diagnose_kw=None, progress=None) -> Ladder:
    """Fit, diagnose on held-out data, add the top significant effect, refit, until none is left.

    Each step changes one thing from the step below it (an effect of the catalog or a setting
    the diagnosis found significant) and is kept only when the held-out VAF rises; the loop
    stops when the diagnosis names nothing significant, a step does not help, or after
    ``max_steps``.

    Parameters
    ----------
    ident : lpvpc.io.PerturbationData
        The identification record.
    heldout : lpvpc.io.PerturbationData
        The held-out record each step is diagnosed and scored on (at least 20 s: the
        diagnosis's cross-validation folds).
    settings : dict, optional
        Estimator settings of the base model (:class:`~lpvpc.identification.identify.LPVPCEstimator`; may include
        ``effects``). Default: identify's defaults.
    max_steps : int, optional
        The most effects or settings added (default ``MAX_STEPS``).
    diagnose_kw : dict, optional
        Keywords for each step's :func:`lpvpc.diagnosis.diagnose.diagnose`.
    progress : callable, optional
        Receives each :class:`Rung` as it is made.

    Returns
    -------
    Ladder
        Every step, the kept ones, and ``final``: the improved model.

    Raises
    ------
    lpvpc.errors.InsufficientExcitationError
        A held-out record too short or mostly outside the identified range for a diagnosis.

    Examples
    --------
    >>> from lpvpc import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> from lpvpc import hold_out
    >>> ident, held = hold_out(data, 0.4)
    >>> ladder = improve(ident, held, max_steps=1)
    >>> ladder.rungs[0].label, ladder.final.heldout_vaf >= ladder.rungs[0].heldout_vaf
    ('base model', True)
    """
    settings = dict(settings or {})
    effects = tuple(settings.pop("effects", ()) or ())
    diagnose_kw = dict(diagnose_kw or {})
    ladder = Ladder()
    applied = set()

    def rung(index, label, change, st, eff, poles_from=None):
        t0 = time.perf_counter()
        report(f"improve: step {index} ({label}): fitting")
        model = LPVPCEstimator(**st, effects=eff).fit(ident).model_
        if poles_from is not None:
            # The reflex poles' refinement from MOESP's start and from where the model below ended
            # (as identify's own refit of a selected structure starts): the better identification
            # fit is kept (same parameters); either start alone failed a step
            # (docs/design_notes.md, "Improve: the reflex poles' two starts").
            est = LPVPCEstimator(**st, effects=eff)
            below = est._fit_from(ident, WarmStart(poles={int(poles_from.A.shape[0]): np.asarray(poles_from.A,
                                                                                                 dtype=float)})).model_
            if below.fit["vaf"] > model.fit["vaf"]:
                model = below
        t_fit = time.perf_counter() - t0
        v, rmse, r = _evaluate(model, heldout)
        return Rung(index, label, change, dict(st), tuple(eff), model, v, rmse, model.fit["vaf"], r, fit_time=t_fit)

    def diagnose_rung(r):
        t0 = time.perf_counter()
        report(f"improve: step {r.index} ({r.label}): diagnosing on the held-out record (every candidate, "
               f"cross-validated)")
        # with the identification record: an effect whose signal differs between the two records
        # (the background activation) is tried between them too (lpvpc.diagnosis.between)
        r.diagnosis = diagnose(r.model, heldout, **{"reference": ident, **diagnose_kw})
        r.diagnosis_time = time.perf_counter() - t0

    label0 = "base model" + (f" + {', '.join(effects)}" if effects else "")
    current = rung(0, label0, {}, settings, effects)
    # every step changes one thing from the base's structure: the one its cross-validation
    # chose (an extended model is not selected: it would fall back to the default structure)
    # (its structure, the reflex path and the effects it switched on: a later rung refitted
    # without them would change two things at once)
    selected = current.model.fit.get("structure_selection") or {}
    chosen = selected.get("chosen")
    if chosen:
        path = (selected.get("reflex_path") or {}).get("chosen") or {}
        settings = {**settings, **chosen, **path, "state_order": current.model.fit["state_order"],
                    "structure": "fixed"}
        current.settings = dict(settings)
        effects = effects + tuple(e for e in (selected.get("effects") or {}).get("chosen", ()) if e not in effects)
        if effects != current.effects:
            current.effects = effects
            current.label = "base model + " + ", ".join(effects)
    # the effects the base model has (a stationary trial's selection chooses its effects without a
    # "chosen" structure): the rung names what its model holds
    held = tuple(fe.name for fe in current.model.effects or ())
    if any(e not in effects for e in held):
        effects = effects + tuple(e for e in held if e not in effects)
        current.effects = effects
        current.label = "base model + " + ", ".join(effects)
    # the stress-relaxation term the base's cross-validation chose (the catalog's, refitted, would
    # change the base too)
    term = {k: current.model.settings[k] for k in ("relaxation_times", "relaxation_order")
            if current.model.settings.get(k) is not None}
    if term:
        settings = {**settings, **term}
        current.settings = dict(settings)
    # the background activation from the EMG, its reflex bursts explained by the base model's
    # own reflex drive: computed once, so every rung is fitted and scored on the same estimate
    ident, heldout = (with_model_activation(d, current.model) for d in (ident, heldout))
    if reads_activation(effects):  # the base's own effects read the activation: refit on the estimate
        current = rung(0, label0, {}, settings, effects, poles_from=current.model)
    diagnose_rung(current)
    ladder.rungs.append(current)
    if progress:
        progress(current)
    while True:
        if len(ladder.kept) > max_steps:
            ladder.stopped = f"stopped after {max_steps} steps (max_steps)"
            break
        cands = [c for c in current.diagnosis.significant
                 if (c.effect, json.dumps(c.variant, sort_keys=True)) not in applied]
        if not cands:
            ladder.stopped = "nothing significant left"
            break
        top = cands[0]
        applied.add((top.effect, json.dumps(top.variant, sort_keys=True)))
        st, eff = dict(current.settings), tuple(current.effects)
        if top.kind == "effect":
            eff = eff + (top.effect,)
            change, label = {"effect": top.effect}, f"+ {top.effect}"
        else:
            st.update(top.variant)
            change, label = {"setting": dict(top.variant)}, f"{top.effect}{_variant_text(top.variant)}"
        new = rung(len(ladder.rungs), label, change, st, eff, poles_from=current.model)
        if new.heldout_vaf < current.heldout_vaf + NO_GAIN:
            new.kept = False
            ladder.rungs.append(new)
            if progress:
                progress(new)
            ladder.stopped = (f"the refit with {label} did not improve the held-out VAF "
                              f"({new.heldout_vaf:.2f} % vs {current.heldout_vaf:.2f} %): not kept")
            break
        diagnose_rung(new)
        ladder.rungs.append(new)
        if progress:
            progress(new)
        current = new
    return ladder


def write_report(ladder: Ladder, heldout, folder, *, syntax: str = "cli") -> Path:
    """The improve report (``report.html``, self-contained) and ``improve.md``: the ladder
    (one row per step: what it added, held-out VAF and RMSE before and after, K and reflex
    gain before and after), then folded the residual before and after each step; each kept
    model's diagnosis is its own report in ``stepN/``. ``syntax``: how the reports name
    options, "cli" (the default, as the command line spells them) or "python"."""
    import matplotlib.pyplot as plt

    from .. import plotting
    from .diagnose import write_report as write_diagnosis

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ladder.json").write_text(json.dumps(ladder.to_dict(), indent=1) + "\n")
    steps = [{"label": r.label if r.kept else r.label + " (not kept)", "heldout_vaf": r.heldout_vaf,
              "heldout_rmse": r.heldout_rmse} for r in ladder.rungs]
    fig, ax = plt.subplots(figsize=(7, 4))
    plotting.plot_ladder(steps, ax)
    fig.tight_layout()
    fig.savefig(folder / "ladder.png", dpi=110)
    plt.close(fig)
    lines = ["# Improve: the model ladder", "",
             f"Identification on the identification record; VAF and RMSE on the held-out record "
             f"`{getattr(heldout, 'source', '')}`.", "", "```", ladder.table(), "```", "",
             f"Stopped: {ladder.stopped}.", "", "![ladder](ladder.png)", ""]
    rho = _ladder_positions(ladder)
    phys = {r.index: physiology(r.model, rho) for r in ladder.rungs}
    for key, what in (("K", "Elastic stiffness K (N m/rad)"), ("reflex_gain", "Reflex gain (N m s/rad)")):
        lines += [f"{what} of each model at positions (rad):", "", "| step | model | "
                  + " | ".join(f"{x:+.3f}" for x in rho) + " |", "|---|---|" + "---|" * len(rho)]
        lines += [f"| {r.index} | {r.label} | " + " | ".join(f"{v:.2f}" for v in phys[r.index][key]) + " |"
                  for r in ladder.rungs]
        lines.append("")
    prev = None
    for r in ladder.rungs:
        lines += [f"## Step {r.index}: {r.label}" + ("" if r.kept else " (not kept)"), "",
                  f"held-out VAF {r.heldout_vaf:.2f} %, RMSE {r.heldout_rmse:.4f} N m; identification VAF "
                  f"{r.fit_vaf:.2f} %; fit {r.fit_time:.1f} s" +
                  (f", diagnosis {r.diagnosis_time:.1f} s" if r.diagnosis is not None else ""), ""]
        if r.change.get("effect"):
            lines += [f"Effect: {CATALOG[r.change['effect']].explanation}", ""]
        if prev is not None:
            lines += [_change_text(phys[prev.index], phys[r.index], rho, prev.index, r.index), ""]
            fig, axes = plt.subplots(1, 2, figsize=(9.6, 3.2))
            plotting.plot_residual_change(heldout.time, heldout.torque, prev.residual, r.residual,
                                          labels=(f"step {prev.index}", f"step {r.index}"), fs=heldout.fs, axes=axes)
            fig.tight_layout()
            name = f"residual_step{r.index}.png"
            fig.savefig(folder / name, dpi=100)
            plt.close(fig)
            lines += [f"Residual before (step {prev.index}) and after (step {r.index}):", "", f"![residual]({name})", ""]
        if r.diagnosis is not None:
            sub = folder / f"step{r.index}"
            write_diagnosis(r.diagnosis, heldout, sub, title=f"Diagnosis after step {r.index} ({r.label})",
                            syntax=syntax)
            lines += [f"Diagnosis: {r.diagnosis.answer()} ([details](step{r.index}/diagnosis.md))", "",
                      "```", format_table(r.diagnosis, 5, syntax=syntax), "```", ""]
        if r.kept:
            prev = r
    (folder / "improve.md").write_text("\n".join(lines))
    path = folder / "report.html"
    path.write_text(_html(ladder, heldout, folder, syntax))
    return path


def _change_text(before: dict, after: dict, rho, i: int, j: int) -> str:
    """K and reflex gain before and after a step, position by position."""
    def pairs(key, fmt):
        return ", ".join(f"{fmt.format(a)} -> {fmt.format(b)} at {x:+.2f}" for a, b, x in zip(before[key], after[key], rho))
    return (f"Step {i} -> step {j}: K {pairs('K', '{:.1f}')} N m/rad; reflex gain {pairs('reflex_gain', '{:.2f}')} "
            f"N m s/rad.")


def _draw_before_after(ladder: Ladder, path: Path) -> Path:
    """K and reflex gain over position of the base and the final model (each quantity on
    its own axis; the final model with its confidence bands)."""
    from ..report_html import new_figure, save_figure
    from .. import plotting

    first, last = ladder.rungs[0], ladder.final
    fig = new_figure(9, 2.9)
    axes = fig.subplots(1, 2)
    plotting.plot_stiffness_and_reflex(last.model, axes, marks=_ladder_positions(ladder))
    if last is not first and not first.model.one_position:
        lo, hi = first.model.scheduling_range
        rho = np.linspace(lo, hi, 121)
        axes[0].plot(rho, first.model.elastic_stiffness(rho), color="0.3", ls="--", lw=1.2, label="base model")
        g_ok = first.model.reflex_determined(rho)[0]
        axes[1].plot(rho, np.where(g_ok, first.model.reflex_gain_threshold(rho)[0], np.nan), color="0.3", ls="--",
                     lw=1.2, label="base model")
        for ax in axes:
            ax.legend(fontsize="small", loc="upper left", frameon=False)
    save_figure(fig, path)
    return path


def _html(ladder: Ladder, heldout, folder: Path, syntax: str = "cli") -> str:
    """Self-contained HTML, the ladder first: one row per step (what it added, held-out VAF
    and RMSE before and after, K and reflex gain at the command line's positions before and
    after), the final model's physiology with its intervals, what to do next; each step's
    residual and the diagnosis that chose the next step folded below (the full diagnosis of
    each step is its own report, ``stepN/report.html``)."""
    from ..models.summary import physiology_table_html
    from ..models.uncertainty import NOT_DETERMINED
    from ..report_html import breakable as _breakable
    from ..report_html import escape as _e
    from ..report_html import glossary as _glossary
    from ..report_html import inline_figure as _html_img
    from ..report_html import page as _html_page
    from ..report_html import table as _table

    first, last = ladder.rungs[0], ladder.final
    rho = _ladder_positions(ladder)
    phys = {r.index: physiology(r.model, rho) for r in ladder.rungs}
    g_ok = {r.index: r.model.reflex_determined(rho)[0] for r in ladder.rungs}

    def values(r, key, fmt):
        ok = g_ok[r.index] if key == "reflex_gain" else np.ones(len(rho), bool)
        return " / ".join(fmt.format(v) if good else "n.d." for v, good in zip(phys[r.index][key], ok))

    rows, prev = [], None
    for r in ladder.rungs:
        added = ("base model" + (f" (with {', '.join(r.effects)})" if r.effects else "")) if r.index == 0 else \
            (f"added {r.change['effect']}" if r.change.get("effect") else f"changed {r.label}")
        added = _breakable(added) + ("" if r.kept else " <b>(not kept: no held-out gain)</b>")
        vaf = f"{r.heldout_vaf:.2f}" if prev is None else f"{prev.heldout_vaf:.2f} &rarr; {r.heldout_vaf:.2f}"
        rmse = f"{r.heldout_rmse:.4f}" if prev is None else f"{prev.heldout_rmse:.4f} &rarr; {r.heldout_rmse:.4f}"
        rows.append([str(r.index), added, vaf, rmse, values(r, "K", "{:.1f}"), values(r, "reflex_gain", "{:.2f}")])
        if r.kept:
            prev = r
    where = (f"at {rho[0]:+.3f} rad" if len(rho) == 1 else
             "at " + ", ".join(f"{x:+.3f}" for x in rho) + " rad")
    final_effects = ", ".join(last.effects) or "no effects"
    parts = ["<h1>Improve: the model ladder</h1>",
             f"<p class=\"small\">Each model is identified on the identification record and judged on the held-out "
             f"record <code>{_e(getattr(heldout, 'source', ''))}</code>.</p>",
             '<section class="answer" id="answer"><h2>Answer</h2>',
             f"<p class=\"lead\">Held-out VAF <b>{first.heldout_vaf:.2f} % &rarr; {last.heldout_vaf:.2f} %</b> (RMSE "
             f"{first.heldout_rmse:.4f} &rarr; {last.heldout_rmse:.4f} N m) in {len(ladder.kept) - 1} kept "
             f"step{'s' if len(ladder.kept) != 2 else ''}; final model: <b>{_e(final_effects)}</b>. Stopped: "
             f"{_e(ladder.stopped)}.</p>",
             f"<p>One row per step; K and the reflex gain {where} (the positions <code>lpvpc identify</code> prints; "
             f"n.d.: {NOT_DETERMINED}):</p>",
             '<div class="wide">' + _table(["step", "what it added", "held-out VAF (%)", "held-out RMSE (N m)",
                                            "K (N m/rad)", "reflex gain (N m s/rad)"], rows, left=(1, 4, 5)) + "</div>",
             _html_img(_draw_before_after(ladder, folder / "before_after.png"),
                       "K and reflex gain of the final model (bands: 95 % confidence) and of the base model (dashed)")]
    val = ("<code>lpvpc validate FINAL.json --pt PT3 --ut UT3</code>" if syntax == "cli" else
           "<code>lpvpc.validate(final_model, third_record)</code>")
    parts.append(f"<p><b>Next:</b> the held-out record chose the steps, so its VAF flatters the final model a little: "
                 f"validate the final model (the file given with <code>-o</code>) on a third record, {val}.</p>"
                 if syntax == "cli" else
                 f"<p><b>Next:</b> the held-out record chose the steps, so its VAF flatters the final model a little: "
                 f"validate it on a third record, {val}.</p>")
    parts.append(f"<details><summary>The final model's physiology with its 95 % intervals</summary>"
                 f"{physiology_table_html(last.model)}</details>")
    parts.append("</section>")
    parts.append("<details><summary>Each step: what it changed, its residual before and after, what the diagnosis "
                 "found next</summary>")
    parts.append(_html_img(folder / "ladder.png", "Held-out VAF and RMSE of each model on the ladder"))
    prev = None
    for r in ladder.rungs:
        parts.append(f"<h3>Step {r.index}: {_e(r.label)}{'' if r.kept else ' (not kept)'}</h3>")
        parts.append(f"<p>held-out VAF {r.heldout_vaf:.2f} %, RMSE {r.heldout_rmse:.4f} N m; identification VAF "
                     f"{r.fit_vaf:.2f} %; fit {r.fit_time:.1f} s"
                     + (f", diagnosis {r.diagnosis_time:.1f} s" if r.diagnosis is not None else "") + ".</p>")
        if r.change.get("effect"):
            parts.append(f"<p class=\"what\">{_e(CATALOG[r.change['effect']].explanation)}</p>")
        if prev is not None:
            parts.append(f"<p>{_e(_change_text(phys[prev.index], phys[r.index], rho, prev.index, r.index))}</p>")
        if r.kept:
            prev = r
        png = folder / f"residual_step{r.index}.png"
        if png.is_file():
            parts.append(_html_img(png, f"Held-out residual before and after step {r.index}"))
        if r.diagnosis is not None:
            parts.append(f"<p>Diagnosis of this model on the held-out record: {_e(r.diagnosis.answer())} "
                         f"(<a href=\"step{r.index}/report.html\">its report</a>)</p>")
    parts.append("</details>")
    parts.append(_glossary())
    return _html_page("lpvpc improve report", "\n".join(parts))
