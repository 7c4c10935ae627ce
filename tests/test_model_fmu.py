"""The model FMUs (FMI 2.0 and 3.0 co-simulation, causal and exact variants): replay equals
the numpy prediction, the default (causal) FMU keeps the offline VAF, checkers pass,
wrong calls return an error status, instances are independent, FMU state round-trips,
scheduling outside the identified range is clamped."""

import math
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmu_helpers import FMUInstance, reference, shifted_error

from lpvpc import __version__
from lpvpc.models import equations as eq
from lpvpc.export import exporter as ex
from lpvpc.models.model import vaf

TOL = 1e-9
BUILDS = [("sampled", 2), ("sampled", 3), ("causal", 2), ("causal", 3), ("exact", 2), ("exact", 3)]
# the closed-loop form of the whole-joint model (lpvpc.export.closed_loop): inputs angle, angular_velocity
CLOSED_LOOP = [("closed_loop", 2), ("closed_loop", 3)]


@pytest.fixture(scope="module")
def closed_loop(model, subject):
    from lpvpc.export.closed_loop import distillation_trial, fit_closed_loop
    from lpvpc.export.whole_joint import fit_whole_joint

    wj = fit_whole_joint(model, subject["ident_pair"].ut)
    return fit_closed_loop(wj, [distillation_trial(wj, subject["ident_pair"].ut)])


def _closed_loop_reference(cl, inputs):
    """The closed-loop tick function's (torque, torque_intrinsic, torque_reflex) over ``inputs``."""
    from lpvpc.export.closed_loop import closed_loop_step

    step = closed_loop_step(cl)
    out = ex.trajectory_function(step, len(inputs["angle"]))(
        state=np.zeros(step.size1_in(0)), angle=inputs["angle"][None, :],
        angular_velocity=inputs["angular_velocity"][None, :])
    return np.column_stack([np.asarray(out[k]).ravel() for k in ex.OUTPUT_NAMES[1:]])


@pytest.fixture(scope="module")
def fmus(model, closed_loop, tmp_path_factory):
    """Each FMU built once: {(variant, fmi_version): (path, extracted dir, timings)}."""
    from lpvpc.export.closed_loop import export_closed_loop_fmu

    folder = tmp_path_factory.mktemp("model_fmus")
    out = {}
    for variant, fmi in BUILDS + CLOSED_LOOP:
        timings = {}
        if variant == "closed_loop":
            path = export_closed_loop_fmu(closed_loop, folder / f"closed_loop_fmi{fmi}.fmu", fmi)
        else:
            path = ex.export_fmu(model, folder / f"model_{variant}_fmi{fmi}.fmu", fmi_version=fmi, variant=variant,
                                 timings=timings)
        out[(variant, fmi)] = (path, Path(extract(path, unzipdir=folder / f"x_{variant}_{fmi}")), timings)
    return out


class Sim(FMUInstance):
    """A co-simulation instance (tests/fmu_helpers.py) that replays a record."""

    def __init__(self, path, unzipdir, name="inst"):
        super().__init__(path, unzipdir, name, "cs")
        self.slave = self.fmu

    @property
    def sampled(self):  # the wrapper's sampled mode: the default (sampled) variant
        return self.md.coSimulation.modelIdentifier == "lpvpc_model"

    def replay(self, inputs, t0=0.0, h=0.01):
        """inputs: {name: array}; returns (n, 3) torque, torque_intrinsic, torque_reflex: read
        before doStep (direct feedthrough), or after it for the sampled FMU (row k then holds
        the torque of sample k - 1, its declared latency)."""
        names = list(inputs)
        U = np.column_stack([inputs[k] for k in names])
        ins, outs = self.refs(names), self.refs(ex.OUTPUT_NAMES[1:])
        Y = np.empty((len(U), 3))
        for k in range(len(U)):
            self.set(ins, list(U[k]))
            if self.sampled:
                self.slave.doStep(t0 + k * h, h)
            Y[k] = self.get(outs)
            assert np.all(np.isfinite(Y[k])), (k, Y[k])
            if not self.sampled:
                self.slave.doStep(t0 + k * h, h)
        return Y

    def free(self):
        self.slave.freeInstance()


def _inputs(model, position, scheduling, variant):
    rows = ex.replay_inputs(model, position, scheduling, variant)
    return {k: v.ravel() for k, v in rows.items()}


def _ref(model, position, scheduling, variant):
    return np.column_stack(list(reference(model, position, scheduling, variant).values()))


def _rel_err(Y, ref, latency):
    return shifted_error(Y, ref, latency, np.max(np.abs(ref[:, 0])))


