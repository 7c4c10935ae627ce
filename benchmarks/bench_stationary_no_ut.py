"""Stationary trials without a UT trial: what does taking the PT trial's mean as the
operating point cost?

For each seed the virtual subject's stationary experiment (one operating position, 60 s at
1 kHz, decimated to 100 Hz) is identified twice on its first 70 % and judged on the last
30 %: from the PT/UT pair as recorded (lpvpc.io.pair_trials), and from the PT trial alone
with the operating point and torque offset taken as its means
(lpvpc.io.stationary_perturbation, what ``--stationary`` does). Printed: the elastic
stiffness K at the operating position (N m/rad) and the held-out VAF (%) of both.

Run: python benchmarks/bench_stationary_no_ut.py [n_seeds]
     (writes benchmarks/results/stationary_no_ut.txt)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import pair_trials, stationary_perturbation  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from _results import write_results  # noqa: E402


def fit_and_judge(data):
    n = int(0.7 * data.n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the StationaryWarning is expected here
        model = identify(data.segment(0, n))
    test = data.segment(n)
    K = float(model.elastic_stiffness([data.scheduling[0]])[0])
    return K, vaf(test.torque, model.predict(test.position, test.scheduling, warn=False).total)


def main(n_seeds: int) -> None:
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    say("Stationary trials: PT/UT pair vs PT alone with its mean as operating point (virtual subject, 60 s, 100 Hz)")
    say(f"{'seed':>4} {'K pair':>8} {'K PT alone':>10} {'dK %':>7} {'VAF pair':>9} {'VAF PT alone':>12}")
    dks, dv = [], []
    for seed in range(n_seeds):
        pair = simulate_pair("stationary", seed=seed, duration=60.0)
        Ka, va = fit_and_judge(pair_trials(pair.pt, pair.ut))
        Kb, vb = fit_and_judge(stationary_perturbation(pair.pt))
        dks.append(100 * (Kb - Ka) / Ka)
        dv.append(vb - va)
        say(f"{seed:>4} {Ka:8.2f} {Kb:10.2f} {dks[-1]:+7.2f} {va:9.2f} {vb:12.2f}")
    say()
    say(f"K from the PT trial alone vs the pair: median {np.median(dks):+.2f} %, worst {max(dks, key=abs):+.2f} %; "
        f"held-out VAF {np.median(dv):+.2f} points (median; the pair's difference carries the UT trial's noise too)")
    say(f"one BLAS thread; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    write_results("stationary_no_ut.txt", lines)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
