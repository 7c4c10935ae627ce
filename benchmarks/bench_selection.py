"""Structure selection by cross-validation (issue 22), measured in one run.

1. The lab's pilot trial (``pilot_ident.csv``, the first 70 % of the recording; torque
   negated), leave-one-level-out: each level of the staircase (every visit to it, end
   plateaus included) is predicted by models identified on the rest (the remaining
   stretches joined as trials: nothing crosses a gap), the whole record predicted and the
   level's samples scored. Side by side: the new default (structure chosen by
   cross-validation, run inside each training set on its own levels: nested), the
   previous default settings (structure="fixed"), a fixed-setting implementation of the
   paper's algorithm in lpvpc (no pole refinement, no curvature term, state order 2, no
   time-constant cap; the previous default's basis orders and IRF) and the crude flexible
   least-squares fit (``flexible_fit.py``, fitted on the training rows). Pooled CV VAF
   over all folds, and over the two end plateaus alone (extrapolation). Then the
   development split: the same methods identified on the first 70 % of the file, its last
   30 % predicted. The kept-back last 30 % of the recording is not available here: no
   figure on it.
2. The virtual subject (2-minute multilevel records, seeds 0-4): novel-trajectory VAF and
   K(theta) error against the truth, the new default against the previous one.

Run: python benchmarks/bench_selection.py   (writes benchmarks/results/selection.txt)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from _results import write_results  # noqa: E402
from flexible_fit import FlexibleFit  # noqa: E402
from real_data import real_data_dir  # noqa: E402

from lpvpc.models import equations as eq  # noqa: E402
from lpvpc.models.basis import basis_from_data  # noqa: E402
from lpvpc.io import join_trials, load_identification_data, pair_trials  # noqa: E402
from lpvpc.identification.identify import LPVPCEstimator  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.identification.selection import level_folds  # noqa: E402

MIN_PIECE_S = 1.0  # training stretches shorter than this are left out (too short for the subspace step)

NEW = "lpvpc new default (structure chosen by CV inside each training set)"
METHODS = {
    NEW: {},
    "lpvpc previous default (structure='fixed')": {"structure": "fixed"},
    "paper's algorithm, fixed settings (no refinement/curvature, m = 2)": {
        "structure": "fixed", "refine": False, "elastic_curvature": False, "state_order": 2,
        "max_reflex_time_constant": None},
}
FLEX = "flexible least squares (training rows)"


def flexible_prediction(d, train):
    """The crude flexible fit on the training rows (its bases on their range), predicting every row."""
    fl = FlexibleFit(d.fs)
    ro, rro, vo = fl.orders
    rho, p = d.scheduling, d.position
    fl.Gi = basis_from_data(rho[train], "chebyshev", ro)
    fl.Gr = basis_from_data(rho[train], "chebyshev", rro)
    fl.Vb = basis_from_data(eq.velocity(p, d.fs)[train], "hinge", vo, extrapolation="linear")
    X = fl._features(p, rho)
    theta = np.linalg.lstsq(X[train], d.torque[train], rcond=None)[0]
    return X @ theta


def _reflex_path(sel) -> dict:
    """The reflex nonlinearity's velocity the selection chose (data that keep their 1 kHz signals)."""
    return {"reflex_path": sel["reflex_path"]["label"]} if "reflex_path" in sel else {}


