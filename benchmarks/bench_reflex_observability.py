"""How much of the reflex rectifier a model sampled at fs can see at all.

The virtual subject's reflex rectifies the delayed 1 kHz joint velocity: G(theta) *
max(v(t - d) - th(theta), 0). PRALDS steps through the 25 Hz servo give velocity pulses
~20 ms wide, so a model identified on data decimated to 100 Hz sees them smoothed (the
central difference of anti-aliased positions) and a rectifier of THAT velocity cannot
reproduce the 1 kHz one with the simulator's gain and threshold.

For each seed this benchmark takes the noise-free truth (the identification trial's
trajectory and PRALDS, the true rectifier output of the PT minus the UT trial, no
identification and no noise) and fits, per position bin, the rectifier g * max(v - t, 0) + c
that best maps the delayed central-difference perturbation velocity at rate fs to the
true rectifier output decimated to fs. The slopes over position of the fitted g and t,
divided by the simulator's, are what an ideal identification at that rate could reach:
the observability bound of the issue's "gain and threshold trend within 20 %" target.
The identified model (default settings, 100 Hz) is then compared with both.

Run: python benchmarks/bench_reflex_observability.py [n_seeds]
     (writes benchmarks/results/reflex_observability.txt)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.models import equations as eq  # noqa: E402
from lpvpc.simulation import simulate as sim  # noqa: E402
from lpvpc.io import decimate_signal, pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from _results import write_results  # noqa: E402

RATES = (1000, 500, 200, 100)
EDGES = np.linspace(-0.4, 0.2, 7)  # position bins (rad) over the identified range
THRESHOLDS = np.linspace(0.0, 1.5, 301)  # rad/s, grid of the per-bin rectifier fit


def true_drives(seed, duration=120.0):
    """1 kHz rectifier output of PT minus UT, PT - UT position and UT position, for the
    identification trial of ``seed`` (the same random streams as simulate_pair)."""
    p = sim.SubjectParams()
    fs = sim.FS_SIM
    ss = np.random.SeedSequence([int(seed), 0])
    r_traj, r_pert = (np.random.default_rng(s) for s in ss.spawn(6)[:2])
    traj = sim.multilevel_trajectory(duration, fs, r_traj)
    pert = sim.pralds(duration, fs, r_pert)
    out = {}
    for key, cmd in (("UT", traj), ("PT", traj + pert)):
        theta, vel, _ = sim.servo(cmd, fs, p)
        _, z = sim.reflex_torque(theta, vel, fs, p)
        out[key] = (theta, z)
    return out["PT"][1] - out["UT"][1], out["PT"][0] - out["UT"][0], out["UT"][0], p


def rectifier_fit(v, z):
    """(gain, threshold) of the least-squares g * max(v - t, 0) + c, t on a grid."""
    best = None
    for t in THRESHOLDS:
        X = np.column_stack([np.maximum(v - t, 0.0), np.ones_like(v)])
        coef = np.linalg.lstsq(X, z, rcond=None)[0]
        sse = float(np.sum((X @ coef - z) ** 2))
        if best is None or sse < best[0]:
            best = (sse, coef[0], t)
    return best[1], best[2]


def slope(x, y):
    return np.polyfit(x, y, 1)[0]


def bound_at_rate(z, pos, rho, p, rate):
    """Per-bin rectifier fits at ``rate``; returns (bin centres, gains, thresholds)."""
    q = int(round(sim.FS_SIM / rate))
    dec = (lambda x: x) if q == 1 else (lambda x: decimate_signal(x, q))
    zd, pd, rd = dec(z), dec(pos), dec(rho)
    d = int(round(p.reflex_delay * rate))
    v = eq.delayed_velocity(pd, rate, d)
    centres, gains, thresholds = [], [], []
    for lo, hi in zip(EDGES[:-1], EDGES[1:]):
        m = (rd >= lo) & (rd < hi)
        g, t = rectifier_fit(v[m], zd[m])
        centres.append(0.5 * (lo + hi))
        gains.append(g)
        thresholds.append(t)
    return np.array(centres), np.array(gains), np.array(thresholds)


def one_seed(seed):
    z, pos, rho, p = true_drives(seed)
    row = {"seed": seed}
    for rate in RATES:
        c, g, t = bound_at_rate(z, pos, rho, p, rate)
        row[rate] = (slope(c, g) / slope(c, p.reflex_gain(c)), slope(c, t) / slope(c, p.reflex_threshold(c)))
        if rate == 100:
            c100, g100, t100 = c, g, t
    pair = sim.simulate_pair("multilevel", seed=seed, fs_out=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(pair_trials(pair.pt, pair.ut))
    gi, ti = model.reflex_gain_threshold(c100)
    row["identified_vs_simulator"] = (slope(c100, gi) / slope(c100, p.reflex_gain(c100)),
                                      slope(c100, ti) / slope(c100, p.reflex_threshold(c100)))
    row["identified_vs_bound100"] = (slope(c100, gi) / slope(c100, g100), slope(c100, ti) / slope(c100, t100))
    return row


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    t0 = time.time()
    rows = [one_seed(s) for s in range(n)]
    lines = ["# Reflex rectifier observability (python benchmarks/bench_reflex_observability.py)", "",
             "Slope over position of the rectifier gain / threshold, as a ratio to the simulator's (1 = exact).",
             "Columns 'ideal at R Hz': the best rectifier of the delayed central-difference velocity at R Hz fitted",
             "to the noise-free true rectifier output (no identification, no noise): what any identification at",
             "that rate can reach. 'identified': lpvpc at default settings (100 Hz) from the noisy trials.", ""]
    head = "| seed | " + " | ".join(f"ideal at {r} Hz: gain, threshold" for r in RATES) + \
        " | identified vs simulator | identified vs ideal at 100 Hz |"
    lines += [head, "|" + "---|" * (len(RATES) + 3)]
    for r in rows:
        cells = [f"{r[rate][0]:.2f}, {r[rate][1]:.2f}" for rate in RATES]
        iv, ib = r["identified_vs_simulator"], r["identified_vs_bound100"]
        lines.append(f"| {r['seed']} | " + " | ".join(cells) + f" | {iv[0]:.2f}, {iv[1]:.2f} | {ib[0]:.2f}, {ib[1]:.2f} |")
    med = lambda key, i: np.median([r[key][i] for r in rows])  # noqa: E731
    lines += ["", "medians: " + "; ".join(f"ideal at {rate} Hz gain {med(rate, 0):.2f}, threshold {med(rate, 1):.2f}"
                                          for rate in RATES),
              f"identified vs simulator: gain {med('identified_vs_simulator', 0):.2f}, threshold "
              f"{med('identified_vs_simulator', 1):.2f}; identified vs ideal at 100 Hz: gain "
              f"{med('identified_vs_bound100', 0):.2f}, threshold {med('identified_vs_bound100', 1):.2f}",
              f"total time {time.time() - t0:.0f} s"]
    write_results("reflex_observability.txt", lines, echo=True)


if __name__ == "__main__":
    main()
