"""The CasADi step function: one symbolic definition of the model, equal to the numpy
prediction sample by sample, saved with Function.save and usable with casadi alone."""

import dataclasses
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from fmu_helpers import reference, shifted_error

from lpvpc.models import equations as eq
from lpvpc.export import exporter as ex
from lpvpc.errors import ExportError

TOL = 1e-9  # max abs error / max abs torque


def _run(step, n, model, position, scheduling, variant, params=None):
    traj = ex.trajectory_function(step, n)
    args = ex.replay_inputs(model, position, scheduling, variant)
    if params is not None:
        args["params"] = params
    out = traj(state=np.zeros(step.size1_in("state")), **args)
    return {k: np.asarray(v) for k, v in out.items()}


def _rel_errors(out, ref, latency):
    """Max abs error / max abs total torque of each output; exact outputs are shifted."""
    scale = np.max(np.abs(ref["torque"]))
    return {k: shifted_error(out[k].ravel(), ref[k], latency, scale) for k in ref}


@pytest.mark.parametrize("parametric", [False, True], ids=["baked", "parametric"])
@pytest.mark.parametrize("variant", ["sampled", "causal", "exact"])
def test_mapaccum_matches_numpy_on_two_minute_record(model, subject, variant, parametric):
    data = subject["ident"]
    n = data.n
    assert n == 12000
    step = ex.step_function(model, variant, parametric=parametric)
    params = ex.parameter_vector(model, variant) if parametric else None
    out = _run(step, n, model, data.position, data.scheduling, variant, params)
    lat = ex.latency_samples(model, variant)
    errors = _rel_errors(out, reference(model, data.position, data.scheduling, variant), lat)
    assert max(errors.values()) < TOL, errors
    if variant == "exact":
        assert lat == -min(model.lags) > 0
        # before the record starts nothing is defined: the output is zero
        assert np.all(out["torque"].ravel()[:lat] == 0.0)
    elif variant == "sampled":  # 5-point central differences of sample k need position k + 2
        assert lat == ex.derivative_points(model) // 2 == 2 and np.all(out["torque"].ravel()[:lat] == 0.0)
    else:
        assert lat == 0


def test_step_interface(model):
    causal = ex.step_function(model, "causal")
    assert causal.name_in() == ["state", "position", "scheduling", "velocity", "acceleration"]
    assert causal.name_out() == ["next_state", "torque", "torque_intrinsic", "torque_reflex"]
    exact = ex.step_function(model, "exact", parametric=True)
    assert exact.name_in() == ["state", "position", "scheduling", "params"]
    assert exact.size1_in("params") == len(ex.parameter_vector(model, "exact"))
    sampled = ex.step_function(model, "sampled")
    assert sampled.name_in() == ["state", "position", "scheduling"]
    for variant, f in (("causal", causal), ("exact", exact), ("sampled", sampled)):
        lay = ex.state_layout(model, variant)
        assert f.size1_in("state") == f.size1_out("next_state") == lay.size == len(lay.describe())
    with pytest.raises(ExportError, match="unknown export variant 'lookahead'"):
        ex.step_function(model, "lookahead")


def test_parameter_vector_and_names(model):
    for variant, H_name, H in (("causal", "H_causal", model.H_causal), ("exact", "H", model.H)):
        names = ex.parameter_names(model, variant)
        vec = ex.parameter_vector(model, variant)
        info = ex.parameter_info(model, variant)
        m = model.A.shape[0]
        n_i = model.intrinsic_basis.size
        assert len(names) == len(vec) == len(info) == H.size + model.Omega.size + m * m + 2 * m + 1 + n_i
        assert len(set(names)) == len(names)
        i = names.index(f"{H_name}[2,1]")
        assert vec[i] == H[2, 1]
        r, c = model.Omega.shape
        assert vec[names.index(f"Omega[{r - 1},{c - 1}]")] == model.Omega[r - 1, c - 1]
        assert vec[names.index(f"A[0,{m - 1}]")] == model.A[0, m - 1]
        assert vec[names.index("D")] == model.D
        assert names[-n_i:] == [f"curvature[{j}]" for j in range(n_i)]  # the elastic curvature term's
        assert np.array_equal(vec[-n_i:], model.curvature) and info[-1][1] == "N.m/rad2"
        assert info[0][1] == "N.m/rad"
    assert ex.fmu_parameter_name("H_causal[2,1]") == "H_causal_2_1"


