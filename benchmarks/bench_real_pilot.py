"""Real data: the lab's pilot LPV trial, identified on its first 70 %, predicting its last 30 %.

Data: ``pilot_ident.csv`` of the lab's public recordings (1 kHz, perturbation position and
torque already PT - UT, scheduling = ankle position; torque negated: with the file's sign
the elastic stiffness comes out negative). Decimated to 100 Hz by the package's loader,
split at 70 % (development split: nothing else of that trial is used).

Printed side by side from one run: the package at default settings (two-sided and causal
form, 5-point derivatives), with the causal form on 3-point derivatives (the previous
default), at its previous default IRF length
(lags -3..3), a position-independent (LTI) parallel cascade, and a crude flexible
least-squares fit (``flexible_fit.py``). Writes benchmarks/results/real_pilot.txt.

Run: python benchmarks/bench_real_pilot.py   (skips when the recordings are absent)
"""

from __future__ import annotations

import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from flexible_fit import FlexibleFit  # noqa: E402
from real_data import require  # noqa: E402

from lpvpc.data import load_identification_data  # noqa: E402
from lpvpc.identify import identify  # noqa: E402
from lpvpc.model import vaf  # noqa: E402
from _results import write_results  # noqa: E402


def main():
    path = require("pilot_ident.csv")
    d = load_identification_data(data=path, torque_sign=-1)
    k = int(0.7 * d.n)
    ident, held = d.segment(0, k), d.segment(k, None)
    rows = []
    variants = [
        ("lpvpc, default settings", {}),
        ("lpvpc, causal form on 3-point derivatives", {"causal_derivatives": "central3"}),
        ("lpvpc, previous defaults (IRF lags -3..3)", {"irf_lags": 3}),
        ("lpvpc, position-independent (LTI, orders 0)", {"intrinsic_order": 0, "reflex_order": 0}),
    ]
    for name, settings in variants:
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = identify(ident, **settings)
            # the whole record is predicted and its last 30 % scored: the held-out part starts
            # from the trial's own past, not from rest
            two = m.predict(d.position, d.scheduling).total[k:]
            cau = m.predict(d.position, d.scheduling, causal=True).total[k:]
        el = time.perf_counter() - t
        rows.append((name, m.fit["vaf"], vaf(held.torque, two), vaf(held.torque, cau), len(m.H.ravel()) + m.Omega.size, el))
        if not settings:
            default = m
    t = time.perf_counter()
    fl = FlexibleFit(d.fs).fit(ident.position, ident.torque, ident.scheduling)
    pf = fl.predict(d.position, d.scheduling)[k:]
    el = time.perf_counter() - t
    rows.append(("flexible least squares (LPV FIR, 0.31 s reflex memory)",
                 vaf(ident.torque, fl.predict(ident.position, ident.scheduling)), vaf(held.torque, pf), float("nan"),
                 fl.n_params, el))

    lines = [
        "# Real data: pilot LPV trial (lab's public recording), identify on the first 70 %, predict the last 30 %",
        f"# {path.name}: {d.n} samples at {d.fs:g} Hz (decimated from 1 kHz), torque negated; split at sample {k}",
        f"# machine: {platform.machine()}, python {platform.python_version()}",
        f"{'model':58} {'fit VAF':>8} {'held-out':>9} {'causal':>8} {'params':>7} {'time s':>7}",
    ]
    for name, fit, h, c, npar, el in rows:
        cs = f"{c:8.2f}" if np.isfinite(c) else f"{'-':>8}"
        lines.append(f"{name:58} {fit:8.2f} {h:9.2f} {cs} {npar:7d} {el:7.2f}")
    rho = np.linspace(*default.scheduling_range, 5)
    lines.append("default model: K(theta) " + ", ".join(f"{x:.1f}" for x in default.elastic_stiffness(rho))
                 + " N m/rad at " + ", ".join(f"{r:+.2f}" for r in rho) + " rad")
    best = rows[0]
    lines.append(f"causal form loses {best[2] - best[3]:.2f} points (3-point derivatives: {rows[1][2] - rows[1][3]:.2f}; "
                 f"floor 1.5); flexible fit - package: "
                 f"{rows[-1][2] - best[2]:+.2f} points")
    write_results("real_pilot.txt", lines, echo=True)


if __name__ == "__main__":
    main()
