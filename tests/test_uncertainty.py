"""Confidence intervals (lpvpc.models.uncertainty): the HAC estimate, the intervals of the
physical quantities against the virtual subject's truth, storage in the model file.
Coverage over many seeds is measured in benchmarks/bench_uncertainty.py."""

import json

import numpy as np
import pytest

from lpvpc.errors import ModelFileError
from lpvpc.models.model import LPVPCModel, rectifier_fit
from lpvpc.simulation.simulate import SubjectParams
from lpvpc.models.uncertainty import long_run_covariance, vaf_interval

TRUTH = SubjectParams()


def central_rho(model, n=9):
    lo, hi = model.scheduling_range
    return np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n)


def test_long_run_covariance_of_ar1_matches_theory():
    """For AR(1) u_k = phi u_{k-1} + e_k, Var(sum u) / N -> sigma^2 / (1 - phi)^2; a
    white-noise formula would be (1 - phi^2)^-1 instead, 4.75x too small at phi = 0.8."""
    import scipy.signal

    rng = np.random.default_rng(3)
    phi, n = 0.8, 200_000
    u = scipy.signal.lfilter([1.0], [1.0, -phi], rng.standard_normal(n))[:, None]
    got = long_run_covariance(u, 200)[0, 0] / n
    assert got == pytest.approx(1 / (1 - phi) ** 2, rel=0.1)
    assert long_run_covariance(u, 1)[0, 0] / n == pytest.approx(1 / (1 - phi**2), rel=0.05)


def test_stiffness_interval_brackets_estimate_and_mostly_the_truth(model):
    rho = central_rho(model)
    lo, hi = model.elastic_stiffness_interval(rho)
    K = model.elastic_stiffness(rho)
    assert np.all(lo < K) and np.all(K < hi)
    half = (hi - lo) / 2 / K
    assert np.all(half > 0.003) and np.all(half < 0.15), half  # a few percent, not degenerate
    inside = (lo <= TRUTH.K(rho)) & (TRUTH.K(rho) <= hi)
    assert inside.sum() >= 6, (lo, TRUTH.K(rho), hi)  # one seed; the coverage benchmark pools 20


def test_wider_level_gives_wider_interval(model):
    rho = central_rho(model, 5)
    lo90, hi90 = model.elastic_stiffness_interval(rho, level=0.90)
    lo99, hi99 = model.elastic_stiffness_interval(rho, level=0.99)
    assert np.all(lo99 < lo90) and np.all(hi90 < hi99)
    with pytest.raises(ValueError, match="level"):
        model.elastic_stiffness_interval(rho, level=95)


def test_reflex_and_mechanics_intervals_bracket_their_estimates(model):
    rho = central_rho(model, 5)
    gain, thr = model.reflex_gain_threshold(rho)
    for (lo, hi), est in ((model.reflex_gain_interval(rho), gain), (model.reflex_threshold_interval(rho), thr),
                          (model.viscosity_interval(rho), model.viscosity(rho)),
                          (model.inertia_interval(rho), model.inertia(rho))):
        assert lo.shape == hi.shape == (5,)
        assert np.all(lo <= est + 1e-12) and np.all(est <= hi + 1e-12) and np.all(lo < hi)
    # the reflex gain interval covers the true gain in the plantarflexed half (the 100 Hz
    # model's gain is biased high toward dorsiflexion: benchmarks/results/uncertainty.txt)
    lo, hi = model.reflex_gain_interval(rho[:2])
    assert np.all(lo < TRUTH.reflex_gain(rho[:2]) * 1.2) and np.all(TRUTH.reflex_gain(rho[:2]) * 0.8 < hi)
    assert 0.4 < model.viscosity(rho).mean() < 1.2 and 0.008 < model.inertia(rho).mean() < 0.03


def test_vaf_interval_brackets_the_fit_vaf(model):
    lo, hi = model.vaf_interval()
    assert lo < model.fit["vaf"] < hi and hi - lo < 2.0
    rng = np.random.default_rng(0)
    y = rng.standard_normal(4000)
    narrow = vaf_interval(y, y + 0.1 * rng.standard_normal(4000), 20)
    wide = vaf_interval(y, y + 0.5 * rng.standard_normal(4000), 20)
    assert narrow["upper"] - narrow["lower"] < wide["upper"] - wide["lower"]


def test_rectifier_fit_matches_a_loop_of_least_squares(model):
    v, _ = model.rectifier_velocity_grid()
    curves = model.reflex_nonlinearity(v, central_rho(model, 4))
    g, th = rectifier_fit(v, curves)
    for f, gi, ti in zip(curves, g, th):
        best = min(((float(np.sum((np.column_stack([np.maximum(v - t, 0), np.ones_like(v)])
                                   @ np.linalg.lstsq(np.column_stack([np.maximum(v - t, 0), np.ones_like(v)]), f,
                                                     rcond=None)[0] - f) ** 2)), t) for t in v[:-5]))
        assert ti == pytest.approx(best[1], abs=v[1] * 1.01)
        assert gi > 0