@pytest.mark.parametrize("variant,fmi", BUILDS)
def test_replay_equals_numpy_prediction(model, subject, fmus, variant, fmi):
    """A manual fmpy loop (set inputs, read outputs, doStep) over the 2-minute record."""
    data = subject["ident"]
    path, unzipdir, _ = fmus[(variant, fmi)]
    sim = Sim(path, unzipdir).initialize()
    Y = sim.replay(_inputs(model, data.position, data.scheduling, variant), h=1.0 / model.fs)
    sim.slave.terminate()
    sim.free()
    lat = ex.latency_samples(model, variant)
    err = _rel_err(Y, _ref(model, data.position, data.scheduling, variant), lat)
    assert err < TOL, f"{variant} FMI {fmi}: max abs error / max abs torque = {err:.2e}"
    assert not [m for s, m in sim.log if s >= 2], sim.log


def test_causal_fmu_keeps_the_offline_vaf_on_novel_record(model, subject, fmus):
    """The default FMU (causal, no latency) versus the offline two-sided prediction, both
    against the measured torque of the novel held-out trajectory."""
    data = subject["novel"]
    path, unzipdir, _ = fmus[("causal", 2)]
    sim = Sim(path, unzipdir).initialize()
    Y = sim.replay(_inputs(model, data.position, data.scheduling, "causal"), h=1.0 / model.fs)
    sim.free()
    offline = model.predict(data.position, data.scheduling, warn=False).total
    vaf_fmu, vaf_offline = vaf(data.torque, Y[:, 0]), vaf(data.torque, offline)
    message = f"novel record: causal FMU VAF {vaf_fmu:.2f} %, offline two-sided VAF {vaf_offline:.2f} %"
    assert abs(vaf_fmu - vaf_offline) < 1.0, message
    assert vaf_offline > vaf(data.torque, subject["novel_clean"].torque) - 1.0, message  # the noise ceiling
    print(message)


@pytest.mark.parametrize("variant,fmi", BUILDS)
def test_model_description(model, fmus, variant, fmi):
    path, _, timings = fmus[(variant, fmi)]
    md = read_model_description(path)
    assert md.fmiVersion == ("2.0" if fmi == 2 else "3.0")
    tick = 1.0 / model.fs / (ex.ticks_per_sample(model) if variant == "sampled" else 1)
    assert float(md.defaultExperiment.stepSize) == pytest.approx(tick, rel=1e-15)
    assert f"lpvpc {__version__}" in md.description and model.model_hash in md.description
    variables = {v.name: v for v in md.modelVariables}
    expected_inputs = ["position", "scheduling"] + (["velocity", "acceleration"] if variant == "causal" else [])
    assert [v.name for v in md.modelVariables if v.causality == "input"] == expected_inputs
    assert [v.name for v in md.modelVariables if v.causality == "output"] == list(ex.OUTPUT_NAMES[1:]) + [
        "latency", "sample_period"] + (["derivative_points"] if variant == "causal" else [])
    if variant == "causal":  # the differences a master must supply, as the model was identified
        assert float(variables["derivative_points"].start) == ex.derivative_points(model) == 5
    # the timing contract as declared constant outputs
    assert variables["latency"].variability == "constant" and variables["latency"].unit == "s"
    assert float(variables["latency"].start) == pytest.approx(ex.latency_samples(model, variant) / model.fs)
    assert float(variables["sample_period"].start) == pytest.approx(1.0 / model.fs)
    assert {variables[n].unit for n in ("position", "scheduling")} == {"rad"}
    assert all(variables[n].unit == "N.m" for n in ex.OUTPUT_NAMES[1:])
    if variant == "causal":
        assert variables["velocity"].unit == "rad/s" and variables["acceleration"].unit == "rad/s2"
    params = [v for v in md.modelVariables if v.causality == "parameter"]
    assert [v.name for v in params] == [ex.fmu_parameter_name(n) for n in ex.parameter_names(model, variant)]
    assert np.array_equal([float(v.start) for v in params], ex.parameter_vector(model, variant))
    units_defined = {u.name for u in md.unitDefinitions}
    assert {v.unit for v in md.modelVariables if v.unit} <= units_defined
    # latency: in the description and the vendor annotation
    root = ET.fromstring(zipfile.ZipFile(path).read("modelDescription.xml"))
    latency = float(root.find(".//Latency").get("seconds"))
    assert latency == pytest.approx(ex.latency_samples(model, variant) / model.fs)
    if variant != "causal":
        assert latency > 0 and "latency" in md.description
    else:
        assert latency == 0.0
    assert timings["total"] > 0


