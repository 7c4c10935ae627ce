"""Bias-aware intrinsic intervals (lpvpc.models.uncertainty.structural_bias_bound) and the
stiffness truth the coverage benchmark uses (SubjectParams.incremental_stiffness)."""

import dataclasses
import json
import warnings

import numpy as np
import pytest

from lpvpc.errors import ModelFileError
from lpvpc.identification.identify import identify
from lpvpc.models.model import LPVPCModel
from lpvpc.simulation.simulate import SubjectParams
from lpvpc.models.uncertainty import (
    bias_aware_critical_value,
    intrinsic_interval,
    reflex_leak_shift,
    structural_bias_bound,
    structural_shift,
    z_value,
)

TRUTH = SubjectParams()


def central_rho(model, n=9):
    lo, hi = model.scheduling_range
    return np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n)


def test_incremental_stiffness_is_the_least_squares_slope_over_the_perturbation():
    theta, a = np.array([-0.35, -0.2, 0.0, 0.15]), 0.04
    s = np.linspace(-a, a, 40001)
    dE = TRUTH.elastic_torque(theta[:, None] + s) - TRUTH.elastic_torque(theta)[:, None]
    slope = (dE @ s) / (s @ s)  # least squares on a fine uniform grid
    assert TRUTH.incremental_stiffness(theta, a) == pytest.approx(slope, rel=1e-6)
    excess = TRUTH.incremental_stiffness(theta, a) / TRUTH.K(theta) - 1
    assert np.all(excess > 0.002) and np.all(excess < 0.008)  # convex curve: above the tangent
    assert TRUTH.incremental_stiffness(theta, 0.0) == pytest.approx(TRUTH.K(theta), rel=1e-12)
    assert TRUTH.incremental_stiffness(theta, 0.02) / TRUTH.K(theta) - 1 == pytest.approx(excess / 4, rel=0.02)


def _plain(model, quantity, rho):
    """The HAC interval without the structural terms (specifications and structures)."""
    d = json.loads(json.dumps(model.to_dict()))
    for key in ("truncation", "richer_basis", "structural"):
        d["uncertainty"].pop(key, None)
    return intrinsic_interval(LPVPCModel.from_dict(d), quantity, rho)


def test_stiffness_interval_is_bias_aware_with_the_sum_of_both_specification_shifts(model):
    rho = central_rho(model)
    u = model.uncertainty
    assert {"truncation", "richer_basis"} <= set(u)
    assert u["richer_basis"]["basis"]["order"] == model.intrinsic_basis.order + 1
    est, lo, hi = intrinsic_interval(model, "stiffness", rho)
    _, lo0, hi0 = _plain(model, "stiffness", rho)
    se = (hi0 - est) / z_value(0.95)
    bound = structural_bias_bound(model, "stiffness", rho, est)
    # each stored specification alone gives a positive shift; the bound is their sum
    d = json.loads(json.dumps(model.to_dict()))
    d["uncertainty"].pop("richer_basis")
    only_trunc = structural_bias_bound(LPVPCModel.from_dict(d), "stiffness", rho, est)
    assert np.all(only_trunc > 0) and np.all(bound > only_trunc)
    # with the structures cross-validation cannot tell apart (identify's selection ran), added
    structures = structural_shift(model, "stiffness", rho)
    leak = reflex_leak_shift(model, "stiffness", rho)  # and the reflex dynamics left free
    assert hi - est == pytest.approx(bias_aware_critical_value((bound + structures + leak) / se) * se, rel=1e-9)
    assert np.all(hi - lo > hi0 - lo0)


def test_the_shorter_irf_bounds_k_and_inertia_not_viscosity(model):
    """Viscosity weights the IRF by the lag: the shorter IRF's shift of it is the dropped
    lags' moment arm, not bias (it made its intervals cover 100 % at twice the noise band's
    width), so its bound is the richer basis's alone; K and inertia keep both."""
    rho = central_rho(model)
    d = json.loads(json.dumps(model.to_dict()))
    d["uncertainty"].pop("truncation")
    no_trunc = LPVPCModel.from_dict(d)
    for quantity, value in (("stiffness", model.elastic_stiffness(rho)), ("viscosity", model.viscosity(rho)),
                            ("inertia", model.inertia(rho))):
        with_t = structural_bias_bound(model, quantity, rho, value)
        without = structural_bias_bound(no_trunc, quantity, rho, value)
        if quantity != "viscosity":
            assert np.all(with_t > without)
        else:
            assert np.array_equal(with_t, without) and np.all(with_t > 0)
    # the truncation's viscosity shift is large against the noise: it would have dominated
    from lpvpc.models.uncertainty import _gradients_intrinsic, intrinsic_interval_parts, lag_moment_weights

    est, se, bias = intrinsic_interval_parts(model, "viscosity", rho)
    t = model.uncertainty["truncation"]
    g = _gradients_intrinsic(model, rho, lag_moment_weights(model, "viscosity", t["lags"]))
    shift = np.abs(g @ np.asarray(t["H"]).ravel() - est)
    assert np.median(shift / se) > 1.0 and np.median(shift) > np.median(bias["specification"])