def test_parametric_step_follows_its_parameters(model, subject):
    """Changing the params input is the same as changing the model's coefficients."""
    rng = np.random.default_rng(3)
    changed = dataclasses.replace(
        model,
        H_causal=model.H_causal * (1 + 0.2 * rng.standard_normal(model.H_causal.shape)),
        Omega=model.Omega * 1.3,
        A=model.A * 0.9,
        B=model.B * 1.1,
        C=model.C * 0.8,
        D=model.D + 0.1,
        curvature=model.curvature * 1.5,
    )
    data = subject["ident"].segment(0, 2000)
    step = ex.step_function(model, "causal", parametric=True)
    out = _run(step, data.n, model, data.position, data.scheduling, "causal", ex.parameter_vector(changed))
    errors = _rel_errors(out, reference(changed, data.position, data.scheduling, "causal"), 0)
    assert max(errors.values()) < TOL, errors


def test_one_definition_of_the_equations(model, monkeypatch):
    """The step is built from lpvpc.models.equations (no second copy of the model equations)."""
    called = []
    for name in ("intrinsic_torque", "reflex_drive", "reflex_step", "central_velocity", "central_acceleration",
                 "five_point_derivatives", "elastic_curvature_torque"):
        original = getattr(eq, name)

        def spy(*args, _original=original, _name=name, **kwargs):
            called.append(_name)
            return _original(*args, **kwargs)

        monkeypatch.setattr(eq, name, spy)
    for variant in ex.VARIANTS:
        called.clear()
        ex.step_function(model, variant)
        inside = ["five_point_derivatives"] if variant == "sampled" else []  # the model's derivatives inside
        assert sorted(called) == sorted(["central_velocity", "intrinsic_torque", "reflex_drive", "reflex_step",
                                         "elastic_curvature_torque"] + inside), (variant, called)


@pytest.mark.parametrize("variant", ["sampled", "causal", "exact"])
def test_random_record_nonzero_start_and_scheduling_out_of_range(model, variant):
    """A record that starts away from zero (the velocity before the record is 0, as in
    equations.delayed_velocity) and scheduling far outside the identified range (clamped)."""
    rng = np.random.default_rng(11)
    n = 600
    position = 0.05 + 0.03 * np.cumsum(rng.standard_normal(n)) / 10
    lo, hi = model.scheduling_range
    scheduling = np.linspace(lo - 0.5, hi + 0.5, n)
    step = ex.step_function(model, variant)
    out = _run(step, n, model, position, scheduling, variant)
    ref = reference(model, position, scheduling, variant)
    lat = ex.latency_samples(model, variant)
    errors = _rel_errors(out, ref, lat)
    assert max(errors.values()) < TOL, errors
    if model.intrinsic_basis.extrapolation == "clip":  # held at the edge (the default structure may choose
        # "linear" continuation: then the export's agreement with numpy beyond the range is what is checked above)
        clamped = reference(model, position, np.clip(scheduling, lo, hi), variant)
        assert np.max(np.abs(ref["torque"] - clamped["torque"])) < 1e-12 * np.max(np.abs(ref["torque"]))
    assert np.all(np.isfinite(out["torque"]))