@pytest.mark.parametrize("variant,fmi", BUILDS + CLOSED_LOOP)
def test_fmpy_validation_reports_nothing(fmus, variant, fmi):
    assert validate_fmu(str(fmus[(variant, fmi)][0])) == []


@pytest.mark.parametrize("variant,fmi", [("sampled", 2), ("sampled", 3), ("causal", 2), ("exact", 2)] + CLOSED_LOOP)
def test_fmutool_check_passes(fmus, variant, fmi):
    exe = Path(sys.executable).parent / "fmutool"
    if not exe.exists():
        exe = shutil.which("fmutool")
    assert exe, "fmutool (fmu-manipulation-toolbox) is a test dependency"
    proc = subprocess.run([str(exe), "-input", str(fmus[(variant, fmi)][0]), "-check"], capture_output=True,
                          text=True, timeout=120)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text
    assert f"compliant with FMI-{fmi}.0" in text and f"No semantic error against the FMI-{fmi} standard" in text, text
    assert "ERROR" not in text, text


@pytest.mark.parametrize("variant,fmi", [("causal", 2), ("exact", 3)])
def test_fmpy_compile_rebuilds_from_sources(model, subject, fmus, tmp_path, variant, fmi):
    """The shipped sources/ rebuild the binary (fmpy compile) and the rebuilt FMU still
    equals the numpy prediction."""
    from fmpy.build import build_platform_binary

    path = fmus[(variant, fmi)][0]
    unzipdir = Path(extract(path, unzipdir=tmp_path / "fmu"))
    shutil.rmtree(unzipdir / "binaries")
    (tmp_path / "cmake").mkdir()
    build_platform_binary(unzipdir=unzipdir, build_dir=tmp_path / "cmake")
    assert list((unzipdir / "binaries").rglob("*.so"))
    data = subject["ident"].segment(0, 1500)
    sim = Sim(path, unzipdir).initialize()
    Y = sim.replay(_inputs(model, data.position, data.scheduling, variant), h=1.0 / model.fs)
    sim.free()
    err = _rel_err(Y, _ref(model, data.position, data.scheduling, variant), ex.latency_samples(model, variant))
    assert err < TOL


@pytest.mark.parametrize("variant,fmi", [("sampled", 2), ("sampled", 3), ("causal", 2), ("causal", 3),
                                         ("exact", 2)] + CLOSED_LOOP)
def test_wrong_calls_return_an_error_status_and_log_why(model, closed_loop, fmus, variant, fmi):
    path, unzipdir, _ = fmus[(variant, fmi)]
    h = 1.0 / model.fs
    tick = h / (ex.ticks_per_sample(model) if variant in ("sampled", "closed_loop") else 1)
    sim = Sim(path, unzipdir)
    errors = lambda: [m for s, m in sim.log if s >= 3]  # noqa: E731

    def expect_error(call, *args, match):
        before = len(errors())
        with pytest.raises(FMICallException):
            call(*args)
        new = errors()[before:]
        assert new and match in new[-1], (match, new)

    # illegal call order: a step before initialization
    expect_error(sim.slave.doStep, 0.0, h, match="illegal call sequence")
    sim.initialize()
    pos = sim.vr["angle" if variant == "closed_loop" else "position"]
    expect_error(sim.slave.doStep, 0.5, h, match="does not match the FMU time")
    expect_error(sim.slave.doStep, 0.0, 0.0, match="must be > 0")
    expect_error(sim.slave.doStep, 0.0, -h, match="must be > 0")
    expect_error(sim.slave.doStep, 0.5 * tick, tick, match="does not match the FMU time")
    expect_error(sim.set, [pos], [math.nan], match="not finite")
    expect_error(sim.get, [9999], match="unknown value reference")
    expect_error(sim.set, [sim.vr["D"]], [1.0], match="fixed parameter")  # after initialization
    expect_error(sim.set, [sim.vr["latency"]], [0.0], match="cannot be set")  # a constant output
    # the wrong calls left the instance unchanged: it still reproduces the prediction
    if variant == "closed_loop":  # its reference: the tick function, at 1 ms communication steps
        u = {"angle": np.full(25, 0.02), "angular_velocity": np.linspace(0.0, 0.5, 25)}
        Y = sim.replay(u, h=tick)
        ref = _closed_loop_reference(closed_loop, u)
        assert np.max(np.abs(Y - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref)))
        sim.slave.doStep(25 * tick, 3 * h)  # a step of several sample periods is fine (inputs held)
        sim.free()
        return
    data_pos, data_rho = np.full(5, 0.02), np.zeros(5)
    Y = sim.replay(_inputs(model, data_pos, data_rho, variant), h=h)
    ref = _ref(model, data_pos, data_rho, variant)
    lat = ex.latency_samples(model, variant)
    assert np.max(np.abs(Y[lat:] - ref[:5 - lat])) <= 1e-12 * max(1.0, np.max(np.abs(ref)))
    # a step of several sample periods is fine (inputs held)
    sim.slave.doStep(5 * h, 3 * h)
    sim.free()


