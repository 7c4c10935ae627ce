"""Diagnosis judged over a population of virtual subjects (lpvpc.simulation.population), not one.

Effect draws: for each effect of :data:`lpvpc.simulation.population.POPULATION_EFFECTS`, N draws
(``--draws``, default 30); each is ``draw_subject(seed, effect=name)``: its form, its subject
(stiffness shape, mechanics, reflex, noise, EMG) and its perturbation design are all drawn
from the seed. Per draw: a 2-minute identification pair and a 2-minute novel pair at 1 kHz,
paired and decimated as the loaders do (``lpvpc.pair_trials``); the improve ladder
(``lpvpc.improve(ident, novel)``: the base model identified on the identification pair, diagnosed
on the held-out novel pair with ``lpvpc.diagnose``, the first significant candidate added,
refitted and diagnosed again, until nothing significant is left), as
benchmarks/bench_diagnose.py runs it; and the same subject's clean model:
``lpvpc.identify`` on the subject without its effect (``simulate_subject(..., clean=True)``,
the same seed, noise and trajectories), its held-out VAF on the clean novel pair computed as the
ladder computes its own (``model.predict`` with ``signals_from_data``). Recorded: seed,
effect, form, design, the base diagnosis's first significant candidate (effect, pathway,
signals), whether it is right, the ladder's final held-out VAF, the clean model's, and
whether the ladder ends within 1 point of it; also each novel pair's noise ceiling (the VAF
of its noise-free torque) and where the right catalog entry ranked in the base diagnosis
(its gain and p), so that a miss can be told from an effect the data hardly show.

"Right" comes from the diagnosis catalog (:data:`lpvpc.models.effects.CATALOG`): every
catalog entry names its pathway and the signals its term reads; an entry that reads no extra
signal reads position alone (the scheduling variable). The population effect's own catalog
entry (the names are shared) gives the right (pathway, signals), except background activation,
whose form says which pathway it changes: "intrinsic" is the catalog's
``background_activation`` (intrinsic, activation), "reflex" its ``activation_reflex_gain``
(reflex, activation), "both" either; so is a "reflex" form whose two trials have their own
activation (its tonic torque is then intrinsic torque in the paired record: :func:`accepted`). The first significant candidate names the right pathway
and signal when it is a catalog effect (not a settings candidate: those say an estimator
setting is wrong, not what the subject does) with that pathway and those signals; so a
position-dependent reflex delay named as position-dependent reflex dynamics (reflex,
position) is right, habituation named as activation-scaled reflex gain (reflex, activation
instead of trial time) is not. When the base model already holds a right entry (identify's
cross-validation may switch an effect on), it counts as named. A stricter column counts the
entry itself (or the entry the top candidate is tied with). A draw that raises is a row with
its one-line reason and a miss in every count.

Clean draws (``--clean``, default 100): ``draw_subject(seed)`` without an effect; the model
identified on the identification pair and diagnosed on the novel pair: is any candidate
significant (a false alarm)?

Targets: named right on at least 90 % of effect draws, the ladder within 1 point of the clean
model on at least 90 %, false alarms on at most 2 % of clean draws. Every share is given with
its 95 % Wilson score interval.

Seeds: DEVELOPMENT_SEEDS by default; ``--record`` uses RECORD_SEEDS (for results recorded after
the methods are settled). Effect k of POPULATION_EFFECTS draws seeds start + k * SEED_BLOCK
onward, the clean draws start + 5 * SEED_BLOCK onward, so no subject repeats across effects;
``--first-seed I`` starts each at its start + I instead (a fresh range: a run with it is recorded
as its own section). Every run also writes its rows, with every candidate of each base
diagnosis over the base alone (gain, p, p_mean, whether its signal leaks), to
benchmarks/out/population_diagnosis_candidates.json (git-ignored data) (one entry per command), so that
significance rules can be compared offline (benchmarks/population_significance_rules.py).
A development run at the defaults writes benchmarks/results/population_diagnosis.txt
(a record run population_diagnosis_record.txt); a run with other numbers of draws is recorded
as its own section below the default run's table (replacing an earlier section of the same
command). ``--jobs N`` runs the draws in a pool of N forked processes, each with one BLAS thread
(the figures do not depend on it). The wall time of a full run is estimated in the results
from the measured time per draw (``--draws 1 --clean 1`` measures one draw per effect);
``--profile EFFECT`` profiles one draw of EFFECT ("clean" for a clean draw) with cProfile and
writes its largest costs to benchmarks/results/population_diagnosis_profile.txt.

``--position-noise RAD``: the position sensor's noise floor in every trial (the population has
none; the lab's pilot trial about 5e-5 rad), recorded as its own section.

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_population_diagnosis.py [--draws N] [--clean N] [--first-seed I] [--jobs N] [--record] [--position-noise RAD]
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import lpvpc  # noqa: E402
from lpvpc.diagnosis.candidates import LEAK_R2, TIES, _tie_p  # noqa: E402
from lpvpc.diagnosis.cv import robust_paired_test  # noqa: E402
from lpvpc.models.effects import CATALOG, signals_from_data  # noqa: E402
from lpvpc.simulation.population import (DEVELOPMENT_SEEDS, POPULATION_EFFECTS, RECORD_SEEDS,  # noqa: E402
                                         draw_subject, simulate_subject)
from _results import RESULTS, add_position_noise_option, position_noise_text, write_results  # noqa: E402

SEED_BLOCK = 10_000  # seeds per effect (and for the clean draws)
DEFAULT_DRAWS, DEFAULT_CLEAN = 30, 100
WITHIN = 1.0  # points of held-out VAF: the ladder's end against the clean model's
Z95 = 1.959963984540054
TARGETS = {"named": 0.90, "ladder": 0.90, "alarm": 0.02}
EFFECTS = tuple(POPULATION_EFFECTS)


def accepted(effect, form, effect_params=None):
    """The catalog entries that are a right answer for a population effect in ``form`` (its
    drawn ``effect_params``: a background activation's ``shared`` and ``tonic_torque``).

    Every form of background activation also adds a tonic torque in proportion to the
    activation. Shared by the two trials it cancels in PT - UT; when each trial has its own
    activation it is intrinsic torque in the paired record (development seed 10019, "reflex"
    form: 48 % of the effect torque's variance), which the catalog's ``background_activation``
    takes by its tonic-torque terms. So a "reflex" form with an unshared activation takes
    either entry, as "both" does.

    >>> accepted("background_activation", "reflex", {"shared": True, "tonic_torque": 1.0})
    ('activation_reflex_gain',)
    >>> accepted("background_activation", "reflex", {"shared": False, "tonic_torque": 1.0})
    ('background_activation', 'activation_reflex_gain')
    """
    if effect == "background_activation":
        p = effect_params or {}
        if form == "reflex" and p and not p.get("shared", True) and p.get("tonic_torque", 0.0) > 0:
            form = "both"
        return {"intrinsic": ("background_activation",), "reflex": ("activation_reflex_gain",),
                "both": ("background_activation", "activation_reflex_gain")}[form]
    return (effect,)


def where(name):
    """(pathway, signals) of a catalog entry; an entry reading no extra signal reads position."""
    e = CATALOG[name]
    return e.pathway, tuple(sorted(e.signals)) or ("position",)


def wilson(k, n, z=Z95):
    """Wilson score interval of the share k / n (0..1)."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - h), min(1.0, c + h)


def share(k, n):
    lo, hi = wilson(k, n)
    return f"{k}/{n} = {100 * k / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]" if n else "-"


def _one_line(text, limit=200):
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


#: rad: white noise in each trial's recorded position (``--position-noise``; the forked workers
#: inherit it)
POSITION_NOISE = 0.0


def _pairs(s, clean=False):
    """The identification and novel PerturbationData of subject ``s`` and the novel pair's
    noise ceiling (VAF % of its noise-free torque)."""
    ident, novel = (simulate_subject(s, t, clean=clean, position_noise=POSITION_NOISE) for t in ("multilevel", "novel"))
    nv = lpvpc.pair_trials(novel.pt, novel.ut)
    ceiling = lpvpc.vaf(nv.torque, lpvpc.pair_trials(novel.pt_clean, novel.ut_clean).torque)
    return lpvpc.pair_trials(ident.pt, ident.ut), nv, ceiling


def heldout_vaf(model, data):
    """Held-out VAF (%) as the improve ladder computes its rungs'."""
    return lpvpc.vaf(data.torque, model.predict(data.position, data.scheduling, warn=False,
                                                signals=signals_from_data(data)).total)


def candidate_records(d):
    """Every candidate of diagnosis ``d`` over the base alone, for judging significance rules
    offline: {"cands": {name: [gain, p, p_mean, leaky, significant] or None (not available)},
    "ties": {"a|b": two-sided tie p}, "n_available": n}. ``gain`` is the marginal held-out VAF
    gain (pp); ``p``, ``p_mean`` its test recomputed from the marginal residual (the forward
    selection overwrites a ranked candidate's p with its conditional one); ``leaky``: 1 when
    the candidate reads a signal the model's reflex drive explains (not named); the ties are
    the :data:`TIES` pairs' marginal residuals compared. Pathway and signals: the catalog's."""
    block_s = (d.settings or {}).get("block_s", 2.0)
    cands = {}
    for c in d.candidates:
        if not (c.available and c.residual is not None and d.base_residual is not None):
            cands[c.effect] = None
            continue
        t, p, pm = robust_paired_test(d.base_residual, c.residual, d.fs, block_s)
        leaky = any(d.leaks.get(k, 0.0) >= LEAK_R2 for k in c.signals)
        cands[c.effect] = [float(f"{c.vaf_gain:.4g}"), float(f"{p:.3g}"), float(f"{pm:.3g}"), int(leaky),
                           int(c.significant)]
    by = {c.effect: c for c in d.candidates}
    ties = {}
    for pair in TIES:
        a, b = sorted(pair)
        if a in by and b in by and by[a].residual is not None and by[b].residual is not None:
            ties[f"{a}|{b}"] = float(f"{_tie_p(by[a].residual, by[b].residual, d.fs, block_s):.3g}")
    return {"cands": cands, "ties": ties, "n_available": sum(c.available for c in d.candidates)}


def _effect_draw(seed, effect, out):
    s = draw_subject(seed, effect=effect)
    out.update(form=s.form, design=s.design, stiffness=s.stiffness_form)
    t = time.perf_counter()
    ident, novel, out["ceiling"] = _pairs(s)
    ci, cn, out["clean_ceiling"] = _pairs(s, clean=True)
    out["t_sim"] = time.perf_counter() - t
    t = time.perf_counter()
    ladder = lpvpc.improve(ident, novel)
    out["t_improve"] = time.perf_counter() - t
    out["t_fit"] = sum(r.fit_time for r in ladder.rungs)
    out["t_diagnose"] = sum(getattr(r, "diagnosis_time", 0.0) or 0.0 for r in ladder.rungs)
    t = time.perf_counter()
    clean_model = lpvpc.identify(ci)
    out["clean_vaf"] = heldout_vaf(clean_model, cn)
    out["t_clean"] = time.perf_counter() - t
    ok = accepted(effect, s.form, s.effect_params)
    right_where = {where(a) for a in ok}
    base = ladder.rungs[0]
    d = base.diagnosis
    in_model = sorted({fe.name for fe in base.model.effects} & set(ok))
    top = d.top
    if top is not None:
        out["top"] = f"{top.effect} ({top.pathway}; {', '.join(top.signals) or 'position'})"
        out["top_gain"], out["top_p"] = top.vaf_gain, top.p_value
        if top.tied_with:
            out["top"] += f" tied with {top.tied_with}"
    else:
        out["top"] = "none significant"
    out["in_model"] = ", ".join(in_model)
    ranked = [(i + 1, c) for i, c in enumerate(d.candidates) if c.effect in ok]
    if ranked:  # the best-ranked right entry: was it seen at all?
        i, c = ranked[0]
        out["right_entry"] = f"{c.effect}: rank {i}, {c.vaf_gain:+.3f} pp, p {c.p_value:.1e}" + (
            "" if c.available else f" (not available: {_one_line(c.reason, 80)})")
    out["named"] = bool(in_model) or (top is not None and top.kind == "effect" and where(top.effect) in right_where)
    out["entry"] = bool(in_model) or (top is not None and (top.effect in ok or top.tied_with in ok))
    out["base_vaf"] = base.heldout_vaf
    out["final_vaf"] = ladder.final.heldout_vaf
    out["steps"] = " -> ".join(r.label for r in ladder.rungs[1:] if r.kept) or "none"
    out["ladder"] = out["clean_vaf"] - out["final_vaf"] <= WITHIN
    out["base_candidates"] = candidate_records(d)
    out["accepted"] = list(ok)
    out["in_model_list"] = in_model
    out["rungs"] = [{"label": r.label, "change": r.change, "kept": bool(r.kept), "vaf": r.heldout_vaf}
                    for r in ladder.rungs]


def _clean_draw(seed, out):
    s = draw_subject(seed)
    out.update(form="-", design=s.design, stiffness=s.stiffness_form)
    t = time.perf_counter()
    ident, novel, out["ceiling"] = _pairs(s)
    out["t_sim"] = time.perf_counter() - t
    t = time.perf_counter()
    model = lpvpc.identify(ident)
    out["t_fit"] = time.perf_counter() - t
    t = time.perf_counter()
    d = lpvpc.diagnose(model, novel, reference=ident)  # as improve diagnoses: between records too
    out["t_diagnose"] = time.perf_counter() - t
    out["base_vaf"] = d.vaf
    sig = d.significant
    out["alarm"] = bool(sig)
    top = sig[0] if sig else d.candidates[0]
    out["top"] = (f"{top.effect} ({top.pathway}; {', '.join(top.signals) or 'position'}; "
                  f"{'significant' if sig else 'not significant'})")
    out["top_gain"], out["top_p"] = top.vaf_gain, top.p_value
    out["base_candidates"] = candidate_records(d)


def one_draw(task):
    """One draw, ``task`` = (seed, effect or None): a dict row; an error is its one-line reason."""
    from threadpoolctl import threadpool_limits

    seed, effect = task
    out = {"seed": seed, "effect": effect or "none", "form": "?", "design": "?", "stiffness": "?", "error": ""}
    t0 = time.perf_counter()
    try:
        with threadpool_limits(1), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # physiology and range notes on unusual subjects
            (_clean_draw(seed, out) if effect is None else _effect_draw(seed, effect, out))
    except Exception as exc:  # one draw's failure is its own row: a miss, never skipped
        tb = traceback.extract_tb(exc.__traceback__)[-1]
        out["error"] = _one_line(f"{type(exc).__name__}: {exc} ({Path(tb.filename).name}:{tb.lineno})")
        out.update(named=False, entry=False, ladder=False, alarm=True)
    out["time"] = time.perf_counter() - t0
    return out


def run(tasks, jobs, progress):
    if jobs <= 1:
        rows = []
        for task in tasks:
            rows.append(one_draw(task))
            progress(rows[-1])
        return rows
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else None)
    rows = [None] * len(tasks)
    with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx) as pool:
        futures = {pool.submit(one_draw, t): i for i, t in enumerate(tasks)}
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                rows[i] = fut.result()
            except Exception as exc:  # the worker died
                seed, effect = tasks[i]
                rows[i] = {"seed": seed, "effect": effect or "none", "form": "?", "design": "?", "stiffness": "?",
                           "error": _one_line(f"worker lost: {type(exc).__name__}: {exc}"), "named": False,
                           "entry": False, "ladder": False, "alarm": True, "time": float("nan")}
            progress(rows[i])
    return rows