def test_state_carries_a_record_across_calls(model, subject):
    data = subject["ident"].segment(0, 1000)
    step = ex.step_function(model, "exact")
    args = ex.replay_inputs(model, data.position, data.scheduling, "exact")
    whole = ex.trajectory_function(step, 1000)(state=np.zeros(step.size1_in(0)), **args)
    first = ex.trajectory_function(step, 400)(state=np.zeros(step.size1_in(0)),
                                              **{k: v[:, :400] for k, v in args.items()})
    second = ex.trajectory_function(step, 600)(state=first["next_state"][:, -1],
                                               **{k: v[:, 400:] for k, v in args.items()})
    joined = np.concatenate([np.asarray(first["torque"]).ravel(), np.asarray(second["torque"]).ravel()])
    assert np.array_equal(joined, np.asarray(whole["torque"]).ravel())


def test_trajectory_function_rejects_bad_length(model):
    with pytest.raises(ExportError, match="at least 1"):
        ex.trajectory_function(ex.step_function(model), 0)


@pytest.mark.parametrize("variant", ["sampled", "causal", "exact"])
def test_saved_function_runs_with_casadi_alone(model, subject, tmp_path, variant):
    """export_casadi writes the step; a process that imports only casadi and numpy loads
    it, builds the mapaccum and runs the 2-minute record."""
    data = subject["ident"]
    path = ex.export_casadi(model, tmp_path / "model.casadi", variant=variant)
    meta = json.loads((tmp_path / "model.casadi.json").read_text())
    assert meta["variant"] == variant and meta["model_hash"] == model.model_hash
    assert meta["latency_samples"] == ex.latency_samples(model, variant)
    assert path.stat().st_size < 1_000_000  # the step, not a 12,000-step mapaccum
    rows = ex.replay_inputs(model, data.position, data.scheduling, variant)
    np.savez(tmp_path / "inputs.npz", **{k: v.ravel() for k, v in rows.items()})
    script = textwrap.dedent(
        """
        import sys
        sys.modules["lpvpc"] = None  # any import of lpvpc would now fail
        import casadi, numpy as np
        step = casadi.Function.load("model.casadi")
        rows = dict(np.load("inputs.npz"))
        n = len(rows["position"])
        traj = step.mapaccum(n)
        out = traj(state=np.zeros(step.size1_in("state")), **{k: v[None, :] for k, v in rows.items()})
        np.save("torque.npy", np.asarray(out["torque"]).ravel())
        assert not [m for m, mod in sys.modules.items() if m.startswith("lpvpc") and mod is not None]
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    torque = np.load(tmp_path / "torque.npy")
    ref = reference(model, data.position, data.scheduling, variant)["torque"]
    lat = meta["latency_samples"]
    err = np.max(np.abs(torque[lat:] - ref[: data.n - lat])) / np.max(np.abs(ref))
    assert err < TOL
    # the documented helper gives the same from the file
    traj = ex.trajectory_function(path, data.n)
    again = traj(state=np.zeros(meta["state_size"]), **rows)
    assert np.array_equal(np.asarray(again["torque"]).ravel(), torque)


def test_export_casadi_unwritable_path(model, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ExportError, match="could not save"):
        ex.export_casadi(model, blocker / "sub" / "model.casadi")


def test_sampled_step_of_a_five_point_model_matches_its_causal_form(subject):
    """A model identified with causal_derivatives="central5": the sampled step computes the
    same 5-point differences (positions j-2..j+2) and so lags the numpy causal form by 2."""
    from lpvpc.identification.identify import identify

    data = subject["ident"].segment(0, 6000)
    m5 = identify(data, causal_derivatives="central5", state_order=2)
    seg = subject["novel"].segment(0, 3000)
    step = ex.step_function(m5, "sampled")
    out = _run(step, seg.n, m5, seg.position, seg.scheduling, "sampled")
    lat = ex.latency_samples(m5, "sampled")
    assert lat == 2 and out["torque"].ravel()[0] == 0.0
    errors = _rel_errors(out, reference(m5, seg.position, seg.scheduling, "sampled"), lat)
    assert max(errors.values()) < TOL, errors
