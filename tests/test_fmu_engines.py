"""The exported FMUs in tools nobody here wrote: fmpy's ``simulate_fmu`` with the user guide's
recipe (copied verbatim from docs/guide/fmu_casadi.md), libcosim (``libcosimpy``, FMI 2.0 only) and ECOS
(``ecospy``, FMI 2.0 and 3.0; needs Debian's libtbb12), each on the virtual subject's novel
trajectory at the FMU's declared step, read at the engine's own times with the guide's
timing contract (the value at time t is the torque of sample ceil((t - L)/T) - 1), and
compared with the offline prediction. Each test prints its VAF against the offline one.

The engines are test extras (pyproject); a test is skipped with the reason when its engine
cannot be imported here.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from lpvpc.export import exporter as ex
from lpvpc.models.model import vaf

REPO = Path(__file__).resolve().parents[1]
RECIPE_PAGE = REPO / "docs" / "guide" / "fmu_casadi.md"  # the user guide's FMU page
SAMPLED_TOL = 0.5  # VAF points from the offline prediction (the floor for simulate_fmu)
ENGINE_TOL = 1.0  # VAF points from the offline prediction (the floor for libcosim and ECOS)


@pytest.fixture(scope="module")
def fmus(model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("engine_fmus")
    return {(v, fmi): ex.export_fmu(model, folder / f"model_{v}_fmi{fmi}.fmu", fmi_version=fmi, variant=v)
            for v in ("sampled",) for fmi in (2, 3)}


def _offline(model, data, variant):
    """The offline prediction of the model form the FMU runs (causal IRF for the default
    FMU, the two-sided model for the exact one) and the two-sided one."""
    return (model.predict(data.position, data.scheduling, causal=variant == "sampled", warn=False).total,
            model.predict(data.position, data.scheduling, warn=False).total)


def _contract(md):
    """(T, L) in s from the FMU's constant outputs."""
    c = {v.name: float(v.start) for v in md.modelVariables if v.variability == "constant"}
    return c["sample_period"], c["latency"]


def _sample_index(times, T, L):
    """The guide's timing contract: the output at time t is the torque of sample
    ceil((t - L) / T) - 1 (times within 1e-6 T of a sample time count as on it)."""
    return np.ceil((np.asarray(times) - L) / T - 1e-6).astype(int) - 1


def _report(name, data, y, k, offline, two_sided, tol):
    ok = (k >= 0) & (k < len(data.torque))
    assert ok.sum() >= len(data.torque) - 2, (name, ok.sum())
    got = vaf(data.torque[k[ok]], y[ok])
    ref, ref2 = vaf(data.torque, offline), vaf(data.torque, two_sided)
    err = float(np.max(np.abs(y[ok] - offline[k[ok]])))
    print(f"{name}: VAF {got:.3f} % vs offline {ref:.3f} % (two-sided {ref2:.3f} %); max |FMU - offline| "
          f"{err:.1e} N m")
    assert abs(got - ref) < tol, (name, got, ref)
    # issue 12's floor: within 0.5 point of the offline (two-sided) prediction; the default
    # 5-point causal form costs 0.08 here (3-point differences cost 0.6)
    assert ref2 - got <= 0.5, (name, got, ref2)
    return got, err


def _guide_recipe() -> str:
    text = RECIPE_PAGE.read_text()
    m = re.search(r"<!-- fmu-recipe -->\s*```python\n(.*?)```\s*<!-- /fmu-recipe -->", text, re.S)
    assert m, f"{RECIPE_PAGE.relative_to(REPO)} has no fmu-recipe block"
    return m.group(1)


