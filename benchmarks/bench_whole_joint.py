"""Benchmark of the whole-joint model (lpvpc.export.whole_joint): angle in, total torque out.

    python benchmarks/bench_whole_joint.py [--seeds 3]

For each seed s: identify the LPV-PC model on the virtual subject's multilevel record
(seed s, 2 min, 100 Hz), fit the quasi-static curve to its UT trial, then on the novel
trajectory (``simulate_pair("novel", seed=1)``) measure the total-torque VAF of the PT trial
(numpy and the FMI 2.0 FMU, manual master loop, latency L removed), the whole-joint model's
perturbation part (its PT minus its UT prediction) against the measured PT - UT torque, and
the two-input model fed the measured split. Also a sweep of the low-pass cutoff (seed 0).
Prints a table and writes it to ``benchmarks/results/whole_joint.txt``. Units: %, Hz.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.export import whole_joint as W  # noqa: E402
from lpvpc.io import decimate_trial, pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from lpvpc.validation.whole_joint import fmu_replay  # noqa: E402
from _results import write_results  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    novel = simulate_pair("novel", seed=1)
    pt, ut = decimate_trial(novel.pt, 100.0), decimate_trial(novel.ut, 100.0)
    d = pair_trials(novel.pt, novel.ut)
    lines = ["Whole-joint model on the novel trajectory (simulate_pair('novel', seed=1), 2 min at 100 Hz)",
             f"cutoff {W.DEFAULT_CUTOFF} Hz, quasi-static order {W.DEFAULT_ORDER}; VAF in %",
             "",
             f"{'seed':>4} {'total':>7} {'total FMU':>9} {'pert. part':>10} {'two-input':>9} {'gap':>6} "
             f"{'FMU-numpy':>10} {'FMU steps/s':>11}"]
    gaps = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            ident = simulate_pair("multilevel", seed=seed)
            model = identify(pair_trials(ident.pt, ident.ut))
            wj = W.fit_whole_joint(model, ident.ut)
            p_pt, p_ut = wj.predict(pt.position, warn=False), wj.predict(ut.position, warn=False)
            total = vaf(pt.torque, p_pt.total)
            part = vaf(pt.torque - ut.torque, p_pt.total - p_ut.total)
            two = vaf(d.torque, model.predict(d.position, d.scheduling, warn=False).total)
            L = W.latency_samples(wj)
            y, rate = fmu_replay(W.export_whole_joint_fmu(wj, Path(tmp) / f"wj{seed}.fmu", 2), pt.position, L, wj.fs)
            n = len(y) - L
            err = np.max(np.abs(y[:n] - p_pt.total[:n])) / np.max(np.abs(p_pt.total[:n]))
            gaps.append(two - part)
            lines.append(f"{seed:>4} {total:7.2f} {vaf(pt.torque[:n], y[:n]):9.2f} {part:10.2f} {two:9.2f} "
                         f"{two - part:6.2f} {err:10.1e} {rate:11.0f}")
            if seed == 0:
                sweep = []
                for fc in (0.2, 0.3, 0.5, 0.8, 1.0, 2.0, 3.0):
                    w = W.WholeJointModel(model, wj.curve_basis, wj.curve, cutoff=fc)
                    a, b = w.predict(pt.position, warn=False), w.predict(ut.position, warn=False)
                    sweep.append(f"{fc:>10g} {vaf(pt.torque, a.total):7.2f} "
                                 f"{vaf(pt.torque - ut.torque, a.total - b.total):10.2f}")
    lines += ["", f"perturbation-part gap to the two-input model: max {max(gaps):.2f} points over {len(gaps)} seeds",
              f"latency of the step/FMU: {L} samples ({L * 10} ms)", "",
              "cutoff sweep (seed 0):", f"{'cutoff Hz':>10} {'total':>7} {'pert. part':>10}", *sweep, "",
              f"{platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}, "
              f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}"]
    write_results("whole_joint.txt", lines, echo=True)


if __name__ == "__main__":
    main()
