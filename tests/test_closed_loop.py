"""The closed-loop form of the whole-joint model (lpvpc.export.closed_loop) and the compliant loop
(lpvpc.simulation.compliant_loop): identified against the virtual subject's known inertia, numpy = CasADi
= FMU (FMI 2.0 / 3.0, co-simulation and Model Exchange) tick by tick, and in the exoskeleton
loop with the torque fed back: stable where the replay FMU diverges, and close to the subject."""

import math

import numpy as np
import pytest

from lpvpc.export import closed_loop as CL
from lpvpc.simulation import compliant_loop as LOOP
from lpvpc.io import decimate_trial
from lpvpc.errors import DataError, ModelFileError
from lpvpc.export.exporter import trajectory_function
from lpvpc.models.model import vaf
from lpvpc.simulation.simulate import SubjectParams
from lpvpc.export.whole_joint import export_whole_joint_fmu, fit_whole_joint


@pytest.fixture(scope="module")
def wj(model, subject):
    return fit_whole_joint(model, subject["ident_pair"].ut)


@pytest.fixture(scope="module")
def cl(wj, subject):
    """Fitted to the two-sided model's torque (the CLI's default, without --pt)."""
    return CL.fit_closed_loop(wj, [CL.distillation_trial(wj, subject["ident_pair"].ut)])


@pytest.fixture(scope="module")
def fmus(cl, wj, tmp_path_factory):
    folder = tmp_path_factory.mktemp("closed_loop_fmus")
    out = {(v, t): CL.export_closed_loop_fmu(cl, folder / f"cl_{t}{v}.fmu", v, fmi_type=t)
           for v in (2, 3) for t in ("cs", "me")}
    out["replay"] = export_whole_joint_fmu(wj, folder / "replay.fmu", 2)
    return out


def test_inertia_stiffness_and_viscosity_against_the_subject(cl, wj, subject):
    """The acceleration's coefficient is the foot's inertia (0.015 kg m^2), declared apart, in
    both fits; fitted to the two-sided model's torque, K(rho) and B(rho) are the subject's
    within 15 % and 40 % (fitted to the PT/UT trials directly, K comes out ~20 % high: printed)."""
    truth = SubjectParams()
    pair = subject["ident_pair"]
    direct = CL.fit_closed_loop(wj, [pair.pt, pair.ut])
    rho = np.linspace(-0.3, 0.1, 5)
    for fit in (cl, direct):
        assert abs(fit.inertia - truth.inertia) < 0.1 * truth.inertia, fit.inertia
        print("K / truth", (fit.stiffness(rho) / truth.K(rho)).round(3), "B", fit.viscosity(rho).round(3))
    assert cl.W.shape == (3, cl.model.intrinsic_basis.size)
    assert np.max(np.abs(cl.stiffness(rho) / truth.K(rho) - 1)) < 0.15
    assert np.max(np.abs(cl.viscosity(rho) / truth.viscosity - 1)) < 0.4


def test_causal_form_costs_little_on_a_novel_trajectory(cl, wj, subject):
    """Total torque of the novel PT trial from its angle (and the record's velocity): the causal
    form plus its declared inertia against the two-sided whole-joint model."""
    pt = decimate_trial(subject["novel_pair"].pt, cl.fs)
    prediction = cl.predict(pt.position)
    assert isinstance(prediction, CL.ClosedLoopPrediction)
    assert np.allclose(prediction.total, prediction.intrinsic + prediction.reflex)
    causal = vaf(pt.torque, prediction.measured)
    two_sided = vaf(pt.torque, wj.predict(pt.position, warn=False).total)
    print(f"novel trajectory: causal {causal:.2f} %, two-sided {two_sided:.2f} %")
    assert causal > 99.0 and causal > two_sided - 1.0


def _ticks(cl, angle):
    """The angle record at the base tick (held between samples, as a master at 1 ms sees a
    100 Hz record) and a velocity that changes every tick."""
    N = CL.ticks(cl)
    a = np.repeat(angle, N) + 1e-3 * np.sin(np.arange(N * len(angle)) * 0.37)
    return a, np.gradient(a) / (1.0 / (cl.fs * N))


