"""Monte Carlo accuracy on the virtual subject: bias and spread over noise seeds.

For each seed: simulate identification and novel trials (1 kHz, written through the CSV
loaders' pairing and decimation), identify at default settings, and record
- K(theta) error over the central 80 % of the identified position range (worst and mean);
- novel-trajectory VAF, its noise ceiling (VAF of the noise-free torque) and the gap;
- intrinsic-torque VAF against the true intrinsic torque;
- reflex gain and threshold trends (slope over the central range) against the truth.

Run: python benchmarks/bench_montecarlo.py [n_seeds]  (writes benchmarks/results/montecarlo.txt)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import Trial, pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import SubjectParams, simulate_pair  # noqa: E402
from _results import write_results  # noqa: E402


def true_component(pair, key):
    c, t = pair.components, pair.pt.time
    return pair_trials(Trial(t, pair.pt.position, c["pt_" + key]), Trial(t, pair.ut.position, c["ut_" + key])).torque


def one_seed(seed):
    truth = SubjectParams()
    ident = simulate_pair("multilevel", seed=seed)
    novel = simulate_pair("novel", seed=seed + 1000)
    d, nv = pair_trials(ident.pt, ident.ut), pair_trials(novel.pt, novel.ut)
    ceiling = vaf(nv.torque, pair_trials(novel.pt_clean, novel.ut_clean).torque)
    t = time.perf_counter()
    model = identify(d)
    elapsed = time.perf_counter() - t
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pred = model.predict(nv.position, nv.scheduling)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 25)
    k_err = 100 * (model.elastic_stiffness(rho) / truth.K(rho) - 1)
    gain, thr = model.reflex_gain_threshold(rho)
    g_slope = np.polyfit(rho, gain, 1)[0] / np.polyfit(rho, truth.reflex_gain(rho), 1)[0]
    t_slope = np.polyfit(rho, thr, 1)[0] / np.polyfit(rho, truth.reflex_threshold(rho), 1)[0]
    return {
        "seed": seed, "time": elapsed, "order": model.fit["state_order"],
        "k_worst": float(np.max(np.abs(k_err))), "k_mean": float(np.mean(k_err)),
        "vaf": vaf(nv.torque, pred.total), "ceiling": ceiling,
        "vaf_intrinsic": vaf(true_component(novel, "intrinsic"), pred.intrinsic),
        "gain_slope_ratio": float(g_slope), "threshold_slope_ratio": float(t_slope),
        "gain_mean_ratio": float(np.mean(gain / truth.reflex_gain(rho))),
    }


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    rows = [one_seed(s) for s in range(n)]
    head = "| seed | order | K worst err % | K mean err % | novel VAF | ceiling | gap | intrinsic VAF | gain slope ratio | threshold slope ratio | time s |"
    lines = ["# Monte Carlo accuracy on the virtual subject (python benchmarks/bench_montecarlo.py)", "", head,
             "|" + "---|" * 11]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['order']} | {r['k_worst']:.1f} | {r['k_mean']:+.1f} | {r['vaf']:.2f} | {r['ceiling']:.2f} | "
                     f"{r['ceiling'] - r['vaf']:.2f} | {r['vaf_intrinsic']:.2f} | {r['gain_slope_ratio']:.2f} | "
                     f"{r['threshold_slope_ratio']:.2f} | {r['time']:.1f} |")
    a = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    gap = a["ceiling"] - a["vaf"]
    lines += ["", f"seeds: {n}",
              f"K worst central error: median {np.median(a['k_worst']):.1f} %, max {a['k_worst'].max():.1f} %; "
              f"K bias (mean signed error) {np.mean(a['k_mean']):+.1f} %, spread (sd) {np.std(a['k_mean']):.1f} %",
              f"novel VAF gap to noise ceiling: median {np.median(gap):.2f}, max {gap.max():.2f} percentage points",
              f"intrinsic VAF vs true intrinsic torque: min {a['vaf_intrinsic'].min():.2f} %",
              f"reflex gain slope ratio (identified/true): median {np.median(a['gain_slope_ratio']):.2f}, "
              f"range {a['gain_slope_ratio'].min():.2f}..{a['gain_slope_ratio'].max():.2f}; "
              f"mean gain ratio median {np.median(a['gain_mean_ratio']):.2f}",
              f"reflex threshold slope ratio: median {np.median(a['threshold_slope_ratio']):.2f}, "
              f"range {a['threshold_slope_ratio'].min():.2f}..{a['threshold_slope_ratio'].max():.2f}",
              f"state order chosen: {dict(zip(*np.unique(a['order'], return_counts=True)))}"]
    write_results("montecarlo.txt", lines, echo=True)


if __name__ == "__main__":
    main()
