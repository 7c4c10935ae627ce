"""Reflex gain and threshold intervals (lpvpc.models.reflex_uncertainty.reflex_interval): the delta
method through the identifiable product of nonlinearity and dynamics, checked against the
spread of the estimate over noise realisations of the same trials."""

import dataclasses
import json
import warnings

import numpy as np
import pytest

from lpvpc.io import pair_trials
from lpvpc.errors import ModelFileError
from lpvpc.identification.identify import identify
from lpvpc.models.model import LPVPCModel
from lpvpc.simulation.simulate import coloured_noise
from lpvpc.identification.subspace import companion_form
from lpvpc.models.uncertainty import z_value
from lpvpc.models.reflex_uncertainty import MODEL_RATE_BIAS_NOTE, nonlinearity_jacobian, reflex_bias_bound


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


def test_the_knee_rounding_widens_the_threshold_interval_on_its_own_side_only(model_1k, monkeypatch):
    """The velocity basis's rounding of the knee has a known sign (estimate minus truth within
    [0, shift]): the threshold interval reaches further by it on that side and no further on
    the other, where a bias of unknown sign would widen both."""
    import lpvpc.models.reflex_uncertainty as unc

    rho = central_rho(model_1k, 9)
    v = model_1k.rectifier_velocity_grid()[0]
    real = unc._threshold_shift_curve

    def with_shift(value):  # the same shift whatever the true threshold
        def shifted(model):
            t, _ = real(model)
            return t, np.full(len(t), value)
        monkeypatch.setattr(unc, "_threshold_shift_curve", shifted)
        (g_lo, _), (lo, hi) = unc.reflex_interval(model_1k, rho)
        return np.asarray(g_lo), np.asarray(lo), np.asarray(hi)

    # the threshold's shift reaches the gain's interval only through the thresholds it allows
    # (the rounding factor's range over them, :func:`lpvpc.models.reflex_uncertainty._gain_rounding_range`)
    monkeypatch.setattr(unc, "_gain_rounding_range", lambda model, gain, t_lo, t_hi: (0 * gain, 0 * gain))
    g0, lo0, hi0 = with_shift(0.0)
    g_up, lo_up, hi_up = with_shift(0.1)  # the estimate above the truth by up to 0.1 rad/s
    below = lo0 - 0.1 > v[0] + 1e-9  # not clipped at the fitted range's ends
    above = hi0 + 0.1 < v[-6] - 1e-9
    assert below.any() and above.any()
    # most of the shift: a bias on one side only needs a one-sided critical value (1.64, not 1.96)
    assert np.all(lo_up[below] <= lo0[below] - 0.05), (lo0 - lo_up)[below]
    assert np.all(hi_up <= hi0 + 1e-12), hi_up - hi0
    _, lo_dn, hi_dn = with_shift(-0.1)  # below the truth: the mirror image
    assert np.all(hi_dn[above] >= hi0[above] + 0.05), (hi_dn - hi0)[above]
    assert np.all(lo_dn >= lo0 - 1e-12), lo0 - lo_dn
    assert np.array_equal(g_up, g0)  # the gain's interval does not take the threshold's shift


@pytest.fixture(scope="module")
def model_rate(subject, model):
    """The session's model on the model-rate velocity (the structure selection may have put
    its nonlinearity on the 1 kHz velocity: then the same files with that path fixed)."""
    if model.high_rate is None:
        return model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(subject["ident"], high_rate_reflex=False)


def test_model_rate_reflex_intervals_are_marked_biased(model_rate, model_1k):
    model = model_rate
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


@pytest.fixture(scope="module")
def model_weak(tmp_path_factory):
    """30 s of +-0.01 rad perturbations from 1 kHz files (through the CSV loaders): the
    stretch velocities rarely pass the plantarflexed threshold (0.7 rad/s), too little
    reflex excitation to determine it."""
    from lpvpc.io import load_identification_data, write_trial_csv
    from lpvpc.simulation.simulate import simulate_pair

    folder = tmp_path_factory.mktemp("weak")
    sim = simulate_pair("multilevel", seed=3, duration=30.0, perturbation_amplitude=0.01)
    write_trial_csv(sim.pt, folder / "weak_PT.csv")
    write_trial_csv(sim.ut, folder / "weak_UT.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(load_identification_data(pt=folder / "weak_PT.csv", ut=folder / "weak_UT.csv"),
                        high_rate_reflex=True)


def test_a_normal_record_determines_gain_and_threshold(model_1k):
    """2 minutes of +-0.04 rad from 1 kHz files, reflex on the 1 kHz velocity: over the
    central 80 % of the range both are determined, and the intervals are the ones shown."""
    from lpvpc.models.reflex_uncertainty import THRESHOLD_UNDETERMINED_FRACTION

    rho = central_rho(model_1k)
    g_ok, th_ok = model_1k.reflex_determined(rho)
    assert g_ok.all() and th_ok.all()
    g, th = model_1k.reflex_gain_interval(rho), model_1k.reflex_threshold_interval(rho)
    assert np.all(g.lower > 0) and np.array_equal(g.determined, g_ok) and np.array_equal(th.determined, th_ok)
    assert np.all(th.upper - th.lower < THRESHOLD_UNDETERMINED_FRACTION * model_1k.rectifier_velocity_grid()[1])


