"""Tests of the virtual subject (lpvpc.simulation.simulate)."""

import json
import math

import numpy as np
import pytest

from lpvpc.simulation.simulate import (
    EFFECTS,
    SimulatedPair,
    SubjectParams,
    lab_pulses,
    pralds,
    reflex_torque,
    servo,
    simulate_pair,
    write_dataset,
)

FS = 1000.0


@pytest.fixture(scope="module")
def base100():
    return simulate_pair("multilevel", seed=0, fs_out=100.0)


def _snr_db(pair):
    d_clean = pair.pt_clean.torque - pair.ut_clean.torque
    d_noise = (pair.pt.torque - pair.pt_clean.torque) - (pair.ut.torque - pair.ut_clean.torque)
    return 10 * np.log10(np.var(d_clean) / np.var(d_noise))


# ---- parameters and curves --------------------------------------------------------------


def test_K_curve_shape_and_values():
    p = SubjectParams()
    th = np.linspace(-0.4, 0.2, 1201)
    K = p.K(th)
    i = int(np.argmin(K))
    assert -0.4 < th[i] < 0.0, "minimum between plantarflexion and neutral"
    assert 25.0 <= K[i] <= 35.0
    assert 150.0 <= p.K(0.2) <= 180.0
    assert np.all(np.diff(K[i:]) > 0), "rises monotonically toward dorsiflexion"
    assert p.K(-0.4) > K[i] * 1.1, "rises somewhat again toward -0.4"
    assert np.all(np.isfinite(p.K([-50.0, 50.0])))  # no overflow for absurd angles


def test_elastic_torque_is_exact_integral_of_K():
    p = SubjectParams()
    th = np.linspace(-0.5, 0.3, 81)
    h = 1e-6
    dE = (p.elastic_torque(th + h) - p.elastic_torque(th - h)) / (2 * h)
    np.testing.assert_allclose(dE, p.K(th), rtol=1e-6)
    assert abs(p.elastic_torque(p.elastic_rest)) < 1e-12


def test_reflex_gain_rises_and_threshold_falls_toward_dorsiflexion():
    p = SubjectParams()
    th = np.linspace(-0.4, 0.2, 61)
    assert np.all(np.diff(p.reflex_gain(th)) > 0)
    assert np.all(np.diff(p.reflex_threshold(th)) < 0)
    assert p.reflex_gain(-0.4) == pytest.approx(2.0) and p.reflex_gain(0.2) == pytest.approx(8.0)
    assert p.reflex_threshold(-0.4) == pytest.approx(0.7)
    assert p.reflex_threshold(0.2) == pytest.approx(0.25)
    assert 0.4 < p.reflex_threshold(-0.1) < 0.6


# ---- physical elements ------------------------------------------------------------------


def test_servo_matches_analytic_step_response():
    p = SubjectParams()
    n, k0, step = 400, 50, 0.03
    cmd = np.full(n, -0.1)
    cmd[k0:] += step
    theta, vel, acc = servo(cmd, FS, p)
    wn, z = p.servo_wn, p.servo_zeta
    wd = wn * math.sqrt(1 - z * z)
    t = np.maximum(np.arange(n) - k0, 0) / FS
    env = np.exp(-z * wn * t) * (np.arange(n) >= k0)
    theta_ref = -0.1 + step * (np.arange(n) >= k0) * (1 - np.exp(-z * wn * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))
    vel_ref = step * wn / math.sqrt(1 - z * z) * env * np.sin(wd * t)
    acc_ref = step * wn ** 2 * env * (np.cos(wd * t) - z / math.sqrt(1 - z * z) * np.sin(wd * t))
    np.testing.assert_allclose(theta, theta_ref, atol=1e-12)
    np.testing.assert_allclose(vel, vel_ref, atol=1e-9 * wn)
    np.testing.assert_allclose(acc, acc_ref, atol=1e-9 * wn ** 2)


