"""Structure selection scored forward in time as well as level by level, on the lab's pilot trial.

Data: ``pilot_ident.csv`` (the first 70 % of the lab's pilot session; torque negated). A lab
judges a model on a later stretch of its session, so every split here is forward in time,
inside the file: identify on the first part, predict a later stretch (the whole record up to
its end is predicted, the stretch scored; the model starts from the trial's own past):

- 70 -> 100 %: ``lpvpc.hold_out(data, 0.3)`` (the project's development split);
- 50 -> 70 %, 60 -> 80 %, 80 -> 100 %: further splits, so that one split cannot overstate.

Side by side from one run, on every split: the structure selection's choice rules
(:func:`lpvpc.identification.selection.choose`): "both" (the new default: the one-standard-error rule among
the structures near the best on both fold kinds), "worst_rank" (the best worse rank over the
two) and "level" (the previous default: leave-one-level-out alone, as on main before the
forward folds), each as ``lpvpc identify`` runs it (the channel skew found by the default
identify's scan of the identification part, the file loaded again lined up at 1 kHz); and
a plain fixed-setting implementation of the paper's algorithm (``structure='fixed'``, no pole
refinement, no curvature term, state order 2, no time-constant cap: as
benchmarks/bench_selection.py; the record as loaded). Per method and split: the chosen
structure's forward-in-time and leave-one-level-out CV VAF on the identification part (the
structure scored with the model's own reflex dynamics held, the same folds for all), the
held-out VAF, the causal form's held-out VAF, and the parameter count.

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_forward_selection.py
(writes benchmarks/results/forward_selection.txt; skips when the recordings are absent;
``--cache DIR`` keeps each fit's figures there between runs). With ``--subjects``: the virtual
subject over bench_selection.py's seeds, the rule before and after
(benchmarks/results/forward_selection_subjects.txt).
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from _results import write_results  # noqa: E402
from real_data import require  # noqa: E402

import lpvpc.identification.selection as S  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.io import hold_out, load_identification_data  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402

SPLITS = (("70 -> 100 %", 0.7, 1.0), ("50 -> 70 %", 0.5, 0.7), ("65 -> 85 %", 0.65, 0.85), ("75 -> 95 %", 0.75, 0.95),
          ("80 -> 100 %", 0.8, 1.0))
PAPER = {"structure": "fixed", "refine": False, "elastic_curvature": False, "state_order": 2,
         "max_reflex_time_constant": None}
METHODS = (
    ("new default (rule 'both')", "both", {}),
    ("rule 'worst_rank'", "worst_rank", {}),
    ("previous default (rule 'level', main)", "level", {}),
    ("paper, fixed settings (structure='fixed')", None, PAPER),
)


def structure_scores(m, data):
    """(forward VAF %, leave-one-level-out VAF %) of the model's structure on ``data`` (its
    identification part), its reflex dynamics held."""
    st = S.fitted_structure(m, m.settings.get("scheduling_extrapolation", "clip"))
    dyn = (m.A, m.C[None, :], np.append(m.B, m.D))
    search = S.StructureSearch(data.position, data.torque, data.scheduling, data.fs, dyn,
                               search={k: (v,) for k, v in st.items()})
    sc = search.score(st)
    return float(sc.forward_vaf), float(sc.cv_vaf)


def run_one(path, rule, settings, a, b):
    raw = load_identification_data(data=path, torque_sign=-1)
    stop = int(round(b * raw.n))
    whole = raw.segment(0, stop)
    t0 = time.perf_counter()
    if rule is not None:
        S.CHOICE_RULE = rule
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident, _ = hold_out(whole, 1.0 - a / b)  # 70 -> 100 %: lpvpc.hold_out(data, 0.3)
        skew = 0.0
        if rule is not None:  # lpvpc identify: the scan of the identification part, then lined up at 1 kHz
            skew = float(identify(ident, **settings).fit.get("channel_skew", {}).get("chosen_s", 0.0) or 0.0)
            if skew:
                whole = load_identification_data(data=path, torque_sign=-1, channel_skew=skew).segment(0, stop)
                ident, _ = hold_out(whole, 1.0 - a / b)
        m = identify(ident, **settings)
        k = ident.n
        held = whole.torque[k:]
        two = vaf(held, m.predict(whole).total[k:])
        cau = vaf(held, m.predict(whole, causal=True).total[k:])
        fwd, lolo = structure_scores(m, ident)
    sel = m.fit.get("structure_selection", {})
    return {"held": two, "causal": cau, "forward": fwd, "lolo": lolo, "skew_ms": 1e3 * skew,
            "params": int(len(m.H.ravel()) + m.nonlinearity()[1].size), "chosen": sel.get("chosen"),
            "sel_cv": sel.get("chosen_cv_vaf"), "sel_fwd": sel.get("chosen_forward_vaf"),
            "seconds": time.perf_counter() - t0, "n_ident": k, "n_held": len(held)}


def main():
    path = require("pilot_ident.csv")
    cache = None
    if "--cache" in sys.argv:
        cache = Path(sys.argv[sys.argv.index("--cache") + 1])
        cache.mkdir(parents=True, exist_ok=True)
    code = hashlib.sha1(b"".join((HERE.parent / "lpvpc" / "identification" / f).read_bytes()
                                 for f in ("selection.py", "identify.py"))).hexdigest()[:10]
    res = {}
    for name, rule, settings in METHODS:
        for split, a, b in SPLITS:
            key = cache / f"{code}-{rule}-{a}-{b}.json" if cache else None
            if key is not None and key.is_file():
                res[name, split] = json.loads(key.read_text())
                continue
            res[name, split] = run_one(path, rule, settings, a, b)
            print(f"{name:45} {split:12} held {res[name, split]['held']:6.2f} ({res[name, split]['seconds']:.1f} s)",
                  flush=True)
            if key is not None:
                key.write_text(json.dumps(res[name, split]))
    S.CHOICE_RULE = "both"
    lines = [
        "# Structure selection scored forward in time and level by level: the lab's pilot trial "
        "(python benchmarks/bench_forward_selection.py)",
        f"# {path.name}, torque negated, 100 Hz; splits inside the file, forward in time (identify on the first "
        "part, predict the later stretch)",
        f"# forward folds: {S.FORWARD_FOLDS} stretches of {100 * S.FORWARD_BLOCK:g} % of the identification part, "
        "each predicted from the record before it; LOLO: leave-one-level-out",
        f"# machine: {platform.machine()}, python {platform.python_version()}",
        "",
        "VAF % per split: identification part forward-CV / LOLO-CV of the chosen structure; held-out (two-sided) ; "
        "causal form",
    ]
    head = f"{'method':45} " + " ".join(f"{s:>30}" for s, _, _ in SPLITS)
    lines.append(head)
    lines.append(f"{'':45} " + " ".join(f"{'fwd  LOLO | held causal':>30}" for _ in SPLITS))
    for name, _, _ in METHODS:
        cells = []
        for split, _, _ in SPLITS:
            r = res[name, split]
            cells.append(f"{r['forward']:6.2f} {r['lolo']:6.2f} | {r['held']:6.2f} {r['causal']:6.2f}")
        lines.append(f"{name:45} " + " ".join(f"{c:>30}" for c in cells))
    lines.append("")
    lines.append("held-out VAF: mean and worst over the splits; minus the previous default on each split")
    prev = "previous default (rule 'level', main)"
    for name, _, _ in METHODS:
        h = np.array([res[name, s]["held"] for s, _, _ in SPLITS])
        c = np.array([res[name, s]["causal"] for s, _, _ in SPLITS])
        d = h - np.array([res[prev, s]["held"] for s, _, _ in SPLITS])
        lines.append(f"{name:45} mean {h.mean():6.2f}  worst {h.min():6.2f}  causal mean {c.mean():6.2f} "
                     f"(two-sided - causal, worst {np.max(h - c):5.2f})  vs previous: "
                     + ", ".join(f"{x:+.2f}" for x in d))
    lines.append("")
    lines.append("Chosen structures (L ms, orders intrinsic/reflex/velocity, delay ms, curvature, beyond range), "
                 "parameters, channel skew found (ms), selection record's CV VAF (LOLO / forward), seconds")
    for name, rule, _ in METHODS:
        for split, _, _ in SPLITS:
            r = res[name, split]
            ch = r["chosen"]
            txt = ("fixed settings" if ch is None else
                   f"L {1e3 * ch['irf_length']:g}, {ch['intrinsic_order']}/{ch['reflex_order']}/{ch['velocity_order']}, "
                   f"{1e3 * ch['reflex_delay']:g}, {ch['elastic_curvature']}, {ch['scheduling_extrapolation']}")
            sel = "" if r["sel_cv"] is None else (f"; selection record {r['sel_cv']:.2f} / "
                                                  + (f"{r['sel_fwd']:.2f}" if r["sel_fwd"] is not None else "-"))
            lines.append(f"  {name:45} {split:12} {txt:42} {r['params']:4d} p, skew {r['skew_ms']:.2f}{sel}, "
                         f"{r['seconds']:.1f} s")
    write_results("forward_selection.txt", lines, echo=True)


def subjects(seeds=range(5)):
    """The virtual subject over bench_selection.py's seeds (2-minute multilevel records, the novel
    trajectory of seed + 1000 predicted): the choice rules before ("level") and after ("both"),
    novel-trajectory VAF and K(theta) error against the truth (central 80 % of the range)."""
    from lpvpc.io import pair_trials
    from lpvpc.identification.identify import LPVPCEstimator
    from lpvpc.simulation.simulate import SubjectParams, simulate_pair

    from bench_selection import fit_and_score

    truth = SubjectParams()
    lines = ["# Virtual subject, choice rule before ('level') and after ('both') "
             "(python benchmarks/bench_forward_selection.py --subjects)", "",
             "| seed | rule | novel VAF (%) | K worst err (%) | K mean abs err (%) | LOLO / forward CV VAF (%) | "
             "identify (s) | chosen |", "|---|---|---|---|---|---|---|---|"]
    agg = {"level": [], "both": []}
    for seed in seeds:
        ident, novel = simulate_pair("multilevel", seed=seed), simulate_pair("novel", seed=seed + 1000)
        d, nv = pair_trials(ident.pt, ident.ut), pair_trials(novel.pt, novel.ut)
        for rule in agg:
            S.CHOICE_RULE = rule
            model, (v, k_max, k_mean, el), what = fit_and_score(LPVPCEstimator, d, nv, truth)
            agg[rule].append((v, k_max, k_mean, el))
            sel = model.fit.get("structure_selection", {})
            cv = f"{sel.get('chosen_cv_vaf', float('nan')):.2f} / {sel.get('chosen_forward_vaf', float('nan')):.2f}"
            lines.append(f"| {seed} | {rule} | {v:.2f} | {k_max:.1f} | {k_mean:.1f} | {cv} | {el:.2f} | {what} |")
            print(lines[-1], flush=True)
    S.CHOICE_RULE = "both"
    lines.append("")
    for rule, rows in agg.items():
        a = np.array(rows)
        lines.append(f"- rule '{rule}': median novel VAF {np.median(a[:, 0]):.2f} %, worst {a[:, 0].min():.2f} %; "
                     f"median worst K error {np.median(a[:, 1]):.1f} %, median mean K error {np.median(a[:, 2]):.1f} %, "
                     f"median identify time {np.median(a[:, 3]):.2f} s")
    write_results("forward_selection_subjects.txt", lines)


if __name__ == "__main__":
    subjects() if "--subjects" in sys.argv else main()
