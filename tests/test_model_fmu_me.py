"""The Model Exchange model FMUs (FMI 2.0 and 3.0, causal and exact variants): a sampled model
with one time event per sample. fmpy's own Model Exchange simulation (the recipe a user runs)
and a manual event loop equal the numpy prediction; checkers pass; wrong calls return an
error status and log why; FMU state round-trips; instantiate/reset/free cycles keep memory
bounded (benchmarks/bench_fmu_me.py runs 2,000 and records the result)."""

import math
import shutil
import subprocess
import sys
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmu_helpers import FMUInstance, delayed, reference

from lpvpc.export import exporter as ex

TOL = 1e-9
BUILDS = [("causal", 2), ("causal", 3), ("exact", 2), ("exact", 3)]
# the closed-loop form of the whole-joint model (lpvpc.export.closed_loop): inputs angle, angular_velocity,
# a time event per base tick (1 ms)
CLOSED_LOOP = [("closed_loop", 2), ("closed_loop", 3)]


@pytest.fixture(scope="module")
def fmus(model, subject, tmp_path_factory):
    from lpvpc.export.closed_loop import distillation_trial, export_closed_loop_fmu, fit_closed_loop
    from lpvpc.export.whole_joint import fit_whole_joint

    wj = fit_whole_joint(model, subject["ident_pair"].ut)
    cl = fit_closed_loop(wj, [distillation_trial(wj, subject["ident_pair"].ut)])
    folder = tmp_path_factory.mktemp("model_me_fmus")
    out = {}
    for variant, fmi in BUILDS + CLOSED_LOOP:
        if variant == "closed_loop":
            path = export_closed_loop_fmu(cl, folder / f"me_closed_loop_fmi{fmi}.fmu", fmi, fmi_type="me")
        else:
            path = ex.export_fmu(model, folder / f"me_{variant}_fmi{fmi}.fmu", fmi_version=fmi, variant=variant,
                                 fmi_type="me")
        out[(variant, fmi)] = (path, Path(extract(path, unzipdir=folder / f"x_{variant}_{fmi}")))
    return out


def _inputs(model, position, scheduling, variant):
    return {k: v.ravel() for k, v in ex.replay_inputs(model, position, scheduling, variant).items()}


def _reference(model, position, scheduling, variant):
    """numpy prediction as the FMU delivers it: sample k is the torque of k - latency (0 before)."""
    return delayed(reference(model, position, scheduling, variant)["torque"], ex.latency_samples(model, variant))


