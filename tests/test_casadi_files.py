"""The CasADi files `lpvpc export` writes: one default variant for the command line and the
library, the metadata beside the function, the guide's blocks run verbatim on them, and a
step that refuses a host time step other than its tick."""

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from lpvpc.export import closed_loop as CL
from lpvpc.export import exporter as ex
from lpvpc.cli import main
from lpvpc.errors import ExportError, OutOfRangeWarning, StepSizeError
from lpvpc.export.whole_joint import export_whole_joint_casadi, fit_whole_joint

pytest.importorskip("casadi")

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guide" / "fmu_casadi.md"
N = 1500  # samples of the novel record the blocks run on (15 s at 100 Hz)


def _block(name) -> str:
    m = re.search(rf"<!-- {name} -->\s*```python\n(.*?)```\s*<!-- /{name} -->", GUIDE.read_text(), re.S)
    assert m, f"{GUIDE.name} has no {name} block"
    return m.group(1)


@pytest.fixture(scope="module")
def cli_files(model_file, tmp_path_factory):
    """model.casadi and model.casadi.json as `lpvpc export MODEL --casadi model.casadi` writes them."""
    folder = tmp_path_factory.mktemp("casadi_cli")
    assert main(["export", str(model_file), "--casadi", str(folder / "model.casadi")]) == 0
    return folder


def _run_block(name, folder, data, monkeypatch):
    monkeypatch.chdir(folder)
    env = {"position": data.position[:N], "scheduling": data.scheduling[:N]}
    exec(compile(_block(name), f"{GUIDE.name}:{name}", "exec"), env)
    return np.asarray(env["torque"], dtype=float)


def test_command_line_and_python_write_the_one_default_variant(model, cli_files, tmp_path):
    cli_meta = json.loads((cli_files / "model.casadi.json").read_text())
    model.export_casadi(tmp_path / "py.casadi")
    py_meta = json.loads((tmp_path / "py.casadi.json").read_text())
    assert cli_meta["variant"] == py_meta["variant"] == ex.DEFAULT_VARIANT == ex.DEFAULT_FMU_VARIANT
    assert cli_meta["inputs"] == py_meta["inputs"] == ["state", "position", "scheduling"]
    assert {k: v for k, v in cli_meta.items() if k != "lpvpc_version"} == \
           {k: v for k, v in py_meta.items() if k != "lpvpc_version"}


def test_the_metadata_travels_with_the_function(model, cli_files):
    step, meta = ex.load_casadi(cli_files / "model.casadi")
    assert meta["format"] == ex.CASADI_FORMAT and meta["model_hash"] == model.model_hash
    assert meta["tick_s"] == meta["sample_period_s"] == 1.0 / model.fs
    assert meta["latency_samples"] == ex.latency_samples(model, meta["variant"])
    assert meta["inputs"] == list(step.name_in()) and meta["outputs"] == list(step.name_out())
    assert meta["initial_state"] == [0.0] * step.size1_in("state")
    assert meta["inertia"]["in_torque"] is True
    assert {meta["units"][n] for n in ("position", "scheduling")} == {"rad"} and meta["units"]["torque"] == "N m"