def test_reflex_does_not_respond_before_the_delay():
    p = SubjectParams()
    n, k0 = 600, 100
    vel = np.zeros(n)
    vel[k0:] = 2.0  # rad/s, well above every threshold
    theta = np.zeros(n)
    tq, z = reflex_torque(theta, vel, FS, p)
    kd = k0 + int(round(p.reflex_delay * FS))
    assert np.all(tq[:kd] == 0.0) and np.all(z[:kd] == 0.0)
    assert np.all(z[kd:] > 0)
    assert tq[kd + 5] > 0 and tq[-1] > 0.5 * z[-1]  # responds right after, toward unit DC gain
    # a delay that is not a whole number of samples is honoured too
    p2 = SubjectParams(reflex_delay=0.0425)
    tq2, _ = reflex_torque(theta, vel, FS, p2)
    assert np.all(tq2[: k0 + 42] == 0.0) and tq2[k0 + 45] > 0


def test_reflex_is_a_half_wave_rectifier_with_unit_dc_gain():
    p = SubjectParams()
    n = 20000
    theta = np.full(n, 0.2)
    tq_up, _ = reflex_torque(theta, np.full(n, 1.25), FS, p)
    tq_dn, _ = reflex_torque(theta, np.full(n, -1.25), FS, p)
    assert tq_up[-1] == pytest.approx(p.reflex_gain(0.2) * (1.25 - p.reflex_threshold(0.2)), rel=1e-6)
    assert np.all(tq_dn == 0.0)


def test_time_varying_reflex_filter_matches_lti_for_constant_wn():
    p = SubjectParams()
    rng = np.random.default_rng(3)
    vel = np.cumsum(rng.standard_normal(5000)) * 0.05
    theta = np.zeros(5000)
    lti, _ = reflex_torque(theta, vel, FS, p)
    tv, _ = reflex_torque(theta, vel, FS, p, wn=np.full(5000, p.reflex_wn))
    assert np.max(np.abs(lti - tv)) < 1e-3 * np.max(np.abs(lti))


def test_pralds_levels_and_holds():
    x = pralds(60.0, FS, np.random.default_rng(1), amplitude=0.04)
    assert np.max(np.abs(x)) <= 0.04
    edges = np.flatnonzero(np.diff(x) != 0) + 1
    holds = np.diff(edges) / FS
    assert holds.min() >= 0.25 - 1e-9 and holds.max() <= 0.35 + 1e-9


def test_lab_pulses_alternate_between_zero_and_large_levels():
    x = lab_pulses(60.0, FS, np.random.default_rng(1), amplitude=0.04)
    starts = np.r_[0, np.flatnonzero(np.diff(x) != 0) + 1]
    levels, holds = x[starts], np.diff(starts) / FS
    assert np.all(levels[::2] == 0.0)
    assert np.all((np.abs(levels[1::2]) >= 0.02) & (np.abs(levels[1::2]) <= 0.04))
    assert np.any(levels[1::2] > 0) and np.any(levels[1::2] < 0)
    assert holds.min() >= 0.25 - 1e-9 and holds.max() <= 0.35 + 1e-9


def test_the_pair_takes_the_lab_pulse_perturbation_and_records_it():
    pr = simulate_pair("multilevel", seed=0, duration=20.0, fs_out=1000.0, perturbation="lab_pulses")
    d = pr.pt.channels["command"] - pr.ut.channels["command"]
    starts = np.r_[0, np.flatnonzero(np.abs(np.diff(d)) > 1e-12) + 1]
    assert np.all(np.abs(d[starts[::2]]) < 1e-12) and np.all(np.abs(d[starts[1::2]]) >= 0.02)
    assert pr.truth["perturbation"] == "lab_pulses"
    with pytest.raises(ValueError, match="unknown perturbation 'chirp'"):
        simulate_pair("multilevel", seed=0, duration=20.0, perturbation="chirp")


