"""Several trials in one identification: does anything cross the seams?

For each seed the virtual subject's 2-minute identification record (1 kHz, decimated to
100 Hz) is identified four ways, and each model is judged on the novel trajectory (held
out) and by K(theta) over the central 80 % of the identified range, against the model of
the whole record:

- whole: the record as one trial;
- halves: its two halves as two trials (lpvpc.io.join_trials);
- 8 pieces, shuffled, as trials: nothing may cross a seam, so this should match the
  8 pieces in their own order (the joint problem is the sum of the trials' problems);
- 8 pieces, shuffled, put naively end to end (no segments): the seams become jumps in
  position, velocity and reflex state.

Also the time of the joint fits relative to the whole record's, measured in the same run
(shared, noisy machine: compare ratios).

Run: python benchmarks/bench_trials.py [n_seeds]   (writes benchmarks/results/trials.txt)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import PerturbationData, join_trials, pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from _results import write_results  # noqa: E402

N_PIECES = 8


def pieces(data, k):
    cuts = np.linspace(0, data.n, k + 1).astype(int)
    return [data.segment(a, b) for a, b in zip(cuts[:-1], cuts[1:])]


def timed_fit(data):
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(data)
    return model, time.perf_counter() - t


def main(n_seeds: int) -> None:
    rows, lines = [], []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    say("Several trials in one identification (virtual subject, 2-minute record at 100 Hz, default settings)")
    say(f"{'seed':>4}  {'variant':<32} {'novel VAF':>9} {'dVAF':>7} {'max |dK|/K':>10} {'fit s':>6} {'x whole':>7}")
    for seed in range(n_seeds):
        ident = simulate_pair("multilevel", seed=seed)
        novel = simulate_pair("novel", seed=seed + 1000)
        d, nv = pair_trials(ident.pt, ident.ut), pair_trials(novel.pt, novel.ut)
        grid = np.linspace(*np.percentile(d.scheduling, [10, 90]), 41)
        parts = pieces(d, N_PIECES)
        order = np.random.default_rng(seed).permutation(N_PIECES)
        shuffled = [parts[i] for i in order]
        variants = {
            "whole record (1 trial)": d,
            "two halves as 2 trials": join_trials(pieces(d, 2)),
            f"{N_PIECES} pieces in order as trials": join_trials(parts),
            f"{N_PIECES} pieces shuffled as trials": join_trials(shuffled),
            f"{N_PIECES} pieces shuffled, naive": PerturbationData(
                *(np.concatenate([getattr(p, k) for p in shuffled]) for k in ("position", "torque", "scheduling")),
                d.fs),
        }
        ref = None
        for name, data in variants.items():
            model, secs = timed_fit(data)
            v = vaf(nv.torque, model.predict(nv.position, nv.scheduling, warn=False).total)
            K = model.elastic_stiffness(grid)
            if ref is None:
                ref = (v, K, secs)
            dk = float(np.max(np.abs(K - ref[1]) / np.abs(ref[1])))
            rows.append((seed, name, v - ref[0], dk, secs / ref[2]))
            say(f"{seed:>4}  {name:<32} {v:9.3f} {v - ref[0]:+7.3f} {100 * dk:9.3f}% {secs:6.2f} {secs / ref[2]:7.2f}")
    say()
    say("worst over seeds (against the whole record's model):")
    for name in dict.fromkeys(r[1] for r in rows):
        sel = [r for r in rows if r[1] == name]
        say(f"  {name:<32} |dVAF| <= {max(abs(r[2]) for r in sel):.3f} points, max |dK|/K <= "
            f"{100 * max(r[3] for r in sel):.3f} %, fit time x{np.median([r[4] for r in sel]):.2f} (median)")
    say(f"one BLAS thread; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    write_results("trials.txt", lines)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