def test_tick_function_equals_numpy_at_samples_and_fmus_every_tick(cl, fmus, subject):
    import fmpy
    from fmpy.validation import validate_fmu

    angle = decimate_trial(subject["novel_pair"].pt, cl.fs).position[:300]
    a, v = _ticks(cl, angle)
    N = CL.ticks(cl)
    step = CL.closed_loop_step(cl)
    out = trajectory_function(step, len(a))(state=np.zeros(step.size1_in(0)), angle=a[None, :],
                                            angular_velocity=v[None, :])
    ref = {k: np.asarray(out[k]).ravel() for k in CL.OUTPUT_NAMES}
    offline = cl.predict(a[::N], v[::N])
    scale = np.std(ref["torque"])
    assert np.max(np.abs(ref["torque"][::N] - offline.total)) < 1e-9 * scale
    assert np.max(np.abs(ref["torque_reflex"][::N] - offline.reflex)) < 1e-9 * scale
    h = 1.0 / (cl.fs * N)
    for key, path in fmus.items():
        if key == "replay":
            continue
        assert validate_fmu(str(path)) == [], key
        if key[1] == "cs":  # the master's protocol: set inputs, read outputs, doStep
            src = LOOP.FmuSource(path)
            src.reset()
            assert src.inertia == cl.inertia
            y = np.empty(len(a))
            for k in range(len(a)):
                y[k] = src.output(a[k], v[k])
                src.advance(k * h, h)
            src.close()
        else:  # fmpy's Model Exchange loop: outputs aligned with the inputs' time (DESIGN.md)
            signals = np.array(list(zip(np.arange(len(a)) * h, a, v)),
                               dtype=[("time", float), ("angle", float), ("angular_velocity", float)])
            res = fmpy.simulate_fmu(str(path), stop_time=(len(a) - 1) * h, output_interval=h, input=signals,
                                    output=["torque", "inertia"], fmi_type="ModelExchange")
            assert np.all(res["inertia"] == cl.inertia)
            last = np.r_[res["time"][1:] != res["time"][:-1], True]  # rows before and after each event: the last
            y = res["torque"][last]
            assert len(y) == len(a)
        err = np.max(np.abs(y - ref["torque"])) / scale
        assert err < 1e-9, (key, err)


def test_perturbation_level_impedance_on_the_identification_data(model, subject):
    """For data without a whole-joint record (perturbation p and scheduling rho only, as the
    lab's pilot trial): the same causal impedance fitted at that level, judged on the novel data."""
    d, novel = subject["ident"], subject["novel"]
    W, inertia = CL.fit_perturbation_impedance(model, d.position, d.scheduling, d.torque)
    assert abs(inertia - SubjectParams().inertia) < 0.15 * SubjectParams().inertia, inertia
    y = CL.predict_perturbation_impedance(model, W, inertia, novel.position, novel.scheduling)
    two_sided = vaf(novel.torque, model.predict(novel.position, novel.scheduling, warn=False).total)
    assert vaf(novel.torque, y) > two_sided - 2.0, (vaf(novel.torque, y), two_sided)


def test_casadi_tick_function_file(cl, tmp_path):
    """export_closed_loop_casadi saves the tick function; loaded back it gives the same torque."""
    import casadi as ca

    f = ca.Function.load(str(CL.export_closed_loop_casadi(cl, tmp_path / "cl.casadi")))
    assert f.name_in() == ["state", "angle", "angular_velocity"]
    x = np.zeros(f.size1_in(0))
    out = f(x, 0.02, 0.1)
    ref = CL.closed_loop_step(cl)(x, 0.02, 0.1)
    assert float(out[1]) == pytest.approx(float(ref[1]), abs=1e-12) and float(out[1]) != 0.0


def test_errors_and_round_trip(cl, tmp_path):
    path = tmp_path / "cl.json"
    cl.save(path)
    back = CL.ClosedLoopModel.load(path)
    angle = np.linspace(-0.3, 0.1, 300)
    assert np.array_equal(back.predict(angle).total, cl.predict(angle).total)
    with pytest.raises(DataError, match="channel angle: 1 non-finite"):
        cl.predict([0.0, math.nan, 0.1])
    with pytest.raises(DataError, match="angle and velocity differ in length"):
        cl.predict(angle, angle[:-1])
    path.write_text('{"format": "lpvpc-whole-joint"}')
    with pytest.raises(ModelFileError, match="not an lpvpc closed-loop model"):
        CL.ClosedLoopModel.load(path)