def test_the_pair_takes_a_prbs_without_quiet_windows():
    """PRBS: +-amplitude switching every 50-150 ms; unlike PRALDS it leaves almost no
    quiet window (no movement in the last 150 ms) for a background-EMG estimate."""
    from lpvpc.models.effects import quiet_mask

    pr = simulate_pair("multilevel", seed=0, duration=20.0, fs_out=1000.0, perturbation="prbs")
    d = pr.pt.channels["command"] - pr.ut.channels["command"]
    np.testing.assert_allclose(np.abs(d), 0.04)
    holds = np.diff(np.flatnonzero(np.abs(np.diff(d)) > 1e-12)) / 1000.0
    assert holds.min() >= 0.05 - 1e-9 and holds.max() <= 0.15 + 1e-9
    assert pr.truth["perturbation"] == "prbs"
    p = pr.pt.position - pr.ut.position
    ref = simulate_pair("multilevel", seed=0, duration=20.0, fs_out=1000.0)
    quiet = [quiet_mask(x, 1000.0).mean() for x in (p, ref.pt.position - ref.ut.position)]
    assert quiet[0] < 0.05 < 0.2 < quiet[1]


# ---- the pair ---------------------------------------------------------------------------


def test_pair_structure_and_trajectory(base100):
    pr = base100
    assert isinstance(pr, SimulatedPair)
    assert set(pr.components) == {"pt_intrinsic", "pt_reflex", "ut_intrinsic", "ut_reflex"}
    np.testing.assert_allclose(pr.components["pt_intrinsic"] + pr.components["pt_reflex"], pr.pt_clean.torque)
    for tr in (pr.pt, pr.ut, pr.pt_clean, pr.ut_clean):
        assert "command" in tr.channels and len(tr.time) == 12000
    np.testing.assert_array_equal(pr.pt.position, pr.pt_clean.position)
    # UT follows the multilevel range; the perturbation is the PRALDS on top
    lo, hi = pr.truth["measured"]["scheduling_range"]
    assert -0.43 < lo < -0.35 and 0.15 < hi < 0.23
    d = pr.pt.channels["command"] - pr.ut.channels["command"]
    assert np.max(np.abs(d)) < 0.05  # FIR decimation rings ~9 % at steps
    json.dumps(pr.truth)  # JSON-serialisable
    m = pr.truth["measured"]
    assert m["ut_reflex_rms"] > 0 and m["perturbation_reflex_rms"] > 0
    assert pr.truth["reflex_delay"] == 0.040


def test_decimated_output_has_100_hz_step(base100):
    t = base100.pt.time
    np.testing.assert_allclose(np.diff(t), 0.01, atol=1e-12)
    assert base100.pt.fs == pytest.approx(100.0)
    # no edge droop toward zero at either end (the angle starts at rest at its first level)
    ut = base100.ut
    assert abs(ut.position[0] - ut.channels["command"][0]) < 1e-3
    assert np.all(np.abs(np.diff(ut.position[:20])) < 1e-3)


@pytest.mark.parametrize("fs_out,snr", [(100.0, 18.0), (1000.0, 18.0), (100.0, 10.0)])
def test_perturbation_snr_matches_request(fs_out, snr):
    pr = simulate_pair(seed=2, duration=40.0, fs_out=fs_out, snr_db=snr)
    assert abs(_snr_db(pr) - snr) < 0.5
    assert abs(pr.truth["measured"]["snr_db"] - snr) < 0.5
    # independent noise in the two trials
    n_pt = pr.pt.torque - pr.pt_clean.torque
    n_ut = pr.ut.torque - pr.ut_clean.torque
    assert abs(np.corrcoef(n_pt, n_ut)[0, 1]) < 0.2


