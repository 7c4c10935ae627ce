"""The reflex-dynamics leak of the K(theta) intervals
(lpvpc.identification.structural_uncertainty.reflex_leak_shift): under the lab's ramp-and-hold
pulses the reflex torque lasts into the hold, and what the identified reflex dynamics miss of it
is taken for stiffness. Judged on a population subject whose K comes out several percent high
for that reason (its reflex switched off, the bias goes)."""

import copy
import dataclasses
import json
import warnings

import numpy as np
import pytest
import scipy.signal

import lpvpc
from lpvpc.errors import ModelFileError
from lpvpc.identification.structural_uncertainty import reflex_leak_shift as refit_shift
from lpvpc.models.model import LPVPCModel
from lpvpc.models.uncertainty import intrinsic_interval_parts, reflex_leak_shift
from lpvpc.simulation.population import draw_subject, simulate_subject

SEED = 117  # a development draw: cubic K, lab pulses, low reflex threshold


def _identified(subject):
    sim = simulate_subject(subject)
    data = lpvpc.pair_trials(sim.pt, sim.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(data)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)  # central 80 %
    return data, model, rho, subject.params.incremental_stiffness(rho, subject.perturbation_amplitude)


@pytest.fixture(scope="module")
def leaky():
    return _identified(draw_subject(SEED, stiffness="polynomial"))


def _without_leak(model):
    bare = copy.deepcopy(model)
    bare.uncertainty["structural"].pop("leak")
    return bare


def test_the_premise_k_is_high_because_of_the_reflex(leaky):
    _, model, rho, K = leaky
    assert np.median(model.elastic_stiffness(rho) / K - 1) > 0.03
    s = draw_subject(SEED, stiffness="polynomial")
    quiet = dataclasses.replace(s, params=dataclasses.replace(s.params, reflex_gain_pf=1e-9, reflex_gain_df=1e-9))
    _, m0, rho0, K0 = _identified(quiet)
    assert np.median(np.abs(m0.elastic_stiffness(rho0) / K0 - 1)) < 0.02


def test_the_leak_term_covers_what_the_other_terms_miss(leaky):
    _, model, rho, K = leaky
    after = model.elastic_stiffness_interval(rho)
    before = _without_leak(model).elastic_stiffness_interval(rho)
    covered = lambda iv: np.mean((iv.lower <= K) & (K <= iv.upper))  # noqa: E731
    assert covered(before) <= 0.5 and covered(after) >= 0.75
    # it widens K only: viscosity and inertia keep their intervals
    for q in ("viscosity", "inertia"):
        assert np.all(reflex_leak_shift(model, q, rho) == 0)
    assert np.all(reflex_leak_shift(model, "stiffness", rho) > 0)


def test_the_stored_shift_is_the_refit_difference(leaky):
    data, model, rho, _ = leaky
    shift = refit_shift(model, data)
    G = model.intrinsic_basis.evaluate(rho)
    by_hand = np.abs(G @ shift.sum(axis=0))  # K is the IRF's sum over lags
    # the same solve on the same record (a Gram-matrix solve: the last digits follow the model's)
    assert np.allclose(reflex_leak_shift(model, "stiffness", rho), by_hand, rtol=1e-5)
    # the free dynamics lower K here, toward the truth
    assert np.all(G @ shift.sum(axis=0) < 0)
    _, _, bias = intrinsic_interval_parts(model, "stiffness", rho)
    assert np.array_equal(bias["reflex_leak"], reflex_leak_shift(model, "stiffness", rho))


def test_the_shift_noise_is_what_repeated_noise_gives(leaky):
    """The shift's noise covariance (``covariance=True``) is right: the shift is linear in the
    torque, so adding independent coloured noise to the same record many times spreads K's
    shift by the variance it predicts."""
    data, model, rho, _ = leaky
    rng = np.random.default_rng(5)
    c = np.kron(np.ones(len(model.lags)), model.intrinsic_basis.evaluate(rho[4:5])[0])  # K at mid-range
    scale = 2.0 * np.std(np.diff(np.asarray(data.torque)))  # larger than the record's own residual
    assert np.array_equal(refit_shift(model, data, covariance=True)[0], refit_shift(model, data))
    shifts, predicted = [], []
    for _ in range(40):
        noise = scipy.signal.lfilter([1.0], [1.0, -0.8], rng.standard_normal(len(data.torque))) * scale
        shift, cov = refit_shift(model, dataclasses.replace(data, torque=np.asarray(data.torque) + noise),
                                 covariance=True)
        shifts.append(c @ shift.ravel())
        predicted.append(c @ cov @ c)
    assert 0.6 < np.median(predicted) / np.var(shifts, ddof=1) < 1.6


def test_the_model_file_round_trips_the_leak_and_refuses_a_bad_one(leaky, tmp_path):
    _, model, rho, _ = leaky
    path = tmp_path / "m.json"
    model.save(path)
    loaded = LPVPCModel.load(path)
    a, b = model.elastic_stiffness_interval(rho), loaded.elastic_stiffness_interval(rho)
    assert np.array_equal(a.lower, b.lower) and np.array_equal(a.upper, b.upper)
    d = json.loads(path.read_text())
    d["uncertainty"]["structural"]["leak"]["quantities"] = ["reflex_gain"]
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"uncertainty\.structural\.leak\.quantities must be a list drawn from stiffness"):
        LPVPCModel.load(path)
