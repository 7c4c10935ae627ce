"""Significance rules of the diagnosis compared on the same fits (the table of
benchmarks/results/diagnose_significance.txt, section "Issue 23 (branch labsig)").

    python benchmarks/bench_significance_rules.py [--perturbation pralds,lab_pulses,prbs]
        [--clean] [--effects] [--records FILE]

For each design: identify(ident) and diagnose(model, novel) as bench_diagnose.py does (its
``pairs`` and scenarios), then every applicable candidate's held-out gain and two p-values
on the same 60 block means (2 s) of r_base^2 - r_candidate^2: the batch-means t test and
the Wilcoxon signed-rank test. ``--clean``: seeds 0-19 and 40-59 without a hidden effect;
``--effects``: every scenario, 5 seeds. Records are appended to ``--records`` (JSON lines,
default a file in the system's temp folder; a record diagnosed twice counts once, the last),
so a long run can be split and resumed; the table is printed from all records there.

Rules (first significant = the largest candidate passing; Bonferroni 0.1 / applicable
candidates; 0.15 pp, or 0.09 pp at a tenth of the level): the t test alone (before); the
signed rank alone; the smaller p doubled; the same with the small-gain tier on the t test's
p alone (lpvpc.diagnosis.cv.robust_paired_test with lpvpc.diagnosis.candidates.passes, now).
A position-dependent reflex delay and dynamics, tied on torque, count for each other; stress
relaxation absent from the candidates (identify put it in the model) counts as found. The
full ranking (conditional ranking, ties, leak checks) can differ: bench_diagnose.py has it.
"""

import argparse
import collections
import json
import os
import sys
import tempfile

import numpy as np
import scipy.stats

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

SMALL, STRONG, MIN_GAIN, ALPHA, BLOCK = 0.6, 10.0, 0.15, 0.1, 200  # as lpvpc.diagnosis.candidates; 2 s at 100 Hz
TIED = {"position_dependent_reflex_delay", "position_dependent_reflex_dynamics"}


def block_means(d, b=BLOCK):
    nb = len(d) // b
    return d[: nb * b].reshape(nb, b).mean(1)


def _bench_diagnose(design):
    """bench_diagnose (its pairs and scenarios) simulating ``design``."""
    sys.argv = sys.argv[:1]  # it reads its options from the command line at import
    import bench_diagnose as B

    B.PERTURBATION = design  # read by B.pairs
    return B


def diagnose_records(design, jobs, out):
    B = _bench_diagnose(design)
    from lpvpc.diagnosis.diagnose import diagnose
    from lpvpc.diagnosis.cv import paired_test
    from lpvpc.identification.identify import LPVPCEstimator

    with open(out, "a") as fh:
        for name, seed in jobs:
            eff, st, exp = B.SCENARIOS.get(name, ((), {}, None))
            ident, novel = B.pairs(seed, eff, params=B.SCENARIO_PARAMS.get(name))
            model = LPVPCEstimator(**st).fit(ident).model_
            d = diagnose(model, novel, dependence=False)
            r0, cands = d.base_residual, []
            for c in d.candidates:
                if not c.available:
                    continue
                m = block_means(r0 ** 2 - c.residual ** 2)
                w = scipy.stats.wilcoxon(m, alternative="greater").pvalue if np.any(m != 0) else 1.0
                cands.append({"effect": c.effect, "gain": float(c.vaf_gain),
                              "p": float(paired_test(r0, c.residual, 100.0)[1]), "pw": float(w)})
            fh.write(json.dumps({"design": design, "hidden": name, "seed": seed, "expected": exp,
                                 "cands": cands}) + "\n")
            fh.flush()
            print(f"{design} {name} seed {seed}: {len(cands)} candidates", flush=True)


def _passes(gain, p, level):
    return p <= level and (gain >= MIN_GAIN or (gain >= SMALL * MIN_GAIN and p <= level / STRONG))


def first_significant(rec, rule):
    level = ALPHA / max(1, len(rec["cands"]))

    def ok(x):
        pm = min(1.0, 2 * min(x["p"], x["pw"]))
        if rule == "now":
            return ((pm <= level and x["gain"] >= MIN_GAIN)
                    or (x["gain"] >= SMALL * MIN_GAIN and x["p"] <= level / STRONG))
        return _passes(x["gain"], {"t": x["p"], "signed rank": x["pw"], "smaller x2": pm}[rule], level)

    s = [x for x in rec["cands"] if ok(x)]
    return max(s, key=lambda x: x["gain"])["effect"] if s else None


def table(path):
    last = {}
    for line in open(path):
        r = json.loads(line)
        last[(r["design"], r["hidden"], r["seed"])] = r
    rules = ("t", "signed rank", "smaller x2", "now")
    tab = collections.OrderedDict()
    for r in last.values():
        clean = r["hidden"] == "none"
        key = (r["design"], ("none 0-19" if r["seed"] < 20 else "none 40-59") if clean else r["hidden"])
        row = tab.setdefault(key, [0] * (len(rules) + 1))
        row[-1] += 1
        in_model = r["expected"] == "stress_relaxation" and all(x["effect"] != r["expected"] for x in r["cands"])
        for i, rule in enumerate(rules):
            f = first_significant(r, rule)
            row[i] += (f is not None) if clean else (in_model or f == r["expected"] or (f in TIED and r["expected"] in TIED))
    print("| design | hidden | batch-means t (before) | signed rank alone | t or signed rank, smaller p x2 "
          "| the same, the small-gain tier on t alone (now) | records |")
    print("|---|---|---|---|---|---|---|")
    for (design, hidden), v in tab.items():
        print(f"| {design} | {hidden} | " + " | ".join(f"{c}/{v[-1]}" for c in v[:-1]) + f" | {v[-1]} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--perturbation", default="pralds,lab_pulses,prbs")
    ap.add_argument("--clean", action="store_true", help="clean seeds 0-19 and 40-59")
    ap.add_argument("--effects", action="store_true", help="every scenario, 5 seeds")
    ap.add_argument("--records", default=os.path.join(tempfile.gettempdir(), "lpvpc_significance_rules.jsonl"))
    a = ap.parse_args()
    for design in a.perturbation.split(","):
        jobs = [("none", s) for s in [*range(20), *range(40, 60)]] if a.clean else []
        if a.effects:
            jobs += [(n, s) for n in _bench_diagnose(design).SCENARIOS for s in range(5)]
        if jobs:
            diagnose_records(design, jobs, a.records)
    if os.path.exists(a.records):
        table(a.records)


if __name__ == "__main__":
    main()