@pytest.mark.parametrize("kp", [40.0, 150.0])
def test_compliant_loop_stays_stable_and_follows_the_subject(cl, fmus, kp):
    """10 s of the exoskeleton loop (issue 24) with the torque fed back: the closed-loop FMU at
    communication steps of 1, 2, 5 ms and one model period (10 ms) stays stable and within 95 %
    VAF of the virtual subject in the same loop (angle deviation and torque, also above
    0.5 Hz); the replay FMU (two-sided IRF, inertia inside) diverges in the same loop."""
    ref = LOOP.reference_trajectory(10.0, seed=3)
    setup = LOOP.LoopSetup(kp=kp)
    truth = LOOP.run_loop(LOOP.VirtualSubject(), ref, setup)
    assert isinstance(truth, LOOP.LoopRun) and truth.stable
    with pytest.raises(ValueError, match="communication steps up to 0.001 s"):
        LOOP.run_loop(LOOP.VirtualSubject(), ref, setup, 0.01)
    assert abs(np.mean(LOOP.highpass(truth.deviation))) < 1e-3  # the high-pass removes the offset
    src = LOOP.FmuSource(fmus[(2, "cs")])
    try:
        for h in (1e-3, 2e-3, 5e-3, 1.0 / cl.fs):  # any multiple of the tick up to the model period
            run = LOOP.run_loop(src, ref, setup, h)
            assert run.stable, (kp, h, run.diverged_at)
            v = LOOP.loop_vaf(truth, run)
            print(f"Kp {kp:g}, step {h * 1e3:g} ms: {v}")
            assert min(v.values()) > 95.0, (kp, h, v)
    finally:
        src.close()
    src = LOOP.FmuSource(fmus["replay"])
    try:
        replay = LOOP.run_loop(src, ref, setup, 1.0 / cl.fs)
    finally:
        src.close()
    assert not replay.stable and replay.diverged_at < 2.0, replay.diverged_at


def _whole_joint(model_file, folder, *extra):
    """lpvpc whole-joint MODEL --ut ident_UT.csv EXTRA...: (exit status, stdout, stderr)."""
    import contextlib
    import io

    from lpvpc.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["whole-joint", str(model_file), "--ut", str(folder / "ident_UT.csv"), *extra])
    return rc, out.getvalue(), err.getvalue()


def test_cli_whole_joint_closed_loop(subject, model_file, tmp_path):
    """lpvpc whole-joint ... --closed-loop: from the UT trial alone (fitted to the two-sided
    model's torque) and with --pt; FMI 3 Model Exchange; --pt without --closed-loop is a usage error."""
    import contextlib
    import io

    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    from lpvpc.cli import main

    folder = subject["folder"]

    def run(*extra):
        return _whole_joint(model_file, folder, *extra)

    rc, out, err = run("-o", str(tmp_path / "cl.json"), "--fmu", str(tmp_path / "ankle.fmu"), "--closed-loop",
                       "--fmi", "3", "--fmi-type", "me")
    assert rc == 0, err
    assert "two-sided model's torque" in out and "inertia" in out
    distilled = CL.ClosedLoopModel.load(tmp_path / "cl.json")
    assert abs(distilled.inertia - SubjectParams().inertia) < 0.1 * SubjectParams().inertia
    md = read_model_description(str(tmp_path / "ankle.fmu"))
    assert md.modelExchange is not None and [v.name for v in md.modelVariables if v.causality == "input"] == \
        ["angle", "angular_velocity"]
    assert validate_fmu(str(tmp_path / "ankle.fmu")) == []
    rc, out, err = run("-o", str(tmp_path / "cl2.json"), "--closed-loop", "--pt", str(folder / "ident_PT.csv"))
    assert rc == 0 and "PT and UT trials" in out, err
    # --time-unit reads both trials alike: the same files with time in ms give the same model
    for name in ("ident_PT.csv", "ident_UT.csv"):
        table = np.genfromtxt(folder / name, delimiter=",", names=True)
        table["time"] *= 1000.0
        np.savetxt(tmp_path / name, table, delimiter=",", header=",".join(table.dtype.names), comments="",
                   fmt="%.17g")
    out_, err_ = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out_), contextlib.redirect_stderr(err_):
        rc = main(["whole-joint", str(model_file), "--ut", str(tmp_path / "ident_UT.csv"), "--time-unit", "ms",
                   "-o", str(tmp_path / "cl_ms.json"), "--closed-loop", "--pt", str(tmp_path / "ident_PT.csv")])
    assert rc == 0, err_.getvalue()
    from_ms, from_s = CL.ClosedLoopModel.load(tmp_path / "cl_ms.json"), CL.ClosedLoopModel.load(tmp_path / "cl2.json")
    assert abs(from_ms.inertia - from_s.inertia) <= 1e-9 * abs(from_s.inertia)
    rc, out, err = run("-o", str(tmp_path / "wj.json"), "--pt", str(folder / "ident_PT.csv"))
    assert rc == 2 and err.startswith("lpvpc: error: ") and "--closed-loop" in err



