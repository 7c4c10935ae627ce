"""Reflex gain and threshold intervals (lpvpc.uncertainty.reflex_interval): the delta
method through the identifiable product of nonlinearity and dynamics, checked against the
spread of the estimate over noise realisations of the same trials."""

import dataclasses
import json
import warnings

import numpy as np
import pytest

from lpvpc.data import pair_trials
from lpvpc.errors import ModelFileError
from lpvpc.identify import identify
from lpvpc.model import LPVPCModel
from lpvpc.simulate import coloured_noise
from lpvpc.subspace import companion_form
from lpvpc.uncertainty import MODEL_RATE_BIAS_NOTE, nonlinearity_jacobian, reflex_bias_bound, z_value


def central_rho(model, n=9):
    lo, hi = model.scheduling_range
    return np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n)


@pytest.fixture(scope="module")
def model_1k(subject):
    """The 1 kHz files' model with the reflex nonlinearity on the 1 kHz velocity."""
    return identify(subject["ident"], high_rate_reflex=True)


def test_nonlinearity_jacobian_is_blind_to_the_hammerstein_scale(model, model_1k):
    """Omega times a and (B, D) divided by a leave the scaled nonlinearity unchanged: the
    Jacobian has no component along that direction (the scale is not identifiable)."""
    for m in (model, model_1k):
        v, _ = m.rectifier_velocity_grid(50)
        f, J = nonlinearity_jacobian(m, v, central_rho(m, 4))
        omega = m.nonlinearity()[1].ravel()
        gauge = np.concatenate([omega, -m.B, [-m.D], np.zeros(len(J) - len(omega) - len(m.B) - 1)])
        along = np.tensordot(gauge, J, axes=1)
        assert np.max(np.abs(along)) < 1e-8 * np.max(np.abs(f)), np.max(np.abs(along))
        assert np.max(np.abs(J[:len(omega)])) > 1e-3 * np.max(np.abs(f))  # not blind to everything


def test_nonlinearity_jacobian_matches_finite_differences(model_1k):
    """Columns for B, D and the reflex denominator against re-evaluating the model."""
    m = model_1k
    v, rho = np.linspace(0.0, 2.0, 30), central_rho(m, 3)
    f, J = nonlinearity_jacobian(m, v, rho)
    n_w, k = m.nonlinearity()[1].size, m.state_order
    den = -m.A[:, 0]
    assert J.shape[0] == n_w + k + 1 + k  # the file holds the poles' covariance
    h = 1e-6
    for j in range(k + 1 + k):
        fs = []
        for sgn in (1.0, -1.0):
            B, D, d = m.B.copy(), m.D, den.copy()
            if j < k:
                B[j] += sgn * h
            elif j == k:
                D += sgn * h
            else:
                d[j - k - 1] += sgn * h
            fs.append(dataclasses.replace(m, A=companion_form(d)[0], B=B, D=D).reflex_nonlinearity(v, rho))
        assert np.allclose((fs[0] - fs[1]) / (2 * h), J[n_w + j], rtol=1e-4, atol=1e-6 * np.max(np.abs(f)))


def without_bias_bound(m):
    """The model with the statistical part of the reflex intervals only."""
    return dataclasses.replace(m, uncertainty={k: v for k, v in m.uncertainty.items() if k != "curvature_reflex"})


def test_reflex_bias_bound_widens_the_intervals_and_is_stored(model_1k, tmp_path):
    rho = central_rho(model_1k, 5)
    g_bound, th_bound = reflex_bias_bound(model_1k, rho)
    gain, thr = model_1k.reflex_gain_threshold(rho)
    assert np.all(g_bound >= 0) and np.any(g_bound > 0.005 * gain) and np.all(g_bound < 0.5 * gain), g_bound / gain
    plain = without_bias_bound(model_1k)
    assert np.all(reflex_bias_bound(plain, rho)[0] == 0)
    (lo, hi), (lo0, hi0) = model_1k.reflex_gain_interval(rho), plain.reflex_gain_interval(rho)
    assert np.all(lo <= lo0) and np.all(hi0 <= hi) and np.any(hi - lo > (1 + 1e-6) * (hi0 - lo0))
    path = tmp_path / "m.json"
    model_1k.save(path)
    assert np.array_equal(np.array(LPVPCModel.load(path).reflex_gain_interval(rho)), np.array((lo, hi)))
    d = json.loads(path.read_text())
    d["uncertainty"]["curvature_reflex"]["bd"].pop()
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"uncertainty.curvature_reflex.bd has shape"):
        LPVPCModel.load(path)


def test_model_rate_reflex_intervals_are_marked_biased(model, model_1k):
    rho = central_rho(model, 3)
    for interval in (model.reflex_gain_interval(rho), model.reflex_threshold_interval(rho)):
        assert interval.biased and interval.note == MODEL_RATE_BIAS_NOTE
        lo, hi = interval  # still a (lower, upper) pair
        assert np.all(lo < hi)
    assert not model_1k.reflex_gain_interval(rho).biased and not model_1k.reflex_gain_interval(rho).note


@pytest.mark.slow
def test_gain_intervals_match_the_spread_over_noise_realisations(subject, model_1k):
    """The same 1 kHz trials with 8 independent noise records at the simulator's noise
    scale: the intervals' standard error is the spread of the gain over the records (the
    draws of nonlinearity and dynamics this replaced gave 2-3x that), and they cover the
    noise-free identification's gain."""
    pair = subject["ident_pair"]
    scale = pair.truth["noise_scale"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clean = identify(subject["ident_clean"], high_rate_reflex=True)
        models = []
        for r in range(8):
            rng = np.random.default_rng([r, 2014])
            pt, ut = (dataclasses.replace(t, torque=t.torque + scale * coloured_noise(len(t.torque), 1000.0, rng))
                      for t in (pair.pt_clean, pair.ut_clean))
            models.append(identify(pair_trials(pt, ut), high_rate_reflex=True))
    rho = central_rho(clean, 7)
    gain = np.array([m.reflex_gain_threshold(rho)[0] for m in models])
    lo, hi = (np.array(x) for x in zip(*(without_bias_bound(m).reflex_gain_interval(rho) for m in models)))
    se = np.median((hi - lo) / 2 / z_value(0.95), axis=0)
    ratio = se / gain.std(axis=0, ddof=1)
    assert 0.6 < np.median(ratio) < 1.6, ratio
    target = clean.reflex_gain_threshold(rho)[0]
    assert np.mean((lo <= target) & (target <= hi)) >= 0.8
