"""examples/mujoco_exoskeleton.py: the closed-loop ankle model on a MuJoCo foot hinge with a PD
exoskeleton. Runs where MuJoCo is installed (the test extra has it; ``pip install mujoco``)."""

import runpy
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco", reason="MuJoCo is not installed (pip install 'lpvpc[mujoco]')")

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "mujoco_exoskeleton.py"
DURATION = 5.0  # s simulated per run


@pytest.fixture(scope="module")
def example():
    return runpy.run_path(str(EXAMPLE))


@pytest.fixture(scope="module")
def ankle(example, tmp_path_factory):
    """The example's own model (identified from 60 s of the virtual subject), saved as the CLI
    writes it, and its FMU."""
    from lpvpc.export.closed_loop import export_closed_loop_fmu

    folder = tmp_path_factory.mktemp("mujoco")
    cl = example["closed_loop_model"]()
    cl.save(folder / "cl.json")
    return {"cl": cl, "path": folder / "cl.json", "fmu": export_closed_loop_fmu(cl, folder / "ankle.fmu")}


@pytest.fixture(scope="module")
def runs(example, ankle):
    """Both gains, both torque sources, 5 s at MuJoCo's 1 ms step, from the model file."""
    return example["main"](ankle["path"], ankle["fmu"], kps=(40.0, 150.0), duration=DURATION, keep_runs=True)


def test_stable_and_tracking_at_both_gains_with_both_torque_sources(runs):
    """Stable at Kp 40 and 150 N m/rad, no NaN, the foot within the ankle's range, tracking the
    reference within 10 mrad RMS after the first second; the CasADi tick and the FMU give the
    same torque."""
    assert set(runs) == {(kp, s) for kp in (40.0, 150.0) for s in ("casadi", "fmu")}
    for key, s in runs.items():
        r = s["run"]
        assert s["stable"] and s["finite"], key
        assert len(r["angle"]) == int(DURATION / 1e-3) and np.all(np.isfinite(r["exo_torque"])), key
        assert s["max_angle"] < 0.5, key  # rad: the reference spans -0.35..+0.15
        assert s["rms_error"] < 0.01 and s["max_error"] < 0.05, key  # rad, after the first second
        assert s["realtime_factor"] > 1.0, key
    for kp in (40.0, 150.0):
        a, b = runs[(kp, "casadi")]["run"], runs[(kp, "fmu")]["run"]
        assert np.max(np.abs(a["torque"] - b["torque"])) < 1e-9  # N m
        assert np.max(np.abs(a["angle"] - b["angle"])) < 1e-12  # rad
    assert runs[(150.0, "casadi")]["rms_error"] < runs[(40.0, "casadi")]["rms_error"]  # the stiffer controller


def test_mujoco_loop_is_the_projects_loop_and_follows_the_subject(example, ankle, runs):
    """MuJoCo's Euler step is the plant step of lpvpc.simulation.compliant_loop: the same FMU in
    both loops gives the same run; the virtual subject in that loop moves as the model does."""
    from lpvpc.models.model import vaf
    from lpvpc.simulation.compliant_loop import FmuSource, LoopSetup, VirtualSubject, run_loop

    mj = runs[(40.0, "fmu")]["run"]
    feedforward = ankle["cl"].whole.quasi_static(mj["reference"])
    source = FmuSource(ankle["fmu"])
    try:
        own = run_loop(source, mj["reference"], LoopSetup(kp=40.0, kd=example["KD"]), assist=feedforward)
    finally:
        source.close()
    assert own.stable
    assert np.max(np.abs(own.angle - mj["angle"])) < 1e-9  # rad
    assert np.max(np.abs(own.torque - mj["torque"])) < 1e-9  # N m
    subject = run_loop(VirtualSubject(), mj["reference"], LoopSetup(kp=40.0, kd=example["KD"]), assist=feedforward)
    after = 1000  # samples: the first second left out (the loop settles from rest)
    assert vaf((subject.angle - subject.reference)[after:], (mj["angle"] - mj["reference"])[after:]) > 95.0