def test_seeds_reproduce_and_differ():
    a = simulate_pair(seed=5, duration=20.0, fs_out=100.0)
    b = simulate_pair(seed=5, duration=20.0, fs_out=100.0)
    c = simulate_pair(seed=6, duration=20.0, fs_out=100.0)
    for x, y in ((a.pt, b.pt), (a.ut, b.ut)):
        np.testing.assert_array_equal(x.torque, y.torque)
        np.testing.assert_array_equal(x.position, y.position)
    assert not np.allclose(a.ut.position, c.ut.position)  # trajectory
    assert not np.allclose(a.pt.torque - a.pt_clean.torque, c.pt.torque - c.pt_clean.torque)  # noise


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_each_effect_changes_the_torque(name, base100):
    pr = simulate_pair("multilevel", seed=0, fs_out=100.0, effects=(name,))
    assert [e["name"] for e in pr.truth["effects"]] == [name]
    json.dumps(pr.truth)
    np.testing.assert_array_equal(pr.pt.position, base100.pt.position)  # same kinematics
    d_base = base100.pt_clean.torque - base100.ut_clean.torque
    d_eff = pr.pt_clean.torque - pr.ut_clean.torque
    change = np.sqrt(np.mean((d_eff - d_base) ** 2)) / np.std(d_base)
    # 30 ms -> 80 ms of delay over the range changes ~10 % of the torque (9-11 % on seeds 0-3)
    floor = 0.07 if name == "position_dependent_reflex_delay" else 0.05
    assert change > floor, f"{name} changes the perturbation torque by only {100 * change:.1f} %"
    for tr in (pr.pt, pr.ut):
        # volts; an envelope is never negative (the smoother's undershoot after big bursts is clipped)
        assert "emg" in tr.channels and 0 <= tr.channels["emg"].min() and tr.channels["emg"].max() < 2e-3
        assert np.median(tr.channels["emg"]) > 0


@pytest.mark.parametrize("name, pathway", [("oscillating_reflex_gain", "reflex"),
                                           ("stiffness_by_slow_speed", "intrinsic")])
def test_effects_outside_the_catalog_act_on_their_pathway_and_are_off_by_default(name, pathway, base100):
    """The benchmark's out-of-catalog effects: no diagnosis-catalog entry, absent unless asked
    for, and when asked for they change only their own pathway's torque, measurably."""
    from lpvpc.models.effects import CATALOG

    assert name not in CATALOG and name not in {e.subject for e in CATALOG.values()}
    assert base100.truth["effects"] == []  # off by default
    pr = simulate_pair("multilevel", seed=0, fs_out=100.0, effects=(name,))
    assert pr.truth["effects"][0]["parameters"]["outside_catalog"] is True
    other = "intrinsic" if pathway == "reflex" else "reflex"
    np.testing.assert_allclose(pr.components[f"pt_{other}"], base100.components[f"pt_{other}"], atol=1e-9)
    d_base = base100.components[f"pt_{pathway}"] - base100.components[f"ut_{pathway}"]
    change = pr.components[f"pt_{pathway}"] - pr.components[f"ut_{pathway}"] - d_base
    assert np.sqrt(np.mean(change**2)) > 0.05 * np.std(base100.pt_clean.torque - base100.ut_clean.torque)
    if name == "stiffness_by_slow_speed":  # only while the slow trajectory moves: none in the holds
        v_slow = np.gradient(base100.ut.position) * base100.ut.fs
        hold = np.convolve(np.abs(v_slow) < 1e-9, np.ones(21), "same") == 21
        assert hold.mean() > 0.3 and np.max(np.abs(change[hold])) < 1e-3 * np.max(np.abs(change))
    else:  # a periodic gain, not a trend: as large late in the trial as early
        half = len(change) // 2
        assert np.std(change[half:]) > 0.5 * np.std(change[:half])


