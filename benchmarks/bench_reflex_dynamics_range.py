"""Why the improve ladder falls short on reflex dynamics that change ninefold over the range
(python benchmarks/bench_reflex_dynamics_range.py [--perturbation NAME] [--seeds A,B] [--no-ladder]).

The hidden effect: the reflex low-pass natural frequency wn(theta) = 16 * r**((theta + 0.1) / 0.3)
rad/s (bench_diagnose's entries: r = 1.5 the simulator's effect, r = 3 "3x range").
The catalog's position_dependent_reflex_dynamics is a first-order expansion about the model's
reflex poles (rho-weighted reflex states and their second cascade). Per seed:

1. The form's capacity, noise- and intrinsic-free: the base model's reflex drive z on the
   identification record, passed through the true time-varying low-pass (r = 1.5, 2, 3), fitted
   by the expansion about (a) the base model's poles, (b) the true low-pass at the range's middle
   (16 rad/s), (c) poles refitted jointly with the weights; residual in % of that torque's energy.
2. The oracle: the base model's intrinsic regressor and the true time-varying low-pass of its
   drive (the perfect dynamics form; gain, nonlinearity and delay the model's), fitted on the
   identification record: held-out VAF, against the clean subject's base model.
3. The ladder (lpvpc.diagnosis.improve) with the expansion about the base fit's reflex held (poles and
   nonlinearity), and with both refitted jointly with the expansion's weights
   (lpvpc.models.effects.REFIT_POLES, REFIT_DRIVE): the step's and the final held-out VAF.

Identification on the 2-minute multilevel record (seed s), held out the novel record (s + 1),
100 Hz, SNR 18 dB. Units: VAF %, gaps in percentage points. Writes
benchmarks/results/reflex_dynamics_range_<design>.txt.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

from lpvpc.models import effects as fx  # noqa: E402
from lpvpc.models import equations as eq  # noqa: E402
from lpvpc.io import pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.diagnosis.improve import improve  # noqa: E402
from lpvpc.models.intrinsic import curvature_regressor, intrinsic_regressor  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.physics import _tv_lowpass, reflex_lowpass_coefficients  # noqa: E402
from lpvpc.simulation.simulate import EFFECTS, SubjectParams, simulate_pair  # noqa: E402
from _results import write_results  # noqa: E402

warnings.simplefilter("ignore")

DESIGN = sys.argv[sys.argv.index("--perturbation") + 1] if "--perturbation" in sys.argv else "prbs"
SEEDS = range(*(int(x) for x in sys.argv[sys.argv.index("--seeds") + 1].split(","))) if "--seeds" in sys.argv \
    else range(5)
LADDER = "--no-ladder" not in sys.argv
RATIOS = (1.5, 2.0, 3.0)
P = SubjectParams()


def wn_of(theta, ratio):
    return P.reflex_wn * ratio ** ((np.asarray(theta) + 0.1) / 0.3)


def _strong(s):  # as bench_diagnose's "3x range" entry
    s.reflex_wn = s.params.reflex_wn * 3.0 ** ((s.theta + 0.1) / 0.3)
    return {"ratio": 3.0}


EFFECTS.setdefault("strong_reflex_dynamics", ("reflex low-pass wn 5.3-48 rad/s (benchmark only)", _strong))


def pairs(seed, effects=()):
    return [pair_trials(*(lambda pr: (pr.pt, pr.ut))(simulate_pair(kind, seed=s, effects=effects, perturbation=DESIGN)))
            for kind, s in (("multilevel", seed), ("novel", seed + 1))]


def intrinsic_columns(model, data):
    p = np.asarray(data.position, dtype=float)
    G = model.intrinsic_basis
    Gv = G.evaluate(np.asarray(data.scheduling, dtype=float))
    Psi = intrinsic_regressor(p, Gv, model.lags)
    if model.curvature is not None:
        Psi = np.hstack([Psi, curvature_regressor(p, Gv, G)])
    return Psi


def oracle(model, ident, novel, ratio=3.0):
    """Held-out VAF of refits with a perfect dynamics form: least squares of the torque on the
    intrinsic regressor and the reflex through the true time-varying low-pass: "drive held" of
    the base model's drive z (its nonlinearity as the LTI fit left it), "nonlinearity refitted"
    of each column of the reflex input regressor U_r (Omega free). "LTI" (a check): the
    model's LTI low-pass, Omega free."""
    out = {}
    for form in ("drive held", "nonlinearity refitted", "LTI"):
        cols = []
        for d in (ident, novel):
            p, rho = np.asarray(d.position, dtype=float), np.asarray(d.scheduling, dtype=float)
            wn = wn_of(rho + p, ratio)
            if form == "drive held":
                U = model.reflex_drive(p, rho)[:, None]
            else:
                U = model.reflex_input(p, rho)
            if form == "LTI":
                R = np.column_stack([eq.state_trajectory(model.A, model.B, u) @ np.asarray(model.C, dtype=float)
                                     for u in U.T])
            else:
                R = np.column_stack([_tv_lowpass(u, wn, P.reflex_zeta, d.fs) for u in U.T])
            cols.append(np.column_stack([intrinsic_columns(model, d), R]))
        theta = np.linalg.lstsq(cols[0], np.asarray(ident.torque), rcond=None)[0]
        out[form] = vaf(novel.torque, cols[1] @ theta)
    return out