@pytest.mark.slow
@pytest.mark.parametrize("variant,fmi", [("sampled", 2), ("sampled", 3)])
def test_guide_recipe_with_simulate_fmu(model, subject, fmus, tmp_path, monkeypatch, variant, fmi):
    """The user guide's fmpy recipe, verbatim: the torque it returns is the offline prediction
    (to rounding), so its VAF is within 0.5 point of the offline one."""
    data = subject["novel"]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "model.fmu").write_bytes(Path(fmus[(variant, fmi)]).read_bytes())
    env = {"position": data.position, "scheduling": data.scheduling}
    exec(compile(_guide_recipe(), "docs/guide/fmu_casadi.md:fmu-recipe", "exec"), env)
    torque = np.asarray(env["torque"])
    assert torque.shape == data.torque.shape
    offline, two_sided = _offline(model, data, variant)
    k = np.arange(len(torque))
    _, err = _report(f"simulate_fmu (guide recipe), {variant} FMI {fmi}", data, torque, k, offline, two_sided,
                     SAMPLED_TOL)
    assert err < 1e-9 * np.max(np.abs(offline))


def _feed(data, times, T):
    """Inputs at the engine's communication points: the record's sample at or before t."""
    k = np.minimum(np.floor(np.asarray(times) / T + 1e-6).astype(int), len(data.position) - 1)
    return data.position[k], data.scheduling[k]


@pytest.mark.slow
def test_libcosim_at_the_declared_step(model, subject, fmus):
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
    except (ImportError, OSError) as exc:  # not installed, or its library does not load here
        pytest.skip(f"libcosimpy not usable here: {exc}")
    log_output_level(CosimLogLevel.ERROR)
    data = subject["novel"]
    path = fmus[("sampled", 2)]  # libcosim has no FMI 3
    md = read_model_description(str(path))
    T, L = _contract(md)
    step = float(md.defaultExperiment.stepSize)
    execution = CosimExecution.from_step_size(int(round(step * 1e9)))  # ns
    idx = execution.add_local_slave(CosimLocalSlave(fmu_path=str(path), instance_name="model"))
    vr = {v.name.decode(): v.reference for v in execution.slave_variables(idx)}
    override = CosimManipulator.create_override()
    execution.add_manipulator(override)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    n_steps = int(round((len(data.position) * T + L + T) / step))
    times, y = np.empty(n_steps), np.empty(n_steps)
    t = 0.0
    for i in range(n_steps):
        p, r = _feed(data, [t], T)
        override.slave_real_values(idx, [vr["position"], vr["scheduling"]], [float(p[0]), float(r[0])])
        assert execution.step(1)
        t = execution.status().current_time * 1e-9  # the engine's own time
        times[i] = t
        y[i] = observer.last_real_values(idx, [vr["torque"]])[0]
    offline, two_sided = _offline(model, data, "sampled")
    _report(f"libcosim, step {step * 1e3:g} ms, sampled FMI 2", data, y, _sample_index(times, T, L), offline,
            two_sided, ENGINE_TOL)


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_ecos_at_the_declared_step(model, subject, fmus, fmi):
    try:
        from ecospy.EcosSimulation import EcosSimulation
        from ecospy.EcosSimulationStructure import EcosSimulationStructure
    except (ImportError, OSError) as exc:  # ecospy's library needs Debian's libtbb12 (make test installs it)
        pytest.skip(f"ecospy not usable here: {exc}")
    data = subject["novel"]
    path = fmus[("sampled", fmi)]
    md = read_model_description(str(path))
    T, L = _contract(md)
    step = float(md.defaultExperiment.stepSize)
    structure = EcosSimulationStructure()
    structure.add_model("model", str(path))
    sim = EcosSimulation(structure=structure, step_size=step)
    sim.init()
    n_steps = int(round((len(data.position) * T + L + T) / step))
    times, y = np.empty(n_steps), np.empty(n_steps)
    for i in range(n_steps):
        p, r = _feed(data, [sim.get_time()], T)
        sim.set_real("model::position", float(p[0]))
        sim.set_real("model::scheduling", float(r[0]))
        sim.step(1)
        times[i] = sim.get_time()  # the engine's own time
        y[i] = sim.get_real("model::torque")
    sim.terminate()
    assert all(math.isfinite(v) for v in y)
    offline, two_sided = _offline(model, data, "sampled")
    _report(f"ECOS, step {step * 1e3:g} ms, sampled FMI {fmi}", data, y, _sample_index(times, T, L), offline,
            two_sided, ENGINE_TOL)
