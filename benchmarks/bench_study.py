"""lpvpc study on virtual cohorts: (a) does the group difference's 95 % interval cover the
true difference, and (b) how fast and how large is a study on one and on two workers.

(a) Virtual cohorts of ``--subjects`` population subjects (lpvpc.study.cohort.write_cohort:
exponential K, patient group K x1.5 toward dorsiflexion and reflex gain x2, alternating
groups) from DEVELOPMENT_SEEDS, cohort c taking seeds c * subjects ...; ``--cohorts`` with
the difference and ``--null-cohorts`` without (their seeds follow). Each is run as
``lpvpc.study.run_study`` does (hold out the last 30 %, identify the rest) on records of
``--duration`` s at 100 Hz. Per quantity (K and reflex gain), pooled over the common grid
positions of every cohort: the fraction whose Welch 95 % interval covers the population-mean
difference (truth.json), the fraction with the sign right among positions where the true
difference exceeds the interval's half-width, and on null cohorts the fraction whose
interval excludes zero.

(b) ``--speed-records`` records of ``--speed-duration`` s (one cohort) run with 1 and with 2
workers (``jobs``), no cache: wall time, speed-up, and each worker process's peak resident
memory (ru_maxrss, reported by the jobs).

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_study.py [--cohorts 6] [--null-cohorts 4]
     [--subjects 24] [--duration 60] [--speed-records 24] [--speed-duration 120]
Writes benchmarks/results/study.txt.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks._results import write_results  # noqa: E402
from lpvpc.simulation.population import DEVELOPMENT_SEEDS  # noqa: E402
from lpvpc.study import run_study  # noqa: E402
from lpvpc.study.cohort import write_cohort  # noqa: E402
from lpvpc.study.tables import GROUP_COLUMNS  # noqa: E402,F401


def _groups(path):
    import csv

    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def coverage_run(tmp, index, subjects, duration, null):
    first = DEVELOPMENT_SEEDS[0] + index * subjects
    folder = tmp / f"cohort{index}"
    paths = write_cohort(folder, subjects, first_seed=first, null=null, duration=duration, fs=100.0)
    truth = json.loads(paths["truth"].read_text())
    t0 = time.perf_counter()
    result = run_study(paths["manifest"], folder / "study", jobs=1, report=False)
    seconds = time.perf_counter() - t0
    t_theta = np.array(truth["theta"])
    out = {"failed": result.failed, "seconds": seconds, "positions": len(result.grid),
           "range": (result.grid[0] * 0.01, result.grid[-1] * 0.01) if result.grid else None}
    rows = [r for r in _groups(folder / "study" / "groups.csv") if r["group"] == "patient - control"]
    for q in ("stiffness", "reflex_gain"):
        sel = [r for r in rows if r["quantity"] == q and r["lower"] != ""]
        th = np.array([float(r["theta"]) for r in sel])
        d, lo, hi = (np.array([float(r[c]) for r in sel]) for c in ("mean", "lower", "upper"))
        true = np.interp(th, t_theta, truth["difference"][q])
        half = 0.5 * (hi - lo)
        out[q] = {"n": len(sel), "covered": int(np.sum((lo <= true) & (true <= hi))),
                  "excludes_zero": int(np.sum((lo > 0) | (hi < 0))),
                  "big": int(np.sum(np.abs(true) > half)),
                  "sign_right": int(np.sum((np.abs(true) > half) & (np.sign(d) == np.sign(true)))),
                  "bias": float(np.sum(d - true)), "abs_true": float(np.sum(np.abs(true)))}
    shutil.rmtree(folder)
    return out


def speed_run(tmp, records, duration):
    folder = tmp / "speed"
    paths = write_cohort(folder, records, first_seed=DEVELOPMENT_SEEDS[0] + 50_000, duration=duration, fs=100.0)
    out = {}
    for jobs in (1, 2):
        study = folder / f"study_j{jobs}"
        t0 = time.perf_counter()
        result = run_study(paths["manifest"], study, jobs=jobs, report=False)
        wall = time.perf_counter() - t0
        peak = {}
        for r in result.results:
            if "pid" in r:
                peak[r["pid"]] = max(peak.get(r["pid"], 0.0), r["peak_rss_mb"])
        out[jobs] = {"wall": wall, "failed": result.failed, "peak": sorted(peak.values()),
                     "job_seconds": float(np.nansum([r.get("seconds", np.nan) for r in result.results]))}
    shutil.rmtree(folder)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cohorts", type=int, default=6)
    ap.add_argument("--null-cohorts", type=int, default=4)
    ap.add_argument("--subjects", type=int, default=24)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--speed-records", type=int, default=24)
    ap.add_argument("--speed-duration", type=float, default=120.0)
    ap.add_argument("--skip-coverage", action="store_true")
    args = ap.parse_args(argv)
    cpu0 = time.process_time()
    t_start = time.perf_counter()
    lines = ["# lpvpc study on virtual cohorts (benchmarks/bench_study.py)", "",
             f"command: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_study.py --cohorts {args.cohorts} "
             f"--null-cohorts {args.null_cohorts} --subjects {args.subjects} --duration {args.duration:g} "
             f"--speed-records {args.speed_records} --speed-duration {args.speed_duration:g}", ""]
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        if not args.skip_coverage:
            runs = {"difference": [], "null": []}
            for c in range(args.cohorts + args.null_cohorts):
                null = c >= args.cohorts
                r = coverage_run(tmp, c, args.subjects, args.duration, null)
                runs["null" if null else "difference"].append(r)
                print(f"cohort {c} ({'null' if null else 'difference'}): {r['positions']} positions, "
                      f"{r['failed']} failed, {r['seconds']:.1f} s; K covered {r['stiffness']['covered']}/"
                      f"{r['stiffness']['n']}, gain covered {r['reflex_gain']['covered']}/{r['reflex_gain']['n']}",
                      flush=True)
            lines += ["## (a) coverage of the group difference's Welch 95 % interval", "",
                      f"{args.cohorts} cohorts with a difference (patient: K x1.5 toward dorsiflexion, reflex gain "
                      f"x2) and {args.null_cohorts} null cohorts, {args.subjects} subjects each ({args.subjects // 2} per group), "
                      f"one {args.duration:g}-s record per subject at 100 Hz (last 30 % held out), "
                      "DEVELOPMENT_SEEDS from 0; truth: the population-mean difference (lpvpc.study.cohort).",
                      "covered: interval holds the true difference; excl. 0: interval excludes zero; |true|>hw: "
                      "positions whose true difference exceeds the interval's half-width, and of those the share "
                      "with the estimated sign right; bias/|true|: sum of (estimate - truth) over sum of |truth|.", ""]
            for kind, rs in runs.items():
                if not rs:
                    continue
                ranges = [r["range"] for r in rs if r["range"]]
                lines.append(f"{kind} cohorts: {len(rs)}; records failed: {sum(r['failed'] for r in rs)}; common "
                             f"grid positions per cohort: {min(r['positions'] for r in rs)}-"
                             f"{max(r['positions'] for r in rs)} (ranges from "
                             f"{min(a for a, _ in ranges):+.2f}..{max(b for _, b in ranges):+.2f} rad)")
                lines.append(f"{'quantity':<12} {'positions':>9} {'covered':>9} {'excl. 0':>9} "
                             f"{'|true|>hw':>10} {'sign right':>10} {'bias/|true|':>15}")
                for q in ("stiffness", "reflex_gain"):
                    n = sum(r[q]["n"] for r in rs)
                    cov = sum(r[q]["covered"] for r in rs)
                    exz = sum(r[q]["excludes_zero"] for r in rs)
                    big = sum(r[q]["big"] for r in rs)
                    sr = sum(r[q]["sign_right"] for r in rs)
                    abs_true = sum(r[q]["abs_true"] for r in rs)
                    bias = sum(r[q]["bias"] for r in rs) / abs_true if abs_true > 0 else float("nan")
                    lines.append(f"{q:<12} {n:>9} {100 * cov / max(n, 1):>8.1f}% {100 * exz / max(n, 1):>8.1f}% "
                                 f"{big:>10} {(f'{100 * sr / big:.1f}%' if big else '-'):>10} "
                                 f"{('' if np.isnan(bias) else f'{100 * bias:+.1f}%'):>15}")
                lines.append("")
            cpu_a = time.process_time() - cpu0
            lines.append(f"coverage part: {time.perf_counter() - t_start:.0f} s wall, {cpu_a:.0f} s CPU "
                         "(one process)")
            lines.append("")
        t1 = time.perf_counter()
        sp = speed_run(tmp, args.speed_records, args.speed_duration)
        lines += ["## (b) speed and memory: one study, 1 and 2 workers", "",
                  f"{args.speed_records} records of {args.speed_duration:g} s at 100 Hz (a virtual cohort), no "
                  "cache; 2-core machine shared with other work (nice), so wall times are indicative.", "",
                  f"{'workers':>7} {'wall s':>8} {'sum of job s':>12} {'failed':>6}  peak RSS per worker process (MB)"]
        for jobs, r in sp.items():
            lines.append(f"{jobs:>7} {r['wall']:>8.1f} {r['job_seconds']:>12.1f} {r['failed']:>6}  "
                         + ", ".join(f"{p:.0f}" for p in r["peak"])
                         + ("  (the calling process itself)" if jobs == 1 else ""))
        lines.append(f"speed-up 2 vs 1 worker: {sp[1]['wall'] / sp[2]['wall']:.2f}x")
        lines.append(f"speed part: {time.perf_counter() - t1:.0f} s wall")
    lines += ["", f"total: {time.perf_counter() - t_start:.0f} s wall; CPU of this process "
              f"{time.process_time() - cpu0:.0f} s (pool workers' CPU not included)"]
    write_results("study.txt", lines, echo=True)


if __name__ == "__main__":
    main()
