"""Identification speed and memory.

- 2-minute 100 Hz record: wall time per stage (median of 3 runs);
- cost versus record length (2, 7.5, 15, 30 minutes): the records are simulated here and
  written as 100 Hz CSV files; each length is loaded and identified in a fresh subprocess,
  so that its peak resident memory is that of loading and identifying, not of the
  simulator (VmHWM of /proc/self/status: ru_maxrss would carry the parent's resident size
  at the fork over the exec on Linux, and the parent holds the simulated records);
- the projection (27)-(28) computed as lpvpc does (least squares after projecting out
  range(Psi_r)) versus the literal formula with explicit pseudo-inverses and the N x N
  projector, at N = 12,000: time ratio and largest difference.

- issue 10's speed floor: identification against a bare least-squares solve of its final
  regressor and against one of the subspace step's block-Hankel data matrix, and load +
  identify from 1 kHz files against 100 Hz files (``--floor`` runs only this, into
  benchmarks/results/identify_floor.txt);
- a library session's identification on one BLAS thread (lpvpc.linalg.one_blas_thread)
  against OpenBLAS threads on every CPU.

- issue 22's long-record floor (``--long``, into benchmarks/results/identify_long.txt):
  for a 2- and a 30-minute record written as 100 Hz CSV files, the whole ``lpvpc identify``
  process (load, identify, write the model file) against a process that loads the same
  files, builds the seed-sized regressor (the subspace step's block-Hankel matrix at the
  default settings) and solves it by numpy lstsq; each in a fresh process, wall time and
  peak resident memory by /usr/bin/time -v; the default (structure selected by
  cross-validation) and ``--structure fixed``.

Run: python benchmarks/bench_identify.py   (writes benchmarks/results/identify.txt)
     python benchmarks/bench_identify.py --long   (writes benchmarks/results/identify_long.txt)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _results import write_results

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def subject_data(duration, seed=0):
    from lpvpc.io import pair_trials
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=seed, duration=duration, fs_out=100.0)
    return pair_trials(pair.pt, pair.ut)


def _peak_rss_kib() -> float:
    """This process's peak resident size (KiB) since its exec: VmHWM (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1])
    raise RuntimeError("no VmHWM in /proc/self/status (Linux only)")


def one_length(pt, ut):
    """Child process: load and identify one record from its files, print JSON with time and
    peak memory."""
    from lpvpc.io import load_identification_data
    from lpvpc.identification.identify import identify

    data = load_identification_data(pt=pt, ut=ut)
    rss0 = _peak_rss_kib()
    t = time.perf_counter()
    model = identify(data)
    elapsed = time.perf_counter() - t
    peak = _peak_rss_kib()
    print(json.dumps({"n": data.n, "time_s": elapsed, "peak_rss_mb": peak / 1024,
                      "rss_before_identify_mb": rss0 / 1024, "vaf": model.fit["vaf"], "timings": model.fit["timings_s"]}))


def projection_comparison():
    from lpvpc.models.basis import basis_from_data
    from lpvpc.models import equations as eq
    from lpvpc.identification.identify import LPVPCEstimator, project_out_and_solve
    from lpvpc.models.intrinsic import intrinsic_regressor, two_sided_lags
    from lpvpc.models.reflex import reflex_input_regressor, reflex_regressor

    data = subject_data(120.0)
    est = LPVPCEstimator()
    p, y, rho = data.position, data.torque, data.scheduling
    dvel = eq.delayed_velocity(p, data.fs, 4)
    Psi_i = intrinsic_regressor(p, basis_from_data(rho, "chebyshev", est.intrinsic_order).evaluate(rho),
                                two_sided_lags(est.resolved_lags(data.fs)))
    U_r = reflex_input_regressor(basis_from_data(dvel, "chebyshev", est.velocity_order, "linear").evaluate(dvel),
                                 basis_from_data(rho, "chebyshev", est.reflex_order).evaluate(rho))
    A = np.array([[1.8, 1.0], [-0.82, 0.0]])
    C = np.array([[1.0, 0.0]])
    Psi_r = np.hstack(reflex_regressor(U_r, A, C))
    t = time.perf_counter()
    fast = project_out_and_solve(Psi_r, Psi_i, y)
    t_fast = time.perf_counter() - t
    t = time.perf_counter()
    pinv_r, pinv_i = np.linalg.pinv(Psi_r), np.linalg.pinv(Psi_i)
    projector = np.eye(len(y)) - Psi_r @ pinv_r  # N x N, as written in (27)
    Cmat = np.eye(Psi_i.shape[1]) - pinv_i @ Psi_r @ pinv_r @ Psi_i  # (28)
    direct = np.linalg.pinv(Cmat) @ pinv_i @ projector @ y
    t_direct = time.perf_counter() - t
    return {"n": len(y), "t_lpvpc_s": t_fast, "t_pinv_s": t_direct, "ratio": t_direct / t_fast,
            "max_rel_diff": float(np.max(np.abs(fast - direct)) / np.max(np.abs(direct)))}