def test_emg_is_realistic_reflex_bursts_tonic_activation_noise_volts(base100):
    """PT EMG: tonic level + reflex-evoked bursts ~40 ms after the velocity pulses (so it
    correlates with the reflex drive, not with the undelayed velocity); UT EMG: the tonic
    level and noise; volts by default, other units on request; activation shows in both."""

    pr = simulate_pair("multilevel", seed=3, duration=30.0)
    e_pt, e_ut = pr.pt.channels["emg"], pr.ut.channels["emg"]
    p = SubjectParams()
    tonic = p.emg_tonic * p.emg_volts
    assert np.median(e_ut) == pytest.approx(tonic, rel=0.3)  # tonic level, in V
    # bursts after every stretching perturbation step in PT; in UT only on fast trajectory transitions
    excess = [np.mean(np.maximum(e - 2 * tonic, 0)) for e in (e_pt, e_ut)]
    assert np.percentile(e_pt, 99.5) > 5 * tonic and excess[0] > 2 * excess[1]
    # the bursts follow the perturbation velocity by the reflex delay
    v = np.maximum(np.gradient(pr.pt.position - pr.ut.position) * 1000.0, 0)
    lags = np.arange(0, 120)
    xc = [np.corrcoef(v[: len(v) - k], e_pt[k:])[0, 1] for k in lags]
    assert 35 <= lags[int(np.argmax(xc))] <= 70
    mv = simulate_pair("multilevel", seed=3, duration=30.0, emg_unit="mV")
    np.testing.assert_allclose(mv.pt.channels["emg"], 1e3 * e_pt)
    with pytest.raises(ValueError, match="EMG unit"):
        simulate_pair(duration=5.0, emg_unit="kV")
    act = simulate_pair("multilevel", seed=3, duration=30.0, effects=("background_activation",))
    for a, b in ((act.pt, pr.pt), (act.ut, pr.ut)):  # activation raises both trials' EMG
        assert np.mean(a.channels["emg"]) > np.mean(b.channels["emg"])


def test_unknown_effect_and_bad_rate_are_rejected():
    with pytest.raises(ValueError, match="unknown effect"):
        simulate_pair(duration=5.0, effects=("nope",))
    with pytest.raises(ValueError, match="fs_out"):
        simulate_pair(duration=5.0, fs_out=300.0)
    with pytest.raises(ValueError, match="trajectory"):
        simulate_pair("zigzag", duration=5.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_novel_trajectory_leaves_the_identified_range(seed):
    ident = simulate_pair("multilevel", seed=seed, fs_out=100.0, snr_db=None)
    novel = simulate_pair("novel", seed=seed, fs_out=100.0, snr_db=None)
    lo_i, hi_i = ident.truth["measured"]["scheduling_range"]
    lo_n, hi_n = novel.truth["measured"]["scheduling_range"]
    assert lo_n < min(lo_i, -0.4) and hi_n > max(hi_i, 0.2)
    # only briefly: less than 5 % of the time outside [-0.4, 0.2]
    outside = np.mean((novel.ut.position < -0.4) | (novel.ut.position > 0.2))
    assert 0 < outside < 0.05
    assert not np.allclose(novel.ut.position[:500], ident.ut.position[:500])


def test_larger_perturbation_gives_faster_perturbation_velocity():
    small = simulate_pair("novel", seed=4, duration=40.0, fs_out=100.0, perturbation_amplitude=0.04)
    big = simulate_pair("novel", seed=4, duration=40.0, fs_out=100.0, perturbation_amplitude=0.06)
    np.testing.assert_array_equal(small.ut.position, big.ut.position)  # same trajectory
    assert big.truth["measured"]["peak_perturbation_velocity"] > 1.2 * small.truth["measured"]["peak_perturbation_velocity"]


def test_write_dataset_roundtrip(tmp_path):
    paths = write_dataset(tmp_path, seed=1, duration=30.0, fs_out=100.0)
    for stem in ("ident_PT", "ident_UT", "novel_PT", "novel_UT"):
        p = paths[stem]
        assert p.name == f"{stem}.csv"
        assert p.read_text().splitlines()[0] == "time,position,torque,emg,command"
        data = np.loadtxt(p, delimiter=",", skiprows=1)
        assert data.shape == (3000, 5)
        np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, atol=1e-9)
    truth = json.loads(paths["truth"].read_text())
    assert {"params", "curves", "ident", "novel"} <= set(truth)
    assert truth["ident"]["trajectory"] == "multilevel" and truth["novel"]["trajectory"] == "novel"
    with np.load(paths["truth_ident"]) as z:
        for key in ("time", "pt_torque_clean", "ut_torque_clean", "pt_intrinsic", "pt_reflex",
                    "ut_intrinsic", "ut_reflex", "perturbation_intrinsic", "perturbation_reflex"):
            assert len(z[key]) == 3000
    ident = np.loadtxt(paths["ident_UT"], delimiter=",", skiprows=1)
    novel = np.loadtxt(paths["novel_UT"], delimiter=",", skiprows=1)
    assert not np.allclose(ident[:, 1], novel[:, 1])