def test_guide_casadi_recipe_runs_verbatim_on_the_cli_file(model, subject, cli_files, monkeypatch):
    """The guide's casadi-only block on the command line's file: the torque of every sample,
    equal to the offline causal prediction (the sampled variant's differences) except the last
    L samples, whose differences need positions after the record."""
    data = subject["novel"]
    torque = _run_block("casadi-recipe", cli_files, data, monkeypatch)
    L = ex.latency_samples(model, ex.DEFAULT_VARIANT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        ref = model.predict(data.position[:N], data.scheduling[:N], causal=True).total
    assert torque.shape == (N,)
    assert np.max(np.abs(torque[: N - L] - ref[: N - L])) <= 1e-9 * np.max(np.abs(ref))


def test_guide_checked_step_block_runs_verbatim_on_the_cli_file(model, subject, cli_files, monkeypatch):
    """The guide's loop over load_casadi(...).step: the recipe's torques, L calls later."""
    data = subject["novel"]
    stepped = _run_block("casadi-step", cli_files, data, monkeypatch)
    whole = _run_block("casadi-recipe", cli_files, data, monkeypatch)
    L = ex.latency_samples(model, ex.DEFAULT_VARIANT)
    assert np.array_equal(stepped[:L], np.zeros(L))
    assert np.max(np.abs(stepped[L:] - whole[: N - L])) <= 1e-12 * np.max(np.abs(whole))


def test_a_host_step_that_is_not_the_tick_is_refused(cli_files, subject):
    exported = ex.load_casadi(cli_files / "model.casadi")
    assert isinstance(exported, ex.CasadiExport)
    x = exported.initial_state()
    with pytest.raises(StepSizeError, match=r"0\.0005 s is not the exported function's tick 0\.01 s"):
        exported.step(0.0005, x, position=0.0, scheduling=0.0)
    with pytest.raises(StepSizeError):
        exported.trajectory(100, 0.02)
    exported.check_step(0.01 * (1 + 1e-9))  # a step computed differently, within the tolerance
    out = exported.step(0.01, x, position=1e-3, scheduling=0.0)
    assert out["next_state"].shape == x.shape and isinstance(out["torque"], float)


def test_load_casadi_refuses_missing_or_foreign_metadata(cli_files, tmp_path):
    (tmp_path / "m.casadi").write_bytes((cli_files / "model.casadi").read_bytes())
    with pytest.raises(ExportError, match=r"m\.casadi\.json: no such file"):
        ex.load_casadi(tmp_path / "m.casadi")
    meta = json.loads((cli_files / "model.casadi.json").read_text())
    (tmp_path / "m.casadi.json").write_text(json.dumps({**meta, "inputs": ["state", "angle"]}))
    with pytest.raises(ExportError, match="describes function"):
        ex.load_casadi(tmp_path / "m.casadi")
    (tmp_path / "m.casadi.json").write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ExportError, match="not the metadata of an lpvpc CasADi export"):
        ex.load_casadi(tmp_path / "m.casadi")


def test_whole_joint_and_closed_loop_files_carry_tick_and_inertia(model, subject, tmp_path):
    """The closed-loop tick is the base tick (1 ms at 100 Hz) and its inertia is the plant's to
    add; the whole-joint step ticks at the sample period with the inertia in its torque."""
    ut = subject["ident_pair"].ut
    wj = fit_whole_joint(model, ut)
    cl = CL.fit_closed_loop(wj, [CL.distillation_trial(wj, ut)])
    w = ex.load_casadi(export_whole_joint_casadi(wj, tmp_path / "wj.casadi"))
    c = ex.load_casadi(CL.export_closed_loop_casadi(cl, tmp_path / "ankle.casadi"))
    assert w.metadata["kind"] == "whole-joint" and w.tick == 1.0 / wj.fs
    assert w.metadata["inertia"]["in_torque"] is True and w.metadata["inputs"] == ["state", "angle"]
    assert c.metadata["kind"] == "closed-loop" and c.tick == pytest.approx(1.0 / (cl.fs * CL.ticks(cl)), rel=1e-15)
    assert c.metadata["inertia"] == {**c.metadata["inertia"], "kg_m2": cl.inertia, "in_torque": False}
    assert c.metadata["units"]["angular_velocity"] == "rad/s"
    with pytest.raises(StepSizeError, match="tick 0.001 s"):  # MuJoCo at 0.5 ms
        c.step(0.0005, c.initial_state(), angle=0.0, angular_velocity=0.0)
    out = c.step(0.001, c.initial_state(), angle=0.01, angular_velocity=0.0)
    direct = c.function(c.initial_state(), 0.01, 0.0)
    assert out["torque"] == float(direct[1])


def test_save_casadi_writes_any_step_with_its_metadata(tmp_path):
    """The one writer: the function and a sidecar with the names, sizes and initial state taken
    from the function, and the caller's metadata (here a 1 kHz tick) kept."""
    import casadi as ca

    x, u = ca.SX.sym("state", 2), ca.SX.sym("u")
    step = ca.Function("delay2", [x, u], [ca.vertcat(u, x[0]), x[1]], ["state", "u"], ["next_state", "y"])
    path = ex.save_casadi(step, tmp_path / "d.casadi", {"kind": "test", "tick_s": 0.001, "units": {"u": "rad"}})
    f, meta = ex.load_casadi(path)
    assert meta["inputs"] == ["state", "u"] and meta["outputs"] == ["next_state", "y"]
    assert meta["state_size"] == 2 and meta["initial_state"] == [0.0, 0.0] and meta["kind"] == "test"
    e = ex.load_casadi(path)
    ys, s = [], e.initial_state()
    for u_k in (1.0, 2.0, 3.0, 4.0):
        out = e.step(0.001, s, u=u_k)
        s = out["next_state"]
        ys.append(out["y"])
    assert ys == [0.0, 0.0, 1.0, 2.0]  # two samples late
