"""The reflex nonlinearity identified on the high-rate delayed velocity (1 kHz files, issue 10).

The data keep the file's 1 kHz position beside the 100 Hz model-rate record; the reflex
rectifier acts on the 1 kHz delayed velocity and its output is decimated; the model keeps
running at 100 Hz. The session's ``subject`` fixture is loaded from 1 kHz CSV files, so the
session ``model`` takes this path (and tests/test_export_casadi.py checks that its exports
equal ``model.predict(position, scheduling)``, the model-rate stand-in).
"""

import json
import warnings

import numpy as np
import pytest

from lpvpc.io import HighRate, PerturbationData, decimate_trial, join_trials, load_identification_data, pair_trials
from lpvpc.errors import DataError, ModelFileError
from lpvpc.identification.identify import identify
from lpvpc.models.model import LPVPCModel, vaf
from lpvpc.simulation.simulate import SubjectParams

TRUTH = SubjectParams()


def central_rho(model, n=25):
    lo, hi = model.scheduling_range
    return np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n)


def slope_ratios(model):
    rho = central_rho(model)
    gain, thr = model.reflex_gain_threshold(rho)
    return (np.polyfit(rho, gain, 1)[0] / np.polyfit(rho, TRUTH.reflex_gain(rho), 1)[0],
            np.polyfit(rho, thr, 1)[0] / np.polyfit(rho, TRUTH.reflex_threshold(rho), 1)[0])


def without_high_rate(d):
    return PerturbationData(d.position, d.torque, d.scheduling, d.fs, d.extra, d.source, d.meta, d.segments)


@pytest.fixture(scope="module")
def model(subject):
    """The 1 kHz files' model with the reflex nonlinearity on the 1 kHz velocity (opt-in)."""
    return identify(subject["ident"], high_rate_reflex=True)


def test_the_high_rate_reflex_is_chosen_per_record(subject):
    """By default the structure selection chooses the velocity the nonlinearity sees on 1 kHz
    files (issue 22: on the lab's pilot trial the 1 kHz one predicted the held-out part worse,
    on the virtual subject it recovers the gain trend); structure="fixed" keeps the model rate."""
    assert subject["ident"].high_rate is not None
    chosen = identify(subject["ident"])
    path = chosen.fit["structure_selection"]["reflex_path"]
    assert (chosen.high_rate is not None) == path["chosen"]["high_rate_reflex"]
    assert identify(subject["ident"], structure="fixed").high_rate is None


@pytest.fixture(scope="module")
def model_100(subject):
    """The same recording seen at 100 Hz only (as from 100 Hz files)."""
    return identify(without_high_rate(subject["ident"]))


# -- data -------------------------------------------------------------------------------
def test_1khz_files_keep_the_high_rate_position(subject):
    d = subject["ident"]
    assert d.fs == 100.0 and d.high_rate is not None and d.high_rate.fs == pytest.approx(1000.0)
    assert d.decimation == 10 and d.high_rate.n == len(subject["ident_pair"].pt.time)
    pair = subject["ident_pair"]
    np.testing.assert_allclose(d.high_rate.scheduling, pair.ut.position, atol=1e-12)  # the UT position at 1 kHz
    np.testing.assert_allclose(d.high_rate.position, pair.pt.position - pair.ut.position, atol=1e-9)  # CSV digits


def test_100hz_files_and_kept_rate_have_no_high_rate(subject):
    pair = subject["ident_pair"]
    assert pair_trials(decimate_trial(pair.pt, 100.0), decimate_trial(pair.ut, 100.0)).high_rate is None
    assert pair_trials(pair.pt, pair.ut, target_fs=None).high_rate is None


def test_segment_and_join_carry_the_high_rate_signals(subject):
    d = subject["ident"]
    part = d.segment(1000, 5001)
    assert part.high_rate.n == 40010
    np.testing.assert_array_equal(part.high_rate.position, d.high_rate.position[10000:50010])
    joint = join_trials([d.segment(None, 3000), d.segment(3000, None)])
    assert joint.high_rate.segments == ((0, 30000), (30000, d.high_rate.n))
    np.testing.assert_array_equal(joint.high_rate.position, d.high_rate.position)
    assert joint.segment(2000, 4000).high_rate.segments == ((0, 10000), (10000, 20000))


def test_inconsistent_high_rate_signals_are_refused(subject):
    d = subject["ident"]
    with pytest.raises(DataError, match="does not decimate by 10"):
        PerturbationData(d.position, d.torque, d.scheduling, d.fs,
                         high_rate=HighRate(d.high_rate.position[:-20], d.high_rate.scheduling[:-20], 1000.0))
    with pytest.raises(DataError, match="not an integer multiple"):
        PerturbationData(d.position, d.torque, d.scheduling, d.fs,
                         high_rate=HighRate(d.high_rate.position, d.high_rate.scheduling, 1050.0))


