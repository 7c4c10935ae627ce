"""The model FMUs over 120 s in masters nobody here wrote: OMSimulator 3.0 (its FMU API,
sample by sample and its own ``simulate`` loop) and fmpy driven with times built by adding
steps. Virtual subject of the README's quick start (identification seed 0, novel record
seed 1, repeated to 120 s).

For each model FMU (sampled, causal, exact; FMI 2 and 3): samples wrong (> 1e-9 N m after the
declared latency) and the largest error, for

- ``stepUntil(t_k+1)``: OMSimulator's FMU API, the call a user writes first;
- ``stepUntil(t_k+1 - tick/2)``: the call the guide gives for OMSimulator;
- ``simulate``: OMSimulator's loop to 120 s at the FMU's DefaultExperiment step, inputs held
  (it ends with a step that is a sliver off whole ticks): "ok" or its error;
- fmpy at 1 ms and 10 ms master steps, t += h, the last step clipped to the stop time
  (1 ms is a tenth of the causal and exact FMUs' tick: those steps end between grid points).

For each Model Exchange model FMU (FMI 2; OMSimulator does not load FMI 3 Model Exchange):

- ``ME stepUntil(t_k+1)``: OMSimulator's FMU API at its default step (the FMU's
  DefaultExperiment step, one sample), inputs of sample k set, ``stepUntil(t_k+1)``, read;
- ``ME h=T/10, stepUntil(t_k+T/2)``: the call the guide gives for the FMU API;
- ``ME table, default step`` / ``ME table, 1 ms``: OMSimulator's own loop (strongly coupled
  system) with the inputs from a CSV table, read at t_k + T/2;
- ``ME fmpy simulate_fmu``: fmpy's Model Exchange simulation (CVode).

For the two SSPs ``lpvpc validate`` writes (120 s of the novel record): OMSimulator at its
default step, 1 ms and 10 ms ("ok" or its error; for the portable set-up the model torque's
VAF against the measured torque, beside the harness's co-simulation), and fmpy's
``simulate_ssp`` at 1 ms and 10 ms.

Run: ``PYTHONPATH=../shared/tools/omsimulator/lib/x86_64-linux-gnu python
benchmarks/bench_foreign_masters.py`` (needs ``pip install lxml``). Results:
benchmarks/results/foreign_masters.txt.
"""

import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
from _results import write_results
from fmpy import extract

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fmu_helpers import FMUInstance, reference  # noqa: E402

from lpvpc import export as ex  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402

SECONDS = 120.0
TOL = 1e-9


def _count(y, ref, lat):
    e = np.abs(y[lat:] - ref[: len(ref) - lat])
    return int((e > TOL).sum()), float(e.max())


def _oms_step_until(OMS, path, inputs, T, tick, sampled, half):
    n = len(next(iter(inputs.values())))
    fmu = OMS.FMU(str(path), instanceName=f"b{uuid.uuid4().hex[:10]}")
    fmu.instantiate()
    fmu.setStopTime(n * T + 1.0)
    fmu.initialize()
    y = np.empty(n)
    for k in range(n):
        for name, v in inputs.items():
            fmu.setValue(name, float(v[k]))
        if not sampled:
            y[k] = fmu.getValue("torque")
        fmu.stepUntil((k + 1) * T - (tick / 2 if half else 0.0))
        if sampled:
            y[k] = fmu.getValue("torque")
    fmu.terminate()
    return y


def _oms_simulate(OMS, path):
    fmu = OMS.FMU(str(path), instanceName=f"s{uuid.uuid4().hex[:10]}")
    fmu.instantiate()
    fmu.setStopTime(SECONDS)
    fmu.initialize()
    fmu.setValue("position", 0.03)
    fmu.setValue("scheduling", -0.05)
    try:
        fmu.simulate()
        return "ok"
    except RuntimeError as exc:
        return f"error ({exc})"
    finally:
        fmu.terminate()


def _fmpy_added(path, unzipdir, inputs, T, h, sampled):
    inst = FMUInstance(path, unzipdir, "f", "cs").initialize()
    names = list(inputs)
    n = len(inputs[names[0]])
    ins, out = inst.refs(names), inst.refs(["torque"])
    per = int(round(T / h))
    y, t, j = np.empty(n), 0.0, 0
    try:
        for k in range(n):
            inst.set(ins, [float(inputs[q][k]) for q in names])
            if not sampled:
                y[k] = inst.get(out)[0]
            for _ in range(per):
                step = n * T - t if j == n * per - 1 else h
                inst.fmu.doStep(t, step)
                t += step
                j += 1
            if sampled:
                y[k] = inst.get(out)[0]
    except Exception:  # noqa: BLE001 - the row reports the FMU's refusal
        return None, [m for s, m in inst.log if s >= 2][-1:]
    return y, []