def test_mujoco_steps_other_than_the_tick(example, ankle, runs):
    """A MuJoCo step of 0.5 ms (the tick every second step, its torque held) or 2 ms (two ticks per
    step) gives nearly the 1 ms run; 0.7 ms is refused before the run."""
    clock_ratio = example["clock_ratio"]
    assert clock_ratio(1e-3, 1e-3) == (1, 1)
    assert clock_ratio(2e-3, 1e-3) == (2, 1) and clock_ratio(5e-4, 1e-3) == (1, 2)
    assert clock_ratio(0.1 * 3, 1e-3) == (300, 1)  # a step built by arithmetic, not exactly 0.3
    base = runs[(150.0, "casadi")]
    for step in (5e-4, 2e-3):
        out = example["main"](ankle["cl"], ankle["fmu"], kps=(150.0,), duration=DURATION, timestep=step)
        for source in ("casadi", "fmu"):
            s = out[(150.0, source)]
            assert s["stable"] and abs(s["rms_error"] - base["rms_error"]) < 1e-3, (step, source, s)
        assert out[(150.0, "casadi")]["rms_error"] == pytest.approx(out[(150.0, "fmu")]["rms_error"], abs=1e-12)
    with pytest.raises(ValueError, match=r"timestep 0\.0007 s is neither a whole number of the model's ticks"):
        example["main"](ankle["cl"], kps=(40.0,), duration=0.1, timestep=7e-4, sources=("casadi",))


def test_gravity_and_the_foot_weight(example, ankle, runs):
    """The virtual subject's model holds no weight: gravity cancelled on the foot ("in-model") gives
    the run without gravity; gravity on the foot ("not-in-model") pulls it toward plantarflexion."""
    cl = ankle["cl"]
    base = runs[(40.0, "casadi")]["run"]
    kw = dict(kps=(40.0,), duration=DURATION, sources=("casadi",), keep_runs=True)
    cancelled = example["main"](cl, gravity="in-model", **kw)[(40.0, "casadi")]["run"]
    assert np.array_equal(cancelled["angle"], base["angle"])
    pulled = example["main"](cl, gravity="not-in-model", **kw)[(40.0, "casadi")]["run"]
    weight = example["FOOT_MASS"] * example["GRAVITY"] * example["FOOT_COM"]  # N m, foot horizontal
    shift = np.mean((pulled["angle"] - base["angle"])[1000:])  # rad
    assert -weight / 40.0 < shift < -0.1 * weight / 40.0  # down, by less than the PD alone would give
    with pytest.raises(ValueError, match="gravity 'on': expected one of off, in-model, not-in-model"):
        example["foot_mjcf"](cl.inertia, gravity="on")
    with pytest.raises(ValueError, match=r"the foot's inertia 0\.001 kg m\^2 about the ankle is less"):
        example["foot_mjcf"](0.001)


def test_guide_minimal_loop_runs_as_written(ankle, tmp_path, monkeypatch):
    """docs/guide/mujoco.md's code block, verbatim, on the example's model file: the foot held
    near -0.1 rad, below it by the ankle's rest torque over Kp plus the ankle's stiffness."""
    import re

    page = (Path(__file__).resolve().parent.parent / "docs" / "guide" / "mujoco.md").read_text()
    block = re.search(r"## A minimal loop\n.*?```python\n(.*?)```", page, re.S)
    assert block, "docs/guide/mujoco.md has no minimal loop"
    (tmp_path / "cl.json").write_text(ankle["path"].read_text())
    monkeypatch.chdir(tmp_path)
    env: dict = {}
    exec(compile(block.group(1), "mujoco.md:minimal-loop", "exec"), env)
    cl, theta, torque = ankle["cl"], float(env["data"].qpos[0]), float(env["torque"])
    assert np.isfinite(theta) and -0.1 - 0.05 < theta < -0.1  # rad
    rest = float(cl.whole.quasi_static(np.array([theta]))[0])  # N m: at rest the torque is the curve's
    assert torque == pytest.approx(rest, abs=0.05) and 40.0 * (-0.1 - theta) == pytest.approx(torque, abs=0.05)
