"""Benchmark of the model export (lpvpc.export.exporter): export time, FMU stepping speed, CasADi
whole-trajectory evaluation against the numpy prediction, and instantiate/reset/free cycles.

    python benchmarks/bench_export.py [--model model.json] [--repeats 5] [--cycles 2000]

Without ``--model`` it identifies a model from the virtual subject (seed 0, 2-minute
multilevel record at 100 Hz, 12,000 samples) and replays that record. Prints a table and
writes it to ``benchmarks/results/export.txt``. Machines are shared and noisy: compare
the ratios within one run, not absolute times across runs. Units: s, steps/s, MB.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import casadi as ca  # noqa: E402
import fmpy  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402

import lpvpc  # noqa: E402
from lpvpc.export import exporter as ex  # noqa: E402
from lpvpc.models.model import LPVPCModel, vaf  # noqa: E402
from _results import write_results  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "export.txt"


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def model_and_record(model_path):
    from lpvpc.io import pair_trials
    from lpvpc.identification.identify import identify
    from lpvpc.simulation.simulate import simulate_pair

    data = pair_trials(*(lambda p: (p.pt, p.ut))(simulate_pair("multilevel", seed=0)))
    if model_path:
        return LPVPCModel.load(model_path), data, 0.0
    t0 = time.perf_counter()
    model = identify(data)
    return model, data, time.perf_counter() - t0


class Slave:
    def __init__(self, path, unzipdir, name="bench"):
        md = read_model_description(path)
        self.fmi = 2 if md.fmiVersion.startswith("2") else 3
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        cls = FMU2Slave if self.fmi == 2 else FMU3Slave
        self.s = cls(guid=md.guid, unzipDirectory=str(unzipdir), modelIdentifier=md.coSimulation.modelIdentifier,
                     instanceName=name)
        self.set = None

    def instantiate(self):
        self.s.instantiate()
        if self.fmi == 2:
            self.set, self.get = self.s.setReal, self.s.getReal
        else:
            self.set, self.get = self.s.setFloat64, self.s.getFloat64

    def init(self):
        if self.fmi == 2:
            self.s.setupExperiment(startTime=0.0)
            self.s.enterInitializationMode()
        else:
            self.s.enterInitializationMode(startTime=0.0)
        self.s.exitInitializationMode()


def bench_fmu(model, data, path, unzipdir, variant):
    """(plain doStep loop steps/s, record replay s, record steps/s, rel. error)."""
    n, h = data.n, 1.0 / model.fs
    sl = Slave(path, unzipdir)
    sl.instantiate()
    sl.init()
    t0 = time.perf_counter()
    for k in range(n):
        sl.s.doStep(k * h, h)
    plain = n / (time.perf_counter() - t0)
    sl.s.reset()
    sl.init()
    rows = {k: v.ravel() for k, v in ex.replay_inputs(model, data.position, data.scheduling, variant).items()}
    ins = [sl.vr[k] for k in rows]
    U = np.column_stack(list(rows.values())).tolist()
    out = [sl.vr["torque"]]
    y = np.empty(n)
    t0 = time.perf_counter()
    for k in range(n):
        sl.set(ins, U[k])
        y[k] = sl.get(out)[0]
        sl.s.doStep(k * h, h)
    record = time.perf_counter() - t0
    sl.s.terminate()
    sl.s.freeInstance()
    ref = model.predict(data.position, data.scheduling, causal=variant == "causal", warn=False).total
    lat = ex.latency_samples(model, variant)
    err = np.max(np.abs(y[lat:] - ref[: n - lat])) / np.max(np.abs(ref))
    return plain, record, n / record, err, y


def bench_cycles(path, unzipdir, cycles):
    """RSS before/after ``cycles`` cycles of: load + instantiate, (initialize, 10 steps,
    reset) x 2, free (fmpy's freeInstance also unloads the library)."""
    h = float(read_model_description(path).defaultExperiment.stepSize)

    def one():
        sl = Slave(path, unzipdir)
        sl.instantiate()
        for _ in range(2):
            sl.init()
            for k in range(10):
                sl.s.doStep(k * h, h)
            sl.s.reset()
        sl.s.freeInstance()

    for _ in range(50):  # warm up the allocator
        one()
    gc.collect()
    before = rss_mb()
    t0 = time.perf_counter()
    for _ in range(cycles):
        one()
    elapsed = time.perf_counter() - t0
    gc.collect()
    return before, rss_mb(), elapsed


def compiled_mapaccum(traj, folder):
    """The mapaccum as C, compiled with gcc and loaded back with casadi.external."""
    t0 = time.perf_counter()
    c_file = traj.generate(f"{traj.name()}.c", {"with_header": False})
    shutil.move(c_file, folder / c_file)
    lib = folder / f"{traj.name()}.so"
    subprocess.run(["gcc", "-O2", "-shared", "-fPIC", str(folder / c_file), "-o", str(lib), "-lm"], check=True)
    f = ca.external(traj.name(), str(lib))
    return f, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", help="model JSON (default: identify one from the virtual subject)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)

    model, data, t_ident = model_and_record(args.model)
    n = data.n
    lines = []

    def header(text):
        lines.append(text)
        print(text, flush=True)

    def row(label, value, note=""):
        lines.append(f"{label:<58} {value:>14} {note}")
        print(lines[-1], flush=True)

    lines += [
        "lpvpc export benchmark (benchmarks/bench_export.py)",
        f"date {time.strftime('%Y-%m-%d %H:%M')}, {platform.platform()}, {os.cpu_count()} CPUs, python "
        f"{platform.python_version()}, numpy {np.__version__}, casadi {ca.__version__}, fmpy {fmpy.__version__}, "
        f"lpvpc {lpvpc.__version__}",
        f"model: {args.model or 'identified from the virtual subject (seed 0)'}"
        + (f" in {t_ident:.1f} s" if t_ident else "")
        + f"; record {n} samples at {model.fs:g} Hz ({n / model.fs:.0f} s); lags {model.lags[0]}..{model.lags[-1]}, "
        f"causal lags 0..{model.causal_lags[-1]}, delay {model.delay}, reflex order {model.state_order}",
        f"median of {args.repeats} repeats where repeated; shared machine: compare ratios within this run",
        "",
    ]
    print("\n".join(lines), flush=True)

    with tempfile.TemporaryDirectory(prefix="bench-export-") as tmp:
        tmp = Path(tmp)
        # ---- export time
        header("Export time (s)")
        fmus = {}
        for variant, fmi in (("causal", 2), ("causal", 3), ("exact", 2)):
            runs = []
            for r in range(args.repeats):
                t = {}
                path = ex.export_fmu(model, tmp / f"{variant}_{fmi}_{r}.fmu", fmi_version=fmi, variant=variant,
                                     timings=t)
                runs.append(t)
            fmus[(variant, fmi)] = path
            med = {k: statistics.median(t[k] for t in runs) for k in ("codegen", "compile", "total")}
            row(f"  FMU {variant} FMI {fmi}: codegen / gcc compile / total",
                f"{med['codegen']:.3f} / {med['compile']:.3f} / {med['total']:.3f}")
        t_cas = median_time(lambda: ex.export_casadi(model, tmp / "model.casadi"), args.repeats)
        row("  .casadi (causal step, Function.save)", f"{t_cas:.3f}",
            f"({(tmp / 'model.casadi').stat().st_size / 1024:.0f} kB)")

        # ---- FMU stepping
        header("")
        header(f"FMU stepping in a plain fmpy loop (FMU2Slave/FMU3Slave), {n} steps")
        replays = {}
        for key, path in fmus.items():
            unz = extract(path, unzipdir=tmp / f"x_{key[0]}_{key[1]}")
            plain, record, rate, err, y = bench_fmu(model, data, path, unz, key[0])
            replays[key] = y
            row(f"  {key[0]} FMI {key[1]}: doStep only", f"{plain:,.0f}", "steps/s")
            row(f"  {key[0]} FMI {key[1]}: 2-minute record (set, get, doStep)", f"{record:.3f} s",
                f"{rate:,.0f} steps/s, {n / model.fs / record:,.0f}x real time, max err/max |tq| {err:.1e}")
        offline = model.predict(data.position, data.scheduling, warn=False).total
        row("  VAF on this record: causal FMU / offline two-sided", f"{vaf(data.torque, replays[('causal', 2)]):.2f} / "
            f"{vaf(data.torque, offline):.2f}", "%")

        # ---- CasADi vs numpy
        header("")
        header(f"Whole-trajectory evaluation, {n} samples (s; ratio to numpy predict of the same variant)")
        for variant in ("causal", "exact"):
            causal = variant == "causal"
            t_np = median_time(lambda: model.predict(data.position, data.scheduling, causal=causal, warn=False),
                               args.repeats)
            step = ex.step_function(model, variant)
            t_build = median_time(lambda: ex.trajectory_function(step, n), args.repeats)
            traj = ex.trajectory_function(step, n)
            rows = ex.replay_inputs(model, data.position, data.scheduling, variant)
            x0 = np.zeros(step.size1_in("state"))
            t_vm = median_time(lambda: traj(state=x0, **rows), args.repeats)
            f_c, t_compile = compiled_mapaccum(traj, tmp)
            t_c = median_time(lambda: f_c(state=x0, **rows), args.repeats)
            out = np.asarray(f_c(state=x0, **rows)["torque"]).ravel()
            ref = model.predict(data.position, data.scheduling, causal=causal, warn=False).total
            lat = ex.latency_samples(model, variant)
            err = np.max(np.abs(out[lat:] - ref[: n - lat])) / np.max(np.abs(ref))
            row(f"  {variant}: numpy model.predict", f"{t_np:.4f}", "1.0x")
            row(f"  {variant}: CasADi mapaccum, SX virtual machine", f"{t_vm:.4f}", f"{t_vm / t_np:.1f}x "
                f"(building the mapaccum: {t_build:.4f} s)")
            row(f"  {variant}: CasADi mapaccum, compiled C (casadi.external)", f"{t_c:.4f}",
                f"{t_c / t_np:.1f}x (codegen + gcc once: {t_compile:.2f} s; max err/max |tq| {err:.1e})")
            if variant == "causal":
                args_k = [rows[k][0] for k in ex.input_names(variant)[1:]]

                def loop():
                    x = x0
                    for k in range(n):
                        x, *_ = step(x, *[a[k] for a in args_k])

                t_loop = median_time(loop, 1)
                row(f"  {variant}: Python loop calling the step", f"{t_loop:.3f}", f"{t_loop / t_np:.0f}x")

        # ---- instantiate/reset/free cycles
        header("")
        header(f"{args.cycles} cycles of load + instantiate, (initialize, 10 steps, reset) x 2, free + unload: "
                     "resident memory")
        for key in (("causal", 2), ("causal", 3)):
            unz = tmp / f"x_{key[0]}_{key[1]}"
            before, after, elapsed = bench_cycles(fmus[key], unz, args.cycles)
            row(f"  {key[0]} FMI {key[1]}: RSS before -> after (MB)", f"{before:.1f} -> {after:.1f}",
                f"(+{after - before:.2f} MB, {elapsed:.2f} s, {args.cycles / elapsed:,.0f} cycles/s)")

    write_results(Path(args.out), lines)


if __name__ == "__main__":
    main()
