"""Every FMU kind the project writes, run as masters nobody here wrote run it.

Two masters:

- fmpy driven the way OMSimulator and most fixed-step masters drive an FMU: the
  communication time is built by adding the step (``t += h``), so it drifts from the tick
  grid by rounding, and the last step is clipped to the stop time (a sliver shorter or longer
  than whole ticks); also a last step of fewer ticks than the master step;
- OMSimulator 3.0 (OpenModelica's FMI/SSP simulator) through its Python API, where a build
  is found (``$LPVPC_OMSIMULATOR`` or ``../shared/tools/omsimulator`` beside the
  repository; a fresh clone has neither and these tests skip, saying so).

Each run must end without error and agree with the offline prediction to 1e-9 N m after the
FMU's declared latency. The Model Exchange FMUs run in OMSimulator's strongly coupled system
(its FMU API, and its own loop with the inputs from a CSV table) and in fmpy's
``simulate_fmu``; a Model Exchange event loop in fmpy checks the start when no input is set
in initialization. The long (120 s) runs are in benchmarks/bench_foreign_masters.py.
"""

import os
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from fmu_helpers import FMUInstance, reference

from lpvpc.export import exporter as ex
ABS_TOL = 1e-9  # N m
RUN_S = 20.0  # s per run (the benchmark runs 120 s)
KINDS = [("sampled", 2), ("sampled", 3), ("causal", 2), ("causal", 3), ("exact", 2), ("exact", 3),
         ("closed_loop", 2), ("closed_loop", 3), ("whole_joint", 2), ("whole_joint", 3)]
OUTPUTS = ("torque", "torque_intrinsic", "torque_reflex")