def test_a_weakly_excited_record_says_not_determined(model_weak, tmp_path):
    """Where the intervals span most of the plausible range, the model says so: summary
    lines, Fig. 5A (no curve at those positions) and the model file."""
    import matplotlib.pyplot as plt

    from lpvpc import plotting
    from lpvpc.models.summary import physiology_lines
    from lpvpc.models.uncertainty import NOT_DETERMINED

    lo, hi = model_weak.scheduling_range
    rho = np.linspace(lo, hi, 9)
    g_ok, th_ok = model_weak.reflex_determined(rho)
    assert not th_ok.all() and not g_ok.all() and g_ok.any()  # the dorsiflexed end (low threshold) still is
    g = model_weak.reflex_gain_interval(rho)
    assert np.all(g.lower[~g_ok] <= 0)  # the data cannot tell the reflex there from none
    assert np.all(~th_ok[~g_ok])
    summary = " ".join(physiology_lines(model_weak))
    assert NOT_DETERMINED in summary.split("reflex gain:")[1]
    assert not model_weak.reflex_determined([lo, hi])[0].all()  # an end of the range too
    gain_text = summary.split("reflex gain: ")[1].split("; threshold")[0]  # units on numbers only, each end placed
    assert gain_text.count(" at ") == 2 and f"{NOT_DETERMINED} at " in gain_text and ".." not in gain_text, gain_text
    fig = plotting.plot_reflex_nonlinearity(model_weak, positions=rho)
    ax = fig.axes[0]
    labels = ax.get_legend_handles_labels()[1]
    assert sum(NOT_DETERMINED in lab for lab in labels) >= int(np.sum(~g_ok))
    drawn = [ln for ln in ax.lines if ln.get_label().endswith("rad") or "(threshold" in ln.get_label()]
    assert len(drawn) == int(np.sum(g_ok))  # a curve only where the reflex is determined
    plt.close(fig)
    path = tmp_path / "weak.json"
    model_weak.save(path)
    rec = json.loads(path.read_text())["uncertainty"]["reflex_determined"]
    assert not all(rec["threshold"]) and len(rec["rho"]) == len(rec["gain"]) == 9
    again = tmp_path / "again.json"
    LPVPCModel.load(path).save(again)
    assert again.read_text() == path.read_text()  # round-trips exactly
    rec["gain"] = rec["gain"][:-1]
    d = json.loads(path.read_text())
    d["uncertainty"]["reflex_determined"] = rec
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"reflex_determined.gain must be a list of 9"):
        LPVPCModel.load(path)


def test_model_rate_threshold_is_not_determined_and_gain_is(model_rate):
    """The 100 Hz nonlinearity: the threshold is not observable (smoothed pulses),
    the gain is determined and its interval allows for the smoothed knee."""
    from lpvpc.models.summary import physiology_lines
    from lpvpc.models.uncertainty import NOT_DETERMINED

    model = model_rate
    rho = central_rho(model)
    g_ok, th_ok = model.reflex_determined(rho)
    assert g_ok.all() and not th_ok.any()
    line = [ln for ln in physiology_lines(model) if ln.startswith("reflex gain:")][0]
    assert f"threshold {NOT_DETERMINED}" in line and "threshold biased" in line
    plain = without_bias_bound(model)
    (lo, hi), (lo0, hi0) = model.reflex_gain_interval(rho), plain.reflex_gain_interval(rho)
    assert np.all(lo < lo0 + 1e-12) and np.all(hi0 < hi + 1e-12)


def test_the_threshold_interval_keeps_a_truth_whose_knee_the_basis_rounds_into_the_data():
    """The rounding belongs to the true threshold: a knee at 0.3 rad/s that the velocity basis
    rounds up by 0.3 is fitted at ~0.6, inside the data's interval [0.5, 0.7], so 0.3 stays in
    the threshold's interval; a shift taken at the estimate (0 at 0.6) would have dropped it.
    Thresholds consistent with no shift stay in; those fitted outside the data's interval do not."""
    from lpvpc.models.reflex_uncertainty import _inverted_threshold_interval

    t = np.linspace(0.0, 1.5, 301)  # rad/s
    s_t = np.where(t < 0.4, 0.3, 0.0)  # the basis rounds low knees up by 0.3 rad/s
    (lo,), (hi,) = _inverted_threshold_interval([0.5], [0.7], [0.0], t, s_t, 0.95)
    assert 0.2 < lo < 0.3 and hi == pytest.approx(0.7, abs=0.01)  # (t on a 0.005 rad/s grid)
    (lo,), (hi,) = _inverted_threshold_interval([0.5], [0.7], [0.0], t, np.zeros_like(t), 0.95)
    assert (lo, hi) == pytest.approx((0.5, 0.7), abs=0.01)
    lo, hi = _inverted_threshold_interval([0.5], [0.7], [0.0], t[t > 1.0], s_t[t > 1.0], 0.95)
    assert np.isnan(lo[0]) and np.isnan(hi[0])  # nothing consistent: the caller keeps its interval
