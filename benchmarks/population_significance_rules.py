"""Significance rules for the diagnosis judged offline on a population run's candidates.

benchmarks/bench_population_diagnosis.py saves, per draw, every candidate of the base
diagnosis over the base alone (held-out VAF gain, robust p, p of the mean, whether its signal
leaks into the reflex drive) to benchmarks/out/population_diagnosis_candidates.json (git-ignored data). This
script replays the diagnosis's choice of its first significant candidate under other rules
(:func:`lpvpc.diagnosis.candidates.passes` with other constants, per-pathway floors, another
Bonferroni family) without refitting anything:

* a candidate is significant when it is available, its signal does not leak
  (``LEAK_R2``), and the rule passes it at the Bonferroni level ALPHA / family;
* the first significant one is the one with the largest gain (the forward selection's first
  round: the marginal gains); activation_reflex_gain tied with reflex_habituation (their
  two-sided tie p above TIE_P) is named habituation when that has a positive gain at p <=
  ALPHA (``_prefer_underived``); the EMG's tie break between the position-dependent reflex
  delay and dynamics changes neither pathway nor signal, so it is not replayed;
* right, as the bench counts it: the base model holds a right entry, or the first
  significant candidate is a catalog effect with the right (pathway, signals);
* a clean draw's false alarm: any candidate significant;
* the ladder within 1 point of the clean model: the draw's own ladder when the rule's first
  choice is the ladder's first step (or both are none), yes when the base model already is
  within 1 point (a step the ladder does not keep cannot lower its end), the VAF of the rung
  that added the rule's choice when the ladder added it later, else unknown (counted as a
  miss and as a hit for the two bounds).

The draws are split by seed parity: rules are tuned on the even seeds (the best right share
with no clean alarm, ties to the rule with the fewest
clean alarms at ten times the level, then the later,
stricter, rule of its grid) and checked on the odd ones; both halves are reported.
The right share is also tabulated against the effect's cost (clean VAF minus base VAF).

Run: python benchmarks/population_significance_rules.py [--run COMMAND-KEY] [--check-run COMMAND-KEY]
[--own RECORDS] [--tune-alarms N]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from lpvpc.diagnosis.candidates import ALPHA, EMG_SIGNALS, MIN_GAIN, SMALL_GAIN, STRONG_EVIDENCE, TIE_P  # noqa: E402
from lpvpc.models.effects import CATALOG, SETTINGS  # noqa: E402
from _results import RESULTS, write_results  # noqa: E402

WITHIN = 1.0
HAB, ACT = "reflex_habituation", "activation_reflex_gain"
COST_BINS = (-math.inf, 0.05, 0.1, 0.2, 0.5, 1.0, math.inf)


def where(name):
    e = CATALOG[name]
    return e.pathway, tuple(sorted(e.signals)) or ("position",)


def pathway(name):
    return CATALOG[name].pathway if name in CATALOG else SETTINGS[name].pathway


class Rule:
    """A significance rule: floor (per pathway), small-gain tier (share of the floor, evidence
    factor, on p of the mean or the robust p), an optional third tier (gain, evidence factor),
    the Bonferroni family (None: the candidates available)."""

    def __init__(self, name, floor=MIN_GAIN, small=SMALL_GAIN, strong=STRONG_EVIDENCE, small_p="mean",
                 floors=None, tier3=None, family=None, alpha=ALPHA, reflex_floor=None,
                 reflex_emg=False, reflex_strong=1.0):
        self.name, self.floor, self.small, self.strong, self.small_p = name, floor, small, strong, small_p
        self.reflex_floor, self.reflex_emg, self.reflex_strong = reflex_floor, reflex_emg, reflex_strong
        self.floors, self.tier3, self.family, self.alpha = floors or {}, tier3, family, alpha

    def passes(self, name, gain, p, p_mean, level):
        if not (np.isfinite(gain) and np.isfinite(p)) or p > level:
            return False
        if (self.reflex_floor is not None and name in CATALOG and pathway(name) == "reflex" and gain >= self.reflex_floor
                and (self.reflex_emg or not set(CATALOG[name].signals) & set(EMG_SIGNALS))
                and p_mean <= level / self.reflex_strong):
            return True
        f = self.floors.get(pathway(name), self.floor)
        ps = p_mean if self.small_p == "mean" else p
        if gain >= f or (gain >= self.small * f and ps <= level / self.strong):
            return True
        if self.tier3 is not None:
            g3, s3 = self.tier3
            return gain >= g3 and ps <= level / s3
        return False

    def significant(self, cands, n_available):
        level = self.alpha / (self.family or max(1, n_available))
        out = []
        for name, c in cands.items():
            if c is None:
                continue
            gain, p, pm, leaky = c[0], c[1], c[2], c[3]
            if gain is None or p is None:
                continue
            if not leaky and self.passes(name, gain, p, pm if pm is not None else p, level):
                out.append((gain, name))
        return [n for _, n in sorted(out, reverse=True)]

    def first(self, row):
        bc = row["base_candidates"]
        sig = self.significant(bc["cands"], bc["n_available"])
        if not sig:
            return None
        top = sig[0]
        if top == ACT:
            hab = bc["cands"].get(HAB)
            tie = bc["ties"].get(f"{ACT}|{HAB}")
            if hab is not None and tie is not None and tie > TIE_P and hab[0] > 0 and hab[1] <= self.alpha:
                top = HAB
        return top


def right(row, top):
    if row.get("in_model_list"):
        return True
    if top is None or top not in CATALOG:
        return False
    return where(top) in {where(a) for a in row["accepted"]}


def ladder(row, top):
    """(lower, upper) bound of 'the ladder ends within 1 point' under a rule choosing ``top``."""
    if row.get("error"):
        return False, False
    rungs = row["rungs"]
    first = (rungs[1]["change"].get("effect") or "setting") if len(rungs) > 1 else None
    same = top == first or (first == "setting" and top in SETTINGS)
    if same or (top is None and first is None):
        return bool(row["ladder"]), bool(row["ladder"])
    if row["clean_vaf"] - row["base_vaf"] <= WITHIN:
        return True, True
    for r in rungs[1:]:
        if r["change"].get("effect") == top:
            ok = row["clean_vaf"] - max(row["base_vaf"], r["vaf"]) <= WITHIN
            return ok, ok
    return False, True


def evaluate(rule, eff, clean):
    tops = [rule.first(r) if not r.get("error") else None for r in eff]
    named = sum(right(r, t) and not r.get("error") for r, t in zip(eff, tops))
    lad = [ladder(r, t) for r, t in zip(eff, tops)]
    alarms = sum(bool(r.get("error")) or bool(rule.significant(r["base_candidates"]["cands"],
                                                               r["base_candidates"]["n_available"]))
                 for r in clean)
    return {"named": named, "n": len(eff), "alarms": alarms, "clean": len(clean),
            "ladder_lo": sum(a for a, _ in lad), "ladder_hi": sum(b for _, b in lad), "tops": tops}


def rules():
    out = [Rule("current (0.15; 0.6x with p_mean <= level/10)")]
    for f, s, st, sp in itertools.product((0.05, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2), (0.25, 0.33, 0.4, 0.5, 0.6, 1.0),
                                          (1, 10, 100, 1000), ("mean", "robust")):
        if s == 1.0 and (st != 1 or sp != "mean"):
            continue
        out.append(Rule(f"floor {f:g}; {s:g}x with {'p_mean' if sp == 'mean' else 'p'} <= level/{st:g}"
                        if s < 1 else f"floor {f:g} alone", floor=f, small=s, strong=st, small_p=sp))
    for fi, fr in itertools.product((0.05, 0.08, 0.1, 0.15, 0.2), (0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.15)):
        for st in (10, 100):
            out.append(Rule(f"floors intrinsic {fi:g} / reflex {fr:g}; 0.6x with p_mean <= level/{st:g}",
                            floors={"intrinsic": fi, "reflex": fr}, strong=st))
    for fr in (0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.1):
        out.append(Rule(f"current + reflex-pathway effects at {fr:g} pp", reflex_floor=fr, reflex_emg=True))
        out.append(Rule(f"current + reflex-pathway effects not reading the EMG at {fr:g} pp", reflex_floor=fr))
    for g3, s3 in itertools.product((0.02, 0.03, 0.04, 0.05, 0.06), (100, 1000, 1e4, 1e5)):
        out.append(Rule(f"current + tier {g3:g} pp with p_mean <= level/{s3:g}", tier3=(g3, s3)))
    for fam in (5, 10, 14, 20):
        out.append(Rule(f"current, Bonferroni family fixed at {fam}", family=fam))
        out.append(Rule(f"current + tier 0.04 pp with p_mean <= level/1000, family {fam}", tier3=(0.04, 1000),
                        family=fam))
    return out


def own_subject(path, chosen):
    """Clean alarms of ``chosen`` rules on bench_significance_rules.py's records (the own
    virtual subject, clean seeds 0-19 and 40-59 per design): robust p = the smaller of the t
    test's and the signed rank's doubled, p_mean the t test's; no leak check (the records do
    not say; a leak only removes alarms)."""
    last = {}
    for line in open(path):
        r = json.loads(line)
        if r["hidden"] == "none":
            last[(r["design"], r["seed"])] = r
    designs = list(dict.fromkeys(d for d, _ in last))
    out = ["", f"The own virtual subject's clean records (benchmarks/bench_significance_rules.py --clean, "
           f"{len(last)} records: {', '.join(f'{d} {sum(k[0] == d for k in last)}' for d in designs)}): clean alarms",
           "", "| rule | " + " | ".join(designs) + " |", "|---|" + "---|" * len(designs)]
    for rl in chosen:
        cells = []
        for d in designs:
            recs = [r for k, r in last.items() if k[0] == d]
            n = 0
            for r in recs:
                cands = {x["effect"]: [x["gain"], min(1.0, 2 * min(x["p"], x["pw"])), x["p"], 0, 0] for x in r["cands"]}
                n += bool(rl.significant(cands, len(cands)))
            cells.append(f"{n}/{len(recs)}")
        out.append(f"| {rl.name} | " + " | ".join(cells) + " |")
    top = []
    for (d, seed), r in last.items():
        for x in r["cands"]:
            if x["gain"] >= 0.03 and x["p"] <= 1e-3:
                top.append(f"{d} seed {seed}: {x['effect']} {x['gain']:+.3f} pp, p_mean {x['p']:.1e}, signed rank "
                           f"{x['pw']:.1e}")
    out += ["", "Their candidates with gain >= 0.03 pp and p_mean <= 1e-3: " + ("; ".join(top) or "none")]
    return out


def share(k, n):
    return f"{k}/{n} = {100 * k / n:.0f} %" if n else "-"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default=None, help="the command key in the JSON (default: the default run's)")
    ap.add_argument("--check-run", default=None, help="a further run's command key: the chosen rules on it")
    ap.add_argument("--own", default=None, metavar="FILE",
                    help="records of benchmarks/bench_significance_rules.py --clean (the own subject's clean seeds "
                         "per design): the chosen rules' false alarms on them")
    ap.add_argument("--tune-alarms", type=int, default=0, help="clean alarms allowed on the tuning half (default 0: "
                    "the target's 2 %% of the full 100 leaves one per half, none is the margin)")
    args = ap.parse_args(argv)
    path = RESULTS.parent / "out" / "population_diagnosis_candidates.json"
    if not path.exists():
        sys.exit(f"{path} is missing: run benchmarks/bench_population_diagnosis.py first (it saves every draw's "
                 "candidates there)")
    runs = json.loads(path.read_text())
    key = args.run or next(k for k in runs if "--draws" not in k and "--clean" not in k and "--first-seed" not in k)
    rows = runs[key]["rows"]
    eff = [r for r in rows if r["effect"] != "none"]
    clean = [r for r in rows if r["effect"] == "none"]
    halves = {"tune (even seeds)": ([r for r in eff if r["seed"] % 2 == 0], [r for r in clean if r["seed"] % 2 == 0]),
              "check (odd seeds)": ([r for r in eff if r["seed"] % 2 == 1], [r for r in clean if r["seed"] % 2 == 1]),
              "all": (eff, clean)}
    cands = rules()
    res = {name: [evaluate(rl, *h) for rl in cands] for name, h in halves.items()}
    # consistency: the current rule replayed against what the bench recorded
    cur = res["all"][0]
    bench_named = sum(bool(r["named"]) for r in eff)
    bench_alarms = sum(bool(r["alarm"]) for r in clean)
    mism = [(r["seed"], r["effect"], r.get("top"), t) for r, t in zip(eff, cur["tops"])
            if bool(right(r, t) and not r.get("error")) != bool(r["named"])]
    tune = res["tune (even seeds)"]
    ok = [i for i, e in enumerate(tune) if e["alarms"] <= args.tune_alarms]
    # ties (many rules name the same draws) go to the one with the fewest near alarms: clean
    # tuning draws it would flag at ten times the level (a margin, judged on the tuning half)
    import copy

    def near(rl):
        loose = copy.copy(rl)
        loose.alpha = 10 * rl.alpha
        return evaluate(loose, [], halves["tune (even seeds)"][1])["alarms"]

    nears = {i: near(cands[i]) for i in ok}
    best = sorted(ok, key=lambda i: (-tune[i]["named"], tune[i]["alarms"], nears[i], -i))  # then the later (stricter) of a grid
    # the best few of each family on the tuning half (a family's first members tie often)
    shown = [0]
    for fam in ("floor ", "floors ", "current + reflex-pathway effects at", "current + reflex-pathway effects not",
                "current + tier", "current, Bonferroni"):
        shown += [i for i in best if cands[i].name.startswith(fam) and i not in shown][:4]
    # the strictest rules that keep all clean draws silent on all data, for contrast
    import shlex

    argv_text = " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    lines = [f"# Significance rules replayed on the population's candidates (python "
             f"benchmarks/population_significance_rules.py{' ' + argv_text if argv_text else ''})", "",
             f"Data: {path.name}, run `{key}` (git {runs[key].get('git', '?')}): {len(eff)} effect draws, "
             f"{len(clean)} clean draws. The current rule replayed: right {bench_named - 0 if not mism else '?'} "
             f"recorded by the bench, {sum(right(r, t) and not r.get('error') for r, t in zip(eff, cur['tops']))} "
             f"replayed; clean alarms {bench_alarms} recorded, {cur['alarms']} replayed"
             + (f"; draws replayed differently: {mism}" if mism else " (every draw replayed as recorded)") + ".", "",
             f"{len(cands)} rules evaluated; tuned on the even seeds (the most right namings with at most "
             f"{args.tune_alarms} clean alarm(s) of {len(halves['tune (even seeds)'][1])}), checked on the odd seeds. "
             "Ladder: bounds (a draw whose ladder would take a step it did not take is unknown). Tune alarms in brackets: at "
             "ten times the level (the tie-break).", "",
             "| rule | tune: right | tune: clean alarms | tune: ladder | check: right | check: clean alarms | "
             "check: ladder | all: right | all: clean alarms |", "|---|---|---|---|---|---|---|---|---|"]

    def lad(e):
        return (share(e["ladder_lo"], e["n"]) if e["ladder_lo"] == e["ladder_hi"]
                else f"{100 * e['ladder_lo'] / e['n']:.0f}-{100 * e['ladder_hi'] / e['n']:.0f} %")

    for i in shown:
        t, c, a = tune[i], res["check (odd seeds)"][i], res["all"][i]
        lines.append(f"| {cands[i].name} | {share(t['named'], t['n'])} | {t['alarms']}/{t['clean']} "
                     f"({nears.get(i, near(cands[i]))}) | {lad(t)} | "
                     f"{share(c['named'], c['n'])} | {c['alarms']}/{c['clean']} | {lad(c)} | "
                     f"{share(a['named'], a['n'])} | {a['alarms']}/{a['clean']} |")
    # frontier on all data: best right per number of alarms
    lines += ["", "Frontier on all draws (the most right namings for each number of clean alarms):", "",
              "| clean alarms | right | rule |", "|---|---|---|"]
    allr = res["all"]
    for k in range(0, 6):
        idx = [i for i, e in enumerate(allr) if e["alarms"] == k]
        if idx:
            i = max(idx, key=lambda i: (allr[i]["named"], -i))
            lines.append(f"| {k}/{allr[i]['clean']} | {share(allr[i]['named'], allr[i]['n'])} | {cands[i].name} |")
    # clean draws: their largest candidates
    lines += ["", "Clean draws' strongest candidates (gain >= 0.03 pp and p <= 1e-3, over the base):", "",
              "| seed | design | candidate | gain (pp) | p | p_mean | family |", "|---|---|---|---|---|---|---|"]
    for r in clean:
        bc = r["base_candidates"]
        for name, c in sorted(bc["cands"].items(), key=lambda kv: -(kv[1][0] if kv[1] else -9)):
            if c and c[0] >= 0.03 and c[1] <= 1e-3:
                lines.append(f"| {r['seed']} | {r['design']} | {name}{' (leaks)' if c[3] else ''} | {c[0]:+.3f} | "
                             f"{c[1]:.1e} | {c[2]:.1e} | {bc['n_available']} |")
    # right against the effect's cost
    pick = best[0] if best else 0
    lines += ["", f"Right naming against the effect's cost to the base model (clean VAF minus base VAF, points), "
              f"all draws: current rule / the tuned rule ({cands[pick].name}):", "",
              "| cost (points) | draws | right, current | right, tuned | right entry's gain (median pp) |",
              "|---|---|---|---|---|"]
    for lo, hi in zip(COST_BINS[:-1], COST_BINS[1:]):
        g = [(r, t0, t1) for r, t0, t1 in zip(eff, allr[0]["tops"], allr[pick]["tops"]) if not r.get("error")
             and lo <= r["clean_vaf"] - r["base_vaf"] < hi]
        if not g:
            continue
        gains = [max((r["base_candidates"]["cands"].get(a) or [np.nan])[0] for a in r["accepted"]) for r, _, _ in g]
        lines.append(f"| {lo:+g} .. {hi:+g} | {len(g)} | {share(sum(right(r, t) for r, t, _ in g), len(g))} | "
                     f"{share(sum(right(r, t) for r, _, t in g), len(g))} | {np.nanmedian(gains):+.3f} |")
    lines += ["", "Per effect, all draws (current / tuned):", "", "| effect | draws | right, current | right, tuned | "
              "median cost (points) |", "|---|---|---|---|---|"]
    for effect in dict.fromkeys(r["effect"] for r in eff):
        g = [(r, t0, t1) for r, t0, t1 in zip(eff, allr[0]["tops"], allr[pick]["tops"]) if r["effect"] == effect]
        cost = [r["clean_vaf"] - r["base_vaf"] for r, _, _ in g if not r.get("error")]
        lines.append(f"| {effect} | {len(g)} | {share(sum(right(r, t) for r, t, _ in g), len(g))} | "
                     f"{share(sum(right(r, t) for r, _, t in g), len(g))} | {np.median(cost):+.2f} |")
    if args.check_run:
        crow = runs[args.check_run]["rows"]
        ce, cc = [r for r in crow if r["effect"] != "none"], [r for r in crow if r["effect"] == "none"]
        lines += ["", f"The same rules on run `{args.check_run}`:", "", "| rule | right | clean alarms | ladder |",
                  "|---|---|---|---|"]
        for i in shown:
            e = evaluate(cands[i], ce, cc)
            lines.append(f"| {cands[i].name} | {share(e['named'], e['n'])} | {e['alarms']}/{e['clean']} | {lad(e)} |")
    if args.own:
        lines += own_subject(args.own, [cands[i] for i in shown])
    write_results("population_significance_rules.txt", lines, echo=True)


if __name__ == "__main__":
    main()