def main():
    lib = Path(os.environ.get("LPVPC_OMSIMULATOR", Path(__file__).resolve().parents[2] / "shared" / "tools"
                              / "omsimulator")) / "lib" / "x86_64-linux-gnu"
    sys.path.insert(0, str(lib))
    import OMSimulator as OMS

    work = Path(tempfile.mkdtemp())
    model = identify(_load(simulate_pair("multilevel", seed=0), work, "ident"))
    data = _load(simulate_pair("novel", seed=1), work, "novel")
    n = int(round(SECONDS * model.fs))
    reps = int(np.ceil(n / len(data.position)))
    pos, sch = np.tile(data.position, reps)[:n], np.tile(data.scheduling, reps)[:n]
    T = 1.0 / model.fs
    lines = [f"# {SECONDS:g} s per run, {n} samples at {model.fs:g} Hz; wrong = samples off by > 1e-9 N m "
             "after the declared latency", "",
             f"{'FMU':<16}{'master / call':<34}{'wrong':>8}{'max err N m':>14}  end"]
    os.chdir(work)  # OMSimulator writes result files into the working folder
    for kind in ("sampled", "causal", "exact"):
        for fmi in (2, 3):
            path = ex.export_fmu(model, work / f"{kind}{fmi}.fmu", fmi_version=fmi, variant=kind)
            unzipdir = extract(path, unzipdir=work / f"x{kind}{fmi}")
            inputs = {k: v.ravel() for k, v in ex.replay_inputs(model, pos, sch, kind).items()}
            ref = reference(model, pos, sch, kind)["torque"]
            lat, sampled = ex.latency_samples(model, kind), kind == "sampled"
            tick = T / ex.ticks_per_sample(model) if sampled else T
            name = f"{kind} FMI {fmi}"
            for label, half in (("OMSimulator stepUntil(t_k+1)", False), ("OMSimulator stepUntil(t_k+1-tick/2)", True)):
                t0 = time.perf_counter()
                try:
                    y = _oms_step_until(OMS, path, inputs, T, tick, sampled, half)
                    w, e = _count(y, ref, lat)
                    lines.append(f"{name:<16}{label:<34}{w:>8}{e:>14.3g}  ok ({time.perf_counter() - t0:.0f} s)")
                except RuntimeError as exc:
                    lines.append(f"{name:<16}{label:<34}{'-':>8}{'-':>14}  error ({exc})")
            lines.append(f"{name:<16}{'OMSimulator simulate (held)':<34}{'':>8}{'':>14}  {_oms_simulate(OMS, path)}")
            for h in (1e-3, 1e-2):
                y, err = _fmpy_added(path, unzipdir, inputs, T, h, sampled)
                label = f"fmpy t += {h * 1e3:g} ms"
                if y is None:
                    lines.append(f"{name:<16}{label:<34}{'-':>8}{'-':>14}  refused: {err[0] if err else ''}")
                else:
                    w, e = _count(y, ref, lat)
                    lines.append(f"{name:<16}{label:<34}{w:>8}{e:>14.3g}  ok")
            print(*lines[-5:], sep="\n", flush=True)
    for kind in ("sampled", "causal", "exact"):
        path = ex.export_fmu(model, work / f"me_{kind}2.fmu", fmi_version=2, variant=kind, fmi_type="me")
        inputs = {k: v.ravel() for k, v in ex.replay_inputs(model, pos, sch, kind).items()}
        ref = reference(model, pos, sch, kind)["torque"]
        lat = ex.latency_samples(model, kind)
        name = f"{kind} ME FMI 2"
        runs = [("ME stepUntil(t_k+1)", lambda: _oms_me_api(OMS, path, inputs, T, None, 0.0)),
                ("ME h=T/10, stepUntil(t_k+T/2)", lambda: _oms_me_api(OMS, path, inputs, T, T / 10, 0.5)),
                ("ME table, default step", lambda: _oms_me_table(OMS, path, inputs, T, work, None)),
                ("ME table, 1 ms", lambda: _oms_me_table(OMS, path, inputs, T, work, 1e-3)),
                ("ME fmpy simulate_fmu", lambda: _fmpy_me(path, inputs, T))]
        for label, run in runs:
            t0 = time.perf_counter()
            try:
                w, e = _count(run(), ref, lat)
                lines.append(f"{name:<17}{label:<33}{w:>8}{e:>14.3g}  ok ({time.perf_counter() - t0:.0f} s)")
            except (RuntimeError, AssertionError) as exc:
                lines.append(f"{name:<17}{label:<33}{'-':>8}{'-':>14}  error ({exc})")
        print(*lines[-len(runs):], sep="\n", flush=True)
    lines += ["", "# The SSPs lpvpc validate writes, 120 s of the novel record", ""]
    lines += _ssp_rows(OMS, model, work)
    print(*lines[-10:], sep="\n", flush=True)
    write_results(os.environ.get("BENCH_OUT") and Path(os.environ["BENCH_OUT"]) or "foreign_masters.txt", lines)