def _median_time(fn, runs=3):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def speed_floor() -> list:
    """Issue 10's speed floor, measured in one run: (a) identification of a 2-minute 100 Hz
    record against a bare least-squares solve of the same regressor (the intrinsic Psi_i and
    the reflex Psi_r built with the identified A, C: everything the identification estimates
    once the reflex poles are known); (b) the whole load + identify from 1 kHz files against
    the same from 100 Hz files of the same record."""
    import tempfile

    from lpvpc.models import equations as eq
    from lpvpc.io import load_identification_data, write_trial_csv
    from lpvpc.identification.identify import identify
    from lpvpc.models.intrinsic import intrinsic_regressor
    from lpvpc.models.reflex import reflex_input_regressor, reflex_regressor
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=0, duration=120.0, fs_out=1000.0)
    pair100 = simulate_pair("multilevel", seed=0, duration=120.0, fs_out=100.0)
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = {}
        for tag, pr in (("1k", pair), ("100", pair100)):
            paths[tag] = (Path(tmp) / f"PT_{tag}.csv", Path(tmp) / f"UT_{tag}.csv")
            write_trial_csv(pr.pt, paths[tag][0])
            write_trial_csv(pr.ut, paths[tag][1])

        def from_files(tag):
            d = load_identification_data(pt=paths[tag][0], ut=paths[tag][1])
            return d, identify(d)

        for _ in range(2):  # alternate, so that load changes hit both alike
            t100, (data, model) = _median_time(lambda: from_files("100"))
            t1k, (data1k, model1k) = _median_time(lambda: from_files("1k"))
    t_ident, model_t = _median_time(lambda: identify(data))
    # The paper's subspace step (PO-MOESP) factors a block-Hankel matrix of the inputs and
    # torque, much wider than the final regressor: time that factorisation in one
    # identification, and keep its inputs for a bare least-squares solve of that matrix.
    import lpvpc.identification.subspace as subspace

    hankel = {}
    moesp_factor = subspace.moesp_factor

    def timed_factor(u_future, u_past, y, s, segments=None, chunk=None):
        t = time.perf_counter()
        R, how = moesp_factor(u_future, u_past, y, s, segments, chunk)
        hankel.update(seconds=time.perf_counter() - t, how=how, args=(u_future, u_past, y, s))
        return R, how

    subspace.moesp_factor = timed_factor
    try:
        identify(data)
    finally:
        subspace.moesp_factor = moesp_factor
    u_f, u_p, y_s, s = hankel["args"]
    H = subspace.hankel_rows(u_f, u_p, y_s, 0, len(y_s) - 2 * s + 1, s)
    # its bare solve: the last future output regressed on the other columns
    t_ls_h, _ = _median_time(lambda: np.linalg.lstsq(H[:, :-1], H[:, -1], rcond=None))
    t_qr_h, _ = _median_time(lambda: subspace.streamed_r(u_f, u_p, y_s, s))
    p, y, rho, fs = data.position, data.torque, data.scheduling, data.fs
    dvel = eq.delayed_velocity(p, fs, model.delay)
    Psi_i = intrinsic_regressor(p, model.intrinsic_basis.evaluate(rho), model.lags)
    U_r = reflex_input_regressor(model.velocity_basis.evaluate(dvel), model.reflex_rho_basis.evaluate(rho))
    X = np.hstack([Psi_i] + reflex_regressor(U_r, model.A, model.C[None, :]))
    t_ls, _ = _median_time(lambda: np.linalg.lstsq(X, y, rcond=None))
    stages = ", ".join(f"{k} {v:.3f} s" for k, v in model_t.fit["timings_s"].items())
    lines.append(f"Speed floor (issues 10, 22), one run, medians of 3: identify a 2-minute 100 Hz record at the default "
                 f"settings (structure chosen by cross-validation) {t_ident:.2f} s (stages of the last run: {stages})")
    lines.append(f"- against a bare least-squares solve of its final regressor ({X.shape[0]} x {X.shape[1]}, numpy lstsq) "
                 f"{t_ls:.3f} s: ratio {t_ident / t_ls:.1f}x (floor 3x)")
    lines.append(f"- against a bare least-squares solve of the subspace step's own data matrix (the {H.shape[0]} x "
                 f"{H.shape[1]} block-Hankel matrix, numpy lstsq) {t_ls_h:.3f} s: ratio {t_ident / t_ls_h:.2f}x (floor 3x, "
                 f"target 2.5x; selection {model_t.fit['timings_s'].get('selection', 0.0):.3f} s of the last run)")
    t_fixed, _ = _median_time(lambda: identify(data, structure="fixed"))
    lines.append(f"- structure='fixed' (selection off) {t_fixed:.2f} s: {t_fixed / t_ls_h:.2f}x that block-Hankel solve; "
                 f"the default takes {t_ident / t_fixed:.2f}x the fixed structure")
    lines.append(f"- the subspace step's factor of that matrix: {hankel['seconds']:.3f} s by the {hankel['how']} route "
                 f"(= {hankel['seconds'] / t_ls:.1f}x the final regressor's solve; its QR, the route before, "
                 f"{t_qr_h:.3f} s = {t_qr_h / t_ls:.1f}x)")
    lines.append(f"From files, load + identify: 100 Hz CSV {t100:.2f} s, 1 kHz CSV (decimated to 100 Hz) {t1k:.2f} s: "
                 f"ratio {t1k / t100:.2f}x (floor 3x); same model rate {model1k.fs:g} Hz, VAF {model1k.fit['vaf']:.2f} / "
                 f"{model.fit['vaf']:.2f} %; reflex nonlinearity of the 1 kHz files on "
                 f"{getattr(model1k, 'nonlinearity_fs', model1k.fs):g} Hz velocity"
                 + (f" (chosen per record by the structure selection: {path['label']}; CV VAF % "
                    + ", ".join(f"{r['label']}: {r['cv_vaf']:.2f}" for r in path["table"]) + ")"
                    if (path := model1k.fit.get("structure_selection", {}).get("reflex_path")) else ""))
    return lines