def capacity(model, ident):
    """{ratio: {centre: residual (% of the torque variance)}} of the expansion fitted to the
    true time-varying low-pass of the model's drive (no noise, no intrinsic part)."""
    p, rho = np.asarray(ident.position, dtype=float), np.asarray(ident.scheduling, dtype=float)
    z = model.reflex_drive(p, rho)
    design = fx.EffectDesign(["position_dependent_reflex_dynamics"], p, rho, ident.fs, model.lags,
                             model.intrinsic_basis, fx.default_signals(rho, ident.fs))
    A_, B_, C_ = np.atleast_2d(model.A), np.asarray(model.B, dtype=float), np.asarray(model.C, dtype=float)
    gain = float(C_ @ np.linalg.solve(np.eye(len(B_)) - A_, B_)) + float(model.D)  # the model's static reflex gain
    m = np.atleast_2d(model.A).shape[0]
    import copy

    import scipy.signal
    num, den = scipy.signal.ss2tf(np.atleast_2d(model.A), np.reshape(model.B, (-1, 1)), np.reshape(model.C, (1, -1)),
                                  np.zeros((1, 1)))
    b, den_model = num[0][1:], den[1:]
    # the true low-pass at the range's middle (16 rad/s), bilinear at the model rate, as z-polynomial
    bm, am = reflex_lowpass_coefficients(P.reflex_wn, P.reflex_zeta, ident.fs)
    den_mid = np.poly(np.r_[np.roots(am), np.zeros(max(m - 2, 0))])[1:] if m >= 2 else None
    trial = copy.copy(model)
    ones = np.ones((len(z), 1))

    def resid(a, target):
        if np.max(np.abs(np.roots(np.r_[1.0, a]))) >= 0.999:
            return np.inf
        A = np.zeros((m, m))
        A[:, 0] = -a
        A[:-1, 1:] = np.eye(m - 1)
        trial.A, trial.B, trial.C = A, b, np.eye(1, m).ravel()
        X_r, _ = design.reflex_columns(trial)
        X = np.column_stack([X_r, eq.state_trajectory(A, b, z) @ trial.C, z, ones])
        r = target - X @ np.linalg.lstsq(X, target, rcond=None)[0]
        return 100.0 * float(r @ r) / float(target @ target)

    out = {}
    for ratio in RATIOS:
        target = gain * _tv_lowpass(z, wn_of(rho + p, ratio), P.reflex_zeta, ident.fs)
        row = {"model poles": resid(den_model, target)}
        if den_mid is not None:
            row["range middle"] = resid(den_mid, target)
        res = scipy.optimize.minimize(lambda a: resid(a, target), den_model, method="Nelder-Mead",
                                      options={"xatol": 1e-6, "fatol": 1e-9, "maxfev": 400})
        row["refitted"] = float(res.fun)
        out[ratio] = row
    return out


