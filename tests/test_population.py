"""The population of virtual subjects (lpvpc.simulation.population): reproducible draws, documented
ranges, each effect form acting on the torque as it should, CLI and Python alike."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpvpc.simulation.population import (CHOICES, DEVELOPMENT_SEEDS, EFFECT_RANGES, POPULATION_EFFECTS, RANGES, RECORD_SEEDS,
                              STIFFNESS_FORMS, PopulationSubject, draw_subject, simulate_subject, write_subject)

DOCS = Path(__file__).resolve().parent.parent / "docs" / "guide" / "population.md"
TH = np.linspace(-0.4, 0.2, 121)  # rad, the identified range


def _pair(subject, **kw):
    kw.setdefault("duration", 30.0)
    kw.setdefault("fs_out", 100.0)
    return simulate_subject(subject, **kw)


def test_same_seed_gives_the_same_subject_and_data_and_other_seeds_differ():
    a, b = draw_subject(11, "background_activation"), draw_subject(11, "background_activation")
    assert a == b and a.to_json() == b.to_json()
    pa, pb = _pair(a), _pair(b)
    assert np.array_equal(pa.pt.torque, pb.pt.torque) and np.array_equal(pa.ut.channels["emg"], pb.ut.channels["emg"])
    c = draw_subject(12, "background_activation")
    assert c != a and c.params.inertia != a.params.inertia
    assert not np.allclose(_pair(c).pt.torque, pa.pt.torque)
    # the same seed is the same subject with or without an effect (the effect has its own stream)
    assert draw_subject(11).params == a.params
    assert PopulationSubject.from_dict(json.loads(a.to_json())) == a


def test_seed_sets_are_disjoint_and_bad_requests_are_refused():
    assert not set(DEVELOPMENT_SEEDS) & set(RECORD_SEEDS)
    with pytest.raises(ValueError, match="unknown population effect"):
        draw_subject(0, "drift")
    with pytest.raises(ValueError, match="unknown form"):
        draw_subject(0, "nonlinear_viscosity", "viscous")
    with pytest.raises(ValueError, match="seed"):
        draw_subject(-1)


def test_every_drawn_parameter_lies_in_its_documented_range_over_200_draws():
    doc = DOCS.read_text()
    seen = {k: set() for k in CHOICES}
    for seed in range(200):
        effect = list(POPULATION_EFFECTS)[seed % len(POPULATION_EFFECTS)]
        s = draw_subject(seed, effect)
        for name, v in s.draws.items():
            if name in CHOICES:
                assert v in CHOICES[name]
                seen[name].add(v)
                continue
            eff, _, key = name.rpartition(".")
            lo, hi, *_ = EFFECT_RANGES[eff][key] if eff else RANGES[name]
            assert lo <= v <= hi, (seed, name, v)
        p = s.params
        assert p.inertia == s.draws["inertia"] and p.reflex_delay == s.draws["reflex_delay"]
        K = p.K(TH)
        assert 15.0 <= K.min() and K.max() <= 200.0 + 1e-9  # N m/rad over the identified range
        assert K[-1] >= 2.0 * K.min()  # rises toward dorsiflexion
        assert p.reflex_threshold_df < p.reflex_threshold_pf and p.reflex_gain_df > p.reflex_gain_pf
    for name, values in seen.items():  # every choice is made somewhere in 200 draws
        if name.startswith("activation_"):
            continue  # drawn for one effect in five only
        assert set(values) == set(CHOICES[name]), name
    # the docs page lists every range with its numbers
    for name, (lo, hi, unit, _) in RANGES.items():
        assert f"`{name}`" in doc, name
    for eff, table in EFFECT_RANGES.items():
        for name in table:
            assert f"`{eff}.{name}`" in doc, (eff, name)


@pytest.mark.parametrize("form", STIFFNESS_FORMS)
def test_stiffness_form_is_drawn_when_asked_and_its_elastic_torque_integrates_K(form):
    s = draw_subject(3, stiffness=form)
    assert s.stiffness_form == form
    E = s.params.elastic_torque(TH)
    assert np.max(np.abs(np.gradient(E, TH)[1:-1] - s.params.K(TH)[1:-1])) < 0.05
    if form == "exponential":
        assert s.params.k_pf == 0.0
    if form == "polynomial":
        assert s.params.stiffness_family == "polynomial"


def _effect_pairs(effect, form, seed=5, **kw):
    s = draw_subject(seed, effect, form, design="pralds")
    return s, _pair(s, clean=False, snr_db=float("inf"), **kw), _pair(s, clean=True, snr_db=float("inf"), **kw)


@pytest.mark.parametrize("form", POPULATION_EFFECTS["reflex_habituation"])
def test_habituation_lowers_late_reflex_torque(form):
    s, eff, clean = _effect_pairs("reflex_habituation", form, duration=120.0)
    t = eff.pt.time
    late = t > 100.0
    r_eff, r_clean = eff.components["pt_reflex"], clean.components["pt_reflex"]
    assert np.sum(np.abs(r_eff[late])) < 0.85 * np.sum(np.abs(r_clean[late]))
    early = t < 5.0
    assert np.sum(np.abs(r_eff[early])) > 0.8 * np.sum(np.abs(r_clean[early]))
    assert np.array_equal(eff.components["pt_intrinsic"], clean.components["pt_intrinsic"])


@pytest.mark.parametrize("form", POPULATION_EFFECTS["background_activation"])
def test_background_activation_scales_the_pathways_its_form_names_and_shows_in_the_emg(form):
    s, eff, clean = _effect_pairs("background_activation", form)
    d_int = eff.components["pt_intrinsic"] - eff.components["ut_intrinsic"]
    c_int = clean.components["pt_intrinsic"] - clean.components["ut_intrinsic"]
    tonic = s.effect_params["tonic_torque"] * (eff.activation["PT"] - eff.activation["UT"])  # N m, in every form
    intrinsic_changed = not np.allclose(d_int - tonic, c_int, atol=1e-3)
    reflex_changed = not np.allclose(eff.components["pt_reflex"], clean.components["pt_reflex"], atol=1e-3)
    assert intrinsic_changed == (form in ("intrinsic", "both"))
    assert reflex_changed == (form in ("reflex", "both"))
    assert np.mean(eff.activation["PT"]) > np.mean(clean.activation["PT"])
    assert np.mean(eff.pt.channels["emg"]) > np.mean(clean.pt.channels["emg"])


@pytest.mark.parametrize("form", POPULATION_EFFECTS["nonlinear_viscosity"])
def test_friction_adds_a_torque_opposing_velocity(form):
    s, eff, clean = _effect_pairs("nonlinear_viscosity", form)
    extra = eff.components["pt_intrinsic"] - clean.components["pt_intrinsic"]
    vel = np.gradient(eff.pt.position, 1.0 / eff.pt.fs)
    fast = np.abs(vel) > 0.2
    assert np.mean(np.sign(extra[fast]) == np.sign(vel[fast])) > 0.9  # resists the motion
    fc = s.effect_params["coulomb_torque"]
    assert 0.5 * fc < np.median(np.abs(extra[fast])) < 1.2 * fc * (1 if form == "coulomb" else s.effect_params["breakaway_ratio"])
    assert np.array_equal(eff.components["pt_reflex"], clean.components["pt_reflex"])


def _burst_lag(pair, theta_band):
    """Mean lag (s) of the reflex torque behind the perturbation velocity where the slow angle is in ``theta_band``."""
    fs = pair.pt.fs
    v = np.gradient(pair.pt.position - pair.ut.position, 1.0 / fs)
    r = pair.components["pt_reflex"]
    inside = (pair.ut.position > theta_band[0]) & (pair.ut.position < theta_band[1])
    lags = np.arange(0, 200)  # samples at 1 kHz: delay plus the reflex low-pass's lag
    score = [np.sum((v[:len(v) - k] * r[k:])[inside[k:]]) for k in lags]
    return lags[int(np.argmax(score))] / fs


@pytest.mark.parametrize("form", POPULATION_EFFECTS["position_dependent_reflex_delay"])
def test_reflex_delay_form_delays_the_reflex_more_toward_dorsiflexion(form):
    s, eff, clean = _effect_pairs("position_dependent_reflex_delay", form, duration=120.0, fs_out=1000.0)
    df, pf = (0.1, 0.25), (-0.45, -0.3)
    assert _burst_lag(eff, df) - _burst_lag(clean, df) >= 0.005  # s: later in dorsiflexion
    assert abs(_burst_lag(eff, pf) - _burst_lag(clean, pf)) <= 0.005 + (0.01 if form == "linear" else 0.0)


@pytest.mark.parametrize("form", POPULATION_EFFECTS["position_dependent_reflex_dynamics"])
def test_reflex_dynamics_form_makes_the_reflex_faster_in_dorsiflexion_and_slower_in_plantarflexion(form):
    s, eff, clean = _effect_pairs("position_dependent_reflex_dynamics", form, duration=120.0, fs_out=1000.0)
    theta = eff.ut.position
    for band, faster in (((0.12, 0.25), True), ((-0.45, -0.3), False)):
        inside = (theta > band[0]) & (theta < band[1])
        a, c = eff.components["pt_reflex"][inside], clean.components["pt_reflex"][inside]
        # a faster low-pass has more of its power at high frequency: larger RMS of the derivative
        ratio = np.sqrt(np.mean(np.diff(a) ** 2)) / np.sqrt(np.mean(np.diff(c) ** 2))
        assert (ratio > 1.05) if faster else (ratio < 0.97), (band, ratio)


def test_emg_forms_and_units():
    rows = {}
    for seed in range(40):
        s = draw_subject(seed)
        rows.setdefault((s.params.emg_form, s.emg_unit), s)
        if len(rows) == 4:
            break
    assert len(rows) == 4
    for (form, unit), s in rows.items():
        pr = _pair(s, duration=20.0)
        emg = pr.pt.channels["emg"]
        assert pr.truth["emg_unit"] == unit and np.all(emg >= 0)
        level = np.median(emg) / (1e3 if unit == "mV" else 1.0)  # V
        assert 1e-6 < level < 1e-3, (form, unit, level)
        if form == "envelope":  # an offset above zero even where nothing drives it
            assert np.percentile(emg, 1) > 0


def test_perturbation_designs_are_those_named():
    for design in CHOICES["design"]:
        s = draw_subject(2, design=design)
        pr = _pair(s, duration=20.0)
        assert pr.truth["perturbation"] == design
        assert pr.truth["perturbation_amplitude"] == s.perturbation_amplitude
        assert pr.truth["measured"]["snr_db"] == pytest.approx(s.snr_db, abs=1e-6)


def test_cli_and_python_write_the_same_files(tmp_path):
    s = draw_subject(21, "nonlinear_viscosity", "stribeck")
    py = write_subject(s, tmp_path / "py", fs_out=100.0, duration=20.0)
    cli = tmp_path / "cli"
    r = subprocess.run([sys.executable, "-m", "lpvpc.cli", "simulate", "--population-seed", "21", "--effect",
                        "nonlinear_viscosity", "--form", "stribeck", "--fs", "100", "--duration", "20", "--out",
                        str(cli)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    for stem, path in py.items():
        assert (cli / path.name).read_bytes() == path.read_bytes(), stem
    truth = json.loads((cli / "truth.json").read_text())
    assert PopulationSubject.from_dict(truth["population_subject"]) == s
    r = subprocess.run([sys.executable, "-m", "lpvpc.cli", "simulate", "--population-seed", "21", "--seed", "3",
                        "--out", str(tmp_path / "x")], capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--seed" in r.stderr


def test_position_noise_floor_is_in_the_recorded_position_only():
    """``position_noise``: white noise of that RMS in each trial's recorded position; the
    joint's motion, the torque and the EMG are those of the same pair without it."""
    s = draw_subject(3)
    quiet = simulate_subject(s, duration=10.0)
    noisy = simulate_subject(s, duration=10.0, position_noise=5e-5)
    for a, b in ((quiet.pt, noisy.pt), (quiet.ut, noisy.ut)):
        e = b.position - a.position
        assert np.std(e) == pytest.approx(5e-5, rel=0.05) and abs(np.mean(e)) < 5e-6
        assert np.array_equal(a.torque, b.torque)
        assert np.array_equal(a.channels["emg"], b.channels["emg"])
    assert not np.allclose(noisy.pt.position - quiet.pt.position, noisy.ut.position - quiet.ut.position)
    assert noisy.truth["position_noise"] == 5e-5 and quiet.truth["position_noise"] == 0.0
    assert np.array_equal(noisy.pt_clean.position, noisy.pt.position)
    with pytest.raises(ValueError, match="position_noise"):
        simulate_subject(s, duration=10.0, position_noise=-1e-5)
