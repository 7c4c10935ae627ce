"""The Python API in the scikit-learn / python-control manner: predict on the loaded data
object, the estimator's fit/predict/score/get_params/set_params, export methods."""

import warnings

import numpy as np
import pytest

from lpvpc.data import PerturbationData
from lpvpc.errors import DataError, IdentificationError, OutOfRangeWarning
from lpvpc.identify import LPVPCEstimator
from lpvpc.model import vaf


def test_predict_accepts_the_loaded_data_object(subject, model):
    data = subject["novel"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        from_object = model.predict(data)
        from_arrays = model.predict(data.position, data.scheduling)
    # (a model with the opt-in 1 kHz reflex predicts a record with 1 kHz signals on that path:
    # tests/test_reflex_1k.py)
    assert np.array_equal(from_object.total, from_arrays.total)
    assert vaf(data.torque, from_object.total) > vaf(data.torque, subject["novel_clean"].torque) - 1.0  # noise ceiling


def test_predict_refuses_data_at_another_rate_and_objects_without_scheduling(subject, model):
    d = subject["novel"]
    other = PerturbationData(position=d.position, torque=d.torque, scheduling=d.scheduling, fs=1000.0)
    with pytest.raises(DataError, match="1000 Hz.*100 Hz"):
        model.predict(other)
    with pytest.raises(DataError, match="scheduling"):
        model.predict(d.position)


def test_estimator_fit_predict_score_params(subject):
    est = LPVPCEstimator()
    with pytest.raises(IdentificationError, match="not fitted"):
        est.predict(subject["novel"])
    assert est.set_params(intrinsic_order=4, state_order=2) is est
    assert est.get_params()["intrinsic_order"] == 4
    with pytest.raises(ValueError, match="unknown estimator setting.*'order'"):
        est.set_params(order=3)
    assert est.fit(subject["ident"]) is est
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        score = est.score(subject["novel"])
        pred = est.predict(subject["novel"])
    assert score == pytest.approx(vaf(subject["novel"].torque, pred))
    assert score > 90
    assert LPVPCEstimator(**est.get_params()).get_params() == est.get_params()


def test_export_methods_write_loadable_artifacts(model, subject, tmp_path):
    import casadi

    path = model.export_casadi(tmp_path / "m.casadi")
    step = casadi.Function.load(str(path))
    assert step.n_out() >= 2
    fmu = model.export_fmu(tmp_path / "m.fmu", variant="exact")
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    assert {"position", "scheduling", "torque"} <= {v.name for v in md.modelVariables}


def test_predict_on_joined_trials_predicts_each_trial_from_rest(subject, model):
    from lpvpc.data import join_trials

    d = subject["novel"]
    half = len(d.position) // 2
    parts = [PerturbationData(position=d.position[a:b], torque=d.torque[a:b], scheduling=d.scheduling[a:b], fs=d.fs)
             for a, b in ((0, half), (half, len(d.position)))]
    joined = join_trials(parts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        got = model.predict(joined).total
        each = np.concatenate([model.predict(q.position, q.scheduling).total for q in parts])
        across = model.predict(joined.position, joined.scheduling).total
    assert np.array_equal(got, each)
    assert not np.array_equal(got, across)  # the seam matters