def step_rung(ladder):
    return next((r for r in ladder.rungs if r.change.get("effect") == "position_dependent_reflex_dynamics"), None)


def main():
    lines = [__doc__.split("\n\n")[0].strip(), "", f"Design {DESIGN}, seeds {SEEDS.start}-{SEEDS.stop - 1}.", ""]

    def say(t=""):
        print(t, flush=True)
        lines.append(t)

    say("Capacity: the expansion fitted to the true time-varying low-pass of the base model's drive (no noise, "
        "no intrinsic part, the drive held): unexplained part, % of that reflex torque's energy, expanded about")
    say("")
    say("| seed | r | the base model's poles | the range's middle (16 rad/s) | poles refitted |")
    say("|---|---|---|---|---|")
    rows2, rows3 = [], []
    for seed in SEEDS:
        t0 = time.perf_counter()
        ident, novel = pairs(seed, ("strong_reflex_dynamics",))
        ci, cn = pairs(seed)
        clean = vaf(cn.torque, identify(ci).predict(cn.position, cn.scheduling, warn=False).total)
        base = identify(ident)
        for ratio, row in capacity(base, ident).items():
            say(f"| {seed} | {ratio:g} | {row['model poles']:.3f} | {row.get('range middle', float('nan')):.3f} | "
                f"{row['refitted']:.3f} |")
        o = oracle(base, ident, novel)
        rows2.append(f"| {seed} | {clean:.2f} | {vaf(novel.torque, base.predict(novel.position, novel.scheduling, warn=False).total):.2f} "
                     f"| {o['LTI']:.2f} | {o['drive held']:.2f} | {o['nonlinearity refitted']:.2f} | "
                     f"{clean - o['nonlinearity refitted']:+.2f} |")
        if LADDER:
            cells = []
            for refit in (False, True):
                fx.REFIT_POLES = fx.REFIT_DRIVE = refit
                lad = improve(ident, novel)
                st = step_rung(lad)
                cells += [f"{st.heldout_vaf:.2f}" if st else "-", f"{st.fit_vaf:.2f}" if st else "-",
                          f"{lad.final.heldout_vaf:.2f}", f"{clean - lad.final.heldout_vaf:+.2f}",
                          " -> ".join(r.label + ("" if r.kept else " (not kept)") for r in lad.rungs[1:]) or "none"]
            fx.REFIT_POLES = fx.REFIT_DRIVE = True
            rows3.append(f"| {seed} | {clean:.2f} | " + " | ".join(cells) + " |")
        print(f"seed {seed}: {time.perf_counter() - t0:.0f} s", flush=True)
    say("")
    say("Oracle (3x): held-out VAF of a refit with the perfect dynamics form (the true time-varying low-pass "
        "of the base model's drive) and, as a check, with the model's LTI form refitted the same way")
    say("")
    say("| seed | clean base | 3x base (identify) | LTI, Omega refitted | true dynamics, drive held | "
        "true dynamics, Omega refitted | gap of the oracle (pp) |")
    say("|---|---|---|---|---|---|---|")
    for r in rows2:
        say(r)
    if LADDER:
        say("")
        say("Ladder (3x), the base fit's reflex held | its poles and nonlinearity refitted jointly with the weights: "
            "the dynamics step's held-out and identification VAF, the final held-out VAF, its gap to clean, the steps")
        say("")
        say("| seed | clean | step held out | step fit | final | gap | steps | step held out (refit) | step fit "
            "(refit) | final (refit) | gap (refit) | steps (refit) |")
        say("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows3:
            say(r)
    write_results(f"reflex_dynamics_range_{DESIGN}.txt", lines)


if __name__ == "__main__":
    main()