def omsimulator_root() -> Path:
    """Where an OMSimulator build is looked for: ``$LPVPC_OMSIMULATOR``, else
    ``../shared/tools/omsimulator`` next to the repository."""
    env = os.environ.get("LPVPC_OMSIMULATOR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "tools" / "omsimulator"


@pytest.fixture(scope="module")
def oms():
    """The OMSimulator Python package, or a skip that says why it is not usable here."""
    lib = omsimulator_root() / "lib" / "x86_64-linux-gnu"
    if not (lib / "OMSimulator").is_dir():
        pytest.skip(f"no OMSimulator build at {omsimulator_root()} (set LPVPC_OMSIMULATOR to one)")
    sys.path.insert(0, str(lib))
    try:
        import OMSimulator
    except Exception as exc:  # noqa: BLE001 - a missing lxml or shared library fails in many ways
        pytest.skip(f"OMSimulator at {lib} not importable: {type(exc).__name__}: {exc}")
    return OMSimulator


@pytest.fixture(scope="module")
def closed_loop(model, subject):
    from lpvpc.export.closed_loop import distillation_trial, fit_closed_loop
    from lpvpc.export.whole_joint import fit_whole_joint

    wj = fit_whole_joint(model, subject["ident_pair"].ut)
    return fit_closed_loop(wj, [distillation_trial(wj, subject["ident_pair"].ut)])


@pytest.fixture(scope="module")
def fmus(model, closed_loop, tmp_path_factory):
    """{(kind, fmi): (path, extracted folder)} for every model kind and the actuator."""
    from lpvpc.export.actuator import build_actuator_fmu
    from lpvpc.export.closed_loop import export_closed_loop_fmu
    from lpvpc.export.whole_joint import export_whole_joint_fmu

    folder = tmp_path_factory.mktemp("foreign")
    out = {}
    for kind, fmi in KINDS + [("actuator", 2), ("actuator", 3)]:
        path = folder / f"{kind}_fmi{fmi}.fmu"
        if kind == "closed_loop":
            export_closed_loop_fmu(closed_loop, path, fmi)
        elif kind == "whole_joint":
            export_whole_joint_fmu(closed_loop.whole, path, fmi)
        elif kind == "actuator":
            build_actuator_fmu(path, fmi)
        else:
            ex.export_fmu(model, path, fmi_version=fmi, variant=kind)
        out[(kind, fmi)] = (path, Path(extract(path, unzipdir=folder / f"x_{kind}_{fmi}")))
    return out


def _case(model, closed_loop, subject, kind, seconds=RUN_S):
    """(inputs {name: per-sample array}, expected torque per sample, latency in samples,
    sampled FMU?) for ``seconds`` of the novel record."""
    data = subject["novel"]
    n = int(round(seconds * model.fs))
    pos, sch = data.position[:n], data.scheduling[:n]
    if kind == "closed_loop":  # its reference is the tick function, with each sample held over its ticks
        from lpvpc.export.closed_loop import closed_loop_step, ticks

        vel = np.gradient(pos, 1.0 / model.fs)
        N = ticks(closed_loop)
        step = closed_loop_step(closed_loop)
        out = ex.trajectory_function(step, n * N)(state=np.zeros(step.size1_in(0)),
                                                  angle=np.repeat(pos, N)[None, :],
                                                  angular_velocity=np.repeat(vel, N)[None, :])
        return {"angle": pos, "angular_velocity": vel}, np.asarray(out["torque"]).ravel()[::N], 0, False
    if kind == "whole_joint":  # the joint angle in; its reference is the CasADi tick over the record
        from lpvpc.export.whole_joint import latency_samples, replay

        angle = sch + pos
        return {"angle": angle}, replay(closed_loop.whole, angle)["torque"], latency_samples(closed_loop.whole), False
    inputs = {k: v.ravel() for k, v in ex.replay_inputs(model, pos, sch, kind).items()}
    return inputs, reference(model, pos, sch, kind)["torque"], ex.latency_samples(model, kind), kind == "sampled"


def _fmpy_added_times(path, unzipdir, inputs, T, h, sampled, name="m"):
    """Run with fmpy, communication times built by adding ``h``; the last step clipped to the
    stop time n T. Returns the torque per sample and the instance's error messages."""
    inst = FMUInstance(path, unzipdir, name, "cs").initialize()
    names = list(inputs)
    n = len(inputs[names[0]])
    ins, out = inst.refs(names), inst.refs(["torque"])
    per = int(round(T / h))
    stop, t, j = n * T, 0.0, 0
    y = np.empty(n)
    for k in range(n):
        inst.set(ins, [float(inputs[q][k]) for q in names])
        if not sampled:
            y[k] = inst.get(out)[0]
        for _ in range(per):
            step = stop - t if j == n * per - 1 else h
            inst.fmu.doStep(t, step)
            t += step
            j += 1
        if sampled:
            y[k] = inst.get(out)[0]
    inst.fmu.terminate()
    inst.fmu.freeInstance()
    return y, [m for s, m in inst.log if s >= 2]


def _agreement(y, expected, lat):
    return float(np.max(np.abs(y[lat:] - expected[: len(expected) - lat])))


@pytest.mark.parametrize("kind,fmi", KINDS)
@pytest.mark.parametrize("master_step", [1e-3, 1e-2])
def test_fmpy_with_added_times_agrees_to_the_end(model, closed_loop, subject, fmus, kind, fmi, master_step):
    """Times built by adding steps over 20 s and a clipped last step: no error, and the
    torque equals the offline prediction. A master step of 1 ms is a whole tick of the
    sampled and closed-loop FMUs and a tenth of the causal and exact FMUs' tick (the 10 ms
    sample): those take the inputs at the step that starts on their grid and hold the outputs
    until the next."""
    inputs, expected, lat, sampled = _case(model, closed_loop, subject, kind)
    path, unzipdir = fmus[(kind, fmi)]
    T = 1.0 / model.fs
    y, errors = _fmpy_added_times(path, unzipdir, inputs, T, master_step, sampled)
    assert not errors
    assert _agreement(y, expected, lat) < ABS_TOL


@pytest.mark.parametrize("fmi", [2, 3])
def test_short_last_step_and_drifted_times_keep_the_grid(model, subject, fmus, fmi):
    """A last step of fewer ticks than the master step, a sliver step of no tick, and a
    communication point that drifted (within tolerance) keep the samples on the absolute
    grid; two half ticks equal one tick, the outputs held between them; a step that does not
    start where the FMU is is refused."""
    from fmpy.fmi1 import FMICallException

    path, unzipdir = fmus[("sampled", fmi)]
    values = {"position": 0.02, "scheduling": 0.0}
    inst = FMUInstance(path, unzipdir, "g", "cs").initialize(values)
    on_grid = FMUInstance(path, unzipdir, "e", "cs").initialize(values)
    out = inst.refs(["torque"])
    t = 0.0
    for k in range(100):  # 1 s at 10 ms, time built by adding
        inst.set(inst.refs(["position"]), [0.02 + 1e-3 * k])
        on_grid.set(inst.refs(["position"]), [0.02 + 1e-3 * k])
        inst.fmu.doStep(t, 0.01)
        on_grid.fmu.doStep(k * 0.01, 0.01)
        t += 0.01
    assert t != 1.0  # the sum drifted off the grid
    inst.fmu.doStep(t, 1e-12)  # a sliver: no tick
    inst.fmu.doStep(1.0 + 2e-12, 0.003)  # a short step of 3 ticks from a drifted point
    on_grid.fmu.doStep(1.0, 0.003)
    assert inst.get(out) == on_grid.get(out)
    for i in (inst, on_grid):
        i.set(inst.refs(["position"]), [0.5])
    held = inst.get(out)
    inst.fmu.doStep(1.003, 0.0005)  # half a tick: ends between ticks, the outputs held
    assert inst.get(out) == held
    inst.fmu.doStep(1.0035, 0.0005)
    on_grid.fmu.doStep(1.003, 0.001)
    assert inst.get(out) == on_grid.get(out)
    with pytest.raises(FMICallException):
        inst.fmu.doStep(1.0045, 0.001)
    assert any("does not match the FMU time" in m for s, m in inst.log if s >= 2)
    for i in (inst, on_grid):
        i.fmu.freeInstance()


@pytest.mark.parametrize("fmi", [2, 3])
def test_steps_shorter_than_the_tick_hold_the_outputs(model, closed_loop, subject, fmus, fmi):
    """The exact FMU (direct feedthrough, tick = the 10 ms sample) stepped at 1 ms: the step
    that starts on the grid takes the inputs set at its start; inputs set between grid points
    do not reach the outputs, which stay those of the last grid point until the next one; the
    torque at every grid point equals the run at whole ticks."""
    inputs, expected, lat, _ = _case(model, closed_loop, subject, "exact", seconds=2.0)
    path, unzipdir = fmus[("exact", fmi)]
    T, n = 1.0 / model.fs, len(expected)
    inst = FMUInstance(path, unzipdir, "fine", "cs").initialize()
    refs, out = inst.refs(list(inputs)), inst.refs(["torque"])
    y, t, held = np.empty(n), 0.0, True
    for k in range(n):
        inst.set(refs, [float(inputs[q][k]) for q in inputs])
        y[k] = inst.get(out)[0]
        for j in range(10):
            inst.fmu.doStep(t, 1e-3)
            t += 1e-3
            if j < 9:
                inst.set(refs, [float(inputs[q][k]) + 0.1 for q in inputs])  # between grid points
                held &= inst.get(out)[0] == y[k]
    assert not [m for s, m in inst.log if s >= 2]
    inst.fmu.freeInstance()
    assert held
    assert _agreement(y, expected, lat) < ABS_TOL


@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("master_step", [1e-3, 1e-2])
def test_actuator_with_added_times_equals_exact_times(fmus, fmi, master_step):
    """The actuator FMU driven with added-up times ends without error and gives the same
    positions as when driven at exact multiples of the step."""
    path, unzipdir = fmus[("actuator", fmi)]
    rng = np.random.default_rng(3)
    n = int(RUN_S / master_step)
    cmd = 0.05 * np.sin(np.arange(n) * master_step * 2 * np.pi) + 1e-3 * rng.standard_normal(n)
    runs = []
    for added in (True, False):
        inst = FMUInstance(path, unzipdir, "a", "cs").initialize()
        vin, vout = inst.refs(["command"]), inst.refs(["position"])
        y, t = np.empty(n), 0.0
        for k in range(n):
            inst.set(vin, [float(cmd[k])])
            tk = t if added else k * master_step
            h = (n * master_step - tk) if (added and k == n - 1) else master_step
            inst.fmu.doStep(tk, h)
            t = tk + h
            y[k] = inst.get(vout)[0]
        assert not [m for s, m in inst.log if s >= 2]
        inst.fmu.freeInstance()
        runs.append(y)
    assert np.max(np.abs(runs[0] - runs[1])) < ABS_TOL


def _oms_fmu(oms, path, stop):
    fmu = oms.FMU(str(path), instanceName=f"i{uuid.uuid4().hex[:10]}")
    fmu.instantiate()
    fmu.setStopTime(stop)
    fmu.initialize()
    return fmu


@pytest.mark.parametrize("kind,fmi", KINDS)
def test_omsimulator_step_until_replay(oms, model, closed_loop, subject, fmus, kind, fmi, tmp_path, monkeypatch):
    """OMSimulator's FMU API, sample by sample with the call the guide gives for it:
    ``stepUntil(t_{k+1} - tick/2)`` (its master adds whole steps until its time reaches the
    target, so a target on the grid can take one tick more; half a tick before it ends on
    t_{k+1}). Every sample equals the prediction."""
    monkeypatch.chdir(tmp_path)  # OMSimulator writes a result file into the working folder
    inputs, expected, lat, sampled = _case(model, closed_loop, subject, kind)
    path, _ = fmus[(kind, fmi)]
    T = 1.0 / model.fs
    tick = T / ex.ticks_per_sample(model) if kind in ("sampled", "closed_loop") else T
    n = len(expected)
    fmu = _oms_fmu(oms, path, n * T + 1.0)
    y = np.empty(n)
    for k in range(n):
        for name, v in inputs.items():
            fmu.setValue(name, float(v[k]))
        if not sampled:
            y[k] = fmu.getValue("torque")
        fmu.stepUntil((k + 1) * T - tick / 2)
        if sampled:
            y[k] = fmu.getValue("torque")
    fmu.terminate()
    assert _agreement(y, expected, lat) < ABS_TOL


@pytest.mark.parametrize("kind", ["sampled", "exact", "actuator"])
@pytest.mark.parametrize("fmi", [2, 3])
def test_omsimulator_simulate_runs_to_the_end(oms, model, fmus, kind, fmi, tmp_path, monkeypatch):
    """OMSimulator's own loop (``simulate``: times built by adding its step, the last step
    clipped to the stop time) runs 20 s to the end without error; with inputs held the
    model's torque is the prediction's last sample."""
    monkeypatch.chdir(tmp_path)
    path, _ = fmus[(kind, fmi)]
    fmu = _oms_fmu(oms, path, RUN_S)
    held = {"position": 0.03, "scheduling": -0.05} if kind != "actuator" else {"command": 0.03}
    for name, v in held.items():
        fmu.setValue(name, v)
    fmu.simulate()
    if kind != "actuator":
        n = int(round(RUN_S * model.fs))
        inputs = {k: v.ravel() for k, v in ex.replay_inputs(model, np.full(n, 0.03), np.full(n, -0.05),
                                                            kind).items()}
        expected = reference(model, inputs["position"], inputs["scheduling"], kind)["torque"]
        assert abs(fmu.getValue("torque") - expected[-1]) < ABS_TOL
    else:
        assert abs(fmu.getValue("position") - 0.03) < 1e-3
    fmu.terminate()


_RUN_SSP = """
import sys
from OMSimulator import SSP
im = SSP(sys.argv[1]).instantiate()
if sys.argv[2] != "default":
    im.setFixedStepSize(float(sys.argv[2]))
im.setResultFile(sys.argv[3])
im.initialize()
im.simulate()
im.terminate()
print("finished")
"""


@pytest.fixture(scope="module")
def validate_ssps(model, subject, tmp_path_factory):
    """``lpvpc validate`` on the first 10 s of the novel record: its result (the harness's
    co-simulation) and the measured torque the VAF is taken against."""
    from lpvpc.io import Trial
    from lpvpc.validation import validate
    from lpvpc.validation.harness import load_record

    pair, n = subject["novel_pair"], 10_000
    pt, ut = (Trial(t.time[:n], t.position[:n], t.torque[:n], {k: v[:n] for k, v in t.channels.items()},
                    name=t.name) for t in (pair.pt, pair.ut))
    result = validate(model, pt, ut, tmp_path_factory.mktemp("validate") / "report", measure_load_effect=False)
    return {"result": result, "measured": load_record(model, pt, ut).measured}


def _ssp_stop_time(ssp) -> float:
    """The stop time (s) an SSP archive's DefaultExperiment states."""
    import xml.etree.ElementTree as ET
    import zipfile

    from lpvpc.validation.ssp import SSD_NAMESPACES

    with zipfile.ZipFile(ssp) as zf:
        root = ET.fromstring(zf.read("SystemStructure.ssd"))
    return float(root.find("ssd:DefaultExperiment", SSD_NAMESPACES).get("stopTime"))


def _run_ssp_in_omsimulator(ssp, step, folder):
    """Run ``ssp`` in its own OMSimulator process (it keeps model names per process) at
    ``step`` (s, or "default"); returns the result table {column: values} (CSV result file)."""
    import csv
    import subprocess

    env = {**os.environ, "PYTHONPATH": str(omsimulator_root() / "lib" / "x86_64-linux-gnu")}
    result = folder / f"{Path(ssp).stem}_{step}.csv"
    run = subprocess.run([sys.executable, "-c", _RUN_SSP, str(ssp), str(step), str(result)], cwd=folder, env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "finished" in run.stdout, (ssp, step, run.stdout[-2000:], run.stderr[-2000:])
    assert "error" not in (run.stdout + run.stderr).lower(), (ssp, step, run.stdout[-2000:], run.stderr[-2000:])
    with open(result) as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


@pytest.mark.parametrize("key", ["ssp", "portable_ssp"])
@pytest.mark.parametrize("step", ["default", 1e-3, 1e-2])
def test_omsimulator_runs_the_validate_ssps_to_the_end(oms, validate_ssps, key, step, tmp_path):
    """Both archives ``lpvpc validate`` writes run as written in OMSimulator, which steps every
    component at its one master step: at its default (1 ms: the model FMU, tick 10 ms, takes
    steps that end between its grid points) and at 10 ms, to the stop time, last step
    included. The portable set-up at 1 ms is the harness's experiment: its model torque is
    within 0.1 VAF point of the harness's co-simulation (OMSimulator passes values in
    dependency order at each communication point, as the harness does; the record player has
    no direct feedthrough, so libcosim and ECOS, which pass them after each step, see the same
    record). At 10 ms the actuators and the record player get one command per 10 ms: a
    different experiment, which only has to run to the end. ``cosimulation.ssp`` leaves the
    signals the harness computes to the tool (system inputs), so only its run is checked."""
    from lpvpc.models.model import vaf

    res = validate_ssps["result"]
    table = _run_ssp_in_omsimulator(res.files[key], step, tmp_path)
    t = table["time"]
    assert t[-1] == pytest.approx(_ssp_stop_time(res.files[key]))
    assert np.isfinite(np.column_stack(list(table.values()))).all()
    if key == "portable_ssp" and step in ("default", 1e-3):
        meas = validate_ssps["measured"]
        L = res.metrics["cosim"]["model_fmu_latency_samples"]
        col = next(k for k in table if k.endswith("model.torque"))
        T = 1.0 / res.metrics["fs"]
        # the last row at each model sample time (OMSimulator writes before and after each step)
        rows = np.searchsorted(t, (np.arange(meas.n + L) * T) + 1e-9, side="right") - 1
        got = vaf(meas.torque, table[col][rows][L:L + meas.n])
        print(f"OMSimulator {step}: VAF {got:.3f} % (harness {res.metrics['vaf_cosim']:.3f} %)")
        assert abs(got - res.metrics["vaf_cosim"]) < 0.1


@pytest.mark.parametrize("key", ["ssp", "portable_ssp"])
@pytest.mark.parametrize("step", [1e-3, 1e-2])
def test_fmpy_runs_the_validate_ssps_to_the_end(validate_ssps, key, step):
    """fmpy's ``simulate_ssp`` (a Jacobi master, one step for all components) runs both
    archives at 1 ms and 10 ms to the stop time without error (it applies no component
    parameter sets, so it is not the harness's experiment)."""
    from fmpy.ssp.simulation import simulate_ssp

    path = validate_ssps["result"].files[key]
    stop = _ssp_stop_time(path)
    res = simulate_ssp(str(path), stop_time=stop, step_size=step)
    # row k: the values after the step from its time (fmpy adds up its time: one more step may come)
    assert res["time"][-1] + step == pytest.approx(stop) or res["time"][-1] == pytest.approx(stop)
    assert np.isfinite(res["model.torque"]).all()


ME_KINDS = [("sampled", 2), ("exact", 2), ("causal", 2), ("whole_joint", 2)]


@pytest.fixture(scope="module")
def me_fmus(model, closed_loop, tmp_path_factory):
    """{(kind, fmi): (path, extracted folder)} of Model Exchange model FMUs."""
    from lpvpc.export.whole_joint import export_whole_joint_fmu

    folder = tmp_path_factory.mktemp("foreign_me")
    out = {}
    for kind, fmi in ME_KINDS + [("sampled", 3)]:
        path = folder / f"me_{kind}_fmi{fmi}.fmu"
        if kind == "whole_joint":
            export_whole_joint_fmu(closed_loop.whole, path, fmi, fmi_type="me")
        else:
            ex.export_fmu(model, path, fmi_version=fmi, variant=kind, fmi_type="me")
        out[(kind, fmi)] = (path, Path(extract(path, unzipdir=folder / f"x_me_{kind}_{fmi}")))
    return out


@pytest.mark.parametrize("kind,fmi", ME_KINDS)
def test_omsimulator_model_exchange_replay(oms, model, closed_loop, subject, me_fmus, kind, fmi, tmp_path,
                                           monkeypatch):
    """OMSimulator's FMI 2 Model Exchange run (its strongly coupled system, CVode), with the call
    the guide gives for it: a maximum step of at most half a sample, the inputs of sample k set,
    ``stepUntil(t_k + T/2)``, the torque read. Every sample after the declared latency equals
    the offline prediction."""
    monkeypatch.chdir(tmp_path)
    inputs, expected, lat, _ = _case(model, closed_loop, subject, kind)
    path, _ = me_fmus[(kind, fmi)]
    T = 1.0 / model.fs
    n = len(expected)
    fmu = oms.FMU(str(path), instanceName=f"m{uuid.uuid4().hex[:10]}")
    fmu.instantiate()
    fmu.setStopTime(n * T + 1.0)
    fmu.setStepSize(T / 10)
    fmu.initialize()
    y = np.empty(n)
    for k in range(n):
        for name, v in inputs.items():
            fmu.setValue(name, float(v[k]))
        fmu.stepUntil((k + 0.5) * T)
        y[k] = fmu.getValue("torque")
    fmu.terminate()
    assert _agreement(y, expected, lat) < ABS_TOL


@pytest.mark.parametrize("fmi", [2, 3])
def test_fmpy_model_exchange_simulation_of_the_default_fmu(model, closed_loop, subject, me_fmus, fmi):
    """fmpy's Model Exchange simulation (``simulate_fmu``, CVode) of the default (sampled)
    variant over 20 s: after each time event the torque equals the offline prediction after
    the declared latency."""
    import fmpy

    inputs, expected, lat, _ = _case(model, closed_loop, subject, "sampled")
    path, _ = me_fmus[("sampled", fmi)]
    T = 1.0 / model.fs
    n = len(expected)
    t = np.arange(n) * T
    names = list(inputs)
    sig = np.array(list(zip(t, *[inputs[q] for q in names])), dtype=[("time", float)] + [(q, float) for q in names])
    res = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", input=sig, stop_time=t[-1], output_interval=T,
                            output=["torque"])
    last = np.r_[res["time"][1:] != res["time"][:-1], True]  # the row after each event
    y = res["torque"][last]
    assert len(y) == n
    assert _agreement(y, expected, lat) < ABS_TOL


def _me_loop(inst, inputs, T, first_set):
    """A Model Exchange event loop over the samples of ``inputs`` that sets no input in
    initialization: inputs are first set at the time ``first_set`` (s) after
    ``exitInitializationMode`` and then at each sample time before its event. Returns the
    torque after each event."""
    update = inst.fmu.newDiscreteStates if inst.fmi == 2 else inst.fmu.updateDiscreteStates
    names = list(inputs)
    ins, out = inst.refs(names), inst.refs(["torque"])
    n = len(inputs[names[0]])
    y = np.empty(n)
    k_first = int(np.ceil(first_set / T - 1e-9))
    update()
    for k in range(n):
        if k > 0:
            inst.fmu.enterContinuousTimeMode()
            if (k - 1) * T < first_set < k * T:  # the first inputs, between two samples
                inst.fmu.setTime(first_set)
                inst.set(ins, [float(inputs[q][k]) for q in names])
            inst.fmu.setTime(k * T)
            if k >= k_first:
                inst.set(ins, [float(inputs[q][k]) for q in names])
            inst.fmu.enterEventMode()
            update()
        elif first_set == 0.0:  # at the start time, after exitInitializationMode (Event Mode)
            inst.set(ins, [float(inputs[q][0]) for q in names])
        y[k] = inst.get(out)[0]
    return y


@pytest.mark.parametrize("fmi", [2, 3])
def test_inputs_first_set_after_initialization_give_a_defined_start(model, closed_loop, subject, me_fmus, fmi):
    """No input set in initialization: inputs set at the start time after
    ``exitInitializationMode`` give the same run as inputs set in initialization (sample 0
    takes them, no start-up jump); inputs first set between two samples start the model at
    the next sample, at rest until then: the torque from there on is the offline prediction
    of the record from that sample."""
    from fmu_helpers import FMUInstance

    kind = "sampled"
    path, unzipdir = me_fmus[(kind, fmi)]
    inputs, _, lat, _ = _case(model, closed_loop, subject, kind, seconds=3.0)
    T = 1.0 / model.fs
    y0 = _me_loop(FMUInstance(path, unzipdir, "a", "me").initialize(), inputs, T, 0.0)
    expected = reference(model, inputs["position"], inputs["scheduling"], kind)["torque"]
    assert _agreement(y0, expected, lat) < ABS_TOL
    assert np.all(y0[:lat] == y0[0])  # within the latency: the torque at rest, no jump
    start = 25  # first inputs at 24.5 samples: sample 0 of the model is sample 25 of the record
    y1 = _me_loop(FMUInstance(path, unzipdir, "b", "me").initialize(), inputs, T, (start - 0.5) * T)
    later = reference(model, inputs["position"][start:], inputs["scheduling"][start:], kind)["torque"]
    assert np.all(y1[:start + lat] == y0[0])
    assert _agreement(y1[start:], later, lat) < ABS_TOL


def _oms_table_run(oms, fmu_path, inputs, T, folder, max_step=None):
    """OMSimulator's own loop over a strongly coupled system (its Model Exchange solver, CVode)
    of the FMU with its inputs from a CSV table, built with its C API (its Python SSP API puts
    a table and a Model Exchange FMU in different simulation units and cannot connect them).
    The torque is read half a sample after each sample time."""
    from OMSimulator.capi import Capi, Status

    names = list(inputs)
    n = len(inputs[names[0]])
    csv = folder / "inputs.csv"
    with open(csv, "w") as f:  # two rows past the end: the solver looks a little ahead
        f.write("time," + ",".join(names) + "\n")
        for k in range(n + 2):
            f.write(f"{k * T!r}," + ",".join(repr(float(inputs[q][min(k, n - 1)])) for q in names) + "\n")
    name = f"t{uuid.uuid4().hex[:10]}"

    def ok(status, what):
        assert status == Status.ok, f"OMSimulator {what}: {status}"

    ok(Capi.setTempDirectory(str(folder)), "setTempDirectory")
    ok(Capi.newModel(name), "newModel")
    ok(Capi.addSystem(f"{name}.root", 2), "addSystem (strongly coupled)")
    ok(Capi.addSubModel(f"{name}.root.m", str(fmu_path)), "addSubModel FMU")
    ok(Capi.addSubModel(f"{name}.root.tab", str(csv)), "addSubModel table")
    for q in names:
        ok(Capi.addConnection(f"{name}.root.tab.{q}", f"{name}.root.m.{q}"), "addConnection")
    ok(Capi.instantiate(name), "instantiate")
    ok(Capi.setStopTime(name, n * T), "setStopTime")
    if max_step:
        ok(Capi.setVariableStepSize(f"{name}.root", 1e-6, 1e-12, max_step), "setVariableStepSize")
    ok(Capi.initialize(name), "initialize")
    y = np.empty(n)
    for k in range(n):
        ok(Capi.stepUntil(name, (k + 0.5) * T), f"stepUntil at sample {k}")
        y[k], status = Capi.getReal(f"{name}.root.m.torque")
        ok(status, "getReal")
    ok(Capi.terminate(name), "terminate")
    ok(Capi.delete(name), "delete")
    return y


@pytest.mark.parametrize("kind", ["sampled", "exact"])
@pytest.mark.parametrize("max_step", [None, 1e-3])
def test_omsimulator_model_exchange_with_inputs_from_a_table(oms, model, closed_loop, subject, me_fmus, kind,
                                                            max_step, tmp_path, monkeypatch):
    """OMSimulator's own loop feeds the inputs from a CSV table and updates them after each
    event iteration (and again after a sliver step past the event): the FMI 2 Model Exchange
    FMU takes the inputs given at the instant of the sample, so every sample after the declared
    latency equals the offline prediction (at OMSimulator's default step and at 1 ms)."""
    monkeypatch.chdir(tmp_path)
    inputs, expected, lat, _ = _case(model, closed_loop, subject, kind)
    y = _oms_table_run(oms, me_fmus[(kind, 2)][0], inputs, 1.0 / model.fs, tmp_path, max_step)
    assert _agreement(y, expected, lat) < ABS_TOL
