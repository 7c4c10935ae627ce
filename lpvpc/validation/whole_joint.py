"""Validation of the whole-joint model (:mod:`lpvpc.export.whole_joint`) on the held-out record.

The whole-joint model sees the PT trial's joint angle alone and predicts its total torque.
Measured here, at the model rate:

- ``vaf_total``: total torque of the PT trial;
- ``vaf_perturbation``: its own perturbation part, whole-joint(PT angle) minus
  whole-joint(UT angle), against the measured PT minus UT torque, next to
  ``vaf_two_input``: the LPV-PC model fed the measured split (PT minus UT position,
  UT position as scheduling);
- the CasADi step and the whole-joint FMU replaying the PT angle (manual master loop: input
  set, output read, step), each against the numpy prediction (max |a - b| / max |b|, over the
  samples whose torque the step has produced, its latency of L samples removed).

Units: rad, N m, percent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lpvpc.models.model import vaf

__all__ = ["evaluate_whole_joint", "fmu_replay"]


def _relative(a, b) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def fmu_replay(fmu_path, angle, latency: int, fs: float) -> tuple[np.ndarray, float]:
    """Total torque of a whole-joint FMU replaying ``angle`` (rad) with a manual master loop
    (input set, output read, step of 1/fs), ``latency`` held samples appended and removed:
    (torque aligned with ``angle``, steps per second)."""
    import time

    from .fmu import FMUError, FMUInstance, inspect_fmu

    x = np.concatenate([angle, np.full(latency, angle[-1])])
    y = np.empty(len(x))
    h = 1.0 / fs
    with FMUInstance(inspect_fmu(fmu_path, "whole-joint FMU"), "whole_joint") as inst:
        inst.initialize()
        u, out = inst.port(["angle"]), inst.port(["torque"])
        t0 = time.perf_counter()
        for k, a in enumerate(x):
            u.set([a])
            y[k] = out.get()[0]
            inst.do_step(k * h, h)
        rate = len(x) / (time.perf_counter() - t0)
    if latency and np.any(y[:latency] != 0.0):
        raise FMUError(f"{Path(fmu_path).name}: nonzero torque before its declared latency of {latency} samples")
    return y[latency:], rate


def evaluate_whole_joint(wj, record, fmu_dir, fmi_version: int = 2) -> tuple[dict, dict]:
    """(metrics, traces) of the whole-joint model ``wj`` on a :class:`~lpvpc.validation.harness.Record`.

    The FMU (FMI ``fmi_version``) is exported into ``fmu_dir``. ``traces`` holds the arrays
    the report draws: time, measured and predicted total torque, quasi-static part."""
    from lpvpc.export import whole_joint as W
    from lpvpc.io import decimate_signal

    meas = record.measured
    q = int(round(record.fs / meas.fs))
    pt_angle = meas.position + meas.scheduling  # the pairing's decimation is linear: this is PT's angle
    ut_angle = meas.scheduling
    pt_torque = decimate_signal(record.pt.torque, q) if q > 1 else np.asarray(record.pt.torque, dtype=float)
    pt_torque = pt_torque[: meas.n]
    whole_pt = wj.predict(pt_angle, warn=False)
    whole_ut = wj.predict(ut_angle, warn=False)
    two_input = wj.model.predict(meas.position, meas.scheduling, warn=False).total

    L = W.latency_samples(wj)
    n = meas.n - L
    cas = W.replay(wj, pt_angle)
    fmu_path = W.export_whole_joint_fmu(wj, Path(fmu_dir) / f"whole_joint_fmi{fmi_version}.fmu", fmi_version)
    y, _ = fmu_replay(fmu_path, pt_angle, L, wj.fs)
    metrics = {
        "vaf_total": vaf(pt_torque, whole_pt.total),
        "vaf_total_fmu": vaf(pt_torque[:n], y[:n]),
        "vaf_perturbation": vaf(meas.torque, whole_pt.total - whole_ut.total),
        "vaf_two_input": vaf(meas.torque, two_input),
        "vaf_quasi_static_ut": vaf(pt_torque - meas.torque, wj.quasi_static(ut_angle)),
        "casadi_vs_numpy": _relative(cas["torque"][:n], whole_pt.total[:n]),
        "fmu_vs_numpy": _relative(y[:n], whole_pt.total[:n]),
        "latency_samples": int(L),
        "latency_s": L / wj.fs,
        "cutoff_hz": float(wj.cutoff),
        "quasi_static_order": int(wj.curve_basis.order),
        "quasi_static_fit_vaf": wj.fit.get("quasi_static_vaf"),
        "fmu": str(fmu_path),
        "fmi_version": int(fmi_version),
    }
    traces = {"time": np.arange(meas.n) / meas.fs, "measured": pt_torque, "predicted": whole_pt.total,
              "quasi_static": whole_pt.quasi_static, "angle": pt_angle, "operating_angle": whole_pt.operating_angle}
    return metrics, traces
