"""Closed loop (issue 24): the closed-loop FMU against the virtual subject in a compliant
exoskeleton loop, the replay FMU beside it, and what the causal form costs offline.

1. Virtual subject, seeds 0..4: identified from its 2-minute PT/UT trials at 100 Hz (defaults),
   whole-joint model, closed-loop form (fitted to the two-sided model's torque: the CLI's
   default), FMI 2.0 co-simulation FMUs of both. In the loop of lpvpc.simulation.compliant_loop (foot +
   device 0.01 kg m^2, PD Kp 40 or 150 N m/rad, Kd 0.5 N m s/rad, 60 s of the multilevel
   reference with +-0.02 rad steps every 100-400 ms, plant at 1 kHz) run by a fixed-step master
   over fmpy's FMU2Slave: the closed-loop FMU at communication steps of 1 ms and 10 ms (the model
   period), the replay (two-sided, latency 40 ms, inertia inside) FMU at 10 ms, and the virtual
   subject itself (its physics stepped at 1 ms with the torque fed back). VAF (%) of the angle
   deviation (angle - reference) and of the torque against the subject's run, whole and above
   0.5 Hz (both high-passed, zero-phase 2nd-order Butterworth), after 1 s.
   The Model Exchange FMU replaying the 1-ms loop's angle and velocity through fmpy.simulate_fmu
   (fmpy's own master; closing the loop there needs a plant FMU, not built): its torque against
   the co-simulation loop's.
2. Offline, the novel trajectory (simulate_pair('novel', seed + 100), 60 s): total torque VAF of
   the causal form (plus its declared inertia x acceleration, as recorded) and of the two-sided
   whole-joint model.
3. The lab's pilot trial (../shared/real/pilot_ident.csv, torque negated; skipped when absent):
   identified on its first 70 %, held-out last 30 %: the two-sided model, the model's causal IRF
   form (lags 0..Lc + 5-point derivatives) and the closed-loop form's impedance (K, B, curvature
   of p, p', p^2 and the inertia) with the reflex held, fitted to the measured torque and to the
   two-sided model's torque. The pilot has no UT torque and no whole-joint record: this is at the
   level of the perturbation data (p, rho = the recorded scheduling). Each form twice: as recorded
   and with the position delayed by the channel skew that lpvpc.export.closed_loop.estimate_channel_skew
   finds on the identified part (the torque channel's lag); past-sample memory with the inertia
   fitted and held; then leave-one-level-out over the development split (all folds, and without
   the two end plateaus).
4. The virtual subject's 1 kHz PT/UT trials with the torque written 1 ms late: the skew estimated
   (and on the unskewed trials), the closed-loop form fitted as recorded and with the delay undone
   (fit_closed_loop(position_delay=)), offline on the novel trajectory and in the loop (1 ms step).

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_closed_loop.py [--seeds 5] [--duration 60]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _results import write_results  # noqa: E402
from real_data import real_data_dir  # noqa: E402

from lpvpc.export import closed_loop as CL  # noqa: E402
from lpvpc.simulation import compliant_loop as LOOP  # noqa: E402
from lpvpc.models import equations as eq  # noqa: E402
from lpvpc.io import decimate_trial, join_trials, load_identification_data, pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.identification.selection import level_folds  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from lpvpc.export.whole_joint import export_whole_joint_fmu, fit_whole_joint  # noqa: E402

KPS = (40.0, 150.0)


def me_replay(path, run: LOOP.LoopRun) -> np.ndarray:
    """The Model Exchange FMU's torque along a loop run's angle and velocity (fmpy.simulate_fmu)."""
    import fmpy

    n = len(run.time)
    sig = np.array(list(zip(run.time, run.angle, run.velocity)),
                   dtype=[("time", float), ("angle", float), ("angular_velocity", float)])
    res = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", input=sig, stop_time=run.time[-1],
                            output_interval=LOOP.PLANT_STEP, output=["torque"])
    last = np.r_[res["time"][1:] != res["time"][:-1], True]
    return np.asarray(res["torque"][last])[:n]


SKEW = 1e-3  # s: the torque channel written this late in the skewed copy of the subject's trials


def late_torque(trial, delay=SKEW):
    """The trial as a recording whose torque channel lags its position by ``delay`` s (whole samples)."""
    from lpvpc.io.trial import Trial

    n = int(round(delay * trial.fs))
    return Trial(trial.time, trial.position, np.r_[np.full(n, trial.torque[0]), trial.torque[:-n]],
                 dict(trial.channels), trial.name)


def skewed_recording(seed, ref, folder, truths):
    """The subject's trials with the torque 1 ms late: the closed-loop form fitted as recorded and
    with the estimated delay undone, offline on the (unskewed) novel trajectory and in the loop."""
    sim = simulate_pair("multilevel", seed=seed, duration=120.0)  # at 1 kHz, where the skew is a whole sample
    pt, ut = late_torque(sim.pt), late_torque(sim.ut)
    data = pair_trials(pt, ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(data)
        skew = CL.estimate_channel_skew(data)
        none = CL.estimate_channel_skew(pair_trials(sim.pt, sim.ut))
    wj = fit_whole_joint(model, ut)
    novel = decimate_trial(simulate_pair("novel", seed=seed + 100, duration=60.0).pt, model.fs)
    row = {"seed": seed, "skew": skew.delay, "none": none.delay}
    for name, delay in (("recorded", 0.0), ("aligned", skew.delay)):
        cl = CL.fit_closed_loop(wj, [CL.distillation_trial(wj, ut)], position_delay=delay)
        row[name] = {"novel": vaf(novel.torque, cl.predict(novel.position).measured), "inertia": cl.inertia}
        src = LOOP.FmuSource(CL.export_closed_loop_fmu(cl, folder / f"skew_{name}{seed}.fmu"))
        try:
            for kp in KPS:
                run = LOOP.run_loop(src, ref, LOOP.LoopSetup(kp=kp), 1e-3)
                row[name][kp] = (run, LOOP.loop_vaf(truths[kp], run))
        finally:
            src.close()
    return row


def virtual(seeds, duration, folder):
    loop_rows, offline_rows, me_err, skew_rows = [], [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        sim = simulate_pair("multilevel", seed=seed, duration=120.0, fs_out=100.0)
        model = identify(pair_trials(sim.pt, sim.ut))
        wj = fit_whole_joint(model, sim.ut)
        cl = CL.fit_closed_loop(wj, [CL.distillation_trial(wj, sim.ut)])
        cl_pt = CL.fit_closed_loop(wj, [sim.pt, sim.ut])
        novel = decimate_trial(simulate_pair("novel", seed=seed + 100, duration=60.0).pt, model.fs)
        offline_rows.append((seed, vaf(novel.torque, cl.predict(novel.position).measured),
                             vaf(novel.torque, cl_pt.predict(novel.position).measured),
                             vaf(novel.torque, wj.predict(novel.position, warn=False).total), cl.inertia))
        fmu = CL.export_closed_loop_fmu(cl, folder / f"cl{seed}.fmu")
        me = CL.export_closed_loop_fmu(cl, folder / f"cl_me{seed}.fmu", fmi_type="me")
        replay_fmu = export_whole_joint_fmu(wj, folder / f"replay{seed}.fmu")
        ref = LOOP.reference_trajectory(duration, seed)
        src, rep = LOOP.FmuSource(fmu), LOOP.FmuSource(replay_fmu)
        truths = {}
        try:
            for kp in KPS:
                setup = LOOP.LoopSetup(kp=kp)
                truth = truths[kp] = LOOP.run_loop(LOOP.VirtualSubject(), ref, setup)
                r1 = LOOP.run_loop(src, ref, setup, 1e-3)
                r10 = LOOP.run_loop(src, ref, setup, 1.0 / cl.fs)
                rr = LOOP.run_loop(rep, ref, setup, 1.0 / cl.fs)
                if kp == KPS[0] and r1.stable:
                    y = me_replay(me, r1)
                    me_err.append(float(np.max(np.abs(y - r1.torque)) / np.std(r1.torque)))
                loop_rows.append((seed, kp, truth.stable, r1, LOOP.loop_vaf(truth, r1), r10, LOOP.loop_vaf(truth, r10),
                                  rr, float(np.nanstd(truth.torque))))
        finally:
            src.close()
            rep.close()
        skew_rows.append(skewed_recording(seed, ref, folder, truths))
        print(f"seed {seed}: {time.perf_counter() - t0:.1f} s", flush=True)
    return loop_rows, offline_rows, me_err, skew_rows


def _skew_lines(skew_rows) -> list:
    lines = ["", f"Virtual subject recorded with the torque channel {SKEW * 1e3:g} ms late (PT and UT files), "
             "closed-loop form fitted to the two-sided model's torque (the CLI default):",
             "seed  estimated skew ms (none imposed)  novel VAF % as recorded / aligned  inertia as recorded / aligned  "
             "loop 1 ms step, dev / tq VAF %: Kp 40 as recorded / aligned; Kp 150 as recorded / aligned"]
    for r in skew_rows:
        def cell(name, kp):
            run, v = r[name][kp]
            return "DIVERGED" if not run.stable else f"{v['deviation']:.2f}/{v['torque']:.2f}"
        lines.append(f"{r['seed']:4d}  {r['skew'] * 1e3:5.2f} ({r['none'] * 1e3:5.2f})"
                     f"{'':20s}{r['recorded']['novel']:6.2f} / {r['aligned']['novel']:6.2f}"
                     f"{'':19s}{r['recorded']['inertia']:.4f} / {r['aligned']['inertia']:.4f}"
                     f"{'':16s}{cell('recorded', KPS[0])} / {cell('aligned', KPS[0])}; "
                     f"{cell('recorded', KPS[1])} / {cell('aligned', KPS[1])}")
    return lines


def _pilot_forms(m, ident, d, k):
    """Held-out VAFs (last 30 %) of the forms identified on the first 70 % with model m."""
    two = m.predict(d).total
    cau = m.predict(d, causal=True).total[k:]
    held = d.torque[k:]
    W, inertia = CL.fit_perturbation_impedance(m, ident.position, ident.scheduling, ident.torque)
    Wd, inertia_d = CL.fit_perturbation_impedance(m, ident.position, ident.scheduling, two[:k])
    imp = CL.predict_perturbation_impedance(m, W, inertia, d.position, d.scheduling)[k:]
    imp_d = CL.predict_perturbation_impedance(m, Wd, inertia_d, d.position, d.scheduling)[k:]
    Wm, inertia_m = CL.fit_perturbation_impedance(m, ident.position, ident.scheduling, ident.torque, memory=2)
    imp_m = CL.predict_perturbation_impedance(m, Wm, inertia_m, d.position, d.scheduling)[k:]
    Wf, _ = CL.fit_perturbation_impedance(m, ident.position, ident.scheduling, ident.torque, memory=2, inertia=inertia)
    imp_f = CL.predict_perturbation_impedance(m, Wf, inertia, d.position, d.scheduling)[k:]
    probes = _pilot_probes(m, d, k)
    G0 = m.intrinsic_basis.evaluate(np.array([0.0]))
    grid = np.linspace(*np.percentile(ident.scheduling, [0.5, 99.5]), 41)
    Gg = m.intrinsic_basis.evaluate(grid)
    return {"two": vaf(held, two[k:]), "causal_irf": vaf(held, cau), "impedance": vaf(held, imp),
            "impedance_distilled": vaf(held, imp_d), "inertia": inertia, "inertia_d": inertia_d,
            "memory": vaf(held, imp_m), "inertia_m": inertia_m, "K_m": float((G0 @ Wm[0])[0]),
            "memory_fixed": vaf(held, imp_f), "K_f": float((G0 @ Wf[0])[0]),
            "K_min": float(np.min(Gg @ W[0])), "K_max": float(np.max(Gg @ W[0])), "B_min": float(np.min(Gg @ W[1])),
            "B_max": float(np.max(Gg @ W[1])), "probes": probes}


PROBES = ("velocity: 3-point central differences", "velocity: backward differences (causal)",
          "+ p omega", "+ omega |omega|", "+ p^3", "+ |omega|", "- curvature p^2")


def _pilot_probes(m, d, k):
    """Held-out VAF (%) of the impedance (fitted to the measured torque) with another velocity
    stencil or one feature added or removed: what a different form would gain (probes, not used)."""
    p, rho = d.position, d.scheduling
    Gi = m.intrinsic_basis.evaluate(rho)
    reflex = m.predict(p, rho, warn=False).reflex
    v5, a5 = eq.derivatives(p, m.fs, CL.STENCIL)
    v3, a3 = eq.derivatives(p, m.fs, "central3")
    vb = np.r_[0.0, np.diff(p)] * m.fs
    ab = np.r_[0.0, np.diff(vb)] * m.fs
    cases = [(v3, a3, [p * p]), (vb, ab, [p * p]), (v5, a5, [p * p, p * v5]), (v5, a5, [p * p, v5 * np.abs(v5)]),
             (v5, a5, [p * p, p ** 3]), (v5, a5, [p * p, np.abs(v5)]), (v5, a5, [])]
    out = []
    for vel, acc, extra in cases:
        F = np.column_stack([p, vel, *extra])
        X = np.column_stack([(F[:, :, None] * Gi[:, None, :]).reshape(len(p), -1), acc])
        theta = np.linalg.lstsq(X[:k], d.torque[:k] - reflex[:k], rcond=None)[0]
        out.append(vaf(d.torque[k:], X[k:] @ theta + reflex[k:]))
    return out


def _pilot_lolo(d):
    """Leave-one-level-out over the development split (lpvpc.identification.selection.level_folds): pooled VAF
    (%) of the two-sided model, its causal IRF form and the closed-loop impedance on the left-out
    levels, all and without the two end plateaus (extrapolation there dominates the pooled figure)."""
    labels, kind = level_folds(d.scheduling, d.fs)
    K = labels.max() + 1
    med = np.array([np.median(d.scheduling[labels == f]) for f in range(K)])
    ends = {int(np.argmin(med)), int(np.argmax(med))}
    names = ("two", "causal_irf", "impedance")
    sse = {(n, inner): 0.0 for n in names for inner in (False, True)}
    ss = {False: 0.0, True: 0.0}
    for f in range(K):
        keep = np.r_[False, labels != f, False]
        e = np.flatnonzero(np.diff(keep.astype(int)))
        pieces = [d.segment(a, b) for a, b in zip(e[::2], e[1::2]) if b - a >= 100]
        m = identify(join_trials(pieces))
        rows, ys = [], []
        for q in pieces:
            vel, acc = eq.derivatives(q.position, m.fs, CL.STENCIL)
            rows.append(CL._impedance_rows(m, q.position, q.scheduling, vel, acc, 0))
            ys.append(q.torque - m.predict(q.position, q.scheduling, warn=False).reflex)
        W, inertia, _ = CL._solve(rows, ys, m, 0)
        test = labels == f
        preds = {"two": m.predict(d).total, "causal_irf": m.predict(d, causal=True).total,
                 "impedance": CL.predict_perturbation_impedance(m, W, inertia, d.position, d.scheduling)}
        for inner in (False, True):
            if inner and f in ends:
                continue
            for n in names:
                r = d.torque[test] - preds[n][test]
                sse[(n, inner)] += r @ r
            ss[inner] += np.sum((d.torque[test] - d.torque.mean()) ** 2)
    return {key: 100 * (1 - v / ss[key[1]]) for key, v in sse.items()}, K, kind


def pilot():
    folder = real_data_dir()
    if folder is None or not (folder / "pilot_ident.csv").is_file():
        return None
    d = load_identification_data(data=folder / "pilot_ident.csv", torque_sign=-1)
    k = int(0.7 * d.n)
    out = {"n_held": d.n - k}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        skew = CL.estimate_channel_skew(d.segment(0, k))  # from the identification part only
        out["skew"] = skew
        for name, data in (("raw", d), ("aligned", CL.delay_position(d, skew.delay))):
            ident = data.segment(0, k)
            out[name] = _pilot_forms(identify(ident), ident, data, k)
            out[name]["lolo"], out["folds"], out["fold_kind"] = _pilot_lolo(data)
    return out


def _pilot_lines(p) -> list:
    skew = p["skew"]
    lines = ["Lab pilot trial (development split: first 70 % identified, last 30 % held out; torque negated), "
             "perturbation level:",
             f"  channel skew: torque {skew.delay * 1e3:.2f} ms behind position (estimated on the identification part: "
             "two-sided in-sample VAF " + ", ".join(f"{c * 1e3:+.1f} ms {v:.2f}" for c, v in zip(skew.candidates, skew.scores))
             + ")", "",
             f"{'held-out VAF (%)':55s} {'as recorded':>12s} {'aligned':>10s}"]
    rows = [("two-sided LPV-PC model", "two"), ("its causal IRF form (lags 0..Lc + 5-point derivatives)", "causal_irf"),
            ("closed-loop impedance, fitted to the measured torque", "impedance"),
            ("closed-loop impedance, fitted to the two-sided model", "impedance_distilled"),
            ("+ 2 past samples of p, inertia fitted (not used)", "memory"),
            ("+ 2 past samples of p, inertia held (not used)", "memory_fixed")]
    r, a = p["raw"], p["aligned"]
    for label, key in rows:
        lines.append(f"  {label:53s} {r[key]:12.2f} {a[key]:10.2f}")
    lines += [f"  {'inertia (kg m^2), measured-torque fit':53s} {r['inertia']:12.4f} {a['inertia']:10.4f}",
              f"  {'K(rho) over the identified range (N m/rad)':53s} {r['K_min']:5.1f}..{r['K_max']:5.1f} "
              f"{a['K_min']:4.1f}..{a['K_max']:4.1f}",
              f"  {'B(rho) over the identified range (N m s/rad)':53s} {r['B_min']:5.2f}..{r['B_max']:5.2f} "
              f"{a['B_min']:4.2f}..{a['B_max']:4.2f}",
              f"  {'memory, inertia fitted: inertia / K(0)':53s} {r['inertia_m']:.4f} / {r['K_m']:.0f}    "
              f"{a['inertia_m']:.4f} / {a['K_m']:.0f}",
              f"  {'memory, inertia held: K(0)':53s} {r['K_f']:12.0f} {a['K_f']:10.0f}",
              "  probes of the impedance (measured-torque fit), held-out VAF (%), not used:",
              *[f"    {name:51s} {x:12.2f} {y:10.2f}" for name, x, y in zip(PROBES, r["probes"], a["probes"])],
              f"  cost of causality (two-sided minus closed-loop impedance, measured-torque fit): as recorded "
              f"{r['two'] - r['impedance']:.2f} points, aligned {a['two'] - a['impedance']:.2f} (against the two-sided "
              f"model on the data as recorded: {r['two'] - a['impedance']:.2f}); {p['n_held']} held-out samples at 100 Hz",
              "",
              f"  leave-one-{p['fold_kind']}-out over the development split ({p['folds']} folds), pooled VAF (%) "
              "all folds / without the 2 end plateaus:"]
    for label, key in rows[:3]:
        lines.append(f"  {label:53s} {r['lolo'][(key, False)]:6.2f} / {r['lolo'][(key, True)]:5.2f}  "
                     f"{a['lolo'][(key, False)]:6.2f} / {a['lolo'][(key, True)]:5.2f}")
    return lines


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--pilot-only", action="store_true", help="only the lab pilot part (printed, not written)")
    args = ap.parse_args()
    if args.pilot_only:
        p = pilot()
        print("\n".join(_pilot_lines(p)) if p else "pilot_ident.csv not found")
        return
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        loop_rows, offline_rows, me_err, skew_rows = virtual(range(args.seeds), args.duration, Path(tmp))
    lines = [f"Closed loop: foot + device 0.01 kg m^2, PD Kd 0.5 N m s/rad, {args.duration:g} s per seed, plant 1 kHz",
             "VAF (%) against the virtual subject in the same loop: angle deviation / torque, whole and above 0.5 Hz",
             "", "seed    Kp  subject  closed-loop FMU, 1 ms step (dev / tq / dev>0.5Hz / tq>0.5Hz)  "
             "10 ms step (same)                    replay FMU (10 ms)   subject tq std",]
    worst = {kp: [] for kp in KPS}
    for seed, kp, ok, r1, v1, r10, v10, rr, tq_std in loop_rows:
        def cell(run, v):
            if not run.stable:
                return f"DIVERGED at {run.diverged_at:.2f} s".ljust(36)
            return " / ".join(f"{v[k]:6.2f}" for k in ("deviation", "torque", "deviation_hp", "torque_hp")).ljust(36)
        rep = "stable" if rr.stable else f"diverged at {rr.diverged_at:.2f} s"
        lines.append(f"{seed:4d} {kp:5g}  {'stable' if ok else 'DIVERGED':7s}  {cell(r1, v1)}   {cell(r10, v10)} "
                     f"{rep:20s} {tq_std:.2f} N m")
        worst[kp] += [min(v1.values()), min(v10.values())]
    lines.append("")
    for kp in KPS:
        lines.append(f"Kp {kp:g}: smallest of the four VAFs over seeds and both steps {min(worst[kp]):.2f} % "
                     f"(stable in {sum(1 for r in loop_rows if r[1] == kp and r[3].stable and r[5].stable)} of "
                     f"{sum(1 for r in loop_rows if r[1] == kp)} seeds); replay FMU diverged in "
                     f"{sum(1 for r in loop_rows if r[1] == kp and not r[7].stable)} of "
                     f"{sum(1 for r in loop_rows if r[1] == kp)}")
    if me_err:
        lines.append(f"Model Exchange FMU via fmpy.simulate_fmu along the 1-ms Kp 40 loop: max |torque - CS loop's| / "
                     f"std {max(me_err):.1e}")
    lines += ["", "Offline, novel trajectory (60 s, seed + 100): total torque VAF (%)",
              "seed  closed-loop form (fitted to two-sided)  (fitted to PT/UT)  two-sided whole-joint  inertia kg m^2"]
    for seed, a, b, c, inertia in offline_rows:
        lines.append(f"{seed:4d}  {a:38.2f}  {b:17.2f}  {c:21.2f}  {inertia:.5f}")
    gaps = [c - a for _, a, _, c, _ in offline_rows]
    lines.append(f"cost of causality (two-sided minus closed-loop form): median {np.median(gaps):.2f}, "
                 f"max {max(gaps):.2f} points; subject's inertia 0.015")
    lines += _skew_lines(skew_rows)
    p = pilot()
    lines.append("")
    if p is None:
        lines.append("lab pilot trial: skipped (../shared/real/pilot_ident.csv not found)")
    else:
        lines += _pilot_lines(p)
    lines += ["", f"total {time.perf_counter() - t0:.0f} s; {platform.platform()}, OPENBLAS_NUM_THREADS=1"]
    write_results("closed_loop.txt", lines, echo=True)


if __name__ == "__main__":
    main()