class MeSim(FMUInstance):
    """A manual Model Exchange master: per sample, set time and inputs, event mode, update."""

    def __init__(self, path, unzipdir, name="me"):
        super().__init__(path, unzipdir, name, "me")
        self.update = self.fmu.newDiscreteStates if self.fmi == 2 else self.fmu.updateDiscreteStates

    def run(self, inputs, h, k0=0):
        """inputs {name: array} from sample k0 on; returns the torque at each sample."""
        names = list(inputs)
        ins, out = self.refs(names), self.refs(["torque"])
        y = np.empty(len(inputs[names[0]]))
        for i in range(len(y)):
            k = k0 + i
            if k > 0:
                self.fmu.setTime(k * h)
                self.set(ins, [inputs[n][i] for n in names])
                self.fmu.enterEventMode()
            self.update()
            y[i] = self.get(out)[0]
            self.fmu.enterContinuousTimeMode()
        return y

    def free(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.mark.parametrize("variant,fmi", BUILDS + CLOSED_LOOP)
def test_fmpy_validation_and_fmutool_check_pass(fmus, variant, fmi):
    path = fmus[(variant, fmi)][0]
    assert validate_fmu(str(path)) == []
    exe = Path(sys.executable).parent / "fmutool"
    exe = exe if exe.exists() else shutil.which("fmutool")
    assert exe, "fmutool (fmu-manipulation-toolbox) is a test dependency"
    proc = subprocess.run([str(exe), "-input", str(path), "-check"], capture_output=True, text=True, timeout=120)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "ERROR" not in text, text
    assert f"No semantic error against the FMI-{fmi} standard" in text, text


@pytest.mark.parametrize("variant,fmi", BUILDS)
def test_fmpy_model_exchange_simulation_equals_numpy(model, subject, fmus, variant, fmi):
    """fmpy.simulate_fmu (Model Exchange, its default CVode solver) evaluates the outputs at the
    inputs' time: after each time event the torque equals the numpy prediction of that sample."""
    data = subject["novel"].segment(0, 1500)
    inputs = _inputs(model, data.position, data.scheduling, variant)
    names, n = list(inputs), len(data.position)
    t = np.arange(n) / model.fs
    sig = np.array(list(zip(t, *[inputs[k] for k in names])), dtype=[("time", float)] + [(k, float) for k in names])
    res = fmpy.simulate_fmu(str(fmus[(variant, fmi)][0]), fmi_type="ModelExchange", input=sig, stop_time=t[-1],
                            output_interval=1.0 / model.fs, output=["torque"])
    # fmpy records before and after each event: keep the last row of each time
    last = np.r_[res["time"][1:] != res["time"][:-1], True]
    y = res["torque"][last]
    ref = _reference(model, data.position, data.scheduling, variant)
    assert len(y) == n
    err = np.max(np.abs(y - ref)) / np.max(np.abs(ref))
    print(f"ME {variant} FMI {fmi}: fmpy simulate_fmu vs numpy {err:.1e}")
    assert err < TOL


@pytest.mark.parametrize("fmi", [2, 3])
def test_manual_event_loop_and_fmu_state_round_trip(model, subject, fmus, fmi):
    path, unzipdir = fmus[("exact", fmi)]
    data = subject["ident"].segment(0, 600)
    u = _inputs(model, data.position, data.scheduling, "exact")
    h = 1.0 / model.fs
    sim = MeSim(path, unzipdir).initialize({k: v[0] for k, v in u.items()})
    y_first = sim.run({k: v[:300] for k, v in u.items()}, h)
    state = sim.fmu.getFMUState() if fmi == 3 else sim.fmu.getFMUstate()
    ser, deser, setst = ((sim.fmu.serializeFMUState, sim.fmu.deserializeFMUState, sim.fmu.setFMUState) if fmi == 3
                         else (sim.fmu.serializeFMUstate, sim.fmu.deSerializeFMUstate, sim.fmu.setFMUstate))
    blob = ser(state)
    rest = {k: v[300:] for k, v in u.items()}
    y1 = sim.run(rest, h, 300)
    setst(state)
    y2 = sim.run(rest, h, 300)
    setst(deser(blob))
    y3 = sim.run(rest, h, 300)
    sim.free()
    ref = _reference(model, data.position, data.scheduling, "exact")
    assert np.max(np.abs(np.r_[y_first, y1] - ref)) < TOL * np.max(np.abs(ref))
    assert np.array_equal(y1, y2) and np.array_equal(y1, y3)


@pytest.mark.parametrize("variant,fmi", [("causal", 2), ("causal", 3)] + CLOSED_LOOP)
def test_wrong_calls_return_an_error_status_and_log_why(model, fmus, variant, fmi):
    path, unzipdir = fmus[(variant, fmi)]
    sim = MeSim(path, unzipdir)
    errors = lambda: [m for s, m in sim.log if s >= 3]  # noqa: E731

    def expect_error(call, *args, match):
        before = len(errors())
        with pytest.raises(FMICallException):
            call(*args)
        new = errors()[before:]
        assert new and match in new[-1], (match, new)

    expect_error(sim.fmu.enterEventMode, match="illegal call sequence")  # before initialization
    sim.initialize()
    pos = sim.vr["angle" if variant == "closed_loop" else "position"]
    h = 1.0 / model.fs / (ex.ticks_per_sample(model) if variant == "closed_loop" else 1)  # the event period
    expect_error(sim.fmu.enterEventMode, match="illegal call sequence")  # already in event mode
    expect_error(sim.set, [pos], [math.nan], match="not finite")
    expect_error(sim.get, [9999], match="unknown value reference")
    expect_error(sim.set, [sim.vr["D"]], [1.0], match="fixed parameter")
    sim.update()
    sim.fmu.enterContinuousTimeMode()
    expect_error(sim.update, match="illegal call sequence")  # not in event mode
    expect_error(sim.fmu.setTime, -1.0, match="before the last sample")
    import ctypes

    get_x = sim.fmu.fmi2GetContinuousStates if fmi == 2 else sim.fmu.fmi3GetContinuousStates
    expect_error(get_x, sim.fmu.component, (ctypes.c_double * 1)(), 1, match="no continuous states")
    # the wrong calls left the instance unchanged: it runs as a fresh instance does
    u = (_inputs(model, np.full(6, 0.02), np.zeros(6), "causal") if variant != "closed_loop" else
         {"angle": np.full(6, 0.02), "angular_velocity": np.linspace(0.0, 0.5, 6)})
    y = sim.run({k: v[1:] for k, v in u.items()}, h, 1)
    sim.free()
    fresh = MeSim(path, unzipdir, "fresh").initialize()
    fresh.update()
    fresh.fmu.enterContinuousTimeMode()
    assert np.array_equal(y, fresh.run({k: v[1:] for k, v in u.items()}, h, 1)) and np.isfinite(y).all()
    fresh.free()


def test_a_sample_stepped_over_is_applied_with_the_held_input(model, fmus):
    """A master that enters Event Mode a sample late gets both updates, the one it skipped with
    the input sampled before it (held), the same as a master that handled it on time without
    changing the input."""
    path, unzipdir = fmus[("causal", 2)]
    h = 1.0 / model.fs
    u = {k: v.ravel() for k, v in ex.replay_inputs(model, np.full(4, 0.03), np.zeros(4)).items()}
    at_rest = {k: 0.0 for k in u}  # sample 0's inputs, set in initialization
    a = MeSim(path, unzipdir, "a").initialize(at_rest)
    refs = a.refs(list(u))
    a.update()
    a.fmu.enterContinuousTimeMode()
    a.fmu.setTime(0.5 * h)  # after sample 0: the input waits for the next sample
    a.set(refs, [u[k][1] for k in u])
    a.fmu.setTime(2 * h)  # sample 1 at h was not handled
    a.fmu.enterEventMode()
    a.update()
    late = a.get(a.refs(["torque"]))[0]
    a.free()
    b = MeSim(path, unzipdir, "b").initialize(at_rest)
    b.update()
    b.fmu.enterContinuousTimeMode()
    for k in (1, 2):  # sample 1 with the input of sample 0, then the new input at sample 2
        b.fmu.setTime(k * h)
        if k == 2:
            b.set(refs, [u[n][1] for n in u])
        b.fmu.enterEventMode()
        b.update()
        b.fmu.enterContinuousTimeMode()
    on_time = b.get(b.refs(["torque"]))[0]
    b.free()
    assert late == on_time and late != 0.0


@pytest.mark.parametrize("variant,fmi", [("causal", 2), ("causal", 3)] + CLOSED_LOOP)
def test_instantiate_reset_free_cycles_have_bounded_memory(model, subject, fmus, variant, fmi):
    """200 cycles here; benchmarks/bench_fmu_me.py runs 2,000 and records the result."""
    import os

    def rss():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

    path, unzipdir = fmus[(variant, fmi)]
    data = subject["ident"].segment(0, 5)
    if variant == "closed_loop":
        u, h = {"angle": data.scheduling + data.position, "angular_velocity": np.full(5, 0.1)}, 1e-3
    else:
        u, h = _inputs(model, data.position, data.scheduling, "causal"), 1.0 / model.fs

    def cycle():
        sim = MeSim(path, unzipdir)
        sim.initialize()
        sim.run(u, h)
        sim.fmu.reset()
        sim.initialize()
        sim.run(u, h)
        sim.free()

    for _ in range(20):
        cycle()
    before = rss()
    for _ in range(200):
        cycle()
    growth = rss() - before
    assert growth < 5 * 2**20, f"RSS grew by {growth / 2**20:.2f} MB over 200 cycles"


def test_cli_exports_model_exchange(model_file, tmp_path):
    import contextlib
    import io

    from lpvpc.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        rc = main(["export", str(model_file), "--fmu", str(tmp_path / "m.fmu"), "--fmi", "3", "--fmi-type", "me"])
    assert rc == 0 and "Model Exchange" in out.getvalue()
    md = read_model_description(str(tmp_path / "m.fmu"))
    assert md.modelExchange is not None and md.coSimulation is None
    assert {v.variability for v in md.modelVariables if v.causality == "output"} == {"discrete"}