def _library_identify_time():
    """Child of blas_threads: median of 3 identifications of the 2-minute 100 Hz record in a
    library session (numpy imported first, as in a notebook)."""
    import warnings

    from lpvpc.identification.identify import identify

    data = subject_data(120.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identify(data)
        print(json.dumps({"time_s": _median_time(lambda: identify(data))[0]}))


def blas_threads() -> list:
    """Identification in a library session (``import lpvpc``, no BLAS variable set), where
    lpvpc.linalg.one_blas_thread limits BLAS to one thread, against the same session with
    OPENBLAS_NUM_THREADS set to the CPU count (a user's choice, which lpvpc leaves alone:
    OpenBLAS's own default). Each in a fresh process, since BLAS reads the variables at load."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    times = {}
    for tag, extra in (("one thread (lpvpc's default)", {}),
                       (f"OPENBLAS_NUM_THREADS={os.cpu_count()}", {"OPENBLAS_NUM_THREADS": str(os.cpu_count())})):
        out = subprocess.run([sys.executable, __file__, "--library-time"], capture_output=True, text=True,
                             env={**env, **extra}, check=True)
        times[tag] = json.loads(out.stdout.strip().splitlines()[-1])["time_s"]
    (a, ta), (b, tb) = times.items()
    return [f"Library session (import lpvpc, no BLAS variable set), 2-minute 100 Hz record, medians of 3: {a} {ta:.2f} s, "
            f"{b} {tb:.2f} s ({tb / ta:.2f}x)"]


def bare_ls(pt, ut):
    """Child of long_records: load the files, build the seed-sized regressor (the subspace
    step's block-Hankel matrix [U_f; U_p; Y_p; Y_f]^T at the default settings) and solve it
    by numpy lstsq (the last future output on the other columns); print JSON timings."""
    t0 = time.perf_counter()
    from lpvpc.models import equations as eq
    from lpvpc.models.basis import basis_from_data
    from lpvpc.io import load_identification_data
    from lpvpc.identification.identify import LPVPCEstimator
    from lpvpc.models.intrinsic import intrinsic_regressor, two_sided_lags
    from lpvpc.models.reflex import reflex_input_regressor
    from lpvpc.identification.subspace import hankel_rows

    data = load_identification_data(pt=pt, ut=ut)
    t_load = time.perf_counter() - t0
    est = LPVPCEstimator()
    p, y, rho, fs = data.position, data.torque, data.scheduling, data.fs
    dvel = eq.delayed_velocity(p, fs, int(round(est.reflex_delay * fs)))
    Psi_i = intrinsic_regressor(p, basis_from_data(rho, est.basis, est.intrinsic_order).evaluate(rho),
                                two_sided_lags(est.resolved_lags(fs)))
    U_r = reflex_input_regressor(basis_from_data(dvel, est.velocity_basis, est.velocity_order, "linear").evaluate(dvel),
                                 basis_from_data(rho, est.basis, est.reflex_order).evaluate(rho))
    s = est.horizon
    H = hankel_rows(np.hstack([U_r, Psi_i]), U_r, y, 0, len(y) - 2 * s + 1, s)
    t = time.perf_counter()
    np.linalg.lstsq(H[:, :-1], H[:, -1], rcond=None)
    t_solve = time.perf_counter() - t
    print(json.dumps({"shape": list(H.shape), "load_s": t_load, "solve_s": t_solve,
                      "total_s": time.perf_counter() - t0}))


def _timed_process(args) -> dict:
    """Wall time (s), peak resident memory (MB) and stdout of a fresh process under /usr/bin/time -v."""
    t = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-v", *args], capture_output=True, text=True,
                         env={**os.environ, "PYTHONWARNINGS": "ignore"})
    wall = time.perf_counter() - t
    if out.returncode != 0:
        raise RuntimeError(f"{args[:3]} failed: {out.stderr.strip().splitlines()[-3:]}")
    rss = next(float(line.split()[-1]) for line in out.stderr.splitlines() if "Maximum resident" in line)
    return {"wall_s": wall, "peak_mb": rss / 1024, "stdout": out.stdout}


def long_records(minutes=(2, 30)) -> list:
    """Issue 22's floor: the whole identify process against load + bare lstsq of the
    seed-sized regressor from the same files, and its peak memory (< 1 GB at 30 minutes)."""
    import tempfile

    from lpvpc.io import write_trial_csv
    from lpvpc.simulation.simulate import simulate_pair

    lpvpc_cli = str(Path(sys.executable).parent / "lpvpc")
    lines = ["# Long records (issue 22): whole `lpvpc identify` process against the bare-LS floor "
             "(python benchmarks/bench_identify.py --long)", "",
             "| record | structure | samples | identify process (s) | its peak RSS (MB) | floor process: load + lstsq "
             "of the seed-sized regressor (s) | its lstsq alone (s) | regressor | ratio (floor 3x) | VAF (%) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m in minutes:
        with tempfile.TemporaryDirectory() as tmp:
            pair = simulate_pair("multilevel", seed=0, duration=60 * m, fs_out=100.0)
            files = [str(Path(tmp) / f"{k}.csv") for k in ("PT", "UT")]
            for trial, path in zip((pair.pt, pair.ut), files):
                write_trial_csv(trial, path)
            del pair
            model = str(Path(tmp) / "model.json")
            floor = _timed_process([sys.executable, __file__, "--bare-ls", *files])
            f = json.loads(floor["stdout"].strip().splitlines()[-1])
            for structure in ("fixed", "default (cv)"):  # the floor between them: load changes hit both alike
                ident = _timed_process([lpvpc_cli, "identify", "--pt", files[0], "--ut", files[1], "-o", model,
                                        *(["--structure", "fixed"] if structure == "fixed" else [])])
                fit = json.loads(Path(model).read_text())["fit"]
                lines.append(f"| {m} min | {structure} | {fit['n_samples']} | {ident['wall_s']:.2f} | "
                             f"{ident['peak_mb']:.0f} | {floor['wall_s']:.2f} | {f['solve_s']:.2f} | {f['shape'][0]} x "
                             f"{f['shape'][1] - 1} | {ident['wall_s'] / floor['wall_s']:.2f}x | {fit['vaf']:.2f} |")
    return lines


def main():
    if len(sys.argv) > 3 and sys.argv[1] == "--bare-ls":
        bare_ls(sys.argv[2], sys.argv[3])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--long":
        load_before = os.getloadavg()
        lines = long_records()
        lines += ["", f"Conditions: {os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS="
                      f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, 1-minute load average {load_before[0]:.1f} "
                      f"at the start and {os.getloadavg()[0]:.1f} at the end (ratios are from one run)"]
        write_results("identify_long.txt", lines, echo=True)
        return
    if len(sys.argv) > 3 and sys.argv[1] == "--one":
        one_length(sys.argv[2], sys.argv[3])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--library-time":
        _library_identify_time()
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--floor":
        load_before = os.getloadavg()
        lines = speed_floor() + blas_threads()
        lines.append(f"Conditions: {os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
                     f"1-minute load average {load_before[0]:.1f} at the start and {os.getloadavg()[0]:.1f} at the end "
                     "(this process counts as 1; ratios are from one run, so load affects both sides)")
        write_results("identify_floor.txt", lines, echo=True)
        return
    from lpvpc.identification.identify import identify

    lines = ["# Identification speed and memory (python benchmarks/bench_identify.py)", ""]
    load_before = os.getloadavg()
    data = subject_data(120.0)
    runs = []
    for _ in range(3):
        t = time.perf_counter()
        m = identify(data)
        runs.append((time.perf_counter() - t, m.fit["timings_s"]))
    runs.sort(key=lambda r: r[0])
    med, timings = runs[1]
    lines.append(f"2-minute record (N = {data.n}, 100 Hz): median {med:.2f} s of 3 runs; stages of that run: "
                 + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    lines.append("")
    lines.append("| record | samples | identify time (s) | time per 1k samples (ms) | RSS after loading (MB) "
                 "| peak RSS, load + identify (MB) |")
    lines.append("|---|---|---|---|---|---|")
    import tempfile

    from lpvpc.io import write_trial_csv
    from lpvpc.simulation.simulate import simulate_pair

    for minutes in (2, 7.5, 15, 30):
        with tempfile.TemporaryDirectory() as tmp:
            pair = simulate_pair("multilevel", seed=0, duration=60 * minutes, fs_out=100.0)
            files = [str(Path(tmp) / f"{k}.csv") for k in ("PT", "UT")]
            for trial, path in zip((pair.pt, pair.ut), files):
                write_trial_csv(trial, path)
            del pair
            out = subprocess.run([sys.executable, __file__, "--one", *files], capture_output=True, text=True,
                                 env={**os.environ, "PYTHONWARNINGS": "ignore"})
        if out.returncode != 0:
            lines.append(f"| {minutes} min | failed: {out.stderr.strip().splitlines()[-1]} |")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        lines.append(f"| {minutes} min | {r['n']} | {r['time_s']:.2f} | {1000 * r['time_s'] / (r['n'] / 1000):.1f} "
                     f"| {r['rss_before_identify_mb']:.0f} | {r['peak_rss_mb']:.0f} |")
    lines.append("")
    pc = projection_comparison()
    lines.append(f"Projection (27)-(28) at N = {pc['n']}: lpvpc {1000 * pc['t_lpvpc_s']:.1f} ms, literal pinv formula "
                 f"{pc['t_pinv_s']:.2f} s, ratio {pc['ratio']:.0f}x, max relative difference {pc['max_rel_diff']:.1e}")
    lines += [""] + speed_floor() + blas_threads()
    # Timings depend on what else runs on the machine: record the conditions with them.
    lines += ["", f"Conditions: {os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
                  f"1-minute load average {load_before[0]:.1f} at the start and {os.getloadavg()[0]:.1f} at the end "
                  "(this process counts as 1)"]
    write_results("identify.txt", lines, echo=True)


if __name__ == "__main__":
    main()
