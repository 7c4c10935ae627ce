"""Closed-loop validation: the identified closed-loop model and the virtual subject in the same
compliant loop, the replay (latency) FMU beside them.

The loop (:mod:`lpvpc.compliant_loop`) has foot plus device inertia 0.01 kg m^2, a PD exoskeleton
(Kp 40 and 150 N m/rad, Kd 0.5 N m s/rad) tracking a slow multilevel trajectory with +-0.02 rad
steps, and the ankle's torque fed back. Each run goes through a fixed-step master over fmpy's
co-simulation slave. Measured, per controller gain:

- the closed-loop FMU at 1 ms and at one model period: stable or not, VAF (%) of the angle
  deviation and of the torque against the virtual subject's run, whole and above 0.5 Hz;
- the replay FMU of the whole-joint model (two-sided IRF, 40 ms latency, inertia inside) at one
  model period: when it diverges. A user sees there why the closed-loop form exists.

The virtual subject is the truth only for a model identified from its trials. For a model of a
real subject, the loop with the virtual subject still shows whether the closed-loop FMU is stable
and how the replay FMU behaves, and the VAFs compare two different ankles.

:func:`write_closed_loop_report` draws the figure and writes a standalone page.
:func:`closed_loop_section` returns the HTML section for the validation report.
Units: rad, N m, s, percent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["evaluate_closed_loop", "closed_loop_section", "write_closed_loop_report", "CLOSED_LOOP_FIGURE"]

CLOSED_LOOP_FIGURE = "closed_loop.png"


def evaluate_closed_loop(cl, fmu_dir, *, duration: float = 20.0, seed: int = 0, kps=(40.0, 150.0),
                         fmi_version: int = 2, params=None) -> tuple[dict, dict]:
    """(metrics, traces) of the closed-loop model ``cl`` (:class:`lpvpc.closed_loop.ClosedLoopModel`)
    in the compliant loop against the virtual subject (``params``: its
    :class:`lpvpc.simulate.SubjectParams`, default the package's subject). The FMUs are exported
    into ``fmu_dir``. ``traces`` holds the first gain's runs for the figure."""
    from lpvpc import compliant_loop as LOOP
    from lpvpc.closed_loop import export_closed_loop_fmu
    from lpvpc.whole_joint import export_whole_joint_fmu

    fmu_dir = Path(fmu_dir)
    cl_fmu = export_closed_loop_fmu(cl, fmu_dir / f"closed_loop_fmi{fmi_version}.fmu", fmi_version)
    replay_fmu = export_whole_joint_fmu(cl.whole, fmu_dir / f"whole_joint_replay_fmi{fmi_version}.fmu", fmi_version)
    ref = LOOP.reference_trajectory(duration, seed)
    period = 1.0 / cl.fs
    metrics = {"duration_s": float(duration), "seed": int(seed), "inertia": float(cl.inertia),
               "device_inertia": LOOP.LoopSetup().device_inertia, "kd": LOOP.LoopSetup().kd,
               "sample_period_s": period, "fmi_version": int(fmi_version), "gains": []}
    traces = {}
    src, rep = LOOP.FmuSource(cl_fmu), LOOP.FmuSource(replay_fmu)
    try:
        for kp in kps:
            setup = LOOP.LoopSetup(kp=float(kp))
            truth = LOOP.run_loop(LOOP.VirtualSubject(params), ref, setup)
            runs = {"1 ms": LOOP.run_loop(src, ref, setup, 1e-3),
                    f"{period * 1e3:g} ms": LOOP.run_loop(src, ref, setup, period)}
            replay = LOOP.run_loop(rep, ref, setup, period)
            metrics["gains"].append({
                "kp": float(kp), "subject_stable": truth.stable,
                "closed_loop": {step: {"stable": r.stable, "diverged_at": r.diverged_at,
                                       **LOOP.loop_vaf(truth, r)} for step, r in runs.items()},
                "replay": {"stable": replay.stable, "diverged_at": replay.diverged_at}})
            if not traces:
                traces = {"time": truth.time, "reference": ref, "subject": truth, "model": runs["1 ms"],
                          "replay": replay, "kp": float(kp)}
    finally:
        src.close()
        rep.close()
    return metrics, traces


def _draw(folder: Path, tr: dict) -> Path:
    from .report import _fig, _save

    t = tr["time"]
    end = tr["replay"].diverged_at
    t1 = min(t[-1], max(3.0, 2.5 * end if end else 3.0))
    sel = t <= t1
    fig = _fig(9, 5.6)
    ax1 = fig.add_subplot(2, 1, 1)
    ax2 = fig.add_subplot(2, 1, 2, sharex=ax1)
    ax1.plot(t[sel], tr["reference"][sel], color="0.6", lw=0.8, label="reference")
    for key, colour, label in (("subject", "0.2", "virtual subject"), ("model", "C0", "closed-loop FMU (1 ms)"),
                               ("replay", "C3", "replay FMU (latency 40 ms)")):
        run = tr[key]
        ax1.plot(t[sel], run.angle[sel], color=colour, lw=1.0, label=label)
        ax2.plot(t[sel], run.torque[sel], color=colour, lw=1.0, label=label)
    lo, hi = np.nanmin(tr["subject"].angle[sel]), np.nanmax(tr["subject"].angle[sel])
    ax1.set_ylim(lo - 0.5 * (hi - lo) - 0.02, hi + 0.5 * (hi - lo) + 0.02)  # the diverging run leaves the frame
    tq = tr["subject"].torque[sel]
    ax2.set_ylim(np.nanmin(tq) - 0.5 * np.ptp(tq) - 0.5, np.nanmax(tq) + 0.5 * np.ptp(tq) + 0.5)
    ax1.set_ylabel("angle (rad)")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.set_ylabel("ankle torque (N m)")
    ax2.set_xlabel("time (s)")
    ax1.set_title(f"Compliant loop, Kp {tr['kp']:g} N m/rad: the replay FMU "
                  + (f"diverges at {end:.2f} s" if end else "stays stable"), fontsize=10)
    path = folder / CLOSED_LOOP_FIGURE
    _save(fig, path)
    return path


def closed_loop_section(m: dict, fig: Path) -> str:
    """The report's HTML section for ``evaluate_closed_loop``'s metrics and figure."""
    from .report import _e, _img, _num, _table

    rows = []
    for g in m["gains"]:
        for step, r in g["closed_loop"].items():
            if r["stable"]:
                cells = [_num(r[k]) for k in ("deviation", "torque", "deviation_hp", "torque_hp")]
            else:
                cells = [f"diverged at {r['diverged_at']:.2f} s", "", "", ""]
            rows.append([f"Kp {g['kp']:g}, closed-loop FMU, step {step}", *cells])
        rep = g["replay"]
        rows.append([f"Kp {g['kp']:g}, replay FMU, step {m['sample_period_s'] * 1e3:g} ms",
                     "stable" if rep["stable"] else f"diverged at {rep['diverged_at']:.2f} s", "", "", ""])
    return "\n".join([
        "<h2>Closed loop</h2>",
        f"<p class=\"what\">{_e('The ankle model in a compliant exoskeleton loop: foot + device inertia ')}"
        f"{m['device_inertia']:g} kg m^2 (+ the model's declared {m['inertia']:.4f} kg m^2), PD controller "
        f"(Kd {m['kd']:g} N m s/rad) tracking a multilevel trajectory with +-0.02 rad steps, {m['duration_s']:g} s, "
        f"the torque fed back; FMI {m['fmi_version']}.0 co-simulation through fmpy. VAF (%) against the virtual "
        f"subject in the same loop. The replay FMU answers 40 ms late with the inertia inside its torque: use the "
        f"closed-loop FMU (lpvpc whole-joint --closed-loop) wherever the torque moves the joint.</p>",
        _table(["run", "angle deviation", "torque", "deviation > 0.5 Hz", "torque > 0.5 Hz"], rows),
        _img(fig, "The compliant loop: virtual subject, closed-loop FMU and replay FMU"),
    ])


def write_closed_loop_report(folder, metrics: dict, traces: dict) -> Path:
    """Draw the figure into ``folder/figures`` and write ``folder/closed_loop.html``; returns its path."""
    from lpvpc.outputs import write_text

    folder = Path(folder)
    (folder / "figures").mkdir(parents=True, exist_ok=True)
    fig = _draw(folder / "figures", traces)
    page = ("<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>lpvpc closed-loop validation</title>"
            "</head><body>" + closed_loop_section(metrics, fig) + "</body></html>")
    path = folder / "closed_loop.html"
    write_text(path, page)
    return path