def test_cli_whole_joint_closed_loop_position_delay(subject, model_file, tmp_path):
    """--position-delay-ms: a number is used for the fit and recorded, 'auto' estimates it from
    the PT/UT files (none in the subject's: |delay| < 0.4 ms); misuse is one line, exit 2."""
    folder = subject["folder"]

    def run(*extra):
        return _whole_joint(model_file, folder, *extra)

    pt = ("--pt", str(folder / "ident_PT.csv"))
    rc, out, err = run("-o", str(tmp_path / "d1.json"), "--closed-loop", *pt, "--position-delay-ms", "1")
    assert rc == 0 and "delayed by 1.00 ms" in out, err
    d1 = CL.ClosedLoopModel.load(tmp_path / "d1.json")
    assert d1.fit["position_delay_s"] == pytest.approx(1e-3)
    rc, out, err = run("-o", str(tmp_path / "auto.json"), "--closed-loop", *pt, "--position-delay-ms", "auto")
    assert rc == 0, err
    auto = CL.ClosedLoopModel.load(tmp_path / "auto.json")
    assert abs(auto.fit["position_delay_s"]) < 0.4e-3 and auto.inertia > 0
    for extra in (["--closed-loop", "--position-delay-ms", "auto"], ["--closed-loop", *pt, "--position-delay-ms", "x"],
                  ["--position-delay-ms", "1"]):
        rc, out, err = run("-o", str(tmp_path / "bad.json"), *extra)
        assert rc == 2 and err.startswith("lpvpc: error: ") and err.count("\n") == 1 and "position-delay" in err, err

def test_example_assistance_profile_designed_with_opti_works_on_the_subject():
    """examples/assistance_profile.py: an exoskeleton torque profile designed with casadi.Opti +
    IPOPT through the closed-loop model's CasADi tick function, then applied (feed-forward, no
    feedback) to the virtual subject in the loop: the subject follows the 0.2 rad target movement
    within 10 % RMS; a profile designed without the ankle model (inertia only) misses it."""
    import runpy
    from pathlib import Path

    example = runpy.run_path(str(Path(__file__).resolve().parent.parent / "examples" / "assistance_profile.py"))
    r = example["main"](seed=0, duration=60.0)
    print(r)
    assert r["stable"]
    assert r["model_rms_error"] < 0.01 * r["movement"]  # the optimiser met the target on the model
    assert r["subject_rms_error"] < 0.1 * r["movement"] and r["subject_vaf"] > 95.0
    assert r["naive_rms_error"] > 5 * r["subject_rms_error"]


def test_validation_closed_loop_section(cl, tmp_path):
    """validation.closed_loop: the closed-loop FMU beside the virtual subject and the replay FMU
    in the same loop, its metrics, figure and HTML section."""
    from lpvpc.validation.closed_loop import (CLOSED_LOOP_FIGURE, closed_loop_section, evaluate_closed_loop,
                                              write_closed_loop_report)

    metrics, traces = evaluate_closed_loop(cl, tmp_path, duration=10.0, seed=1, kps=(40.0,))
    g = metrics["gains"][0]
    assert g["subject_stable"] and not g["replay"]["stable"] and g["replay"]["diverged_at"] < 2.0
    for step, r in g["closed_loop"].items():
        assert r["stable"] and min(r[k] for k in ("deviation", "torque", "deviation_hp", "torque_hp")) > 95.0, step
    page = write_closed_loop_report(tmp_path / "report", metrics, traces)
    text = page.read_text()
    assert "<h2>Closed loop</h2>" in text and "replay FMU" in text and "diverged at" in text
    fig = tmp_path / "report" / "figures" / CLOSED_LOOP_FIGURE
    assert fig.stat().st_size > 10_000
    assert closed_loop_section(metrics, fig) in text  # the section the validation report can embed


