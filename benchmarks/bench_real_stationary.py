"""Real data: the lab's five stationary trials (one operating position each).

Data: ``experimental_data.mat`` of the lab's public recordings (MATLAB ``nldat`` objects
``z_df``, ``z_pf``, ``z_df2``, ``z_df3``, ``z_pf2``; channels ``pos1``, ``tq1``; 1 kHz;
read by the package's .mat reader, which uses the ``mat-io`` package). A stationary trial
has no UT trial; two constructions of the perturbation data are run:

- "means removed": the package's stationary reading (``lpvpc.data.stationary_perturbation``,
  ``--stationary``): position and torque minus their means, scheduling = the mean position;
- "0.3 Hz trend removed": the slow part of position and torque (zero-phase 2nd-order
  Butterworth below 0.3 Hz) plays the UT trial's role and is subtracted from both.

Torque is negated (as on the pilot trial: with the file's sign K comes out negative).
Decimated to 100 Hz by the package's decimator; identified with default settings on the
first 70 %; the whole record is predicted and its last 30 % scored. Side by side from one
run: the package (which detects the stationary trial and identifies the LTI parallel
cascade, saying so with a StationaryWarning) and the crude flexible least-squares fit
(``flexible_fit.py``). Writes benchmarks/results/real_stationary.txt.

Run: python benchmarks/bench_real_stationary.py   (skips when the recordings or mat-io are absent)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.signal

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from flexible_fit import FlexibleFit  # noqa: E402
from real_data import require  # noqa: E402

from lpvpc.data import PerturbationData, Trial, decimate_trial, load_trial, stationary_perturbation  # noqa: E402
from lpvpc.errors import StationaryWarning  # noqa: E402
from lpvpc.identify import identify  # noqa: E402
from lpvpc.model import vaf  # noqa: E402
from _results import write_results  # noqa: E402

NAMES = ("z_df", "z_pf", "z_df2", "z_df3", "z_pf2")
TREND_HZ = 0.3


def load(path):
    """The trials through the package's own .mat reader (lpvpc.data.load_trial: nldat objects
    via mat-io), torque negated."""
    try:
        import matio  # noqa: F401
    except ImportError:
        print("skipped: the mat-io package is not installed (pip install mat-io)")
        sys.exit(0)
    return {name: load_trial(path, variable=name, channels={"position": "pos1", "torque": "tq1"}, torque_sign=-1)
            for name in NAMES}


def perturbation(trial, construction):
    if construction == "means removed":  # the package's stationary reading (lpvpc.data.stationary_perturbation)
        return stationary_perturbation(trial, target_fs=100.0)
    pos, tq = trial.position, trial.torque
    b, a = scipy.signal.butter(2, TREND_HZ, fs=trial.fs)
    p, y = pos - scipy.signal.filtfilt(b, a, pos), tq - scipy.signal.filtfilt(b, a, tq)
    low = decimate_trial(Trial(trial.time, p, y, {"scheduling": np.full_like(pos, pos.mean())}, name=trial.name), 100.0)
    return PerturbationData(low.position, low.torque, low.channels["scheduling"], 100.0, source=trial.name)


def main():
    trials = load(require("experimental_data.mat"))
    lines = ["# Real data: five stationary trials (experimental_data.mat), identify on the first 70 %, predict the last 30 %",
             "# default settings; torque negated; 1 kHz decimated to 100 Hz",
             f"{'construction':22} {'trial':6} {'op. rad':>8} {'lpvpc':>7} {'causal':>7} {'flexible':>9} {'diff':>6} "
             f"{'K N m/rad':>10} {'lpvpc s':>8} {'flex s':>7}  note"]
    for construction in ("means removed", f"{TREND_HZ:g} Hz trend removed"):
        diffs = []
        for name in NAMES:
            d = perturbation(trials[name], construction)
            pos = trials[name].position
            k = int(0.7 * d.n)
            t0 = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                m = identify(d.segment(0, k))
                two = m.predict(d.position, d.scheduling, warn=False).total[k:]
                cau = m.predict(d.position, d.scheduling, causal=True, warn=False).total[k:]
            t_pkg = time.perf_counter() - t0
            t0 = time.perf_counter()
            fl = FlexibleFit(d.fs).fit(d.position[:k], d.torque[:k], d.scheduling[:k])
            pf = fl.predict(d.position, d.scheduling)[k:]
            t_fl = time.perf_counter() - t0
            held = d.torque[k:]
            v_pkg, v_fl = vaf(held, two), vaf(held, pf)
            diffs.append(v_pkg - v_fl)
            note = "LTI (StationaryWarning)" if any(issubclass(w.category, StationaryWarning) for w in caught) else ""
            lines.append(f"{construction:22} {name:6} {pos.mean():+8.3f} {v_pkg:7.2f} {vaf(held, cau):7.2f} {v_fl:9.2f} "
                         f"{v_pkg - v_fl:+6.2f} {m.elastic_stiffness([pos.mean()])[0]:10.1f} {t_pkg:8.2f} {t_fl:7.2f}  {note}")
        lines.append(f"{construction:22} lpvpc - flexible: median {np.median(diffs):+.2f}, worst {min(diffs):+.2f} points; "
                     f"lpvpc at least as good on {sum(x >= 0 for x in diffs)} of {len(diffs)}")
    write_results("real_stationary.txt", lines, echo=True)


if __name__ == "__main__":
    main()