def training_pieces(d, labels, f):
    """The record without fold f, as trials: its contiguous stretches of other folds."""
    keep = np.r_[False, labels != f, False]
    edges = np.flatnonzero(np.diff(keep.astype(int)))
    return [d.segment(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= MIN_PIECE_S * d.fs]


def leave_one_level_out(d):
    labels, kind = level_folds(d.scheduling, d.fs)
    K = labels.max() + 1
    med = np.array([np.median(d.scheduling[labels == f]) for f in range(K)])
    ends = {int(np.argmin(med)), int(np.argmax(med))}
    y = d.torque
    sse = {name: np.zeros(K) for name in [*METHODS, FLEX]}
    chosen, seconds, train_s = [], {name: 0.0 for name in sse}, []
    for f in range(K):
        test = labels == f
        train_data = join_trials(training_pieces(d, labels, f))
        train_s.append(train_data.n / train_data.fs)
        for name, settings in METHODS.items():
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = LPVPCEstimator(**settings).fit(train_data).model_
                pred = model.predict(d).total
            seconds[name] += time.perf_counter() - t
            e = y[test] - pred[test]
            sse[name][f] = e @ e
            if name == NEW:  # (the chosen settings, or why selection was skipped)
                sel = model.fit["structure_selection"]
                chosen.append(sel.get("chosen", {"skipped": sel.get("skipped")}) | _reflex_path(sel))
        name = FLEX
        t = time.perf_counter()
        e = y[test] - flexible_prediction(d, ~test)[test]
        seconds[name] += time.perf_counter() - t
        sse[name][f] = e @ e
    ss = np.array([np.sum((y[labels == f] - y.mean()) ** 2) for f in range(K)])
    return labels, kind, med, ends, sse, ss, chosen, seconds, train_s


def pilot_section() -> list:
    folder = real_data_dir()
    if folder is None or not (folder / "pilot_ident.csv").is_file():
        return ["## 1. Lab pilot trial: skipped (pilot_ident.csv not found; set LPVPC_REAL_DATA)"]
    d = load_identification_data(data=folder / "pilot_ident.csv", torque_sign=-1)
    labels, kind, med, ends, sse, ss, chosen, seconds, train_s = leave_one_level_out(d)
    K = len(med)
    end_idx = sorted(ends)
    lines = [f"## 1. Lab pilot trial (pilot_ident.csv, first 70 % of the recording: {d.n} samples at {d.fs:g} Hz, "
             f"torque negated), leave-one-{kind}-out: {K} folds",
             "levels (rad): " + ", ".join(f"{m:+.3f}" for m in np.sort(med)), "",
             "| method | CV VAF, all folds (%) | CV VAF, the 2 end plateaus (%) | worst fold VAF (%) | time (s, all folds) |",
             "|---|---|---|---|---|"]
    rows = []
    for name, s in sse.items():
        pooled = 100 * (1 - s.sum() / ss.sum())
        end = 100 * (1 - s[end_idx].sum() / ss[end_idx].sum())
        worst = float(np.min(100 * (1 - s / ss)))
        rows.append((name, pooled, end))
        lines.append(f"| {name} | {pooled:.2f} | {end:.2f} | {worst:.2f} | {seconds[name]:.1f} |")
    lines.append("")
    new = rows[0]
    for name, pooled, end in rows[1:]:
        lines.append(f"- new default minus {name}: {new[1] - pooled:+.2f} points (all folds), "
                     f"{new[2] - end:+.2f} (end plateaus)")
    lines.append("")
    lines.append("Per fold (level, rad: VAF % of each method in the order above; * end plateau):")
    for f in np.argsort(med):
        vafs = ", ".join(f"{100 * (1 - sse[n][f] / ss[f]):.2f}" for n in sse)
        lines.append(f"- {med[f]:+.3f}{' *' if f in ends else '  '}: {vafs}")
    lines.append("")
    lines.append("Structures chosen inside the training sets (fold by level):")
    for f in np.argsort(med):
        c = chosen[f]
        if "skipped" in c:
            lines.append(f"- without {med[f]:+.3f}: not selected ({c['skipped']}; {train_s[f]:.0f} s of training data)")
            continue
        lines.append(f"- without {med[f]:+.3f}: L {1e3 * c['irf_length']:g} ms, orders {c['intrinsic_order']}/"
                     f"{c['reflex_order']}/{c['velocity_order']} (intrinsic/reflex/velocity), delay "
                     f"{1e3 * c['reflex_delay']:g} ms, curvature {c['elastic_curvature']}, beyond range "
                     f"{c['scheduling_extrapolation']}" + (f", reflex {c['reflex_path']}" if "reflex_path" in c else ""))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = LPVPCEstimator().fit(d).model_
    c = whole.fit["structure_selection"]["chosen"] | _reflex_path(whole.fit["structure_selection"])
    lines += ["", f"On the whole file, the default chooses: {c} (CV VAF {whole.fit['structure_selection']['chosen_cv_vaf']:.2f} %, "
                  f"selection {whole.fit['structure_selection']['seconds']:.2f} s)"]
    return lines + [""] + development_split(d)


def development_split(d) -> list:
    """Identified on the first 70 % of the file, its last 30 % predicted (the whole record is
    predicted so that the scored part starts from the trial's own past)."""
    k = int(0.7 * d.n)
    ident, held = d.segment(0, k), d.segment(k, None)
    lines = [f"## 1b. Development split: identified on the first 70 % of pilot_ident.csv ({k} samples), its last "
             f"30 % predicted ({d.n - k} samples)", "",
             "| method | held-out VAF (%) | causal form (%) | identification VAF (%) | time (s) |", "|---|---|---|---|---|"]
    for name, settings in METHODS.items():
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = LPVPCEstimator(**settings).fit(ident).model_
            two, cau = m.predict(d).total[k:], m.predict(d, causal=True).total[k:]
        el = time.perf_counter() - t
        lines.append(f"| {name.replace(' inside each training set', '')} | {vaf(held.torque, two):.2f} | "
                     f"{vaf(held.torque, cau):.2f} | {m.fit['vaf']:.2f} | {el:.1f} |")
        if name == NEW:
            sel = m.fit["structure_selection"]
            chosen = sel.get("chosen", f"nothing: selection skipped ({sel.get('skipped')})")
            if "chosen" in sel:
                chosen = chosen | _reflex_path(sel)
    t = time.perf_counter()
    fl = FlexibleFit(d.fs).fit(ident.position, ident.torque, ident.scheduling)
    pf = fl.predict(d.position, d.scheduling)[k:]
    el = time.perf_counter() - t
    lines.append(f"| {FLEX.replace('training rows', 'first 70 %')} | {vaf(held.torque, pf):.2f} | - | "
                 f"{vaf(ident.torque, fl.predict(ident.position, ident.scheduling)):.2f} | {el:.1f} |")
    return lines + ["", f"The new default chose on the first 70 %: {chosen}"]


def fit_and_score(make_estimator, d, nv, truth):
    """Fit ``make_estimator()`` on ``d``, predict the novel record ``nv``: (model, (novel VAF %,
    worst and mean K error % over the central 80 % of the range against ``truth.K``, fit time
    s), the chosen structure as text)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        model = make_estimator().fit(d).model_
        el = time.perf_counter() - t
        pred = model.predict(nv.position, nv.scheduling).total
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 25)
    k_err = 100 * np.abs(model.elastic_stiffness(rho) / truth.K(rho) - 1)
    c = model.fit.get("structure_selection", {}).get("chosen")
    what = "" if c is None else (f"orders {c['intrinsic_order']}/{c['reflex_order']}/{c['velocity_order']}, "
                                 f"L {1e3 * c['irf_length']:g} ms, {c['scheduling_extrapolation']}")
    return model, (vaf(nv.torque, pred), float(k_err.max()), float(k_err.mean()), el), what


def subject_section(seeds=range(5)) -> list:
    from lpvpc.simulation.simulate import SubjectParams, simulate_pair

    truth = SubjectParams()
    lines = ["## 2. Virtual subject: 2-minute multilevel records, novel trajectory predicted (seed + 1000)", "",
             "| seed | structure | novel VAF (%) | K worst err (%) | K mean abs err (%) | identify (s) | chosen |",
             "|---|---|---|---|---|---|---|"]
    agg = {"previous default (fixed)": [], "new default (cv)": []}
    for seed in seeds:
        ident, novel = simulate_pair("multilevel", seed=seed), simulate_pair("novel", seed=seed + 1000)
        d, nv = pair_trials(ident.pt, ident.ut), pair_trials(novel.pt, novel.ut)
        for structure in agg:
            model, (v, k_max, k_mean, el), what = fit_and_score(
                lambda: LPVPCEstimator(**({"structure": "fixed"} if "fixed" in structure else {})), d, nv, truth)
            agg[structure].append((v, k_max, k_mean, el))
            lines.append(f"| {seed} | {structure} | {v:.2f} | {k_max:.1f} | {k_mean:.1f} | {el:.2f} | {what} |")
    lines.append("")
    for s, rows in agg.items():
        a = np.array(rows)
        lines.append(f"- {s}: median novel VAF {np.median(a[:, 0]):.2f} %, median worst K error {np.median(a[:, 1]):.1f} %, "
                     f"median mean K error {np.median(a[:, 2]):.1f} %, median identify time {np.median(a[:, 3]):.2f} s")
    return lines


def main():
    import os

    load = os.getloadavg()[0]
    lines = ["# Structure selection by cross-validation (python benchmarks/bench_selection.py)", ""]
    lines += pilot_section() + [""] + subject_section()
    lines += ["", f"Conditions: {os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
                  f"1-minute load average {load:.1f} at the start and {os.getloadavg()[0]:.1f} at the end"]
    write_results("selection.txt", lines, echo=True)


if __name__ == "__main__":
    main()
