"""How much of each population effect a diagnosis could name at all: the effect's own torque
as the candidate (the oracle), against the clean draws' best candidates.

The diagnosis names an effect when a catalog candidate's held-out gain passes the
significance rule (:func:`lpvpc.diagnosis.candidates.passes`) while the clean draws' candidates
must not (at most 2 % of them may). No candidate can explain more of an effect than the
effect's own torque does. So per effect draw of benchmarks/bench_population_diagnosis.py
(the same seeds, subject, design and records), this benchmark scores the oracle: the draw's
true effect torque (the noise-free novel pair with the effect minus the same pair without it,
paired and decimated as the loaders do) as one column added to the diagnosis's own surrogate
(:func:`lpvpc.diagnosis.diagnose.diagnosis_surrogate` of the base model on the novel pair: its
folds, mask, design and paired test), giving its held-out gain, p and p of the mean as any candidate's.

Two questions per draw:

* capture: the right catalog entry's gain in the base diagnosis over the oracle's (how much
  of what is there the catalog's term takes; from the diagnosis run's saved candidates);
* detectability: how many clean draws have a candidate (available, its signal not leaking
  into the reflex drive) at least as strong as the oracle on all three counts (gain at least
  the oracle's, p and p of the mean at most its). A significance rule that only grows with
  gain and shrinks with p and names the oracle also names those clean candidates; when more
  than 2 % of the clean draws hold one, no such rule can name this draw within the
  false-alarm target. The draws for which at most 2 % do bound the share any such rule can
  name from above, for candidates that capture no more than the oracle. A rule with
  thresholds of its own per catalog entry (the current rule's reflex floor; every rule
  benchmarks/population_significance_rules.py replays) is bounded the same way by the clean
  candidates of the draw's right entries alone.

Needs the diagnosis run's saved candidates (benchmarks/out/population_diagnosis_candidates.json,
or ..._record_candidates.json with ``--record``; run benchmarks/bench_population_diagnosis.py
first). Writes benchmarks/results/diagnosis_oracle.txt (``--record``:
diagnosis_oracle_record.txt).

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_diagnosis_oracle.py [--draws N] [--jobs N] [--record]
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_population_diagnosis as bpd  # noqa: E402  (the diagnosis benchmark's seeds and helpers)
import lpvpc  # noqa: E402
from lpvpc.diagnosis.candidates import ALPHA, EMG_SIGNALS, MIN_GAIN, passes  # noqa: E402
from lpvpc.diagnosis.cv import BLOCK_S, robust_paired_test  # noqa: E402
from lpvpc.diagnosis.diagnose import diagnosis_surrogate  # noqa: E402
from lpvpc.models.effects import CATALOG  # noqa: E402
from lpvpc.simulation.population import DEVELOPMENT_SEEDS, RECORD_SEEDS, draw_subject, simulate_subject  # noqa: E402
from _results import RESULTS, write_results  # noqa: E402

ALARM_SHARE = bpd.TARGETS["alarm"]
COST_BINS = (-math.inf, 0.1, 0.25, 0.5, 1.0, math.inf)


def effect_torque(subject, novel):
    """The subject's effect torque on its novel pair ``novel`` (N m, paired and decimated as the
    loaders do): the pair's noise-free torque minus that of the same pair simulated without the
    effect (same seed, trajectory and streams)."""
    without = simulate_subject(subject, "novel", clean=True)
    return (lpvpc.pair_trials(novel.pt_clean, novel.ut_clean).torque
            - lpvpc.pair_trials(without.pt_clean, without.ut_clean).torque)


def oracle_score(model, data, x):
    """(gain pp, p, p_mean, design) of column ``x`` added to the surrogate :func:`lpvpc.diagnose`
    scores candidates on (:func:`lpvpc.diagnosis.diagnose.diagnosis_surrogate`): the test it
    gives a catalog candidate, on the same samples."""
    sur = diagnosis_surrogate(model, data).surrogate
    r0, _ = sur.cv.fit(sur.base)
    sur.cv.add("oracle", np.asarray(x, dtype=float)[:, None])
    r1, _ = sur.cv.fit(sur.base + ["oracle"])
    _, p, p_mean = robust_paired_test(r0, r1, sur.fs, BLOCK_S)
    return 100.0 * float(r0 @ r0 - r1 @ r1) / sur.sst, float(p), float(p_mean), sur.design


def one_draw(task):
    seed, effect = task
    out = {"seed": seed, "effect": effect, "error": ""}
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = draw_subject(seed, effect=effect)
            out.update(form=s.form, design=s.design)
            ident = simulate_subject(s, "multilevel")
            novel = simulate_subject(s, "novel")
            model = lpvpc.identify(lpvpc.pair_trials(ident.pt, ident.ut))
            scored = oracle_score(model, lpvpc.pair_trials(novel.pt, novel.ut), effect_torque(s, novel))
            out["gain"], out["p"], out["p_mean"], out["surrogate"] = scored
    except Exception as exc:  # a draw's failure is its own row
        out["error"] = bpd._one_line(f"{type(exc).__name__}: {exc}")
    out["time"] = time.perf_counter() - t0
    return out


def run(tasks, jobs):
    if jobs <= 1:
        return [one_draw(t) for t in tasks]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else None)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
        return list(pool.map(one_draw, tasks))


def saved_run(record):
    """(command key, rows) of the diagnosis benchmark's latest run at the issue's size on the seed
    set (its saved candidates)."""
    path = RESULTS.parent / "out" / f"population_diagnosis{'_record' if record else ''}_candidates.json"
    if not path.exists():
        sys.exit(f"{path} is missing: run benchmarks/bench_population_diagnosis.py{' --record' if record else ''} "
                 "first (it saves every draw's candidates there)")
    runs = json.loads(path.read_text())
    other = ("--draws", "--clean", "--first-seed", "--effects", "--position-noise")
    keys = [k for k in runs if not any(o in k for o in other) and ("--record" in k) == record]
    if not keys:
        sys.exit(f"{path} holds no run at the default size (run the diagnosis benchmark without --draws/--clean)")
    return keys[-1], runs[keys[-1]]


def reflex_floor(entries):
    """Whether the rule's reflex floor applies to one of the draw's right entries (a catalog
    effect on the reflex pathway reading no EMG-derived signal)."""
    return any(CATALOG[n].pathway == "reflex" and not set(CATALOG[n].signals) & set(EMG_SIGNALS) for n in entries)


def clean_points(rows):
    """Per clean draw: {candidate name: (gain, p, p_mean)} of its available candidates whose
    signal does not leak into the reflex drive."""
    return [{n: tuple(v[:3]) for n, v in r["base_candidates"]["cands"].items() if v is not None and not v[3]}
            for r in rows if r["effect"] == "none" and not r.get("error")]


def dominated_by(point, pts, names=None):
    """Indices of the clean draws holding a candidate (among ``names``; None: any) at least as
    strong as ``point`` (gain, p, p_mean) on all counts."""
    g, p, pm = point
    return frozenset(i for i, c in enumerate(pts)
                     if any(cg >= g and cp <= p and cpm <= pm for n, (cg, cp, cpm) in c.items()
                            if names is None or n in names))


def best_monotone_rule(dominating, allowed):
    """The most draws one rule monotone in gain and p can name with at most ``allowed`` clean
    alarms: a rule naming a set of oracles also names every clean candidate that dominates one of
    them, so it names draw i only if its dominating clean draws lie within the rule's alarm set
    A (|A| <= allowed); the count maximised over every such A among the clean draws seen."""
    seen = sorted({j for d in dominating for j in d})
    best = sum(not d for d in dominating)
    for k in range(1, allowed + 1):
        for a in itertools.combinations(seen, k):
            a = set(a)
            best = max(best, sum(d <= a for d in dominating))
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=bpd.DEFAULT_DRAWS, help="draws per effect (default 30)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--record", action="store_true", help="the record seeds (RECORD_SEEDS) and their diagnosis run")
    args = ap.parse_args(argv)
    seeds = RECORD_SEEDS if args.record else DEVELOPMENT_SEEDS
    key, saved = saved_run(args.record)
    by_draw = {(r["seed"], r["effect"]): r for r in saved["rows"]}
    tasks = [(seeds.start + k * bpd.SEED_BLOCK + i, e) for i in range(args.draws) for k, e in enumerate(bpd.EFFECTS)]
    t0 = time.perf_counter()
    rows = run(tasks, args.jobs)
    wall = time.perf_counter() - t0
    pts = clean_points(saved["rows"])
    n_clean = len(pts)
    allowed = math.floor(ALARM_SHARE * n_clean + 1e-9)
    cmd = ("OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_diagnosis_oracle.py"
           + (f" --draws {args.draws}" if args.draws != bpd.DEFAULT_DRAWS else "")
           + (f" --jobs {args.jobs}" if args.jobs != 1 else "") + (" --record" if args.record else ""))
    lines = [f"# The diagnosis's oracle: each effect's own torque as the candidate ({cmd})", "",
             f"Seeds: {'RECORD_SEEDS' if args.record else 'DEVELOPMENT_SEEDS'}, the draws of "
             f"bench_population_diagnosis.py; its saved candidates: `{key}` (commit {saved['git']}), "
             f"{n_clean} clean draws. Oracle: the draw's true effect torque as one column in the diagnosis's "
             f"surrogate of the base model on the novel pair (refit, or the model held where diagnose holds it; "
             f"gain pp, robust p, p of the mean). capture: the "
             f"right entry's gain in the base diagnosis over the oracle's. clean >=: clean draws with a "
             f"non-leaking candidate at least as strong on gain, p and p of the mean; at most {allowed} "
             f"({100 * ALARM_SHARE:.0f} %) leaves the draw nameable by a rule monotone in gain and p. "
             f"passes: the current rule (`passes`, level ALPHA over the draw's candidates) on the oracle.", "",
             "| seed | effect | form | design | surrogate | cost (pp) | oracle gain | p | p_mean | passes | clean >= | "
             "right entry's gain | capture | named right | error |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d = by_draw.get((r["seed"], r["effect"]), {})
        r["cost"] = d.get("clean_vaf", float("nan")) - d.get("base_vaf", float("nan"))
        r["named"] = bool(d.get("named"))
        ok = d.get("accepted") or bpd.accepted(r["effect"], r.get("form", "intrinsic"))  # as the diagnosis run judged
        right = [d["base_candidates"]["cands"].get(a) for a in ok] if d.get("base_candidates") else []
        right = [v for v in right if v is not None]
        r["entry_gain"] = max((v[0] for v in right), default=float("nan"))
        if r["error"]:
            r.update(passes=False, dominating=frozenset(range(n_clean)), dominating_entry=frozenset(range(n_clean)),
                     capture=float("nan"))
        else:
            n_avail = (d.get("base_candidates") or {}).get("n_available") or 1
            r["passes"] = passes(r["gain"], r["p"], MIN_GAIN, ALPHA / n_avail, p_mean=r["p_mean"],
                                 reflex=reflex_floor(ok))
            r["dominating"] = dominated_by((r["gain"], r["p"], r["p_mean"]), pts)
            r["dominating_entry"] = dominated_by((r["gain"], r["p"], r["p_mean"]), pts, ok)
            r["capture"] = r["entry_gain"] / r["gain"] if r["gain"] > 0 else float("nan")
        lines.append(f"| {r['seed']} | {r['effect']} | {r.get('form', '?')} | {r.get('design', '?')} | "
                     f"{r.get('surrogate', '-')} | "
                     f"{r['cost']:+.2f} | {r.get('gain', float('nan')):+.3f} | {r.get('p', float('nan')):.1e} | "
                     f"{r.get('p_mean', float('nan')):.1e} | {'yes' if r['passes'] else 'no'} | {len(r['dominating'])} | "
                     f"{r['entry_gain']:+.3f} | {r['capture']:.2f} | {'yes' if r['named'] else 'no'} | "
                     f"{r['error'] or '-'} |")
    lines += ["", f"## Summary (nameable: at most {allowed} of {n_clean} clean draws hold a candidate as strong "
                  "as the oracle)", "",
              "| effect | draws | oracle passes the current rule | nameable by any monotone rule | named right "
              "(diagnosis run) | median capture |",
              "|---|---|---|---|---|---|"]
    for effect in list(bpd.EFFECTS) + ["all"]:
        g = [r for r in rows if effect in ("all", r["effect"])]
        caps = [r["capture"] for r in g if np.isfinite(r["capture"])]
        lines.append(f"| {'**all effects**' if effect == 'all' else effect} | {len(g)} | "
                     f"{bpd.share(sum(r['passes'] for r in g), len(g))} | "
                     f"{bpd.share(sum(len(r['dominating']) <= allowed for r in g), len(g))} | "
                     f"{bpd.share(sum(r['named'] for r in g), len(g))} | "
                     f"{np.median(caps) if caps else float('nan'):.2f} |")
    lines += ["", "| effect's cost to the base model (points) | draws | nameable | named right | median oracle gain |",
              "|---|---|---|---|---|"]
    for lo, hi in zip(COST_BINS[:-1], COST_BINS[1:]):
        g = [r for r in rows if lo <= r["cost"] < hi]
        label = f"< {hi:g}" if lo == -math.inf else (f">= {lo:g}" if hi == math.inf else f"{lo:g}-{hi:g}")
        med = np.median([r["gain"] for r in g if "gain" in r]) if g else float("nan")
        lines.append(f"| {label} | {len(g)} | {bpd.share(sum(len(r['dominating']) <= allowed for r in g), len(g))} | "
                     f"{bpd.share(sum(r['named'] for r in g), len(g))} | {med:+.3f} |")
    best = best_monotone_rule([r["dominating"] for r in rows], allowed)
    best_entry = best_monotone_rule([r["dominating_entry"] for r in rows], allowed)
    lines += ["", f"One rule for all candidates (monotone in gain, p and p of the mean; at most {allowed} clean "
                  f"draws with an alarm) names at most {bpd.share(best, len(rows))} of the effect draws, if its candidates "
                  f"capture no more than the oracle; a rule of its own for each catalog entry (alarms counted on "
                  f"the clean draws' candidates of the entries that are right for the draw) at most "
                  f"{bpd.share(best_entry, len(rows))}."]
    lines += ["", f"wall time {wall:.0f} s with {args.jobs} job(s)"]
    name = "diagnosis_oracle_record.txt" if args.record else "diagnosis_oracle.txt"
    write_results(name, lines)
    print("\n".join(lines[-(len(bpd.EFFECTS) + 16):]))


if __name__ == "__main__":
    main()
