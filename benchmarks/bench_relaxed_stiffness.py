"""Coverage of the 95 % intervals of a model with stress relaxation (issue 22): the
short-range stiffness K (lpvpc.model.LPVPCModel.elastic_stiffness_interval) and the relaxed
stiffness (lpvpc.uncertainty.relaxed_stiffness_interval), against the virtual subject's truth.

Two subjects, 2-minute multilevel pairs at 100 Hz (18 dB), stress relaxation forced
(``identify(data, effects=("stress_relaxation",))``: the selection is skipped, so the
intervals have no structural term):
- clean (no relaxation): short-range = relaxed = K (SubjectParams.incremental_stiffness);
- relaxing (simulate_pair(effects=("stress_relaxation",)): 40 % of the elastic torque relaxes
  with a 0.6 s time constant): short-range K, relaxed 0.6 K.
9 positions over the central 80 % of the identified range; coverage pooled over seeds and
positions, seeds with every position covered, median half-width in % of the estimate,
median absolute error in %.

Run: nice python benchmarks/bench_relaxed_stiffness.py [n_seeds]  (default 8; writes
benchmarks/results/relaxed_stiffness.txt)
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.data import pair_trials  # noqa: E402
from lpvpc.identify import identify  # noqa: E402
from lpvpc.simulate import SubjectParams, simulate_pair  # noqa: E402
from lpvpc.uncertainty import relaxed_stiffness_interval  # noqa: E402
from _results import write_results  # noqa: E402

EFFECT = "stress_relaxation"
RELAXED_FRACTION = 0.6  # of K, what a held displacement keeps on the relaxing subject (lpvpc.simulated_effects)


def one_seed(seed, relaxing):
    pair = simulate_pair("multilevel", seed=seed, fs_out=100.0, effects=(EFFECT,) if relaxing else ())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(pair_trials(pair.pt, pair.ut), effects=(EFFECT,))
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    K = SubjectParams().incremental_stiffness(rho, pair.truth["perturbation_amplitude"])
    k_lo, k_hi = model.elastic_stiffness_interval(rho)
    r_est, r_lo, r_hi = relaxed_stiffness_interval(model, rho)
    return {"short-range stiffness K": (model.elastic_stiffness(rho), k_lo, k_hi, K),
            "relaxed stiffness": (r_est, r_lo, r_hi, RELAXED_FRACTION * K if relaxing else K)}


def main(n_seeds=8):
    t0 = time.time()
    lines = [f"# Intervals of a model with stress relaxation (nice python benchmarks/bench_relaxed_stiffness.py "
             f"{n_seeds})", "",
             f"2-minute multilevel pairs at 100 Hz (18 dB), identify(data, effects=('{EFFECT}',)) (forced: no "
             f"structural term); seeds 0..{n_seeds - 1}; 9 positions over the central 80 % of the range; 95 % "
             f"intervals. Truth: clean subject, both stiffnesses K; relaxing subject, short-range K and relaxed "
             f"{RELAXED_FRACTION} K.", "",
             "| subject | quantity | coverage % (pooled) | seeds with all positions covered | median half-width % "
             "of estimate | median abs error % |", "|---|---|---|---|---|---|"]
    for relaxing in (False, True):
        rows = [one_seed(s, relaxing) for s in range(n_seeds)]
        for q in rows[0]:
            est, lo, hi, tr = (np.concatenate([r[q][i] for r in rows]) for i in range(4))
            inside = (lo <= tr) & (tr <= hi)
            full = sum(bool(np.all((r[q][1] <= r[q][3]) & (r[q][3] <= r[q][2]))) for r in rows)
            lines.append(f"| {'relaxing' if relaxing else 'clean'} | {q} | {100 * inside.mean():.1f} | "
                         f"{full}/{n_seeds} | {100 * np.median((hi - lo) / 2 / np.abs(est)):.1f} | "
                         f"{100 * np.median(np.abs(est / tr - 1)):.1f} |")
            print(lines[-1], flush=True)
    lines += ["", f"conditions: CPUs {os.cpu_count()}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
                  f"wall time {(time.time() - t0) / 60:.1f} min"]
    write_results("relaxed_stiffness.txt", lines, echo=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8)
