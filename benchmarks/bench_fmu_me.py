"""Model Exchange FMU benchmark: memory over 2000 instantiate/reset/free cycles, the event loop's
rate, and agreement with the numpy prediction under fmpy's own Model Exchange simulation.

Uses the model FMU exported with ``fmi_type="me"`` (causal variant, FMI 2 and FMI 3) of a model
identified on the virtual subject (seed 0, 2 min at 100 Hz), through fmpy's FMU2Model / FMU3Model:

- instance cycles: library loaded once; instantiate, initialize, 5 samples (set time and
  inputs, event mode, update, get, continuous-time mode), get/serialize/deserialize/free an FMU
  state, reset, initialize, 5 samples, terminate, free instance;
- event loop: the 2-minute novel record sample by sample from Python (set + event + get);
- fmpy.simulate_fmu(fmi_type="ModelExchange") on the novel record: largest difference from the
  numpy prediction relative to the torque's largest magnitude, and its wall time.

Prints a table and writes benchmarks/results/fmu_me.txt. Compare ratios within one run.

    python benchmarks/bench_fmu_me.py [--cycles 2000]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import fmpy  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Model  # noqa: E402
from fmpy.fmi3 import FMU3Model  # noqa: E402

from lpvpc.export import exporter as ex  # noqa: E402
from lpvpc.io import pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from _results import write_results  # noqa: E402


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def quiet(*args):
    pass


class Loop:
    def __init__(self, version, unzipdir, md, name):
        cls = FMU2Model if version == 2 else FMU3Model
        self.v = version
        self.m = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.modelExchange.modelIdentifier,
                     instanceName=name)
        if version == 2:
            self.m.instantiate()
            self.set, self.get, self.update = self.m.setReal, self.m.getReal, self.m.newDiscreteStates
        else:
            self.m.instantiate(logMessage=quiet)
            self.set, self.get, self.update = self.m.setFloat64, self.m.getFloat64, self.m.updateDiscreteStates
        vr = {v.name: v.valueReference for v in md.modelVariables}
        self.inputs = [vr[n] for n in ex.input_names()[1:]]
        self.out = [vr["torque"]]

    def init(self, u0):
        if self.v == 2:
            self.m.setupExperiment(startTime=0.0)
            self.m.enterInitializationMode()
        else:
            self.m.enterInitializationMode(startTime=0.0)
        self.set(self.inputs, list(u0))  # sampled at the start time when initialization ends
        self.m.exitInitializationMode()

    def run(self, U, h, y=None):
        for k in range(len(U)):
            if k:
                self.m.setTime(k * h)
                self.set(self.inputs, list(U[k]))
                self.m.enterEventMode()
            self.update()
            v = self.get(self.out)[0]
            if y is not None:
                y[k] = v
            self.m.enterContinuousTimeMode()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=2000)
    args = ap.parse_args(argv)
    ident, novel = simulate_pair("multilevel", seed=0), simulate_pair("novel", seed=1)
    model = identify(pair_trials(ident.pt, ident.ut))
    d = pair_trials(novel.pt, novel.ut)
    rows = ex.replay_inputs(model, d.position, d.scheduling, "causal")
    names = list(rows)
    U = np.column_stack([rows[n].ravel() for n in names])
    ref = model.predict(d.position, d.scheduling, causal=True, warn=False).total
    h = 1.0 / model.fs
    lines = [f"# Model Exchange FMU benchmark ({time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, "
             f"Python {platform.python_version()}, fmpy {fmpy.__version__}); causal model FMU, time event every "
             f"{h:g} s", ""]
    mem, rate, agree = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for v in (2, 3):
            path = ex.export_fmu(model, Path(tmp) / f"me{v}.fmu", fmi_version=v, fmi_type="me")
            md = read_model_description(str(path))
            unzipdir = extract(str(path), unzipdir=str(Path(tmp) / f"x{v}"))
            keeper = Loop(v, unzipdir, md, "keeper")
            free = "fmi2FreeInstance" if v == 2 else "fmi3FreeInstance"

            def one(k):
                s = Loop(v, unzipdir, md, f"c{k}")
                s.init(U[0])
                s.run(U[:5], h)
                st = s.m.getFMUState()
                st2 = s.m.deserializeFMUState(s.m.serializeFMUState(st))
                s.m.freeFMUState(st)
                s.m.freeFMUState(st2)
                s.m.reset()
                s.init(U[0])
                s.run(U[:5], h)
                s.m.terminate()
                getattr(s.m, free)(s.m.component)
                s.m.freeLibrary()

            for k in range(50):
                one(k)
            start, marks = rss_mb(), []
            t0 = time.perf_counter()
            for k in range(args.cycles):
                one(k)
                if (k + 1) % (args.cycles // 4) == 0:
                    marks.append(rss_mb())
            dt = time.perf_counter() - t0
            keeper.m.freeInstance()
            mem.append(f"{v:>4} {start:8.2f} " + " ".join(f"{m:8.2f}" for m in marks) +
                       f" {marks[-1] - start:+8.2f} {1000 * dt / args.cycles:9.3f}")

            s = Loop(v, unzipdir, md, "rate")
            s.init(U[0])
            y = np.empty(len(U))
            t0 = time.perf_counter()
            s.run(U, h, y)
            dt = time.perf_counter() - t0
            s.m.freeInstance()
            err_loop = np.max(np.abs(y - ref)) / np.max(np.abs(ref))
            rate.append(f"{v:>4} {len(U):>8} {len(U) / dt:10.0f} {dt:7.3f} {err_loop:10.1e}")

            t = np.arange(len(U)) * h
            sig = np.array([tuple([t[k], *U[k]]) for k in range(len(U))],
                           dtype=[("time", float)] + [(n, float) for n in names])
            t0 = time.perf_counter()
            res = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", input=sig, stop_time=t[-1],
                                    output_interval=h, output=["torque"])
            dt = time.perf_counter() - t0
            last = np.r_[res["time"][1:] != res["time"][:-1], True]
            err = np.max(np.abs(res["torque"][last] - ref)) / np.max(np.abs(ref))
            agree.append(f"{v:>4} {err:10.1e} {dt:7.2f}")
    lines += [f"## Memory: {args.cycles} cycles (after 50 warm-up cycles); RSS in MB",
              " FMI    start      25%      50%      75%     100%   growth  ms/cycle", *mem, "",
              "## Event loop from Python (setTime, set inputs, enterEventMode, update, get, continuous mode)",
              " FMI  samples  samples/s       s  vs numpy", *rate, "",
              "## fmpy.simulate_fmu(fmi_type='ModelExchange') on the 2-minute novel record",
              " FMI  vs numpy  wall s", *agree, "",
              f"{platform.platform()}, load average {os.getloadavg()[0]:.1f}"]
    write_results("fmu_me.txt", lines, echo=True)


if __name__ == "__main__":
    main()