def _f(x, fmt):
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, fmt)


def profile(effect, seeds_set):
    """``--profile EFFECT``: one draw under cProfile; its largest costs to a results file."""
    import cProfile
    import io
    import pstats

    k = EFFECTS.index(effect) if effect != "clean" else len(EFFECTS)
    task = (seeds_set.start + k * SEED_BLOCK, None if effect == "clean" else effect)
    prof = cProfile.Profile()
    prof.enable()
    row = one_draw(task)
    prof.disable()
    lines = [f"# One draw profiled (OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_population_diagnosis.py "
             f"--profile {effect})", "",
             f"seed {task[0]}, effect {row['effect']} ({row['form']}), design {row['design']}: {row['time']:.1f} s"
             + (f"; error {row['error']}" if row["error"] else ""), ""]
    for key, label in (("cumulative", "by cumulative time"), ("tottime", "by own time")):
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats(key).print_stats(25)
        text = buf.getvalue()
        lines += [f"## {label} (top 25)", "", "```"] + [ln.rstrip() for ln in
                                                       text[text.index("ncalls"):].strip().splitlines()] + ["```", ""]
    write_results("population_diagnosis_profile.txt", lines, echo=True)


#: Bins (points of held-out VAF) of an effect's cost to the base model, for the detection table.
COST_BINS = (0.1, 0.25, 0.5, 1.0)


