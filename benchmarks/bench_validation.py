"""Benchmark of the validation harness (package ``validation``): co-simulation speed of a
2-minute record (actuator FMU at 1 kHz, model FMU at 100 Hz) as a real-time factor, the
accuracy of each coupling choice, and the time to generate the report.

    python benchmarks/bench_validation.py [--repeats 3]

Simulates the virtual subject (seed 0, 2-minute identification and novel records at
1 kHz), identifies a model, exports its FMU (FMI 2 and 3) and builds the actuator FMU,
then co-simulates the novel record. Prints a table and writes it to
``benchmarks/results/validation.txt``. Machines are shared and noisy: compare ratios
within one run. Units: s, x real time, VAF %, mrad.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import casadi  # noqa: E402
import fmpy  # noqa: E402

import lpvpc  # noqa: E402
from lpvpc.export.actuator import build_actuator_fmu  # noqa: E402
from lpvpc.io import Trial, decimate_trial, load_identification_data, load_trial, pair_trials  # noqa: E402
from lpvpc.errors import FMUError, OutOfRangeWarning  # noqa: E402
from lpvpc.export.exporter import export_fmu, latency_samples  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import write_dataset  # noqa: E402
from lpvpc.validation import CosimSettings, validate  # noqa: E402
from lpvpc.validation.cosim import run_cosimulation  # noqa: E402
from lpvpc.validation.fmu import inspect_fmu  # noqa: E402
from lpvpc.validation.harness import actuator_drive, check_actuator_fmu, load_record  # noqa: E402
from _results import write_results  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "validation.txt"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="repeats of the default co-simulation (median)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore", OutOfRangeWarning)
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    def row(label, value, note=""):
        say(f"  {label:<58} {value:>14} {note}")

    tmp = Path(tempfile.mkdtemp(prefix="bench-validation-"))
    t0 = time.perf_counter()
    paths = write_dataset(tmp / "data", seed=0, fs_out=1000.0)
    model = identify(load_identification_data(pt=paths["ident_PT"], ut=paths["ident_UT"]))
    model.save(tmp / "model.json")
    fmus = {v: inspect_fmu(export_fmu(model, tmp / f"model{v}.fmu", fmi_version=v)) for v in (2, 3)}
    acts = {v: inspect_fmu(build_actuator_fmu(tmp / f"actuator{v}.fmu", fmi_version=v)) for v in (2, 3)}
    exact = inspect_fmu(export_fmu(model, tmp / "model_exact2.fmu", fmi_version=2, variant="exact"))
    lat = latency_samples(model, "exact")
    t_setup = time.perf_counter() - t0

    record = load_record(model, paths["novel_PT"], paths["novel_UT"])
    meas = record.measured
    z = np.load(paths["truth_novel"])
    clean = pair_trials(Trial(z["time"], z["pt_position"], z["pt_torque_clean"]),
                        Trial(z["time"], z["ut_position"], z["ut_torque_clean"]), target_fs=model.fs)
    ceiling = vaf(meas.torque, clean.torque)
    ratio = check_actuator_fmu(acts[2], model, {})
    drive, params, cal = actuator_drive(record, acts[2], ratio, meas.n, {}, calibrate=True)
    duration = meas.n / meas.fs

    say("lpvpc validation benchmark (benchmarks/bench_validation.py)")
    say(f"date {time.strftime('%Y-%m-%d %H:%M')}, {platform.platform()}, {os.cpu_count()} CPUs, python "
        f"{platform.python_version()}, numpy {np.__version__}, casadi {casadi.__version__}, fmpy {fmpy.__version__}, "
        f"lpvpc {lpvpc.__version__}")
    say(f"virtual subject seed 0: novel record {duration:.0f} s at 1 kHz -> {meas.n} model samples at "
        f"{model.fs:g} Hz; actuator step {drive.step * 1e3:g} ms ({meas.n * ratio} steps per actuator run, two runs); "
        f"set-up (simulate, identify, export) {t_setup:.1f} s")
    say(f"servo calibrated on the record: {cal['servo_bandwidth']:.3f} Hz, damping {cal['servo_damping']:.4f} "
        f"(fit VAF {cal['vaf']:.4f} %, {cal['seconds']:.2f} s); actuator FMU defaults 40 Hz, 0.7")
    say(f"noise ceiling {ceiling:.2f} %; offline two-sided VAF "
        f"{vaf(meas.torque, model.predict(meas.position, meas.scheduling).total):.2f} %, causal (= FMU replay) "
        f"{vaf(meas.torque, model.predict(meas.position, meas.scheduling, causal=True).total):.2f} %")
    say("shared machine: compare ratios within this run")
    say()

    say(f"Co-simulation of the {duration:.0f}-s record, FMI 2, causal model FMU (stepping loop only; median of "
        f"{args.repeats})")
    default = CosimSettings()
    runs = []
    for _ in range(args.repeats):
        runs.append(run_cosimulation(fmus[2], acts[2], drive, settings=default, actuator_parameters=params))
    res = runs[int(np.argsort([r.elapsed for r in runs])[len(runs) // 2])]
    el = statistics.median(r.elapsed for r in runs)
    row("default (iterate, central differences, 1 kHz command, loaded)", f"{el:.2f} s",
        f"{duration / el:,.0f}x real time; VAF {vaf(meas.torque, res.torque):.2f} %; "
        f"iterations mean {res.iterations.mean():.2f}, max {res.iterations.max()}")
    steps = meas.n * ratio * (1 + res.iterations.mean()) + meas.n  # UT, PT (per iteration), model
    row("  FMU doStep calls per second (UT + PT incl. iterations + model)", f"{steps / el:,.0f}")

    def variant(label, **kw):
        s = replace(default, **kw)
        try:
            r = run_cosimulation(fmus[2], acts[2], drive, settings=s, actuator_parameters=params)
        except FMUError as exc:
            row(label, "FAILED", f"{' '.join(str(exc).split())[:170]}")
            return None
        p = r.pt[:, 0] - r.ut[:, 0]
        row(label, f"{r.elapsed:.2f} s", f"{duration / r.elapsed:,.0f}x real time; VAF {vaf(meas.torque, r.torque):.2f} %"
            + (f"; iterations mean {r.iterations.mean():.2f}" if s.coupling == "iterate" and s.load != "none" else ""))
        return r, p

    base_p = res.pt[:, 0] - res.ut[:, 0]
    variant("coupling delay (load torque one model step late)", coupling="delay")
    out = variant("no load torque on either actuator", load="none")
    if out:
        row("  load effect on the perturbation position", f"{1e3 * np.max(np.abs(base_p - out[1])):.3f} mrad",
            f"max; RMS {1e3 * np.sqrt(np.mean((base_p - out[1]) ** 2)):.3f} mrad")
    variant("UT unloaded, PT loaded by the model torque only", load="model")
    variant("command held over each 10 ms model step", command_rate="hold")
    variant("model fed the actuators' own velocity/acceleration (delay)", derivatives="actuator", coupling="delay")
    variant("  the same, iterated", derivatives="actuator", max_iterations=50)
    drive_bl, _, _ = actuator_drive(record, acts[2], ratio, meas.n, {}, calibrate=True, band_limit_to=model.fs)
    rb = run_cosimulation(fmus[2], acts[2], drive_bl, settings=default, actuator_parameters=params)
    row("command band-limited (zero-phase) to the model's band", f"{rb.elapsed:.2f} s",
        f"{duration / rb.elapsed:,.0f}x real time; VAF {vaf(meas.torque, rb.torque):.2f} %")
    for label, drv in (("exact model FMU, command band-limited (the validation default)", drive_bl),
                       ("exact model FMU, full-band command", drive)):
        rx = run_cosimulation(exact, acts[2], drv, settings=default, actuator_parameters=params, latency=lat)
        row(label, f"{rx.elapsed:.2f} s", f"{duration / rx.elapsed:,.0f}x real time; VAF {vaf(meas.torque, rx.torque):.2f} %"
            f" (latency {lat} samples removed)")
    r0 = run_cosimulation(fmus[2], acts[2], drive, settings=default, actuator_parameters={})
    row("actuator at its defaults (40 Hz, not calibrated)", f"{r0.elapsed:.2f} s",
        f"VAF {vaf(meas.torque, r0.torque):.2f} %; perturbation tracking VAF "
        f"{vaf(meas.position, r0.model_inputs['position']):.2f} %")
    r3 = run_cosimulation(fmus[3], acts[3], drive, settings=default, actuator_parameters=params)
    row("FMI 3 (same default settings)", f"{r3.elapsed:.2f} s",
        f"{duration / r3.elapsed:,.0f}x real time; max |FMI 3 - FMI 2| torque {np.max(np.abs(r3.torque - res.torque)):.1e} N m")

    say()
    say("100 Hz record (the novel trials decimated to 100 Hz, command interpolated to 1 kHz)")
    low = [decimate_trial(load_trial(paths[k]), 100.0) for k in ("novel_PT", "novel_UT")]
    r100 = validate(model, low[0], low[1], tmp / "v100", fmu=exact.path, actuator_fmu=acts[2].path,
                    write_report=False, measure_load_effect=False)
    m = r100.metrics
    row("vaf / vaf_fmu / vaf_cosim", f"{m['vaf']:.2f}/{m['vaf_fmu']:.2f}/{m['vaf_cosim']:.2f}",
        f"servo calibrated {m['cosim']['calibration']['servo_bandwidth']:.2f} Hz")

    say()
    say("Whole validation run (lpvpc validate defaults: exact model FMU, band-limited command; checks, routes, "
        "co-simulation twice, report) on the 1 kHz record")
    t0 = time.perf_counter()
    r = validate(tmp / "model.json", paths["novel_PT"], paths["novel_UT"], tmp / "report", fmu=exact.path,
                 actuator_fmu=acts[2].path)
    total = time.perf_counter() - t0
    m = r.metrics
    tm = m["timing_s"]
    for key, label in (("load_and_check", "load model and record, check FMUs"),
                       ("offline_and_casadi", "numpy and CasADi routes"), ("fmu_replay", "FMU replay"),
                       ("calibration", "servo calibration"), ("cosim", "co-simulation"),
                       ("cosim_unloaded", "co-simulation without load (load effect)"),
                       ("report", "report generation (11 figures, HTML, base64)")):
        row(label, f"{tm.get(key, 0.0):.2f} s")
    row("total", f"{total:.2f} s", f"report.html {(tmp / 'report' / 'report.html').stat().st_size / 1e6:.2f} MB")
    row("vaf / vaf_fmu / vaf_cosim / vaf_actuator_replay",
        f"{m['vaf']:.2f}/{m['vaf_fmu']:.2f}/{m['vaf_cosim']:.2f}/{m['vaf_actuator_replay']:.2f}",
        f"ceiling {ceiling:.2f}")
    ag = m["route_agreement"]
    row("route agreement: CasADi causal / FMU exact / CasADi exact vs numpy",
        "/".join(f"{ag[k]['max_relative_difference']:.1e}" for k in ("casadi_vs_numpy_causal", "fmu_vs_numpy",
                                                                     "casadi_exact_vs_numpy")), "max|a-b|/max|b|")
    write_results(RESULTS, lines)


if __name__ == "__main__":
    main()