def test_pair_trials_reproduces_the_simulated_perturbation(base100):
    from lpvpc.io import pair_trials

    pr = simulate_pair("multilevel", seed=0, fs_out=1000.0)
    d = pair_trials(pr.pt_clean, pr.ut_clean, target_fs=100.0)
    assert d.fs == pytest.approx(100.0) and d.n == 12000
    ref = base100.pt_clean.torque - base100.ut_clean.torque
    assert np.corrcoef(d.torque, ref)[0, 1] > 0.999
    np.testing.assert_allclose(d.scheduling, base100.ut.position, atol=1e-3)


def test_emg_is_a_rectified_band_limited_noise_whose_amplitude_follows_the_drive():
    """The raw EMG is band-limited noise: its rectified, smoothed envelope scatters about
    the drive (tonic 0.08 here) by tens of percent at 1 kHz, yet its mean reads the drive."""
    pr = simulate_pair("stationary", seed=2, duration=20.0, fs_out=1000.0)
    p = SubjectParams()
    e = pr.ut.channels["emg"] / p.emg_volts  # activation units; UT: no reflex at a held position
    assert np.mean(e) == pytest.approx(np.hypot(p.emg_tonic, p.emg_noise), rel=0.05)
    assert 0.1 < np.std(e) / np.mean(e) < 0.5  # a noise carrier, not a smooth envelope
    from lpvpc.simulation.simulate import emg_envelope
    rng = np.random.default_rng(0)
    twice = emg_envelope(np.full(20000, 0.3), np.zeros(20000), 1000.0, rng, p)
    assert np.mean(twice) / p.emg_volts == pytest.approx(np.hypot(0.3, p.emg_noise), rel=0.05)


def test_background_activation_is_own_per_trial_unless_shared_and_its_speed_and_gains_are_settable():
    from scipy import signal as sps

    b, a = sps.butter(2, 0.1, fs=100.0)
    corr = {}
    for shared in (False, True):
        pr = simulate_pair("multilevel", seed=1, fs_out=100.0, duration=60.0, effects=("background_activation",),
                           params=SubjectParams(activation_shared=shared))
        slow = [sps.filtfilt(b, a, t.channels["emg"]) for t in (pr.pt, pr.ut)]
        corr[shared] = np.corrcoef(*slow)[0, 1]
        assert pr.truth["effects"][0]["parameters"]["independent_per_trial"] is not shared
    assert corr[True] > 0.95 and abs(corr[False]) < 0.5
    # a faster activation (0.5 Hz) with the gains: recorded in the truth
    pr = simulate_pair("multilevel", seed=1, fs_out=100.0, duration=30.0, effects=("background_activation",),
                       params=SubjectParams(activation_cutoff=0.5, activation_stiffness_gain=1.5))
    eff = pr.truth["effects"][0]["parameters"]
    assert eff["cutoff_hz"] == 0.5 and eff["perturbation_stiffness_scale"] == "1 + 1.5 a"


# ---- stiffness families (issue 22: curves the position basis cannot hold) -------------------


@pytest.mark.parametrize("family", ["standard", "sum_of_exponentials", "piecewise"])
def test_each_stiffness_family_has_its_elastic_torque_as_exact_integral_and_a_realistic_K(family):
    p = SubjectParams().with_stiffness_family(family)
    th = np.linspace(-0.4, 0.2, 6001)  # rad, the identified range
    K = p.K(th)
    assert np.all((K > 15.0) & (K < 220.0))  # N m/rad: realistic ankle values
    assert K[np.argmin(np.abs(th - 0.2))] > 3 * K.min()  # rises toward dorsiflexion
    E = p.elastic_torque(th)
    dE = np.gradient(E, th)
    assert np.max(np.abs(dE[1:-1] - K[1:-1])) < 0.02  # continuous torque whose slope is K
    assert abs(float(p.elastic_torque(p.elastic_rest))) < 1e-12
    # the perturbation-amplitude stiffness tends to the tangent for small amplitudes
    off_knots = np.array([-0.33, -0.07, 0.11])  # rad
    assert np.allclose(p.incremental_stiffness(off_knots, 1e-4), p.K(off_knots), rtol=1e-5)