def _oms_me_api(OMS, path, inputs, T, max_step, half):
    """OMSimulator's FMU API on a Model Exchange FMU: inputs of sample k set, then
    ``stepUntil(t_k+1 - half T)``, torque read; ``max_step`` None keeps its default."""
    n = len(next(iter(inputs.values())))
    fmu = OMS.FMU(str(path), instanceName=f"e{uuid.uuid4().hex[:10]}")
    fmu.instantiate()
    fmu.setStopTime(n * T + 1.0)
    if max_step:
        fmu.setStepSize(max_step)
    fmu.initialize()
    y = np.empty(n)
    for k in range(n):
        for name, v in inputs.items():
            fmu.setValue(name, float(v[k]))
        fmu.stepUntil((k + 1 - half) * T)
        y[k] = fmu.getValue("torque")
    fmu.terminate()
    return y


def _oms_me_table(OMS, path, inputs, T, folder, max_step):
    """OMSimulator's own loop with the inputs from a CSV table (the test's helper)."""
    from test_foreign_masters import _oms_table_run

    return _oms_table_run(OMS, path, inputs, T, folder, max_step)


def _fmpy_me(path, inputs, T):
    import fmpy

    names = list(inputs)
    n = len(inputs[names[0]])
    t = np.arange(n) * T
    sig = np.array(list(zip(t, *[inputs[q] for q in names])), dtype=[("time", float)] + [(q, float) for q in names])
    res = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", input=sig, stop_time=t[-1], output_interval=T,
                            output=["torque"])
    return res["torque"][np.r_[res["time"][1:] != res["time"][:-1], True]]


def _ssp_rows(OMS, model, work):
    """validate on 120 s of the novel record; each SSP in OMSimulator (its own process: it keeps
    model names per process) and in fmpy's simulate_ssp."""
    import csv
    import subprocess

    from fmpy.ssp.simulation import simulate_ssp

    from lpvpc.io import Trial
    from lpvpc.models.model import vaf
    from lpvpc.validation import validate
    from lpvpc.validation.harness import load_record
    from test_foreign_masters import _RUN_SSP  # the test's OMSimulator SSP run, in its own process

    pair = simulate_pair("novel", seed=1)
    n = min(int(SECONDS * 1000), len(pair.pt.time))
    pt, ut = (Trial(t.time[:n], t.position[:n], t.torque[:n], {k: v[:n] for k, v in t.channels.items()},
                    name=t.name) for t in (pair.pt, pair.ut))
    res = validate(model, pt, ut, work / "report", measure_load_effect=False)
    meas = load_record(model, pt, ut).measured
    L, T = res.metrics["cosim"]["model_fmu_latency_samples"], 1.0 / model.fs
    rows = [f"record {n / 1000:g} s; harness co-simulation VAF {res.metrics['vaf_cosim']:.3f} %", "",
            f"{'SSP':<28}{'engine, step':<26}{'end':<8}{'VAF %':>8}{'run s':>8}"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if "omsimulator" in p)}
    for key in ("ssp", "portable_ssp"):
        ssp = res.files[key]
        for step in ("default", 1e-3, 1e-2):
            out = work / f"{key}_{step}.csv"
            t0 = time.perf_counter()
            run = subprocess.run([sys.executable, "-c", _RUN_SSP, str(ssp), str(step), str(out)], cwd=work, env=env,
                                 capture_output=True, text=True)
            dt = time.perf_counter() - t0
            ok = run.returncode == 0 and "error" not in (run.stdout + run.stderr).lower()
            got = ""
            if ok and key == "portable_ssp":
                with open(out) as f:
                    table = list(csv.reader(f))
                col = next(i for i, h in enumerate(table[0]) if h.endswith("model.torque"))
                t = np.array([float(r[0]) for r in table[1:]])
                y = np.array([float(r[col]) for r in table[1:]])
                idx = np.searchsorted(t, np.arange(meas.n + L) * T + 1e-9, side="right") - 1
                got = f"{vaf(meas.torque, y[idx][L:L + meas.n]):.3f}"
            label = f"OMSimulator {step if step == 'default' else f'{step * 1e3:g} ms'}"
            rows.append(f"{ssp.name:<28}{label:<26}{'ok' if ok else 'error':<8}{got:>8}{dt:>8.1f}")
        for step in (1e-3, 1e-2):
            t0 = time.perf_counter()
            try:
                simulate_ssp(str(ssp), stop_time=float(n) / 1000 if key == "ssp" else _stop(ssp), step_size=step)
                end = "ok"
            except Exception as exc:  # noqa: BLE001 - the row reports the failure
                end = f"error ({exc})"
            rows.append(f"{ssp.name:<28}{f'fmpy simulate_ssp {step * 1e3:g} ms':<26}{end:<8}{'':>8}"
                        f"{time.perf_counter() - t0:>8.1f}")
    return rows


def _stop(ssp):
    from lpvpc.validation.engines import ssp_steps

    return ssp_steps(ssp)[2]


def _load(pair, folder, stem):
    """The pair through the loaders a user's files go through (CSV at 1 kHz, decimated)."""
    from lpvpc.io import load_identification_data, write_trial_csv

    pt, ut = folder / f"{stem}_PT.csv", folder / f"{stem}_UT.csv"
    write_trial_csv(pair.pt, pt)
    write_trial_csv(pair.ut, ut)
    return load_identification_data(pt=pt, ut=ut)


if __name__ == "__main__":
    main()