def test_high_rate_regressor_is_the_decimated_nonlinearity(subject):
    """high_rate_input's model-rate regressor times Omega equals high_rate_drive: the
    nonlinearity evaluated on the 1 kHz delayed velocity, then decimated (trial by trial)."""
    from lpvpc.models.basis import basis_from_data
    from lpvpc.models.reflex import high_rate_drive, high_rate_input

    d = join_trials([subject["ident"].segment(None, 5000), subject["ident"].segment(5000, None)])
    rho_basis = basis_from_data(d.scheduling, "chebyshev", 2)
    hi = high_rate_input(d.high_rate, d.decimation, 0.040, rho_basis, "hinge", 8)
    assert hi.U_r.shape == (d.n, 27) and hi.delay == 40 and hi.fs == 1000.0
    assert -3.0 < hi.velocity_basis.lo < 0.0 < hi.velocity_basis.hi < 3.0  # central 99 %, not the extremes
    Omega = np.random.default_rng(0).standard_normal((9, 3))
    z = high_rate_drive(d.high_rate, d.decimation, hi.delay, hi.velocity_basis, rho_basis, Omega)
    np.testing.assert_allclose(z, hi.U_r @ Omega.ravel(), atol=1e-9 * np.max(np.abs(z)))


# -- identification and prediction ------------------------------------------------------
def test_model_identified_from_1khz_carries_the_high_rate_nonlinearity(model):
    assert model.fs == 100.0 and model.high_rate is not None
    assert model.high_rate.fs == pytest.approx(1000.0) and model.high_rate.delay == 40 and model.delay == 4
    assert model.nonlinearity_fs == pytest.approx(1000.0)
    assert model.settings["high_rate_velocity_basis"] == "hinge"


def test_threshold_trend_from_1khz_beats_100hz(model, model_100):
    """From 1 kHz files the threshold falls toward dorsiflexion as the subject's does; from
    100 Hz files its slope is near zero (the bias the summary and figure state). The 20 %
    target is not met on every seed: benchmarks/results/reflex_1k.txt."""
    g1k, t1k = slope_ratios(model)
    g100, t100 = slope_ratios(model_100)
    assert t1k > 0.4, f"1 kHz threshold slope ratio {t1k:.2f}"
    assert t1k > t100 + 0.3, f"threshold slope ratio 1 kHz {t1k:.2f}, 100 Hz {t100:.2f}"
    assert 0.8 < g1k < 1.4, f"1 kHz gain slope ratio {g1k:.2f}"


def test_novel_vaf_no_worse_than_100hz(subject, model, model_100):
    novel = subject["novel"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        high = vaf(novel.torque, model.predict(novel).total)
        low = vaf(novel.torque, model_100.predict(novel).total)
        stand_in = vaf(novel.torque, model.predict(novel.position, novel.scheduling).total)
    assert high > low - 0.1, f"1 kHz path {high:.2f} %, 100 Hz path {low:.2f} %"
    assert stand_in > low - 0.1, f"model-rate stand-in {stand_in:.2f} %, 100 Hz path {low:.2f} %"


def test_predict_uses_the_high_rate_path_when_the_record_has_it(subject, model):
    novel = subject["novel"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        high = model.predict(novel)
        low = model.predict(novel.position, novel.scheduling)
    np.testing.assert_array_equal(high.intrinsic, low.intrinsic)
    assert not np.allclose(high.reflex, low.reflex)
    joint = join_trials([novel.segment(None, 6000), novel.segment(6000, None)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parts = model.predict(joint)
        first = model.predict(novel.segment(None, 6000))
    np.testing.assert_allclose(parts.reflex[:6000], first.reflex, atol=1e-12)


def test_model_file_round_trips_the_high_rate_nonlinearity(model, tmp_path):
    path = tmp_path / "m.json"
    model.save(path)
    back = LPVPCModel.load(path)
    np.testing.assert_array_equal(back.high_rate.Omega, model.high_rate.Omega)
    assert back.high_rate.velocity_basis == model.high_rate.velocity_basis
    assert back.to_dict() == json.loads(json.dumps(model.to_dict()))


def test_files_without_high_rate_still_load(model_100, model, tmp_path):
    d = model_100.to_dict()
    assert "high_rate" not in d["reflex"]  # what every file before this change holds
    path = tmp_path / "old.json"
    path.write_text(json.dumps(d))
    old = LPVPCModel.load(path)
    assert old.high_rate is None and old.nonlinearity_fs == 100.0
    # removing the entry from a 1 kHz model leaves intervals of another nonlinearity: refused
    d = model.to_dict()
    del d["reflex"]["high_rate"]
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match="uncertainty.parameters.omega"):
        LPVPCModel.load(path)


@pytest.mark.parametrize("change, message", [
    (lambda h: h.update(fs=150.0), "not an integer multiple"),
    (lambda h: h.update(Omega=[[1.0, 2.0]]), "Omega"),
    (lambda h: h.update(delay=0), "delay"),
])
def test_bad_high_rate_entry_is_refused(model, tmp_path, change, message):
    d = model.to_dict()
    change(d["reflex"]["high_rate"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=message):
        LPVPCModel.load(path)


def test_summary_says_where_the_threshold_is_biased(model, model_100):
    from lpvpc.models.summary import physiology_lines

    assert "threshold biased" not in " ".join(physiology_lines(model))
    assert "threshold biased" in " ".join(physiology_lines(model_100))
    import matplotlib.pyplot as plt

    from lpvpc import plotting

    for m, biased in ((model, False), (model_100, True)):
        fig = plotting.plot_reflex_nonlinearity(m)
        assert any("threshold is biased" in t.get_text() for t in fig.axes[0].texts) == biased
        plt.close(fig)
