"""Whole-joint model (lpvpc.export.whole_joint): joint angle in, total torque out.

Checked against the virtual subject's ground truth (its elastic torque-angle curve and the
novel trial's PT/UT torques), and numpy = CasADi = FMU (FMI 2.0 and 3.0) sample by sample.
"""

import numpy as np
import pytest

from lpvpc.export import whole_joint as W
from lpvpc.io import decimate_trial
from lpvpc.errors import DataError, ModelFileError
from lpvpc.models.model import vaf
from lpvpc.simulation.simulate import SubjectParams


@pytest.fixture(scope="module")
def wj(model, subject):
    return W.fit_whole_joint(model, subject["ident_pair"].ut)


@pytest.fixture(scope="module")
def novel(subject, model):
    pair = subject["novel_pair"]
    return decimate_trial(pair.pt, model.fs), decimate_trial(pair.ut, model.fs)


def test_quasi_static_curve_matches_the_subjects_elastic_torque(wj):
    """The UT trial's slow torque is the elastic torque E(theta) (plus small viscous/reflex
    parts): the fitted curve follows the subject's E within a few percent of its range."""
    theta = np.linspace(wj.curve_basis.lo + 0.02, wj.curve_basis.hi - 0.02, 50)
    truth = SubjectParams().elastic_torque(theta)
    err = np.max(np.abs(wj.quasi_static(theta) - truth)) / np.ptp(truth)
    assert err < 0.05, err
    assert wj.fit["quasi_static_vaf"] > 98


def test_total_and_perturbation_torque_on_a_novel_trajectory(wj, model, subject, novel):
    """Total torque of the novel PT trial from its angle alone, and the model's own
    perturbation part (whole-joint PT minus whole-joint UT) within 2 VAF points of the
    two-input model fed the measured split."""
    pt, ut = novel
    whole_pt, whole_ut = wj.predict(pt.position, warn=False), wj.predict(ut.position, warn=False)
    total = vaf(pt.torque, whole_pt.total)
    part = vaf(pt.torque - ut.torque, whole_pt.total - whole_ut.total)
    d = subject["novel"]
    two_input = vaf(d.torque, model.predict(d.position, d.scheduling, warn=False).total)
    print(f"whole-joint novel: total VAF {total:.2f} %, perturbation part {part:.2f} %, two-input {two_input:.2f} %")
    assert total > 98
    assert part > two_input - 2.0


def test_casadi_step_and_fmus_agree_with_numpy(wj, novel, tmp_path):
    import fmpy.validation

    from lpvpc.validation.whole_joint import fmu_replay

    angle = novel[0].position[:1500]
    ref = wj.predict(angle, warn=False)
    L = W.latency_samples(wj)
    n = len(angle) - L  # the last L offline samples see the held record end
    scale = np.std(ref.total)
    cas = W.replay(wj, angle)
    for key, attr in (("torque", "total"), ("torque_quasi_static", "quasi_static"),
                      ("torque_perturbation", "perturbation_torque"), ("operating_angle", "operating_angle")):
        assert np.max(np.abs(cas[key][:n] - getattr(ref, attr)[:n])) < 1e-9 * scale, key

    f = W.export_whole_joint_casadi(wj, tmp_path / "wj.casadi")
    import casadi as ca

    assert ca.Function.load(str(f)).name_in() == ["state", "angle"]

    for version in (2, 3):
        path = W.export_whole_joint_fmu(wj, tmp_path / f"wj{version}.fmu", version)
        assert fmpy.validation.validate_fmu(str(path)) == []
        y, _ = fmu_replay(path, angle, L, wj.fs)  # raises if the first L outputs are not 0
        err = np.max(np.abs(y[:n] - ref.total[:n])) / scale
        assert err < 1e-9, (version, err)


def test_save_load_round_trip_and_errors(wj, tmp_path):
    path = tmp_path / "wj.json"
    wj.save(path)
    back = W.WholeJointModel.load(path)
    angle = np.linspace(-0.3, 0.1, 400)
    assert np.array_equal(back.predict(angle, warn=False).total, wj.predict(angle, warn=False).total)
    with pytest.raises(DataError, match="channel angle: 1 non-finite values, first at index 3"):
        wj.predict([0.0, 0.1, 0.2, np.nan, 0.0])
    path.write_text('{"format": "something else"}')
    with pytest.raises(ModelFileError, match="not an lpvpc whole-joint model"):
        W.WholeJointModel.load(path)
    with pytest.raises(ValueError, match="cutoff"):
        W.WholeJointModel(wj.model, wj.curve_basis, wj.curve, cutoff=80.0)