def test_instances_are_independent(model, subject, fmus):
    path, unzipdir, _ = fmus[("causal", 2)]
    a = Sim(path, unzipdir, "a").initialize()
    b = Sim(path, unzipdir, "b").initialize()
    data = subject["ident"].segment(0, 800)
    other = subject["novel"].segment(0, 800)
    ua, ub = _inputs(model, data.position, data.scheduling, "causal"), _inputs(
        model, other.position, other.scheduling, "causal")
    h = 1.0 / model.fs
    Ya, Yb = np.empty((800, 3)), np.empty((800, 3))
    outs = a.refs(ex.OUTPUT_NAMES[1:])
    for k in range(800):  # interleaved
        for sim, u, Y in ((a, ua, Ya), (b, ub, Yb)):
            sim.set(sim.refs(list(u)), [u[n][k] for n in u])
            Y[k] = sim.get(outs)
            sim.slave.doStep(k * h, h)
    a.free()
    b.free()
    assert _rel_err(Ya, _ref(model, data.position, data.scheduling, "causal"), 0) < TOL
    assert _rel_err(Yb, _ref(model, other.position, other.scheduling, "causal"), 0) < TOL


@pytest.mark.parametrize("fmi", [2, 3])
def test_fmu_state_round_trips(model, subject, fmus, fmi):
    path, unzipdir, _ = fmus[("exact", fmi)]
    data = subject["ident"].segment(0, 600)
    u = _inputs(model, data.position, data.scheduling, "exact")
    first = {k: v[:300] for k, v in u.items()}
    rest = {k: v[300:] for k, v in u.items()}
    h = 1.0 / model.fs
    sim = Sim(path, unzipdir).initialize()
    sim.replay(first, h=h)
    state = sim.slave.getFMUState()
    blob = sim.slave.serializeFMUState(state)
    Y1 = sim.replay(rest, t0=300 * h, h=h)
    sim.slave.setFMUState(state)
    Y2 = sim.replay(rest, t0=300 * h, h=h)
    restored = sim.slave.deserializeFMUState(blob)
    sim.slave.setFMUState(restored)
    Y3 = sim.replay(rest, t0=300 * h, h=h)
    sim.slave.freeFMUState(state)
    sim.slave.freeFMUState(restored)
    sim.free()
    assert np.array_equal(Y1, Y2) and np.array_equal(Y1, Y3)
    whole = _ref(model, data.position, data.scheduling, "exact")
    lat = ex.latency_samples(model, "exact")
    assert np.max(np.abs(Y1[:, 0] - whole[300 - lat: 600 - lat, 0])) < TOL * np.max(np.abs(whole[:, 0]))


@pytest.mark.parametrize("variant", ["causal", "exact"])
def test_scheduling_out_of_range_is_clamped(model, subject, fmus, variant):
    """Scheduling far outside the identified range: finite outputs, equal to the numpy
    prediction, which holds the model at the range boundary."""
    data = subject["ident"].segment(0, 1000)
    lo, hi = model.scheduling_range
    scheduling = np.concatenate([np.full(300, lo - 1.0), np.linspace(lo - 0.3, hi + 0.3, 400),
                                 np.full(300, hi + 2.0)])
    path, unzipdir, _ = fmus[(variant, 2)]
    sim = Sim(path, unzipdir).initialize()
    Y = sim.replay(_inputs(model, data.position, scheduling, variant), h=1.0 / model.fs)
    sim.free()
    assert np.all(np.isfinite(Y))
    lat = ex.latency_samples(model, variant)
    with pytest.warns(Warning, match="outside the identified range"):
        ref = model.predict(data.position, scheduling, causal=variant == "causal")
    ref = np.column_stack([ref.total, ref.intrinsic, ref.reflex])
    assert _rel_err(Y, ref, lat) < TOL
    if model.intrinsic_basis.extrapolation == "clip":  # (the default structure may choose "linear" continuation:
        clamped = _ref(model, data.position, np.clip(scheduling, lo, hi), variant)  # then the FMU equals numpy's)
        assert _rel_err(Y, clamped, lat) < TOL