def test_loop_ssp_in_fmpy_and_libcosim(cl, tmp_path):
    """The loop as an SSP 1.0 archive (record player -> series-elastic exoskeleton <-> ankle FMU):
    libcosim runs it as fmpy's master does; the closed-loop FMU stays stable in both, the replay
    FMU fails in both (its torque turns non-finite)."""
    from lpvpc.validation.closed_loop import evaluate_loop_ssp, exoskeleton_parameters, run_loop_fmpy, \
        run_loop_ssp_libcosim, write_loop_ssp
    from lpvpc.validation.engines import available

    if available("libcosim"):
        pytest.skip(available("libcosim"))
    r = evaluate_loop_ssp(cl, tmp_path, duration=5.0, seed=1)
    print(r)
    c, rep = r["closed_loop"], r["replay"]
    assert c["fmpy_failed_at"] is None and c["libcosim_failed_at"] is None
    assert c["vaf_angle"] > 99.0 and c["vaf_torque"] > 99.0
    assert rep["fmpy_failed_at"] is not None and rep["fmpy_failed_at"] < 2.0
    assert rep["libcosim_failed_at"] is not None and rep["libcosim_failed_at"] < 2.0
    assert callable(write_loop_ssp) and callable(run_loop_ssp_libcosim) and callable(run_loop_fmpy)
    assert exoskeleton_parameters(40.0, 0.5, 0.025, 0.0)["coupling_damping"] == pytest.approx(0.25)


def test_channel_skew_estimated_from_the_files_and_undone(subject, tmp_path):
    """A torque channel recorded 1 ms late (the virtual subject's 1 kHz trials written so, read
    back through the loader): the estimate finds ~1 ms there and ~0 on the subject's own files,
    and aligning by it restores the causal impedance's fit (the skew costs it points)."""
    from lpvpc.io import load_identification_data, write_trial_csv
    from lpvpc.io.trial import Trial

    pair = subject["ident_pair"]
    for name, trial in (("PT", pair.pt), ("UT", pair.ut)):
        late = np.r_[trial.torque[0], trial.torque[:-1]]  # one 1 kHz sample late
        write_trial_csv(Trial(trial.time, trial.position, late, dict(trial.channels), trial.name), tmp_path / f"{name}.csv")
    skewed = load_identification_data(pt=tmp_path / "PT.csv", ut=tmp_path / "UT.csv").segment(0, 6000)
    clean = subject["ident"].segment(0, 6000)
    grid = np.arange(-1.0, 2.01, 0.5) * 1e-3
    found = CL.estimate_channel_skew(skewed, grid).delay
    none = CL.estimate_channel_skew(clean, grid).delay
    print(f"estimated skew: {found * 1e3:.2f} ms (1 ms imposed), {none * 1e3:.2f} ms (none)")
    assert abs(found - 1e-3) < 0.4e-3 and abs(none) < 0.4e-3

    def impedance_vaf(d):
        from lpvpc.identification.identify import identify

        m = identify(d)
        W, inertia = CL.fit_perturbation_impedance(m, d.position, d.scheduling, d.torque)
        assert inertia > 0
        return vaf(d.torque, CL.predict_perturbation_impedance(m, W, inertia, d.position, d.scheduling))

    aligned = CL.delay_position(skewed, found)
    assert aligned.meta["position_delay_s"] == found
    assert impedance_vaf(aligned) > impedance_vaf(skewed) + 0.3


def test_delay_position_round_trip(subject):
    d = subject["ident"].segment(0, 3000)
    back = CL.delay_position(CL.delay_position(d, 0.0013), -0.0013)
    inner = slice(100, -100)
    # decimated steps carry content up to the anti-alias edge (~0.4 fs): the interpolator is not exact there
    assert np.max(np.abs(back.position[inner] - d.position[inner])) < 5e-3 * np.std(d.position)
    assert back.meta["position_delay_s"] == pytest.approx(0.0)
    assert np.allclose(CL.delay_position(d, 0.01).position[1:], d.position[:-1], rtol=0, atol=1e-14)  # whole samples