def test_validation_report_has_a_whole_joint_section(wj, model, subject, tmp_path):
    """validate(..., whole_joint=) measures the whole-joint model on the held-out PT trial
    (Trial objects, the first 30 s of the novel record) and writes its report section."""
    from lpvpc.io import Trial
    from lpvpc.validation.harness import validate

    pair, n = subject["novel_pair"], 30_000
    pt, ut = (Trial(t.time[:n], t.position[:n], t.torque[:n], {k: v[:n] for k, v in t.channels.items()}, name=t.name)
              for t in (pair.pt, pair.ut))
    r = validate(model, pt, ut, tmp_path / "report", measure_load_effect=False, whole_joint=wj)
    w = r.metrics["whole_joint"]
    assert w["vaf_total"] > 98 and w["vaf_perturbation"] > w["vaf_two_input"] - 3
    assert abs(w["vaf_total_fmu"] - w["vaf_total"]) < 0.05
    assert w["fmu_vs_numpy"] < 1e-9 and w["casadi_vs_numpy"] < 1e-9
    page = (tmp_path / "report" / "report.html").read_text()
    assert "<h2>Whole-joint model</h2>" in page
    assert (tmp_path / "report" / "figures" / "whole_joint.png").stat().st_size > 10_000


def test_cli_whole_joint_writes_model_and_fmu(subject, model_file, tmp_path):
    import contextlib
    import io

    from lpvpc.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["whole-joint", str(model_file), "--ut", str(subject["folder"] / "ident_UT.csv"),
                   "-o", str(tmp_path / "wj.json"), "--fmu", str(tmp_path / "wj.fmu"), "--fmi", "3",
                   "--fmi-type", "me"])
    assert rc == 0, err.getvalue()
    assert "quasi-static curve VAF" in out.getvalue()
    assert W.WholeJointModel.load(tmp_path / "wj.json").cutoff == W.DEFAULT_CUTOFF
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    assert read_model_description(str(tmp_path / "wj.fmu")).modelExchange is not None
    assert validate_fmu(str(tmp_path / "wj.fmu")) == []
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(["whole-joint", str(model_file), "--ut", str(subject["folder"] / "ident_UT.csv"),
                   "-o", str(tmp_path / "wj2.json"), "--cutoff", "70"])
    assert rc == 2 and err.getvalue().startswith("lpvpc: error: ") and "cutoff" in err.getvalue()


@pytest.mark.parametrize("fmi", [2, 3])
def test_whole_joint_fmu_refuses_wrong_calls_and_survives_cycles(wj, tmp_path, fmi):
    """The whole-joint FMU runs on the project's wrapper: wrong calls return an error status and
    log why (NaN angle, a step that is not a multiple of 1/fs, a parameter after initialization);
    200 instantiate/initialize/step/free cycles keep memory bounded."""
    import os

    from lpvpc.errors import FMUError
    from lpvpc.validation.fmu import FMUInstance, inspect_fmu

    info = inspect_fmu(W.export_whole_joint_fmu(wj, tmp_path / "wj.fmu", fmi), "whole-joint FMU")
    h = 1.0 / wj.fs
    with FMUInstance(info, "wrong") as inst:
        inst.initialize()
        angle = inst.vrs(["angle"])
        with pytest.raises(FMUError, match="not finite"):
            inst.set(angle, [float("nan")])
        with pytest.raises(FMUError, match="fixed parameter"):
            inst.set(inst.vrs(["cutoff"]), [1.0])
        with pytest.raises(FMUError, match="does not match the FMU time"):
            inst.do_step(0.5 * h, h)

    def rss():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

    def cycle():
        with FMUInstance(info, "cycle") as inst:
            inst.initialize()
            inst.set(inst.vrs(["angle"]), [0.05])
            inst.do_step(0.0, h)
            assert np.isfinite(inst.get(inst.vrs(["torque"]))[0])

    for _ in range(20):
        cycle()
    before = rss()
    for _ in range(200):
        cycle()
    assert rss() - before < 5 * 2**20