def test_parameters_are_settable_before_initialization(model, subject, fmus):
    import dataclasses

    changed = dataclasses.replace(model, H_causal=1.5 * model.H_causal, D=model.D - 0.2)
    names = [ex.fmu_parameter_name(n) for n in ex.parameter_names(model)]
    params = dict(zip(names, ex.parameter_vector(changed)))
    data = subject["ident"].segment(0, 1000)
    path, unzipdir, _ = fmus[("causal", 3)]
    sim = Sim(path, unzipdir).initialize(params)
    Y = sim.replay(_inputs(model, data.position, data.scheduling, "causal"), h=1.0 / model.fs)
    sim.free()
    assert _rel_err(Y, _ref(changed, data.position, data.scheduling, "causal"), 0) < TOL


def test_closed_loop_inputs_velocity_acceleration_are_used(model, fmus):
    """In closed loop the actuator supplies velocity and acceleration: the causal FMU uses
    the given values, not differences of position."""
    path, unzipdir, _ = fmus[("causal", 2)]
    rng = np.random.default_rng(5)
    n = 200
    position = 0.01 * rng.standard_normal(n)
    vel, acc = rng.standard_normal(n), 30 * rng.standard_normal(n)
    scheduling = np.full(n, -0.1)
    sim = Sim(path, unzipdir).initialize()
    Y = sim.replay({"position": position, "scheduling": scheduling, "velocity": vel, "acceleration": acc},
                   h=1.0 / model.fs)
    sim.free()
    p = model.predict(position, scheduling, causal=True, velocity=vel, acceleration=acc, warn=False)
    assert _rel_err(Y, np.column_stack([p.total, p.intrinsic, p.reflex]), 0) < TOL
    assert not np.allclose(p.intrinsic, model.predict(position, scheduling, causal=True, warn=False).intrinsic)


def test_replay_helper_signals_match_equations(model):
    x = np.linspace(0, 1, 50) ** 2
    rows = _inputs(model, x, x, "causal")
    vel, acc = eq.derivatives(x, model.fs, model.causal_derivatives)  # the model's stencil
    assert np.array_equal(rows["velocity"], vel) and np.array_equal(rows["acceleration"], acc)


@pytest.mark.parametrize("fmi", [2, 3])
def test_sampled_fmu_any_multiple_of_the_base_tick(model, subject, fmus, fmi):
    """canHandleVariableCommunicationStepSize is true: a random sequence of communication
    steps, each a multiple of the 1-ms base tick (some ending between sample times, some
    spanning several), follows the timing contract exactly: each sample takes the inputs
    set at the start of the step that contains its time, and after a step ending at t the
    output is the torque of sample ceil((t - L) / T) - 1."""
    data = subject["novel"].segment(0, 400)
    path, unzipdir, _ = fmus[("sampled", fmi)]
    sim = Sim(path, unzipdir).initialize()
    assert sim.md.coSimulation.canHandleVariableCommunicationStepSize
    T = 1.0 / model.fs
    N = ex.ticks_per_sample(model)
    tick = T / N
    rng = np.random.default_rng(5)
    ins, outs = sim.refs(["position", "scheduling"]), sim.refs(["torque"])
    used = np.full(len(data.position), -1)  # record index whose inputs sample k took
    ticks, log = 0, []
    while ticks < (len(data.position) - 2) * N:
        j = ticks // N  # the record sample at or before this communication point
        sim.set(ins, [data.position[j], data.scheduling[j]])
        n = int(rng.choice([1, 2, 3, 5, 7, 10, 13, 25]))
        for s in range(ticks, ticks + n):  # samples whose time lies in [t, t + h)
            if s % N == 0:
                used[s // N] = j
        sim.slave.doStep(ticks * tick, n * tick)
        ticks += n
        log.append((ticks * tick, sim.get(outs)[0]))
    sim.free()
    k_max = int(np.max(np.nonzero(used >= 0)))
    pos, rho = data.position[used[:k_max + 1]], data.scheduling[used[:k_max + 1]]
    expected = model.predict(pos, rho, causal=True, warn=False).total  # what the samples saw
    L = ex.latency_samples(model, "sampled") * T
    checked = 0
    for t, y in log:
        k = int(math.ceil((t - L) / T - 1e-6)) - 1
        if 0 <= k < k_max:  # sample k's torque needs sample k + 1's position
            assert abs(y - expected[k]) < 1e-9 * np.max(np.abs(expected)), (t, k, y, expected[k])
            checked += 1
    assert checked > 100 and np.any(used[:k_max] != np.arange(k_max))  # stale inputs did occur
