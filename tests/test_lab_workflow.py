"""The lab's workflow on its own files: stationary trials reported right, no silent wrong
results, physiology warnings that lead somewhere (checks on small stand-in models and on the
virtual subject; the lab's files themselves are used in docs/guide/data.md's table)."""

import types
import warnings

import numpy as np
import pytest

from lpvpc.errors import PhysiologyWarning, StationaryWarning
from lpvpc.identification.identify import check_physiology, time_base_problem


def stand_in(K=50.0, B=1.0, inertia=0.015, gain=5.0, effects=(), fit=None, sign=1.0, rho=(0.1, 0.1)):
    """A model-like object with constant K, B, inertia and reflex gain (what the checks read)."""
    const = lambda v: (lambda r: np.full(len(np.atleast_1d(r)), float(v)))  # noqa: E731
    return types.SimpleNamespace(
        scheduling_range=rho, elastic_stiffness=const(K), viscosity=const(B), inertia=const(inertia),
        reflex_gain_threshold=lambda r: (np.full(len(r), gain), np.zeros(len(r))),
        effects=[types.SimpleNamespace(name=n) for n in effects], conventions={"torque_sign": sign},
        fit=fit or {}, fs=100.0, high_rate=None)


def physiology(model, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_physiology(model, **kw)
    return [str(w.message) for w in caught if issubclass(w.category, PhysiologyWarning)]


def test_plausible_model_is_quiet():
    assert physiology(stand_in()) == []


def test_negative_viscosity_is_flagged_like_negative_stiffness():
    told = physiology(stand_in(B=-1.93))
    assert len(told) == 1 and "viscosity B is negative (-1.93 N m s/rad at +0.100 rad)" in told[0]


def test_reversed_sign_with_effects_is_one_line_naming_the_sign_in_the_printed_numbers():
    model = stand_in(K=-85.9, B=-1.28, effects=("stress_relaxation",))
    told = physiology(model, sign_seen=True)
    assert len(told) == 1 and "--torque-sign -1" in told[0] and "-85.9 N m/rad" in told[0], told
    # without the effect-free fit's sign warning: the effects are blamed, as before
    assert "traded" in physiology(model)[0]


def relaxation_fit(short, relaxed):
    return {"stiffness": {"scheduling": [0.1], "short_range": {"values": [short]},
                          "relaxed": {"values": [relaxed]}}}


@pytest.mark.parametrize("relaxed, words", [(174.0, "above the short-range stiffness"), (-14.0, "below zero")])
def test_relaxed_stiffness_outside_its_range_is_explained(relaxed, words):
    told = physiology(stand_in(K=155.7, fit=relaxation_fit(155.7, relaxed)))
    assert len(told) == 1 and words in told[0] and "cannot tell the relaxed stiffness" in told[0], told
    assert physiology(stand_in(K=155.7, fit=relaxation_fit(155.7, 40.0))) == []


def test_time_base_too_fast_is_named():
    """A time axis ten times too fast: viscosity /10, inertia /100 (the virtual subject read
    as 10 kHz: 0.15 N m s/rad, |I| 0.002 kg m^2); K and the VAF stay plausible."""
    fast = stand_in(K=42.0, B=0.15, inertia=-0.002)
    assert "time axis is probably too fast" in time_base_problem(fast)
    told = physiology(fast)
    assert len(told) == 1 and "--time-unit" in told[0]
    assert time_base_problem(stand_in(K=40.0, B=6.5, inertia=1.5)) is not None  # ten times too slow
    # the lab's stationary trials: noisy inertia, plausible viscosity
    for B, inertia in ((1.28, 0.003), (1.0, -0.0115), (0.79, 0.019), (0.87, 0.027), (0.6, 0.014)):
        assert time_base_problem(stand_in(B=B, inertia=inertia)) is None


def _stationary(declared):
    from lpvpc.io import PerturbationData

    rng = np.random.default_rng(0)
    n, fs = 3000, 100.0
    p = np.repeat(rng.choice([-0.03, 0.03], n // 10), 10) + 0.002 * rng.standard_normal(n)
    y = 40.0 * p + 0.5 * np.gradient(p, 1 / fs) + 0.05 * rng.standard_normal(n)
    d = PerturbationData(p, y, np.full(n, 0.1), fs)
    if declared:
        d.meta["stationary"] = True
    return d


@pytest.mark.parametrize("declared", [False, True])
def test_no_range_warning_when_the_trial_is_declared_stationary(declared):
    from lpvpc.identification.identify import LPVPCEstimator

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = LPVPCEstimator(structure="fixed", stationary_delays=(), state_order=2).fit(_stationary(declared)).model_
    told = [w for w in caught if issubclass(w.category, StationaryWarning)]
    assert m.settings["intrinsic_order"] == 0 or m.fit["stationary"]
    assert len(told) == (0 if declared else 1), [str(w.message) for w in told]


@pytest.fixture(scope="module")
def stationary_ladder():
    """The improve ladder (no step) of a virtual subject's stationary trial with stress
    relaxation, judged on a second stationary trial: the base's selection switches it on."""
    from lpvpc.io import stationary_perturbation
    from lpvpc.diagnosis.improve import improve
    from lpvpc.simulation.simulate import simulate_pair

    ident, held = (stationary_perturbation(simulate_pair("stationary", seed=s, duration=40.0, fs_out=100.0,
                                                         effects=("stress_relaxation",)).pt) for s in (1, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return improve(ident, held, max_steps=0), held


def test_improve_names_the_effects_its_model_has(stationary_ladder):
    rung = stationary_ladder[0].final
    assert [fe.name for fe in rung.model.effects] == ["stress_relaxation"]
    assert rung.effects == ("stress_relaxation",) and "stress_relaxation" in rung.label


def test_stationary_improve_report_has_one_position_column(stationary_ladder, tmp_path):
    from lpvpc.diagnosis.improve import _ladder_positions, write_report

    ladder, held = stationary_ladder
    assert len(_ladder_positions(ladder)) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        write_report(ladder, held, tmp_path)
    md = (tmp_path / "improve.md").read_text()
    header = next(line for line in md.splitlines() if line.startswith("| step | model |"))
    assert header.count("|") == 4, header  # step, model and the one position


@pytest.mark.parametrize("upper, warned", [(0.8, False), (-0.3, True)])
def test_negative_reflex_gain_warned_only_where_its_interval_excludes_zero(upper, warned):
    """A negative gain whose interval reaches zero is "not determined by these data" (as
    the summary says): no warning; one whose interval lies below zero is, with no fix that
    was not seen to work, in plain words."""
    model = stand_in(gain=-1.9, rho=(-0.4, 0.2))
    model.has_intervals = True
    model.reflex_gain_interval = lambda r: (np.full(len(r), -4.0), np.full(len(r), upper))
    told = physiology(model)
    assert len(told) == int(warned), told
    if warned:
        assert "cannot tell" in told[0] and "velocity_order" not in told[0] and "interval up to -0.3" in told[0]


def _options(command):
    from lpvpc.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.choices and command in a.choices)
    return {o for a in sub.choices[command]._actions for o in a.option_strings}


def test_every_option_a_model_reading_command_suggests_is_its_own(tmp_path, capsys):
    """predict reads at the model's rate and has no --fs: a file slower than the model must
    not be told to use --fs 0 (which predict rejects); an option of another command is
    named with that command."""
    import re

    from lpvpc.cli import main
    from lpvpc.io import Trial, pair_trials, write_trial_csv
    from lpvpc.identification.identify import identify
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identify(pair_trials(pair.pt, pair.ut), structure="fixed").save(tmp_path / "m.json")
    for key, tr in (("PT", pair.pt), ("UT", pair.ut)):  # every other sample: 50 Hz
        write_trial_csv(Trial(tr.time[::2], tr.position[::2], tr.torque[::2], {}, name=key), tmp_path / f"{key}.csv")
    assert main(["predict", str(tmp_path / "m.json"), "--pt", str(tmp_path / "PT.csv"),
                 "--ut", str(tmp_path / "UT.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "below" in err and "100 Hz" in err, err
    own = _options("predict")
    for m in re.finditer(r"(lpvpc (\w[\w-]*) )?(--[\w-]+)", err):
        assert m.group(3) in (_options(m.group(2)) if m.group(2) else own), (m.group(0), err)
