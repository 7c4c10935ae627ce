"""FMU wrapper benchmark: memory over 2000 instantiate/reset/free cycles, build time, step rate.

Uses the actuator FMU (FMI 2 and FMI 3; the wrapper's direct mode) and the exported model
FMUs (sampled variant: the wrapper's sampled mode; exact: direct mode; the closed-loop form of
the whole-joint model, lpvpc.export.closed_loop: direct mode on a 1 ms tick; FMI 2 and 3) through fmpy's
FMU2Slave / FMU3Slave:

- instance cycles: library loaded once; instantiate, initialize, step, get/serialize/
  deserialize/free an FMU state, reset, initialize, step, terminate, free instance;
- load cycles: the same plus loading and unloading the shared library every cycle;
- build time: a fresh build of the FMU (generate, gcc, zip), median of 3;
- step rate: 120,000 internal steps (1 ms) driven at 10 ms and 1 ms communication steps from
  Python, and in one doStep of 120 s (the C cost alone).

Prints a table and writes benchmarks/results/fmu_cycles.txt. Timings are machine-dependent
(shared, noisy machines): compare ratios within one run.

    python benchmarks/bench_fmu_cycles.py [--cycles 2000]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import fmpy  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402

from lpvpc.export.actuator import build_actuator_fmu  # noqa: E402
from _results import write_results  # noqa: E402

CMD = 4  # the actuator's command; the model FMUs' position has the same value reference


def model_fmus(tmp: Path) -> dict:
    """{(variant, fmi): path} of the model FMUs of a model identified on the virtual subject."""
    from lpvpc.export import exporter as ex
    from lpvpc.io import load_identification_data, write_trial_csv
    from lpvpc.identification.identify import identify
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=0)
    write_trial_csv(pair.pt, tmp / "PT.csv")
    write_trial_csv(pair.ut, tmp / "UT.csv")
    model = identify(load_identification_data(pt=tmp / "PT.csv", ut=tmp / "UT.csv"))
    out = {(v, f): ex.export_fmu(model, tmp / f"model_{v}_{f}.fmu", fmi_version=f, variant=v)
           for v in ("sampled", "exact") for f in (2, 3)}
    from lpvpc.export.closed_loop import distillation_trial, export_closed_loop_fmu, fit_closed_loop
    from lpvpc.export.whole_joint import fit_whole_joint

    wj = fit_whole_joint(model, pair.ut)
    cl = fit_closed_loop(wj, [distillation_trial(wj, pair.ut)])
    out.update({("closed_loop", f): export_closed_loop_fmu(cl, tmp / f"closed_loop_{f}.fmu", f) for f in (2, 3)})
    return out


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def quiet(*args):
    pass


def make_slave(version, unzipdir, md, name):
    cls = FMU2Slave if version == 2 else FMU3Slave
    s = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName=name)
    if version == 2:
        s.instantiate()
    else:
        s.instantiate(logMessage=quiet)
    return s


def init(s, version):
    if version == 2:
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
    else:
        s.enterInitializationMode(startTime=0.0)
    s.exitInitializationMode()


def cycle_body(s, version, vr_in=CMD):
    init(s, version)
    (s.setReal if version == 2 else s.setFloat64)([vr_in], [0.1])
    s.doStep(0.0, 0.01)
    st = s.getFMUState()
    blob = s.serializeFMUState(st)
    st2 = s.deserializeFMUState(blob)
    s.freeFMUState(st)
    s.freeFMUState(st2)
    s.reset()
    init(s, version)
    s.doStep(0.0, 0.01)
    s.terminate()


def instance_cycles(version, unzipdir, md, n, vr_in=CMD):
    keeper = make_slave(version, unzipdir, md, "keeper")
    free = "fmi2FreeInstance" if version == 2 else "fmi3FreeInstance"

    def one(k):
        s = make_slave(version, unzipdir, md, f"c{k}")
        cycle_body(s, version, vr_in)
        getattr(s, free)(s.component)
        s.freeLibrary()

    return _measure(one, n, keeper)


def load_cycles(version, unzipdir, md, n):
    def one(k):
        s = make_slave(version, unzipdir, md, f"l{k}")
        cycle_body(s, version)
        s.freeInstance()  # frees the instance and unloads the library

    return _measure(one, n, None)


def _measure(one, n, keeper):
    for k in range(50):
        one(k)
    start = rss_mb()
    t0 = time.perf_counter()
    marks = []
    for k in range(n):
        one(k)
        if (k + 1) % (n // 4) == 0:
            marks.append(rss_mb())
    dt = time.perf_counter() - t0
    if keeper is not None:
        keeper.freeInstance()
    return start, marks, dt


def step_rates(version, unzipdir, md):
    rows = []
    for h in (0.01, 0.001):
        s = make_slave(version, unzipdir, md, "rate")
        init(s, version)
        setter = s.setReal if version == 2 else s.setFloat64
        getter = s.getReal if version == 2 else s.getFloat64
        n = round(120.0 / h)
        t, t0 = 0.0, time.perf_counter()
        for k in range(n):
            setter([CMD, 5], [0.1 if (k // 30) % 2 else -0.1, 1.0])
            s.doStep(t, h)
            t += h
            getter([1, 2, 3])
        dt = time.perf_counter() - t0
        rows.append((f"120 s record, h_c = {h * 1000:g} ms (set+doStep+get)", 120_000 / dt, n / dt, dt))
        s.freeInstance()
    s = make_slave(version, unzipdir, md, "rate")
    init(s, version)
    t0 = time.perf_counter()
    s.doStep(0.0, 120.0)
    dt = time.perf_counter() - t0
    rows.append(("120 s in one doStep (C only)", 120_000 / dt, 1 / dt, dt))
    s.freeInstance()
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=2000)
    args = ap.parse_args(argv)
    lines = [f"# FMU wrapper benchmark ({time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, "
             f"Python {platform.python_version()}, fmpy {fmpy.__version__})", ""]

    def out(s=""):
        print(s)
        lines.append(s)

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        out("## Build time (fresh build: generate + gcc + zip), median of 3")
        out(f"{'FMI':>4} {'total s':>8} {'compile s':>10}")
        paths = {}
        for v in (2, 3):
            totals, compiles = [], []
            for r in range(3):
                t = {}
                paths[v] = build_actuator_fmu(tmp / f"a{v}_{r}.fmu", fmi_version=v, timings=t)
                totals.append(t["total"])
                compiles.append(t["compile"])
            out(f"{v:>4} {statistics.median(totals):>8.3f} {statistics.median(compiles):>10.3f}")
        out()

        out(f"## Memory: {args.cycles} cycles (after 50 warm-up cycles); RSS in MB")
        out(f"{'FMI':>4} {'kind':<10} {'start':>8} {'25%':>8} {'50%':>8} {'75%':>8} {'100%':>8} "
            f"{'growth':>8} {'ms/cycle':>9}")
        for v in (2, 3):
            md = read_model_description(str(paths[v]))
            unzipdir = extract(str(paths[v]), unzipdir=str(tmp / f"u{v}"))
            for kind, fn in (("instance", instance_cycles), ("load", load_cycles)):
                start, marks, dt = fn(v, unzipdir, md, args.cycles)
                out(f"{v:>4} {kind:<10} {start:>8.2f} " + " ".join(f"{m:>8.2f}" for m in marks) +
                    f" {marks[-1] - start:>+8.2f} {1000 * dt / args.cycles:>9.3f}")
        out()

        out(f"## Memory, model FMUs (sampled: sampled mode; exact, closed_loop: direct): {args.cycles} instance cycles "
            f"(after 50 warm-up); RSS in MB")
        out(f"{'FMU':<14} {'start':>8} {'25%':>8} {'50%':>8} {'75%':>8} {'100%':>8} {'growth':>8} {'ms/cycle':>9}")
        for (variant, v), path in model_fmus(tmp).items():
            md = read_model_description(str(path))
            vr = {x.name: x.valueReference for x in md.modelVariables}
            vr_in = vr["angle"] if variant == "closed_loop" else vr["position"]
            unzipdir = extract(str(path), unzipdir=str(tmp / f"m_{variant}_{v}"))
            start, marks, dt = instance_cycles(v, unzipdir, md, args.cycles, vr_in)
            out(f"{variant + ' ' + str(v):<14} {start:>8.2f} " + " ".join(f"{m:>8.2f}" for m in marks) +
                f" {marks[-1] - start:>+8.2f} {1000 * dt / args.cycles:>9.3f}")
        out()

        out("## Step rate (actuator, 1 ms internal step)")
        out(f"{'FMI':>4} {'case':<46} {'internal/s':>12} {'doStep/s':>10} {'s':>7}")
        for v in (2, 3):
            md = read_model_description(str(paths[v]))
            unzipdir = str(tmp / f"u{v}")
            for case, internal, calls, dt in step_rates(v, unzipdir, md):
                out(f"{v:>4} {case:<46} {internal:>12,.0f} {calls:>10,.0f} {dt:>7.3f}")

    write_results("fmu_cycles.txt", lines)


if __name__ == "__main__":
    main()