def test_intervals_survive_save_and_load(model, tmp_path):
    path = tmp_path / "m.json"
    model.save(path)
    loaded = LPVPCModel.load(path)
    rho = central_rho(model, 3)
    assert np.array_equal(np.array(loaded.elastic_stiffness_interval(rho)), np.array(model.elastic_stiffness_interval(rho)))
    assert np.array_equal(np.array(loaded.reflex_gain_interval(rho)), np.array(model.reflex_gain_interval(rho)))
    assert loaded.model_hash == model.model_hash


def test_old_model_file_without_intervals_loads_and_says_so(model, tmp_path):
    d = model.to_dict()
    del d["uncertainty"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(d))
    old = LPVPCModel.load(path)
    assert not old.has_intervals
    assert np.allclose(old.elastic_stiffness([0.0]), model.elastic_stiffness([0.0]))
    with pytest.raises(ModelFileError, match="no uncertainty"):
        old.elastic_stiffness_interval([0.0])
    with pytest.raises(ModelFileError, match="re-identify"):
        old.reflex_gain_interval([0.0])


@pytest.mark.parametrize("mutate, message", [
    (lambda u: u["covariance"].pop(), "uncertainty.covariance has shape"),
    (lambda u: u["covariance"][0].__setitem__(0, -1.0), "non-negative diagonal"),
    (lambda u: u["covariance"][1].__setitem__(0, 1e6), "symmetric"),
    (lambda u: u["covariance"][0].__setitem__(1, "x"), "uncertainty.covariance[0][1] must be a number"),
    (lambda u: u["parameters"].__setitem__("omega", 3), "parameters.omega = 3 does not match the model"),
    (lambda u: u["vaf"].__setitem__("level", 95), "uncertainty.vaf.level = 95"),
    (lambda u: u["truncation"]["H"].pop(), "uncertainty.truncation.H has shape"),
])
def test_model_file_schema_checks_the_uncertainty_section(model, tmp_path, mutate, message):
    d = json.loads(json.dumps(model.to_dict()))
    mutate(d["uncertainty"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=message.replace("[", r"\[").replace("]", r"\]")):
        LPVPCModel.load(path)


def test_model_file_schema_checks_the_data_density(model, tmp_path):
    d = json.loads(json.dumps(model.to_dict()))
    d["fit"]["data_density"]["counts"][0][0] = -1
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match="data_density.counts must be non-negative"):
        LPVPCModel.load(path)


def test_bias_aware_critical_value_keeps_coverage_under_the_bias_bound():
    from lpvpc.models.uncertainty import bias_aware_critical_value

    rng = np.random.default_rng(5)
    for t in (0.0, 0.7, 2.5):
        c = float(bias_aware_critical_value(t))
        x = t + rng.standard_normal(200_000)  # estimate - truth in standard errors, bias at the bound
        assert np.mean(np.abs(x) <= c) == pytest.approx(0.95, abs=0.004)
        assert c >= 1.959 and c <= t + 1.96 + 1e-9


def test_old_model_figures_draw_without_bands_or_density(model):
    from lpvpc import plotting

    d = model.to_dict()
    del d["uncertainty"]
    del d["fit"]["data_density"]
    old = LPVPCModel.from_dict(d)
    fig = plotting.plot_reflex_nonlinearity(old)
    ax = fig.axes[0]
    assert not ax.child_axes and not ax.collections and len(ax.lines) >= 5
    fig = plotting.plot_intrinsic_gain(old)
    assert not fig.axes[0].child_axes


def test_unidentified_parameters_give_no_interval_rather_than_noise(model):
    """A reflex pathway that came out zero (B = D = 0) leaves the nonlinearity's direction
    undetermined: the final fit's Jacobian is singular, and fit_uncertainty says so instead of
    inverting rounding errors into enormous 'intervals'. With a reflex it gives finite ones."""
    from lpvpc.models.uncertainty import fit_uncertainty

    rng = np.random.default_rng(0)
    n = 2000
    psi_i, y = rng.standard_normal((n, 6)), rng.standard_normal(n)
    blocks = [rng.standard_normal((n, 4)) for _ in range(3)]
    omega = np.full(4, 0.5)
    with pytest.raises(np.linalg.LinAlgError, match="not all identified"):
        fit_uncertainty(model, psi_i, blocks, y, np.zeros(3), omega, np.zeros(6))
    out = fit_uncertainty(model, psi_i, blocks, y, np.array([1.0, 0.5, 0.2]), omega, np.zeros(6))
    cov = np.asarray(out["covariance"])
    assert cov.shape == (6 + 4 + 3, 6 + 4 + 3) and np.all(np.isfinite(cov)) and np.all(np.diag(cov) >= 0)
