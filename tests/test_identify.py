"""Identification on the virtual subject (known truth) and its failure modes."""

import json
import re
import warnings

import numpy as np
import pytest

from lpvpc.models.basis import Basis
from lpvpc.io import PerturbationData, Trial, pair_trials
from lpvpc.errors import DataError, InsufficientExcitationError, ModelFileError, OutOfRangeWarning
from lpvpc.identification.identify import LPVPCEstimator, identify, project_out_and_solve
from lpvpc.models.model import LPVPCModel, vaf
from lpvpc.simulation.simulate import SubjectParams, simulate_pair

TRUTH = SubjectParams()


def true_component(pair, key):
    c, t = pair.components, pair.pt.time
    return pair_trials(Trial(t, pair.pt.position, c["pt_" + key]), Trial(t, pair.ut.position, c["ut_" + key])).torque


def central_rho(model, n=25):
    lo, hi = model.scheduling_range
    return np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), n)


def predict_quiet(model, data, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        return model.predict(data.position, data.scheduling, **kw)


# -- accuracy ---------------------------------------------------------------------------
def test_novel_vaf_within_one_point_of_noise_ceiling(subject, model):
    ceiling = vaf(subject["novel"].torque, subject["novel_clean"].torque)
    got = vaf(subject["novel"].torque, predict_quiet(model, subject["novel"]).total)
    assert got > ceiling - 1.0, f"novel VAF {got:.2f} % vs noise ceiling {ceiling:.2f} %"


def test_elastic_stiffness_within_ten_percent_over_central_range(model):
    rho = central_rho(model)
    err = 100 * (model.elastic_stiffness(rho) / TRUTH.K(rho) - 1)
    assert np.max(np.abs(err)) < 10.0, f"K error {np.round(err, 1)} %"


def test_predicted_intrinsic_torque_matches_true_intrinsic(subject, model):
    pred = predict_quiet(model, subject["novel"])
    got = vaf(true_component(subject["novel_pair"], "intrinsic"), pred.intrinsic)
    assert got >= 95.0, f"intrinsic VAF {got:.2f} %"


def test_elastic_curvature_follows_the_subjects_stiffness_gradient(model):
    """The second-order elastic term is 0.5 K'(theta) of the identified K (tied), and so close
    to the virtual subject's 0.5 dK/dtheta where K rises steeply (dorsiflexion)."""
    rho = central_rho(model)
    half_slope = 0.5 * (TRUTH.K(rho + 1e-5) - TRUTH.K(rho - 1e-5)) / 2e-5  # N m/rad^2
    got = model.intrinsic_basis.evaluate(rho) @ model.curvature
    steep = half_slope > 40.0  # N m/rad^2: the dorsiflexion half, where the term matters
    assert steep.sum() >= 5
    err = got[steep] / half_slope[steep] - 1
    assert np.max(np.abs(err)) < 0.3, f"curvature error {np.round(100 * err, 1)} %"
    # tied: exactly half the slope of the model's own K(theta)
    own_half_slope = 0.5 * (model.elastic_stiffness(rho + 1e-5) - model.elastic_stiffness(rho - 1e-5)) / 2e-5
    assert np.allclose(got, own_half_slope, rtol=1e-3, atol=1e-3 * np.abs(own_half_slope).max())


def test_elastic_curvature_keeps_the_reflex_gain_level_on_the_1khz_path(subject):
    """Noise-free 1 kHz record: without the term the reflex nonlinearity takes up part of
    0.5 K' p^2 and its gain comes out ~10 % high; with it, within 6 % on average (measured
    +1..+4 % on seeds 0-3, +8..+18 % without; benchmarks/results/reflex_1k_bias.txt)."""
    clean = subject["ident_clean"]
    ratio = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for curvature in (True, False):
            m = identify(clean, high_rate_reflex=True, elastic_curvature=curvature)
            rho = central_rho(m, 9)
            ratio[curvature] = float(np.mean(m.reflex_gain_threshold(rho)[0] / TRUTH.reflex_gain(rho)))
    assert abs(ratio[True] - 1) < 0.06 and ratio[False] > ratio[True] + 0.03, ratio


def test_model_without_elastic_curvature_keeps_the_papers_structure_and_file_format(subject, tmp_path):
    data = subject["ident"].segment(0, 3000)
    est = LPVPCEstimator(elastic_curvature=False).fit(data)
    assert est.model_.curvature is None and est.model_.to_dict()["format_version"] == 1
    assert "curvature" not in est.model_.to_dict()["intrinsic"]
    est.model_.save(tmp_path / "v1.json")  # a format-1 file (as older lpvpc wrote) loads and predicts alike
    again = LPVPCModel.load(tmp_path / "v1.json")
    assert again.curvature is None
    assert np.array_equal(again.predict(data, warn=False).total, est.model_.predict(data, warn=False).total)
    with_term = identify(data)
    n_i = with_term.settings["intrinsic_order"] + 1  # (chosen by the default structure selection)
    assert with_term.to_dict()["format_version"] == 3 and len(with_term.to_dict()["intrinsic"]["curvature"]) == n_i


def test_reflex_poles_stay_within_the_time_constant_limit_under_slow_unmodelled_torque():
    """A hidden background activation (slow torque the model lacks): uncapped, the refined
    reflex poles run to the stability limit (0.999 per sample, an integrator that follows
    the slow torque) and the model fails on another record; capped at the default 1 s they
    stay inside exp(-1 / (1 s * fs)) and the novel-record VAF is far higher."""
    ident = simulate_pair("multilevel", seed=4, effects=("background_activation",), fs_out=100.0)
    novel = simulate_pair("novel", seed=5, effects=("background_activation",), fs_out=100.0)
    data, test = pair_trials(ident.pt, ident.ut), pair_trials(novel.pt, novel.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        capped = identify(data)
        free = identify(data, max_reflex_time_constant=None)
        v_capped, v_free = (vaf(test.torque, m.predict(test, warn=False).total) for m in (capped, free))
    from lpvpc.identification.identify import DEFAULT_MAX_REFLEX_TIME_CONSTANT

    radius = np.abs(np.linalg.eigvals(capped.A))
    assert radius.max() < np.exp(-1.0 / (DEFAULT_MAX_REFLEX_TIME_CONSTANT * 100.0)) and np.abs(np.linalg.eigvals(free.A)).max() > 0.995
    assert v_capped > v_free + 10.0, (v_capped, v_free)


def test_reflex_gain_rises_toward_dorsiflexion(model):
    rho = central_rho(model)
    gain, _ = model.reflex_gain_threshold(rho)
    assert np.polyfit(rho, gain, 1)[0] > 0, f"gain {np.round(gain, 2)}"
    assert np.all(gain > 0)


@pytest.mark.xfail(reason="issue 10 target not met: by default the nonlinearity sees the 100 Hz delayed "
                          "velocity, where the target is out of reach even for an ideal fit "
                          "(benchmarks/results/reflex_observability.txt); with high_rate_reflex=True (1 kHz "
                          "velocity) the threshold slope still scatters from seed to seed (reflex_1k.txt); "
                          "tests/test_reflex_1k.py checks the 1 kHz path against the 100 Hz one", strict=False)
def test_reflex_threshold_falls_toward_dorsiflexion_within_20_percent(model):
    rho = central_rho(model)
    _, threshold = model.reflex_gain_threshold(rho)
    slope = np.polyfit(rho, threshold, 1)[0] / np.polyfit(rho, TRUTH.reflex_threshold(rho), 1)[0]
    assert 0.8 < slope < 1.2, f"threshold {np.round(threshold, 2)}, slope ratio {slope:.2f}"


def test_each_order_is_fitted_at_its_best_minimum():
    """Seed 13's alternating LS for order 2 started from every singular pair of the
    unstructured fit ends at twice order 1's error; the direction search over [B; d] finds
    the real minimum, so BIC picks the subject's second-order reflex."""
    pair = simulate_pair("multilevel", seed=13, fs_out=100.0)
    model = identify(pair_trials(pair.pt, pair.ut))
    bic = {int(k): v for k, v in model.fit["state_order_candidates"].items()}
    assert model.state_order == 2, bic
    assert bic[2] < bic[1] - 1000 and bic[3] < bic[1] - 1000, bic


def test_reflex_dynamics_are_second_order_low_pass_near_truth(model):
    # Truth: wn = 16 rad/s, zeta = 0.65 (continuous) at fs = 100 Hz.
    assert model.state_order >= 2
    poles = np.linalg.eigvals(model.A)
    s = np.log(poles.astype(complex)) * model.fs
    dominant = s[np.argsort(np.abs(s))[:2]]
    wn = float(np.sqrt(np.prod(np.abs(dominant))))
    assert 10.0 < wn < 24.0, f"dominant poles {dominant}"
    t, irf = model.reflex_impulse_response()
    assert np.all(np.isfinite(irf)) and abs(irf[-1]) < 0.05 * np.max(np.abs(irf))


def test_held_out_faster_than_identification_gives_no_spikes(subject, model):
    """A held-out record whose peak velocity exceeds the identified range must not turn
    the velocity polynomial into torque spikes (the failure of the lab's MATLAB code)."""
    pair = simulate_pair("novel", seed=7, perturbation_amplitude=0.06)
    data = pair_trials(pair.pt, pair.ut)
    clean = pair_trials(pair.pt_clean, pair.ut_clean)
    from lpvpc.models import equations as eq

    dvel = eq.delayed_velocity(data.position, data.fs, model.delay)
    assert dvel.max() > model.velocity_range[1] * 1.1, "test record must exceed the identified velocity range"
    pred = predict_quiet(model, data)
    assert np.max(np.abs(pred.total)) < 1.1 * np.max(np.abs(clean.torque))
    # 1.5 points measured: larger perturbations than identified also carry more elastic
    # nonlinearity; a polynomial spike would cost tens of points.
    assert vaf(data.torque, pred.total) > vaf(data.torque, clean.torque) - 2.0


# -- algorithm pieces --------------------------------------------------------------------
def test_projection_equals_literal_pseudo_inverse_formula():
    rng = np.random.default_rng(3)
    n = 400
    Psi_r, Psi_i = rng.standard_normal((n, 6)), rng.standard_normal((n, 5))
    y = Psi_i @ rng.standard_normal(5) + Psi_r @ rng.standard_normal(6) + 0.1 * rng.standard_normal(n)
    pr, pi = np.linalg.pinv(Psi_r), np.linalg.pinv(Psi_i)
    C = np.eye(5) - pi @ Psi_r @ pr @ Psi_i
    literal = np.linalg.pinv(C) @ pi @ (np.eye(n) - Psi_r @ pr) @ y
    np.testing.assert_allclose(project_out_and_solve(Psi_r, Psi_i, y), literal, rtol=1e-9, atol=1e-12)


def test_chebyshev_linear_extension_is_continuous_and_tangent():
    b = Basis("chebyshev", 6, -2.0, 3.0, extrapolation="linear")
    eps = 1e-6
    for edge in (-2.0, 3.0):
        inside, outside = b.evaluate([edge - np.sign(edge) * eps]), b.evaluate([edge + np.sign(edge) * eps])
        np.testing.assert_allclose(inside, outside, atol=1e-3)
    far = b.evaluate([3.0 + 10.0])[0]
    edge_val, edge_slope = b.evaluate([3.0])[0], (b.evaluate([3.0])[0] - b.evaluate([3.0 - 1e-6])[0]) / 1e-6
    np.testing.assert_allclose(far, edge_val + 10.0 * edge_slope, rtol=1e-4)
    clipped = Basis("chebyshev", 6, -2.0, 3.0)
    np.testing.assert_array_equal(clipped.evaluate([50.0]), clipped.evaluate([3.0]))


def test_out_of_range_scheduling_warns_and_holds_the_boundary(subject):
    # the clip rule given (the default structure may choose "linear" continuation): it stays as given
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(subject["ident"], scheduling_extrapolation="clip")
    assert model.fit["structure_selection"]["chosen"]["scheduling_extrapolation"] == "clip"
    lo, hi = model.scheduling_range
    n = 300
    pos = 0.01 * np.sin(np.arange(n) / 5.0)
    with pytest.warns(OutOfRangeWarning, match="outside the identified range.*held at the boundary there"):
        beyond = model.predict(pos, np.full(n, hi + 0.2))
    at_edge = model.predict(pos, np.full(n, hi))
    np.testing.assert_array_equal(beyond.total, at_edge.total)
    assert beyond.out_of_range_fraction == 1.0


def test_out_of_range_warning_says_what_a_linear_extrapolation_model_does(subject):
    """The warning said "held at the boundary" for every model, also one whose
    cross-validation chose linear continuation."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(subject["ident"], scheduling_extrapolation="linear", structure="fixed")
    lo, hi = model.scheduling_range
    pos = 0.01 * np.sin(np.arange(300) / 5.0)
    with pytest.warns(OutOfRangeWarning, match="continued linearly from the boundary"):
        beyond = model.predict(pos, np.full(300, hi + 0.2))
    assert not np.array_equal(beyond.total, model.predict(pos, np.full(300, hi)).total)


# -- persistence -------------------------------------------------------------------------
def test_save_load_round_trips_exactly(model, model_file, subject):
    loaded = LPVPCModel.load(model_file)
    assert loaded.to_dict() == json.loads(json.dumps(model.to_dict()))
    a, b = predict_quiet(model, subject["novel"]), predict_quiet(loaded, subject["novel"])
    np.testing.assert_array_equal(a.total, b.total)
    assert loaded.model_hash == model.model_hash
    d = loaded.to_dict()
    assert d["provenance"]["data_hash"] == subject["ident"].data_hash
    assert d["settings"]["irf_lags"] == 4 and d["fs"] == 100.0  # irf_length 0.04 s at 100 Hz


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda text: text[: len(text) // 2], "corrupt model file"),
        (lambda text: text.replace('"lpvpc-model"', '"something-else"'), "not an lpvpc model"),
        (lambda text: json.dumps({**json.loads(text), "format_version": 99}), "format_version"),
        (lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "reflex"}), "corrupt model file"),
    ],
)
def test_corrupt_model_file_names_the_problem(model_file, tmp_path, mutate, message):
    bad = tmp_path / "bad.json"
    bad.write_text(mutate(model_file.read_text()))
    with pytest.raises(ModelFileError, match=message):
        LPVPCModel.load(bad)


def test_model_with_wrong_coefficient_shape_is_rejected(model_file, tmp_path):
    d = json.loads(model_file.read_text())
    d["reflex"]["Omega"] = d["reflex"]["Omega"][:-1]
    bad = tmp_path / "shape.json"
    bad.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match="Omega has shape"):
        LPVPCModel.load(bad)


# -- bad input ---------------------------------------------------------------------------
def _data(n=3000, seed=0, **over):
    rng = np.random.default_rng(seed)
    fields = dict(position=0.02 * rng.standard_normal(n), torque=rng.standard_normal(n),
                  scheduling=np.linspace(-0.4, 0.2, n), fs=100.0)
    fields.update(over)
    return PerturbationData(**fields) if all(np.all(np.isfinite(np.atleast_1d(v))) for v in fields.values()) else type("D", (), fields)


def test_too_few_samples_names_the_counts():
    with pytest.raises(InsufficientExcitationError, match=r"too few samples.*300 samples for \d+ parameters"):
        identify(_data(300))


def test_zero_perturbation_is_insufficient_excitation():
    with pytest.raises(InsufficientExcitationError, match="no perturbation"):
        identify(_data(position=np.zeros(3000)))


def test_constant_scheduling_with_forced_lpv_orders_is_rank_deficient(subject):
    d = subject["ident"]
    const = PerturbationData(position=d.position, torque=d.torque, scheduling=np.full(d.n, -0.1), fs=d.fs)
    with pytest.raises(InsufficientExcitationError, match="rank-deficient intrinsic regressor: rank"):
        identify(const, state_order=2, stationary_range=0.0)  # automatic LTI switched off


def test_rank_check_on_the_triangular_factor_matches_the_full_regressor(subject):
    # identify checks rank on Psi_i's triangular factor (cheaper): the same rank as the
    # pivoted QR of the N-row regressor itself (which columns of an exactly dependent set
    # get named is a tie among roundoff-sized norms, in either)
    from lpvpc.models.basis import basis_from_data
    from lpvpc.identification.identify import check_full_rank
    from lpvpc.models.intrinsic import intrinsic_regressor, two_sided_lags
    from lpvpc.linalg import triangular_factor

    d = subject["ident"]
    rho = np.where(np.arange(d.n) < d.n // 2, -0.1, 0.05)  # two levels: order-5 basis columns depend
    Psi = intrinsic_regressor(d.position, basis_from_data(rho, "chebyshev", 5).evaluate(rho), two_sided_lags(4))
    messages = []
    for M in (Psi, triangular_factor(Psi)):
        with pytest.raises(InsufficientExcitationError) as err:
            check_full_rank(M, "intrinsic")
        messages.append(str(err.value))
    assert all(m.startswith("rank-deficient intrinsic regressor: rank 18 of 54 columns (columns [") for m in messages)


def test_non_finite_identification_data_names_channel_and_index():
    pos = 0.02 * np.random.default_rng(0).standard_normal(3000)
    pos[17] = np.nan
    with pytest.raises(DataError, match="channel position: 1 non-finite values, first at index 17"):
        LPVPCEstimator().fit(_data(position=pos))


def test_prediction_rejects_unequal_lengths(model):
    with pytest.raises(DataError, match="equal length"):
        model.predict(np.zeros(10), np.zeros(9))


def test_hinge_basis_is_piecewise_linear_and_extends_linearly():
    b = Basis("hinge", 6, -3.0, 4.0, extrapolation="linear")
    x = np.linspace(-6.0, 8.0, 1401)
    values = b.evaluate(x)
    second_diff = np.abs(np.diff(values, 2, axis=0))
    # piecewise linear: curvature only at the knots (at most one grid cell each side)
    knots = (b.knots() * (b.hi - b.lo) + (b.hi + b.lo)) / 2
    near_knot = np.min(np.abs(x[1:-1, None] - knots[None, :]), axis=1) < 0.02
    assert np.all(second_diff[~near_knot] < 1e-9)
    assert values.shape == (len(x), 7)


def test_identify_with_hinge_velocity_basis(subject):
    model = identify(subject["ident"], velocity_basis="hinge", velocity_order=6)
    ceiling = vaf(subject["novel"].torque, subject["novel_clean"].torque)
    got = vaf(subject["novel"].torque, predict_quiet(model, subject["novel"]).total)
    assert got > ceiling - 1.0, f"hinge basis: novel VAF {got:.2f} % vs ceiling {ceiling:.2f} %"
    assert LPVPCModel.from_dict(json.loads(json.dumps(model.to_dict()))).velocity_basis.family == "hinge"


# -- physiology and stationary trials (issue 10) --------------------------------------------
def test_reversed_torque_sign_warns_with_the_option_to_use(subject):
    from lpvpc.errors import PhysiologyWarning

    d = subject["ident"]
    flipped = PerturbationData(position=d.position, torque=-d.torque, scheduling=d.scheduling, fs=d.fs)
    with pytest.warns(PhysiologyWarning, match=r"negative over 100 % .*--torque-sign -1"):
        m = identify(flipped, state_order=2)
    assert np.all(m.elastic_stiffness(central_rho(m)) < 0)


def test_negative_stiffness_of_an_extended_model_names_its_effect_terms(subject):
    # K(theta) of an extended model is the stiffness at zero displacement with the effects'
    # inputs at zero: negative there, the warning names the effect terms, not only the sign.
    from lpvpc.errors import PhysiologyWarning

    d = subject["ident"]
    flipped = PerturbationData(position=d.position, torque=-d.torque, scheduling=d.scheduling, fs=d.fs)
    with pytest.warns(PhysiologyWarning, match=r"zero displacement is negative over \d+ % .*extended by "
                                               r"amplitude_dependent_stiffness"):
        m = identify(flipped, state_order=2, effects=("amplitude_dependent_stiffness",))
    assert np.mean(m.elastic_stiffness(central_rho(m)) < 0) > 0.5


def test_negative_reflex_gain_warns_only_where_the_data_determine_it(subject, model):
    # A reflex gain turned negative: a model without intervals (nothing to judge by but the
    # estimate) warns, in plain words, that the data cannot tell why; the same model with its
    # intervals, which reach zero there, does not warn (its summary reads the reflex as not
    # determined instead), for the 1 kHz path and for the model-rate one.
    import copy

    from lpvpc.errors import PhysiologyWarning
    from lpvpc.identification.identify import check_physiology

    with warnings.catch_warnings():
        warnings.simplefilter("error", PhysiologyWarning)  # the models as identified: no warning
        model_1k = identify(subject["ident"], high_rate_reflex=True)
        # (the session's model may have taken the 1 kHz path: the structure selection chooses it per record)
        model_rate = model if model.high_rate is None else identify(subject["ident"], high_rate_reflex=False)
        check_physiology(model_rate)
    for m in (model_1k, model_rate):
        flipped = copy.deepcopy(m)
        if flipped.high_rate is not None:
            flipped.high_rate.Omega = -flipped.high_rate.Omega
        else:
            flipped.Omega = -flipped.Omega
        lo, hi = flipped.scheduling_range
        rho = np.linspace(lo, hi, 51)
        assert np.mean(flipped.reflex_gain_threshold(rho)[0] < 0) > 0.5
        assert np.all(flipped.reflex_gain_interval(rho)[1] > 0)  # the interval reaches zero
        with warnings.catch_warnings():
            warnings.simplefilter("error", PhysiologyWarning)
            check_physiology(flipped)
        flipped.uncertainty = None
        with pytest.warns(PhysiologyWarning, match=r"reflex gain is negative over \d+ % .*no interval to judge by.*"
                                                   r"cannot tell why"):
            check_physiology(flipped)


def test_a_missing_effect_that_turns_the_reflex_gain_negative_is_named_as_a_cause():
    # A hidden background activation turns the fixed structure's reflex gain negative over part
    # of the range; judged by the estimate (no intervals), the warning points to diagnose for
    # an effect the model lacks; with the effect in the model the gain is positive everywhere.
    from lpvpc.errors import PhysiologyWarning
    from lpvpc.identification.identify import check_physiology

    pair = simulate_pair("multilevel", seed=5, effects=("background_activation",))
    data = pair_trials(pair.pt, pair.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PhysiologyWarning)
        fixed = identify(data, structure="fixed")
    fixed.uncertainty = None
    with pytest.warns(PhysiologyWarning, match=r"reflex gain is negative .*an effect the model lacks"):
        check_physiology(fixed)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhysiologyWarning)
        extended = identify(data, effects=("background_activation",))
    lo, hi = extended.scheduling_range
    assert np.all(extended.reflex_gain_threshold(np.linspace(lo, hi, 51))[0] > 0)


def test_correct_torque_sign_gives_no_physiology_warning(model):
    from lpvpc.errors import PhysiologyWarning
    from lpvpc.identification.identify import check_physiology

    with warnings.catch_warnings():
        warnings.simplefilter("error", PhysiologyWarning)
        check_physiology(model)


def test_stationary_trial_identifies_the_lti_cascade():
    from lpvpc.errors import StationaryWarning

    pair = simulate_pair("stationary", seed=3, duration=60.0)
    d = pair_trials(pair.pt, pair.ut)
    k = int(0.7 * d.n)
    with pytest.warns(StationaryWarning, match="position-independent \\(LTI\\) parallel cascade"):
        m = identify(d.segment(0, k))
    assert m.fit["stationary"] and m.settings["intrinsic_order"] == m.settings["reflex_order"] == 0
    held = d.segment(k, None)
    clean = pair_trials(pair.pt_clean, pair.ut_clean).segment(k, None)
    ceiling = vaf(held.torque, clean.torque)
    got = vaf(held.torque, m.predict(held.position, held.scheduling, warn=False).total)
    assert got > ceiling - 1.5, f"held-out VAF {got:.2f} % vs noise ceiling {ceiling:.2f} %"
    K = m.elastic_stiffness([-0.1])[0]
    assert abs(K / TRUTH.K(-0.1) - 1) < 0.15, f"K {K:.1f} vs truth {TRUTH.K(-0.1):.1f} N m/rad"


def test_model_files_from_before_the_derivative_stencil_load_as_three_point(model, model_file, tmp_path, subject):
    d = json.loads(model_file.read_text())
    assert d["intrinsic"].pop("derivatives") == model.causal_derivatives
    old = tmp_path / "old.json"
    old.write_text(json.dumps(d))
    loaded = LPVPCModel.load(old)
    assert loaded.causal_derivatives == "central3"
    nv = subject["novel"]
    got = predict_quiet(loaded, nv, causal=True).total
    from lpvpc.models import equations as eq

    vel, acc = eq.velocity(nv.position, nv.fs), eq.acceleration(nv.position, nv.fs)
    np.testing.assert_array_equal(got, predict_quiet(model, nv, causal=True, velocity=vel, acceleration=acc).total)


def test_five_point_causal_form_is_closer_to_the_two_sided_model(subject):
    m5 = identify(subject["ident"], causal_derivatives="central5")
    assert m5.causal_derivatives == "central5" and LPVPCModel.from_dict(m5.to_dict()).causal_derivatives == "central5"
    nv = subject["novel"]
    two = vaf(nv.torque, predict_quiet(m5, nv).total)
    m3 = identify(subject["ident"], causal_derivatives="central3")
    c3 = vaf(nv.torque, predict_quiet(m3, nv, causal=True).total)
    c5 = vaf(nv.torque, predict_quiet(m5, nv, causal=True).total)
    assert two - c5 < two - c3 and two - c5 < 0.3, (two, c3, c5)


# -- BLAS threads -----------------------------------------------------------------------
def _blas_threads_inside_fit(monkeypatch, data):
    """BLAS thread counts seen inside the identification (set to 2 around it)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    seen = []
    fit = LPVPCEstimator._fit

    def spy(self, d, *args, **kwargs):  # (the fit's warm start and effects' order passed on)
        seen.extend(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
        return fit(self, d, *args, **kwargs)

    monkeypatch.setattr(LPVPCEstimator, "_fit", spy)
    with threadpool_limits(limits=2, user_api="blas"):
        identify(data, intrinsic_order=1, reflex_order=1)
        after = {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    return set(seen), after


def test_identification_runs_on_one_blas_thread_and_restores_the_callers(monkeypatch):
    # a notebook's `import lpvpc` after BLAS started its threads (2 here)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    sim = simulate_pair("multilevel", seed=0, duration=20.0, fs_out=100.0)
    inside, after = _blas_threads_inside_fit(monkeypatch, pair_trials(sim.pt, sim.ut))
    assert inside == {1}
    assert after == {2}


def test_identification_leaves_a_users_blas_thread_setting_alone(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    sim = simulate_pair("multilevel", seed=0, duration=20.0, fs_out=100.0)
    inside, _ = _blas_threads_inside_fit(monkeypatch, pair_trials(sim.pt, sim.ut))
    assert inside == {2}


def test_intrinsic_refitted_jointly_with_the_rank_one_reflex_keeps_k_where_a_slow_reflex_mode_overlaps_it():
    # Seed 1 (2-minute 1 kHz record, every default): the selection chooses three reflex states,
    # one a slow mode (pole ~0.99 at 100 Hz, near the 1 s time-constant cap) that integrates the
    # velocity columns into position-like ones, and the 1 kHz hinge path. Intrinsic parameters
    # taken by the projection (the whole unstructured reflex space removed) left a worst central
    # K(theta) error of 5.1 %; refitted jointly with the rank-1 reflex (lpvpc.models.reflex.refit_jointly)
    # 2.7 %, the fixed structure's 2.5 %.
    from lpvpc.simulation.simulate import SubjectParams

    pair = simulate_pair("multilevel", seed=1)
    data = pair_trials(pair.pt, pair.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(data)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 25)
    err = 100 * np.abs(model.elastic_stiffness(rho) / SubjectParams().K(rho) - 1)
    assert err.max() < 3.5, f"worst central K(theta) error {err.max():.2f} %"
    fit = model.fit
    assert fit["hammerstein_converged"]