def test_piecewise_family_has_a_kink_and_its_incremental_stiffness_averages_it():
    p = SubjectParams().with_stiffness_family("piecewise")
    kink = p.k_knots[1]
    left = (p.K(kink) - p.K(kink - 0.01)) / 0.01
    right = (p.K(kink + 0.01) - p.K(kink)) / 0.01
    assert left < 0 < right  # slope changes sign: a kink, not a smooth minimum
    # at the kink the +-0.04 rad perturbation sees more than the tangent minimum (both sides rise)
    assert float(p.incremental_stiffness(kink, 0.04)) > float(p.K(kink)) + 1.0
    # away from the knots K is linear, so the least-squares slope equals the tangent
    assert np.isclose(float(p.incremental_stiffness(0.05, 0.04)), float(p.K(0.05)), rtol=1e-6)


def test_sum_of_exponentials_family_is_not_held_by_a_quartic():
    th = np.linspace(-0.4, 0.2, 601)  # rad, the identified range
    central = np.abs(th + 0.1) <= 0.24  # its central 80 %
    for family, worst in (("standard", 0.01), ("sum_of_exponentials", 0.03)):
        K = SubjectParams().with_stiffness_family(family).K(th)
        fit = np.polynomial.chebyshev.Chebyshev.fit(th, K, 4)(th)
        err = np.max(np.abs(fit / K - 1)[central])
        assert (err < worst) if family == "standard" else (err > worst)


def test_stiffness_family_keeps_the_random_streams_and_changes_only_the_elastic_torque():
    a = simulate_pair("multilevel", seed=4, duration=20.0, fs_out=100.0)
    b = simulate_pair("multilevel", seed=4, duration=20.0, fs_out=100.0, stiffness_family="piecewise")
    assert np.array_equal(a.pt.position, b.pt.position) and np.array_equal(a.ut.position, b.ut.position)
    noise_a, noise_b = a.pt.torque - a.pt_clean.torque, b.pt.torque - b.pt_clean.torque
    assert np.corrcoef(noise_a, noise_b)[0, 1] > 0.999  # same noise stream (scaled to the SNR)
    assert not np.allclose(a.components["pt_intrinsic"], b.components["pt_intrinsic"])
    assert np.allclose(a.components["pt_reflex"], b.components["pt_reflex"])
    assert b.truth["params"]["stiffness_family"] == "piecewise"
    th = np.array(b.truth["curves"]["theta"])
    assert np.allclose(b.truth["curves"]["K"], SubjectParams().with_stiffness_family("piecewise").K(th))
    default = simulate_pair("multilevel", seed=4, duration=20.0, fs_out=100.0, stiffness_family="standard")
    assert np.array_equal(default.pt.torque, a.pt.torque)  # the default is today's subject
    with pytest.raises(ValueError, match="unknown stiffness family 'cubic'"):
        simulate_pair("multilevel", seed=4, duration=20.0, fs_out=100.0, stiffness_family="cubic")


def test_cli_simulate_writes_the_chosen_stiffness_family_and_refuses_an_unknown_one(tmp_path, capsys):
    from lpvpc.cli import main

    assert main(["simulate", "--out", str(tmp_path / "d"), "--duration", "5", "--fs", "100",
                 "--stiffness-family", "sum_of_exponentials"]) == 0
    truth = json.loads((tmp_path / "d" / "truth.json").read_text())
    assert truth["params"]["stiffness_family"] == "sum_of_exponentials"
    assert truth["params"]["k_df_rate"] == 14.0
    capsys.readouterr()
    assert main(["simulate", "--out", str(tmp_path / "e"), "--stiffness-family", "cubic"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown stiffness family 'cubic'" in err[0]
