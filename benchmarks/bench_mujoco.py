"""The closed-loop ankle model in MuJoCo (examples/mujoco_exoskeleton.py): real-time factor.

The example's loop (a foot hinge, device 0.01 kg m^2 + the model's declared inertia, PD
exoskeleton Kd 0.5 N m s/rad with the model's quasi-static torque as feed-forward, the
multi-level reference with +-0.02 rad steps, MuJoCo's Euler step 1 ms = the model's tick),
20 s, Kp 40 and 150 N m/rad, the ankle torque from the CasADi tick function (called from
Python) and from the FMI 2 co-simulation FMU (fmpy's FMU2Slave). Model: the example's default
(60 s of the virtual subject, seed 0). Each run is repeated and the fastest kept (the machine is
shared); the real-time factor is simulated seconds per wall second of the loop alone (model
fitting and FMU export not counted). Beside it: the same loop with no ankle (MuJoCo and the
controller only), the loop's own cost; and the largest difference between the two sources.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_mujoco.py [--duration 20] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import runpy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _results import write_results  # noqa: E402

EXAMPLE = HERE.parent / "examples" / "mujoco_exoskeleton.py"


class NoAnkle:
    """A torque source of zero: the loop's cost without the ankle model."""

    name = "none"

    def __init__(self, tick):
        self.tick = tick

    def torque(self, angle, velocity):
        return 0.0

    def advance(self, n_ticks):
        pass

    def close(self):
        pass


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)

    import fmpy
    import mujoco

    from lpvpc.export.closed_loop import export_closed_loop_fmu
    from lpvpc.simulation.compliant_loop import reference_trajectory

    ex = runpy.run_path(str(EXAMPLE))
    cl = ex["closed_loop_model"]()
    tick = ex["model_tick"](cl)
    physics = mujoco.MjModel.from_xml_string(ex["foot_mjcf"](cl.inertia))
    n = int(round(args.duration / tick))
    reference = reference_trajectory(n * tick, 0)[:n]
    feedforward = cl.whole.quasi_static(reference)
    rows, runs = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        fmu = export_closed_loop_fmu(cl, Path(tmp) / "ankle.fmu")
        for kp in (40.0, 150.0):
            for source in ("casadi", "fmu", "none"):
                walls = []
                for _ in range(args.repeat):
                    ankle = {"casadi": lambda: ex["CasadiAnkle"](cl), "fmu": lambda: ex["FmuAnkle"](fmu, reference[0]),
                             "none": lambda: NoAnkle(tick)}[source]()
                    try:
                        r = ex["run"](physics, ankle, reference, kp, feedforward=feedforward)
                    finally:
                        ankle.close()
                    walls.append(r["wall"])
                r["wall"] = min(walls)
                runs[(kp, source)] = r
                s = ex["summary"](r, tick)
                rows.append((kp, source, s, min(walls), max(walls)))
    lines = [f"# MuJoCo loop with the closed-loop ankle model ({time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, "
             f"Python {platform.python_version()}, MuJoCo {mujoco.__version__}, fmpy {fmpy.__version__})",
             f"# {args.duration:g} s at a {tick * 1e3:g} ms step (MuJoCo and the model's tick), fastest of "
             f"{args.repeat} runs; model: the example's default (virtual subject, 60 s, seed 0), "
             f"inertia {cl.inertia:.4f} kg m^2 + device {ex['DEVICE_INERTIA']} kg m^2",
             "",
             "  Kp  source   stable  RMS error (mrad)  max (mrad)  real time x  ms per simulated s  us per step  "
             "slowest run (s)"]
    for kp, source, s, best, worst in rows:
        label = {"casadi": "CasADi", "fmu": "FMU", "none": "no ankle"}[source]
        track = (f"{str(s['stable']):6s}  {1e3 * s['rms_error']:16.2f}  {1e3 * s['max_error']:10.2f}"
                 if source != "none" else f"{'-':6s}  {'-':>16s}  {'-':>10s}")  # no ankle: no tracking to score
        lines.append(f"{kp:4.0f}  {label:8s} {track}  {s['realtime_factor']:11.1f}  "
                     f"{1e3 * best / args.duration:18.2f}  {1e6 * best / n:11.1f}  {worst:15.3f}")
    lines.append("")
    for kp in (40.0, 150.0):
        a, b = runs[(kp, "casadi")], runs[(kp, "fmu")]
        lines.append(f"Kp {kp:g}: CasADi tick against the FMU: torque max |diff| "
                     f"{np.max(np.abs(a['torque'] - b['torque'])):.1e} N m, angle {np.max(np.abs(a['angle'] - b['angle'])):.1e} rad")
    lines.append("")
    lines.append(f"{platform.platform()}, load average {os.getloadavg()[0]:.1f}")
    write_results("mujoco.txt", lines, echo=True)


if __name__ == "__main__":
    main()
