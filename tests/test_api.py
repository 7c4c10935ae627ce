"""The Python API in the scikit-learn / python-control manner: predict on the loaded data
object, the estimator's fit/predict/score/get_params/set_params, export methods."""

import warnings

import numpy as np
import pytest

from lpvpc.io import PerturbationData
from lpvpc.errors import DataError, IdentificationError, OutOfRangeWarning
from lpvpc.identification.identify import LPVPCEstimator
from lpvpc.models.model import vaf


def test_predict_accepts_the_loaded_data_object(subject, model):
    from dataclasses import replace

    data = subject["novel"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        from_object = model.predict(data)
        from_arrays = model.predict(data.position, data.scheduling)
        model_rate = model.predict(replace(data, high_rate=None))
    # (a model whose reflex nonlinearity the selection put on the 1 kHz velocity predicts a record
    # with 1 kHz signals on that path, and arrays at the model rate with its stand-in:
    # tests/test_reflex_1k.py)
    assert np.array_equal(model_rate.total, from_arrays.total)
    if model.high_rate is None:
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
    from lpvpc.io import join_trials

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


# --------------------------------------------------------------------------- the top-level API


def test_top_level_names_import_lazily_and_once():
    """``import lpvpc`` loads no numerical library; every name of ``__all__`` imports from
    ``lpvpc``; ``identify``, ``diagnose`` and ``improve`` are their modules, callable as
    their function, whatever was imported first."""
    import subprocess
    import sys

    code = ("import sys, lpvpc; heavy = [m for m in ('numpy', 'scipy', 'casadi', 'fmpy', 'matplotlib') "
            "if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"

    import lpvpc

    for name in lpvpc.__all__:
        assert getattr(lpvpc, name) is not None, name
    assert set(lpvpc.__all__) <= set(dir(lpvpc))
    from lpvpc import LPVPCEstimator as E, LPVPCModel, identify, load_identification_data, simulate_pair  # noqa: F401
    import lpvpc.identification.identify as module

    assert identify is module and identify.LPVPCEstimator is E and callable(identify)
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        lpvpc.nonsense  # noqa: B018


def test_top_level_identify_fits_like_the_estimator(subject):
    import lpvpc

    short = subject["ident"].segment(0, 3000)
    assert lpvpc.identify(short).model_hash == lpvpc.LPVPCEstimator().fit(short).model_.model_hash


def test_reprs_are_short(subject, model):
    from lpvpc.io import load_trial

    data = subject["ident"]
    trial = load_trial(subject["folder"] / "ident_PT.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        pred = model.predict(subject["novel"])
    theta = np.linspace(*model.scheduling_range, 50)
    for obj, must in ((model, "LPVPCModel(100 Hz"), (data, "PerturbationData(12000 samples at 100 Hz"),
                      (trial, "Trial('ident_PT': 120000 samples at 1000 Hz"), (pred, "Prediction(12000 samples"),
                      (model.elastic_stiffness_interval(theta), "Interval(50 values"),
                      (model.reflex_gain_interval(theta), "Interval(50 values")):
        text = repr(obj)
        assert len(text) < 300 and "\n" not in text and must in text, text
        assert "array(" not in text


def test_one_interval_type_unpacks_like_a_pair(model):
    from lpvpc.models.uncertainty import Interval

    theta = np.array([-0.2, 0.0])
    for name in ("elastic_stiffness_interval", "viscosity_interval", "reflex_gain_interval"):
        iv = getattr(model, name)(theta)
        assert isinstance(iv, Interval), name
        lo, hi = iv
        assert np.array_equal(lo, iv.lower) and np.array_equal(hi, iv.upper) and np.all(lo < hi)


def test_data_time_is_the_time_vector_plotting_needs(subject, model):
    from lpvpc.plotting import plot_torque_fit

    data = subject["novel"]
    assert data.time.shape == (data.n,)
    assert np.allclose(np.diff(data.time), 1 / data.fs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        fig = plot_torque_fit(data.time, data.torque, model.predict(data))
    lo, hi = fig.axes[0].get_xlim()  # the time axis in s spans the record (with matplotlib's margins)
    assert lo <= data.time[0] and data.time[-1] <= hi < 1.1 * data.time[-1]