def precision_lines(rows):
    """What the diagnosis says when it names something, and how often it names anything, by
    the effect's cost to the base model (clean VAF minus base VAF, points): an effect that
    costs the model less than the clean records' own systematic gains cannot be told from
    them, and a miss there says nothing was found rather than something wrong."""
    named = [r for r in rows if r.get("top", "none significant") != "none significant" or r.get("in_model")]
    right = sum(bool(r["named"]) for r in named)
    out = ["", f"when the base diagnosis names a significant candidate, it names the right pathway and signal on "
               f"{share(right, len(named))}; it names nothing on {len(rows) - len(named)}/{len(rows)} draws", "",
           "| effect's cost to the base model (points) | draws | right | wrong | nothing significant |",
           "|---|---|---|---|---|"]
    edges = (-np.inf,) + COST_BINS + (np.inf,)
    for lo, hi in zip(edges[:-1], edges[1:]):
        g = [r for r in rows if lo <= r["clean_vaf"] - r["base_vaf"] < hi]
        k_named = [r for r in g if r in named]
        k_right = sum(bool(r["named"]) for r in k_named)
        what = f"< {hi:g}" if lo == -np.inf else (f">= {lo:g}" if hi == np.inf else f"{lo:g}-{hi:g}")
        out.append(f"| {what} | {len(g)} | {share(k_right, len(g))} | {len(k_named) - k_right} | "
                   f"{len(g) - len(k_named)} |")
    return out


