"""Closed-loop validation: the identified closed-loop model and the virtual subject in the same
compliant loop, the replay (latency) FMU beside them.

The loop (:mod:`lpvpc.simulation.compliant_loop`) has foot plus device inertia 0.01 kg m^2, a PD exoskeleton
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

__all__ = ["evaluate_closed_loop", "closed_loop_section", "write_closed_loop_report", "CLOSED_LOOP_FIGURE",
           "evaluate_loop_ssp", "write_loop_ssp", "run_loop_ssp_libcosim", "run_loop_fmpy", "exoskeleton_parameters",
           "LOOP_CONNECTIONS"]

CLOSED_LOOP_FIGURE = "closed_loop.png"


def evaluate_closed_loop(cl, fmu_dir, *, duration: float = 20.0, seed: int = 0, kps=(40.0, 150.0),
                         fmi_version: int = 2, params=None) -> tuple[dict, dict]:
    """(metrics, traces) of the closed-loop model ``cl`` (:class:`lpvpc.export.closed_loop.ClosedLoopModel`)
    in the compliant loop against the virtual subject (``params``: its
    :class:`~lpvpc.simulation.subject.SubjectParams`, default the package's subject). The FMUs are exported
    into ``fmu_dir``. ``traces`` holds the first gain's runs for the figure."""
    from lpvpc.simulation import compliant_loop as LOOP
    from lpvpc.export.closed_loop import export_closed_loop_fmu
    from lpvpc.export.whole_joint import export_whole_joint_fmu

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
    from lpvpc.report_html import new_figure as _fig
    from lpvpc.report_html import save_figure as _save

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
    from lpvpc.report_html import escape as _e
    from lpvpc.report_html import figure_with_file as _img
    from lpvpc.report_html import num as _num
    from lpvpc.report_html import table as _table

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
    from lpvpc.io.outputs import write_text

    folder = Path(folder)
    (folder / "figures").mkdir(parents=True, exist_ok=True)
    fig = _draw(folder / "figures", traces)
    from lpvpc.report_html import CSS as _CSS  # the reports' look

    page = ("<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>lpvpc closed-loop validation</title>"
            f"<style>{_CSS}</style></head><body>" + closed_loop_section(metrics, fig) + "</body></html>")
    path = folder / "closed_loop.html"
    write_text(path, page)
    return path


# ---------------------------------------------------------------------------------------
# The same kind of loop as an SSP 1.0 archive, for engines that connect outputs to inputs only
# (libcosim, ECOS): the record player plays the reference as the command of a series-elastic
# exoskeleton (the actuator FMU with servo_stiffness Kp and coupling damping giving Kd; its
# footplate inertia the device's plus the ankle's declared one), whose position and velocity
# drive the ankle FMU, whose torque loads it.

#: (end component, connector) <- (start component, connector) of the closed-loop SSP.
LOOP_CONNECTIONS = (
    (("exoskeleton", "command"), ("record", "command_ut")),
    (("ankle", "angle"), ("exoskeleton", "position")),
    (("ankle", "angular_velocity"), ("exoskeleton", "velocity")),
    (("exoskeleton", "load_torque"), ("ankle", "torque")),
)


def exoskeleton_parameters(kp: float, kd: float, inertia: float, initial_position: float) -> dict:
    """Actuator FMU parameters of a series-elastic exoskeleton: spring ``kp`` (N m/rad), damping
    ``kd`` (N m s/rad) between motor and footplate, footplate + foot ``inertia`` (kg m^2)."""
    return {"servo_stiffness": float(kp), "coupling_damping": float(kd) / (2.0 * np.sqrt(kp * inertia)),
            "footplate_inertia": float(inertia), "initial_position": float(initial_position)}


def write_loop_ssp(path, ankle_fmu, actuator_fmu, record_fmu, *, stop_time: float, parameters: dict) -> Path:
    """The closed loop as an SSP 1.0 archive (three components, connections :data:`LOOP_CONNECTIONS`,
    the exoskeleton's parameters bound on it as the parameter set ``initialValues``, OSP step
    annotations): libcosim and ECOS run it as it is."""
    import xml.etree.ElementTree as ET
    import zipfile

    from lpvpc.io.outputs import atomic_path

    from .fmu import inspect_fmu
    from .ssp import OSP_ANNOTATION, OSP_NAMESPACE, SSP_VERSION, _fmt, _q, _variables, _write_units, _add_component

    fmus = {"record": inspect_fmu(record_fmu, "record FMU"), "exoskeleton": inspect_fmu(actuator_fmu, "actuator FMU"),
            "ankle": inspect_fmu(ankle_fmu, "ankle FMU")}
    var_of = {c: _variables(f) for c, f in fmus.items()}
    steps = {c: float(f.step_size) for c, f in fmus.items()}
    root = ET.Element(_q("ssd", "SystemStructureDescription"), version=SSP_VERSION, name="lpvpc_closed_loop",
                      generationTool="lpvpc validation.closed_loop")
    system = ET.SubElement(root, _q("ssd", "System"), name="lpvpc_closed_loop",
                           description="A series-elastic exoskeleton tracks the recorded reference; the ankle FMU's "
                                       "torque loads it")
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    for comp in fmus:
        _add_component(elements, comp, f"resources/{comp}.fmu", var_of[comp], parameters.get(comp), steps[comp])
    links = ET.SubElement(system, _q("ssd", "Connections"))
    for (e_comp, e_var), (s_comp, s_var) in LOOP_CONNECTIONS:
        if e_var not in var_of[e_comp]:  # the replay FMU has no angular_velocity input
            continue
        ET.SubElement(links, _q("ssd", "Connection"), startElement=s_comp, startConnector=s_var,
                      endElement=e_comp, endConnector=e_var)
    _write_units(root, fmus.values())
    de = ET.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0", stopTime=_fmt(stop_time))
    ann = ET.SubElement(ET.SubElement(de, _q("ssd", "Annotations")), _q("ssc", "Annotation"), type=OSP_ANNOTATION)
    ET.SubElement(ET.SubElement(ann, f"{{{OSP_NAMESPACE}}}Algorithm"), f"{{{OSP_NAMESPACE}}}FixedStepAlgorithm",
                  baseStepSize=_fmt(min(steps.values())))
    ET.indent(root)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", ET.tostring(root, encoding="UTF-8", xml_declaration=True))
            for comp, info in fmus.items():
                zf.write(info.path, f"resources/{comp}.fmu")
    return path


def run_loop_ssp_libcosim(ssp, n_steps: int) -> dict:
    """Run the closed-loop SSP in libcosim for ``n_steps`` base steps: {"angle", "torque"} after
    each step (rad, N m; NaN from a step the engine refused on: an FMU's error, e.g. a diverged
    loop's non-finite value)."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(ssp))
    idx = {n: ex.slave_index_from_instance_name(n) for n in ("exoskeleton", "ankle")}

    def ref(comp, name):
        return next(v.reference for v in ex.slave_variables(idx[comp]) if v.name in (name.encode(), name))

    vr_angle, vr_torque = ref("exoskeleton", "position"), ref("ankle", "torque")
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    out = {"angle": np.full(n_steps, np.nan), "torque": np.full(n_steps, np.nan)}
    for k in range(n_steps):
        if not ex.step(1):
            break
        out["angle"][k] = obs.last_real_values(idx["exoskeleton"], [vr_angle])[0]
        out["torque"][k] = obs.last_real_values(idx["ankle"], [vr_torque])[0]
    return out


def run_loop_fmpy(ankle_fmu, actuator_fmu, reference, parameters: dict) -> dict:
    """The same loop with fmpy's FMU2Slave and a manual master (Jacobi: outputs read, then all
    inputs set, then every FMU stepped 1 ms, as libcosim's fixed-step algorithm does):
    {"angle", "torque"} after each step."""
    import fmpy
    from fmpy.fmi2 import FMU2Slave

    def open_(path):
        md = fmpy.read_model_description(str(path))
        s = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=Path(path).stem)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        return s, {v.name: v.valueReference for v in md.modelVariables}

    exo, ve = open_(actuator_fmu)
    ankle, va = open_(ankle_fmu)
    per = max(1, int(round(float(fmpy.read_model_description(str(ankle_fmu)).defaultExperiment.stepSize) / 1e-3)))
    exo.setReal([ve[k] for k in parameters], list(parameters.values()))
    exo.exitInitializationMode()
    ankle.exitInitializationMode()
    n, h = len(reference), 1e-3
    out = {"angle": np.full(n, np.nan), "torque": np.full(n, np.nan)}
    try:
        for k in range(n):
            theta, omega = exo.getReal([ve["position"], ve["velocity"]])
            torque = ankle.getReal([va["torque"]])[0]
            exo.setReal([ve["command"], ve["load_torque"]], [reference[k], torque])
            if "angular_velocity" in va:
                ankle.setReal([va["angle"], va["angular_velocity"]], [theta, omega])
            else:  # the replay FMU: angle only, stepped at its own period (10 ms)
                ankle.setReal([va["angle"]], [theta])
            exo.doStep(k * h, h)
            if (k + 1) % per == 0:
                ankle.doStep((k + 1 - per) * h, per * h)
            out["angle"][k] = exo.getReal([ve["position"]])[0]
            out["torque"][k] = ankle.getReal([va["torque"]])[0]
    except Exception:  # an FMU error status (a diverged loop's non-finite value): the record ends there
        pass
    finally:
        for s in (exo, ankle):
            s.terminate()
            s.freeInstance()
    return out


def evaluate_loop_ssp(cl, fmu_dir, *, duration: float = 10.0, seed: int = 0, kp: float = 40.0,
                      kd: float = 0.5) -> dict:
    """The series-elastic loop (:func:`write_loop_ssp`) with the closed-loop FMU and with the
    replay FMU, each run by fmpy (:func:`run_loop_fmpy`) and by libcosim from the SSP archive:
    stability (the angle within 1 rad of the reference, every value finite), the time a run
    failed, and the VAF (%) of libcosim's angle and torque against fmpy's. libcosim absent: its
    entries are None and ``libcosim`` says why."""
    from lpvpc.export.actuator import build_actuator_fmu
    from lpvpc.simulation.compliant_loop import LoopSetup, reference_trajectory
    from lpvpc.export.closed_loop import export_closed_loop_fmu
    from lpvpc.models.model import vaf
    from lpvpc.export.whole_joint import export_whole_joint_fmu

    from .engines import available
    from .ssp import build_record_fmu

    fmu_dir = Path(fmu_dir)
    device = LoopSetup().device_inertia
    ref = reference_trajectory(duration, seed)
    actuator = build_actuator_fmu(fmu_dir / "exoskeleton.fmu", fmi_version=2)
    record = build_record_fmu(fmu_dir / "reference.fmu", ref, ref, np.zeros_like(ref), 1e-3)
    why = available("libcosim")
    out = {"kp": float(kp), "kd": float(kd), "duration_s": float(duration), "libcosim": why or "ran"}

    def failed_at(run):
        bad = np.flatnonzero(~np.isfinite(run["angle"]) | (np.abs(run["angle"] - ref) > 1.0))
        return float(bad[0] * 1e-3) if len(bad) else None

    for name, fmu, inertia in (
            ("closed_loop", export_closed_loop_fmu(cl, fmu_dir / "ankle_closed_loop.fmu", 2), device + cl.inertia),
            ("replay", export_whole_joint_fmu(cl.whole, fmu_dir / "ankle_replay.fmu", 2), device)):
        par = exoskeleton_parameters(kp, kd, inertia, ref[0])
        f = run_loop_fmpy(fmu, actuator, ref, par)
        entry = {"fmpy_failed_at": failed_at(f), "libcosim_failed_at": None, "vaf_angle": None, "vaf_torque": None}
        if why is None:
            ssp = write_loop_ssp(fmu_dir / f"loop_{name}.ssp", fmu, actuator, record, stop_time=duration,
                                 parameters={"exoskeleton": par})
            lc = run_loop_ssp_libcosim(ssp, len(ref))
            entry["libcosim_failed_at"] = failed_at(lc)
            entry["ssp"] = str(ssp)
            if entry["fmpy_failed_at"] is None and entry["libcosim_failed_at"] is None:
                entry["vaf_angle"] = vaf(f["angle"] - ref, lc["angle"] - ref)
                entry["vaf_torque"] = vaf(f["torque"], lc["torque"])
        out[name] = entry
    return out