def test_bias_bound_grows_and_keeps_coverage_when_the_basis_is_too_low(subject, model):
    """Order 3 in position cannot follow the subject's exponential K (errors up to ~6 %):
    the one-order-richer basis sees it, the bound grows and the intervals still cover,
    where the plain HAC intervals (a few percent wide) miss most positions."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        low = identify(subject["ident"], intrinsic_order=3)
    rho = central_rho(low)
    K = low.elastic_stiffness(rho)
    truth = TRUTH.incremental_stiffness(rho)
    assert np.max(np.abs(K / truth - 1)) > 0.03  # the basis really is too low
    ratio = np.median(structural_bias_bound(low, "stiffness", rho, K) / K) / np.median(
        structural_bias_bound(model, "stiffness", central_rho(model), model.elastic_stiffness(central_rho(model)))
        / model.elastic_stiffness(central_rho(model)))
    assert ratio > 2
    lo, hi = low.elastic_stiffness_interval(rho)
    _, lo0, hi0 = _plain(low, "stiffness", rho)
    inside, inside0 = (lo <= truth) & (truth <= hi), (lo0 <= truth) & (truth <= hi0)
    assert inside.sum() >= 8 and inside0.sum() <= 5, (inside, inside0)


@pytest.mark.parametrize("mutate, message", [
    (lambda u: u["richer_basis"]["H"].pop(), "uncertainty.richer_basis.H has shape"),
    (lambda u: u["richer_basis"]["basis"].__setitem__("order", 99), "richer_basis.basis.order"),
    (lambda u: u["richer_basis"].pop("basis"), "richer_basis.basis"),
])
def test_model_file_schema_checks_the_richer_basis(model, tmp_path, mutate, message):
    d = json.loads(json.dumps(model.to_dict()))
    mutate(d["uncertainty"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=message):
        LPVPCModel.load(path)


def test_recorded_inertial_torque_carries_no_spurious_viscosity():
    """An inertia-plus-spring ankle (B = 0) must give an IRF with zero first moment. With
    the servo's acceleration sampled at its jumps (the held command) the IRF read
    ~0.2 N m s/rad of viscosity; the anti-aliased recording does not."""
    from lpvpc.io import decimate_signal
    from lpvpc.models.equations import lagged
    from lpvpc.simulation.simulate import FS_SIM, pralds, recorded_acceleration, servo

    cmd = pralds(60.0, FS_SIM, np.random.default_rng(4))
    theta = servo(cmd, FS_SIM, TRUTH)[0]
    lags = np.arange(-4, 5)

    def viscosity(acc):
        p, y = decimate_signal(theta, 10), decimate_signal(TRUTH.inertia * acc + 50.0 * theta, 10)
        h = np.linalg.lstsq(lagged(p, list(lags)), y, rcond=None)[0]
        return -(h @ lags) / 100.0

    assert abs(viscosity(recorded_acceleration(cmd, FS_SIM, TRUTH))) < 0.03
    assert viscosity(servo(cmd, FS_SIM, TRUTH)[2]) > 0.1


def test_noise_free_identification_recovers_viscosity(subject):
    """Noise-free data: a candidate reflex order the data cannot support is skipped (not
    fatal), and the IRF's first moment is the subject's viscosity within 10 %.

    Measured 0.64-0.70 N m s/rad on the 100 Hz path, 0.63-0.67 on the 1 kHz path, lowest at
    the dorsiflexed end (B = 0.70; before the elastic curvature term 0.685-0.704 and
    0.65-0.67): the IRF's last lag (L = 4 samples, the reflex delay) shares torque with
    the reflex's onset, and the term, by correcting the reflex gain (+10 % to +1 %),
    changes that share. Found with the term: the 5 % tolerance of before no longer holds
    at the two most dorsiflexed of nine positions."""
    clean = subject["ident_clean"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = identify(dataclasses.replace(clean, high_rate=None))  # the reflex on 100 Hz velocity
        m1k = identify(clean)  # on the 1 kHz velocity (the default from 1 kHz files)
    rho = central_rho(m)
    assert m.viscosity(rho) == pytest.approx(np.full(len(rho), TRUTH.viscosity), rel=0.10)
    assert str(m.state_order) in m.fit["state_order_candidates"]
    # measured: the 1 kHz reflex path takes ~4 % of the viscous torque on these noise-free
    # data (0.65-0.67 N m s/rad against 0.68-0.70 on the 100 Hz path; issue 10 item 3)
    assert m1k.viscosity(rho) == pytest.approx(np.full(len(rho), TRUTH.viscosity), rel=0.12)