def summarise(rows, args, name, seeds_of, total, cmd):
    eff_rows = [r for r in rows if r["effect"] != "none"]
    clean_rows = [r for r in rows if r["effect"] == "none"]
    small = args.draws < DEFAULT_DRAWS or args.clean < DEFAULT_CLEAN
    lines = [f"# Diagnosis over population draws ({cmd})", ""]
    if small:
        lines += [f"**Development run, small N** ({args.draws} draws per effect, {args.clean} clean): the intervals "
                  "are wide; the issue's targets need the full run.", ""]
    lines += [f"Subjects from {name}: effect k of {', '.join(EFFECTS)} from seed {seeds_of(0)} + k x {SEED_BLOCK}, "
              f"clean draws from seed {seeds_of(len(EFFECTS))}; form, subject and design drawn per seed "
              "(docs/guide/population.md). 2-minute identification and novel pairs at 1 kHz, paired and decimated as "
              "the loaders do; lpvpc.improve(ident, novel) (base diagnosed with lpvpc.diagnose on the novel pair), "
              "against lpvpc.identify on the same subject without its effect, held-out VAF on its novel pair. "
              "Right: the base diagnosis's first significant candidate is a catalog effect with the pathway and signals "
              "of the effect's catalog entry (background activation: the pathway its form scales); entry: the entry "
              "itself or the one it is tied with. Shares with 95 % Wilson intervals."
              + position_noise_text(args.position_noise), ""]
    lines += ["## Effect draws", "",
              "| seed | effect | form | design | K form | first significant candidate | gain (pp) | p | right | entry | "
              "right entry in the base diagnosis | base VAF | ladder VAF | ceiling | clean VAF | clean ceiling | gap | "
              "within 1 | steps kept | s | error |",
              "|" + "---|" * 21]
    for r in eff_rows:
        gap = r["clean_vaf"] - r["final_vaf"] if "final_vaf" in r and "clean_vaf" in r else None
        top = r.get("top", "-") + (f" (base model has {r['in_model']})" if r.get("in_model") else "")
        lines.append(f"| {r['seed']} | {r['effect']} | {r['form']} | {r['design']} | {r['stiffness']} | {top} | "
                     f"{_f(r.get('top_gain'), '+.3f')} | {_f(r.get('top_p'), '.1e')} | {'yes' if r['named'] else 'NO'} | "
                     f"{'yes' if r['entry'] else 'no'} | {r.get('right_entry', '-')} | {_f(r.get('base_vaf'), '.2f')} | "
                     f"{_f(r.get('final_vaf'), '.2f')} | {_f(r.get('ceiling'), '.2f')} | {_f(r.get('clean_vaf'), '.2f')} | "
                     f"{_f(r.get('clean_ceiling'), '.2f')} | {_f(gap, '+.2f')} | {'yes' if r['ladder'] else 'NO'} | "
                     f"{r.get('steps', '-')} | {_f(r['time'], '.0f')} | {r['error'] or '-'} |")
    lines += ["", f"## Summary (targets: right >= {100 * TARGETS['named']:.0f} %, ladder within {WITHIN:g} point of the "
              f"clean model >= {100 * TARGETS['ladder']:.0f} %, clean false alarms <= {100 * TARGETS['alarm']:.0f} %)", "",
              "| effect | form | draws | first significant names the right pathway and signal | names the entry itself "
              "| ladder within 1 point of clean | errors | s per draw (median) |", "|---|---|---|---|---|---|---|---|"]

    def line(effect, form, group):
        n = len(group)
        k = [sum(bool(r[c]) for r in group) for c in ("named", "entry", "ladder")]
        err = sum(bool(r["error"]) for r in group)
        t = np.nanmedian([r["time"] for r in group]) if group else float("nan")
        lines.append(f"| {effect} | {form} | {n} | {share(k[0], n)} | {share(k[1], n)} | {share(k[2], n)} | {err} | "
                     f"{_f(float(t), '.0f')} |")

    for effect in EFFECTS:
        g = [r for r in eff_rows if r["effect"] == effect]
        for form in POPULATION_EFFECTS[effect]:
            gf = [r for r in g if r["form"] == form]
            if gf:
                line(effect, form, gf)
        if any(r["form"] not in POPULATION_EFFECTS[effect] for r in g):
            line(effect, "unknown (draw failed)", [r for r in g if r["form"] not in POPULATION_EFFECTS[effect]])
        line(f"**{effect}**", "all", g)
    line("**all effects**", "all", eff_rows)
    ok_rows = [r for r in eff_rows if not r["error"]]
    if ok_rows:
        free = sum(r["clean_vaf"] - r["base_vaf"] <= WITHIN for r in ok_rows)
        off = sum(r["clean_ceiling"] - r["clean_vaf"] > WITHIN for r in ok_rows)
        cost = np.array([r["clean_vaf"] - r["base_vaf"] for r in ok_rows])
        lines += ["", f"effect draws whose base model is already within {WITHIN:g} point of the clean model (the ladder "
                  f"target met with no step): {free}/{len(ok_rows)}; the effect's cost to the base model (clean VAF minus "
                  f"base VAF): median {np.median(cost):+.2f}, max {cost.max():+.2f} points",
                  f"effect draws whose clean model is more than {WITHIN:g} point under its own noise ceiling (the "
                  f"reference is off there): {off}/{len(ok_rows)}"]
        lines += precision_lines(ok_rows)
    lines += ["", "## Clean draws", "",
              "| seed | design | K form | held-out VAF | ceiling | top candidate | gain (pp) | p | s | error |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in clean_rows:
        lines.append(f"| {r['seed']} | {r['design']} | {r['stiffness']} | {_f(r.get('base_vaf'), '.2f')} | "
                     f"{_f(r.get('ceiling'), '.2f')} | {r.get('top', '-')} | {_f(r.get('top_gain'), '+.3f')} | {_f(r.get('top_p'), '.1e')} | "
                     f"{_f(r['time'], '.0f')} | {r['error'] or '-'} |")
    n = len(clean_rows)
    lines += ["", f"clean draws with any significant candidate (a failed draw counts as one): "
              f"{share(sum(bool(r['alarm']) for r in clean_rows), n)}", ""]
    # time: per draw, and the full default run estimated from it
    te = [r["time"] for r in eff_rows if np.isfinite(r["time"])]
    tc = [r["time"] for r in clean_rows if np.isfinite(r["time"])]
    lines += ["## Time", "",
              f"total wall time {total:.0f} s with {args.jobs} job(s); load average at the end "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (shared machine: times scale with it)"]
    if te:
        parts = {k: np.mean([r[k] for r in eff_rows if k in r]) for k in ("t_sim", "t_fit", "t_diagnose", "t_clean")}
        lines.append(f"effect draw: mean {np.mean(te):.0f} s, median {np.median(te):.0f} s, max {np.max(te):.0f} s; of the "
                     f"mean: simulation {parts['t_sim']:.0f} s, ladder fits {parts['t_fit']:.0f} s, ladder diagnoses "
                     f"{parts['t_diagnose']:.0f} s, clean model {parts['t_clean']:.0f} s")
        for effect in EFFECTS:
            t = [r["time"] for r in eff_rows if r["effect"] == effect and np.isfinite(r["time"])]
            if t:
                lines.append(f"  {effect}: mean {np.mean(t):.0f} s over {len(t)} draws")
    if tc:
        lines.append(f"clean draw: mean {np.mean(tc):.0f} s, median {np.median(tc):.0f} s")
    if te and tc:
        full = DEFAULT_DRAWS * len(EFFECTS) * np.mean(te) + DEFAULT_CLEAN * np.mean(tc)
        lines.append(f"estimated full default run ({DEFAULT_DRAWS} draws x {len(EFFECTS)} effects + {DEFAULT_CLEAN} clean): "
                     f"{full / 3600:.1f} h of one core, {full / 7200:.1f} h on 2 cores (--jobs 2, the machine otherwise "
                     f"idle); the issue's budget is 1 h for the whole population benchmark")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=DEFAULT_DRAWS, help=f"draws per effect (default {DEFAULT_DRAWS})")
    ap.add_argument("--clean", type=int, default=DEFAULT_CLEAN, help=f"clean draws (default {DEFAULT_CLEAN})")
    ap.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--record", action="store_true", help="draw from RECORD_SEEDS (recorded results)")
    ap.add_argument("--first-seed", type=int, default=0, metavar="I",
                    help="draw i of each effect (and of the clean draws) from start + k x SEED_BLOCK + I + i: a "
                         "seed range not used before (default 0)")
    ap.add_argument("--effects", metavar="NAME", nargs="+", choices=EFFECTS, default=list(EFFECTS),
                    help="only these effects' draws (default all); the summary judges what was run")
    add_position_noise_option(ap)
    ap.add_argument("--profile", metavar="EFFECT", choices=EFFECTS + ("clean",),
                    help="profile one draw of EFFECT ('clean': a clean draw) and stop")
    args = ap.parse_args(argv)
    if (not 0 <= args.draws <= SEED_BLOCK or not 0 <= args.clean <= SEED_BLOCK or args.jobs < 1
            or not 0 <= args.first_seed <= SEED_BLOCK - max(args.draws, args.clean)):
        ap.error(f"--draws and --clean must be 0..{SEED_BLOCK}, --jobs at least 1, --first-seed plus the draws "
                 f"at most {SEED_BLOCK}")
    seeds_set, name = (RECORD_SEEDS, "RECORD_SEEDS") if args.record else (DEVELOPMENT_SEEDS, "DEVELOPMENT_SEEDS")
    global POSITION_NOISE
    POSITION_NOISE = args.position_noise
    if args.profile:
        return profile(args.profile, seeds_set)

    def seeds_of(k):
        return seeds_set.start + k * SEED_BLOCK + args.first_seed

    tasks = [(seeds_of(k) + i, effect) for i in range(args.draws) for k, effect in enumerate(EFFECTS)
             if effect in args.effects]
    tasks += [(seeds_of(len(EFFECTS)) + i, None) for i in range(args.clean)]
    if tasks and tasks[-1][0] not in seeds_set:
        sys.exit(f"seeds up to {max(t[0] for t in tasks)} are not all in {name}")
    cmd = ("OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_population_diagnosis.py"
           + (f" --draws {args.draws}" if args.draws != DEFAULT_DRAWS else "")
           + (f" --clean {args.clean}" if args.clean != DEFAULT_CLEAN else "")
           + (f" --first-seed {args.first_seed}" if args.first_seed else "")
           + (f" --effects {' '.join(args.effects)}" if list(args.effects) != list(EFFECTS) else "")
           + (f" --jobs {args.jobs}" if args.jobs != 1 else "") + (" --record" if args.record else "")
           + (f" --position-noise {args.position_noise:g}" if args.position_noise else ""))

    def progress(r):
        what = (f"alarm {r.get('alarm')}" if r["effect"] == "none" else
                f"right {r.get('named')}, ladder {_f(r.get('final_vaf'), '.2f')} vs clean {_f(r.get('clean_vaf'), '.2f')}")
        print(f"seed {r['seed']} {r['effect']} ({r['form']}, {r['design']}): {r.get('top', '-')}; {what}; "
              f"{_f(r['time'], '.0f')} s {r['error']}", flush=True)

    t0 = time.perf_counter()
    rows = run(tasks, args.jobs, progress)
    total = time.perf_counter() - t0
    lines = summarise(rows, args, name, seeds_of, total, cmd)
    target = RESULTS / ("population_diagnosis_record.txt" if args.record else "population_diagnosis.txt")
    save_candidates(rows, cmd, "population_diagnosis_record" if args.record else "population_diagnosis")
    if (args.draws != DEFAULT_DRAWS or args.clean != DEFAULT_CLEAN or args.first_seed or args.position_noise
            or list(args.effects) != list(EFFECTS)):  # another run: its own section
        head = f"## Run: {cmd}"
        section = ["", head, ""] + [x.replace("## ", "### ", 1) if x.startswith("## ") else x for x in lines[2:]]
        lines = replace_section(target.read_text().split("\n") if target.exists() else [], head, section)
    elif target.exists():  # the default run's table, the other runs' sections kept below it
        old = target.read_text().split("\n")
        runs = next((k for k, x in enumerate(old) if x.startswith("## Run: ")), len(old))
        lines = replace_section(lines, None, [""] + old[runs:]) if runs < len(old) else lines
    write_results(target, lines, echo=True)


def save_candidates(rows, cmd, stem):
    """Every draw's row with its base diagnosis's candidates (:func:`candidate_records`) to
    benchmarks/out/<stem>_candidates.json (git-ignored data), one entry per command (an earlier run of the
    same command replaced): significance rules can be judged on them offline
    (benchmarks/population_significance_rules.py)."""
    import json

    path = RESULTS.parent / "out" / f"{stem}_candidates.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    runs = json.loads(path.read_text()) if path.exists() else {}
    def tidy(v):
        if isinstance(v, float):
            return float(f"{v:.6g}") if np.isfinite(v) else None
        if isinstance(v, dict):
            return {k: tidy(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [tidy(x) for x in v]
        return v

    clean = [tidy(r) for r in rows]
    runs[cmd] = {"git": _git_head(), "rows": clean}
    path.write_text(json.dumps(runs, separators=(",", ":"), sort_keys=True) + "\n")
    print(f"candidates written to {path}")


def _git_head():
    import subprocess

    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10).stdout.strip()
    except Exception:  # no git: the record stands without it
        return ""


def replace_section(old, head, section):
    """``old`` lines with the section starting at ``head`` (up to the next "## Run: " line)
    replaced by ``section``, or ``section`` appended; no leading or doubled blank lines."""
    if head in old:
        i = old.index(head)
        j = next((k for k in range(i + 1, len(old)) if old[k].startswith("## Run: ")), len(old))
        before, after = old[:i], old[j:]
    else:
        before, after = old, []
    while before and not before[-1].strip():
        before = before[:-1]
    while after and not after[-1].strip():
        after = after[:-1]
    out = before + section + ([""] + after if after else [])
    while out and not out[0].strip():
        out = out[1:]
    while out and not out[-1].strip():
        out = out[:-1]
    return out


if __name__ == "__main__":
    main()
