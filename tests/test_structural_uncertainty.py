"""The structural term of the intrinsic intervals (lpvpc.identification.structural_uncertainty): the spread
over the structures cross-validation cannot tell apart, on stiffness families the position
basis cannot hold."""

import copy
import json
import warnings

import numpy as np
import pytest

from lpvpc.io import pair_trials
from lpvpc.errors import ModelFileError
from lpvpc.identification.identify import identify
from lpvpc.models.model import LPVPCModel
from lpvpc.simulation.simulate import SubjectParams, simulate_pair
from lpvpc.identification.structural_uncertainty import (
    INTRINSIC_SETTINGS,
    REFLEX_SETTINGS,
    add_structural_uncertainty,
    near_equivalent,
    structural_term,
    structure_search,
)
from lpvpc.models.uncertainty import intrinsic_interval_parts, structural_shift
from lpvpc.models.reflex_uncertainty import reflex_structural_shift

N_POS = 9


def _fit(family, seed):
    """A 2-minute record of ``family`` at 100 Hz (identify's selection runs on this path),
    identified with structure='cv'; (data, model, truth K at the perturbation amplitude, rho)."""
    sim = simulate_pair("multilevel", seed=seed, fs_out=100.0, stiffness_family=family)
    d = pair_trials(sim.pt, sim.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(d, structure="cv")
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), N_POS)  # central 80 %
    K_true = SubjectParams().with_stiffness_family(family).incremental_stiffness(rho, 0.04)
    return d, model, K_true, rho


def _without_structural_term(model):
    bare = copy.deepcopy(model)
    bare.uncertainty.pop("structural")
    return bare


@pytest.fixture(scope="module")
def piecewise():
    """identify (selection by default) attaches the term from its own search."""
    d, model, K_true, rho = _fit("piecewise", 1)
    assert "structural" in model.uncertainty and any("near-equivalent" in t for t in model.interval_terms)
    before = _without_structural_term(model).elastic_stiffness_interval(rho)
    return d, model, K_true, rho, before


def _covered(interval, truth):
    return (interval.lower <= truth) & (truth <= interval.upper)


def test_on_a_kinked_stiffness_the_structural_interval_covers_where_the_noise_intervals_do_not(piecewise):
    d, model, K_true, rho, before = piecewise
    assert model.fit["structure_selection"].get("chosen")  # identify's cross-validation ran
    after = model.elastic_stiffness_interval(rho)
    est, se, bias = intrinsic_interval_parts(model, "stiffness", rho)
    noise_only = (est - 1.96 * se, est + 1.96 * se)
    # the basis cannot follow the kink: the noise band misses the truth at several positions
    missed = ~((noise_only[0] <= K_true) & (K_true <= noise_only[1]))
    assert missed.sum() >= 3
    # the structures the CV cannot tell apart spread over the miss: the new interval holds the truth
    assert _covered(after, K_true).mean() >= 8 / 9
    assert _covered(after, K_true).sum() > _covered(before, K_true).sum()
    assert np.all(bias["structures"] > 0) and len(model.uncertainty["structural"]["shifts"]) >= 2
    # it widens, it does not move the estimate
    assert np.all(after.lower <= before.lower) and np.all(after.upper >= before.upper)
    assert np.allclose((after.lower + after.upper) / 2, model.elastic_stiffness(rho))


def test_where_the_basis_holds_the_structural_term_adds_little():
    d, model, K_true, rho = _fit("standard", 2)
    # the near-equivalent structures' part (the reflex-dynamics leak, another part of the
    # structural term, is judged in tests/test_reflex_leak.py)
    without = copy.deepcopy(model)
    without.uncertainty["structural"]["shifts"], without.uncertainty["structural"]["structures"] = [], []
    before = without.elastic_stiffness_interval(rho)
    after = model.elastic_stiffness_interval(rho)
    ratio = (after.upper - after.lower) / (before.upper - before.lower)
    assert np.median(ratio) < 1.5
    assert _covered(after, K_true).mean() >= 8 / 9


def test_the_shift_is_the_largest_difference_to_the_model_structure_refitted_alike(piecewise):
    d, model, _, rho, _ = piecewise
    search, start, fixed = structure_search(model, d)
    sel = search.run(start, fixed)
    again = structural_term(model, d, search, sel)  # a search already run is reused
    assert again["shifts"] == structural_term(model, d)["shifts"]  # the same as running it there
    near = near_equivalent(search, sel)
    assert near[0].settings == sel.best  # the best CV structure leads the near-equivalent ones
    # those that count change the intrinsic pathway only; the reflex settings are the model's
    intrinsic = [s for s in near if s.settings != start
                 and all(v == start[k] for k, v in s.settings.items() if k not in INTRINSIC_SETTINGS)]
    assert len(again["shifts"]) == len(intrinsic) >= 2
    assert [x["settings"] for x in again["structures"]] == [s.settings for s in intrinsic]
    assert len(intrinsic) < len([s for s in near if s.settings != start])  # some near ones changed the reflex
    # by hand for one structure: the shift of K is the sum over lags of the IRF weights' shift
    from lpvpc.models.basis import Basis

    st = model.uncertainty["structural"]
    G = Basis.from_dict(st["basis"]).evaluate(rho)
    shifts = np.array([np.asarray(h).sum(axis=0) @ G.T for h in st["shifts"]])
    assert np.allclose(structural_shift(model, "stiffness", rho), np.abs(shifts).max(axis=0))
    # no stored structures: no structural term
    m2 = copy.deepcopy(model)
    m2.uncertainty["structural"]["shifts"], m2.uncertainty["structural"]["structures"] = [], []
    assert np.all(structural_shift(m2, "stiffness", rho) == 0)
    assert np.any(structural_shift(m2, "viscosity", rho) > 0)  # the model's own estimate still counts there
    m2.uncertainty["structural"].pop("path")
    assert np.all(structural_shift(m2, "viscosity", rho) == 0)


def test_the_model_file_records_the_structural_term_and_round_trips(piecewise, tmp_path):
    _, model, _, rho, _ = piecewise
    path = tmp_path / "m.json"
    model.save(path)
    loaded = LPVPCModel.load(path)
    assert "cross-validated" in loaded.uncertainty["structural"]["method"]
    assert loaded.interval_terms[-1] == "near-equivalent structures of the cross-validation"
    a, b = model.elastic_stiffness_interval(rho), loaded.elastic_stiffness_interval(rho)
    assert np.array_equal(a.lower, b.lower) and np.array_equal(a.upper, b.upper)
    loaded.save(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_text() == path.read_text()
    d = json.loads(path.read_text())
    d["uncertainty"]["structural"]["shifts"][0] = d["uncertainty"]["structural"]["shifts"][0][:-1]
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"uncertainty\.structural\.shifts\[0\] has shape"):
        LPVPCModel.load(path)


def test_a_model_without_intervals_gets_a_clear_error(piecewise):
    d, model, _, _, _ = piecewise
    bare = copy.deepcopy(model)
    bare.uncertainty = {}
    assert bare.interval_terms == []
    with pytest.raises(ModelFileError, match="carries no uncertainty"):
        add_structural_uncertainty(bare, d)


def test_a_non_polynomial_basis_is_refused_with_the_reason(piecewise):
    d, model, _, _, _ = piecewise
    other = copy.deepcopy(model)
    other.settings["basis"] = "gaussian"
    with pytest.raises(ValueError, match="needs polynomial bases.*'gaussian' in position"):
        add_structural_uncertainty(other, d)


# ----------------------------------------------------------------- the reflex gain's structural term


@pytest.fixture(scope="module")
def simple_reflex():
    """1 kHz files of the sum-of-exponentials family, seed 10, identified at every default:
    the selection's one-standard-error rule picks a linear reflex scheduling basis
    (reflex_order 1) while the true gain rises about fourfold toward dorsiflexion. (Seed 8,
    order 0, chose stress relaxation once the 1 kHz path's intrinsic refit joined identify.)"""
    from lpvpc.identification import selection

    sim = simulate_pair("multilevel", seed=10, fs_out=1000.0, stiffness_family="sum_of_exponentials")
    d = pair_trials(sim.pt, sim.ut)
    # the case arises under the leave-one-level-out rule alone (the mechanism, not the rule, is tested)
    with warnings.catch_warnings(), pytest.MonkeyPatch.context() as mp:
        mp.setattr(selection, "CHOICE_RULE", "level")
        warnings.simplefilter("ignore")
        model = identify(d)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), N_POS)
    return d, model, SubjectParams().with_stiffness_family("sum_of_exponentials").reflex_gain(rho), rho


def _without_reflex_term(model):
    bare = copy.deepcopy(model)
    bare.uncertainty["structural"].pop("reflex")
    return bare


def test_a_reflex_basis_chosen_too_simple_is_covered_through_the_next_richer_one(simple_reflex):
    d, model, g_true, rho = simple_reflex
    term = model.uncertainty["structural"]["reflex"]
    nr = model.settings["reflex_order"]
    assert nr < 3
    assert term["structures"][0]["settings"]["reflex_order"] == nr + 1  # the next richer reflex basis comes first
    for s in term["structures"][1:]:  # the others differ from the model's in the reflex pathway only
        assert all(v == term["structures"][0]["settings"][k] or k in REFLEX_SETTINGS
                   for k, v in s["settings"].items())
    before = _without_reflex_term(model).reflex_gain_interval(rho)
    after = model.reflex_gain_interval(rho)
    assert np.all(after.lower <= before.lower) and np.all(after.upper >= before.upper)
    # the trend the linear basis cannot follow, read plainly: the knee's rounding measured on the
    # record (uncertainty.knee_rounding) maps the plantarflexed end's gain most of the way back
    # here (1.74 -> 2.10 N m s/rad, truth 2.28) and its interval then covers 8 of 9 without the term
    plain = _without_reflex_term(model)
    plain.uncertainty.pop("knee_rounding")
    assert _covered(plain.reflex_gain_interval(rho), g_true).sum() <= 5
    assert _covered(after, g_true).sum() >= 8
    # the threshold's interval does not take the term
    a, b = model.reflex_threshold_interval(rho), _without_reflex_term(model).reflex_threshold_interval(rho)
    assert np.array_equal(a.lower, b.lower) and np.array_equal(a.upper, b.upper)


def test_the_reflex_term_refits_the_model_structure_alike(piecewise):
    """The reference (the model's structure refitted in the search's columns, the dynamics
    held) gives the model's own gain within a few per cent: the columns are read right."""
    _, model, _, rho, _ = piecewise
    term = model.uncertainty["structural"]["reflex"]
    from lpvpc.models.basis import Basis
    from lpvpc.models.reflex import rectifier_fit

    G = Basis.from_dict(term["rho_basis"]).evaluate(rho)
    v, _ = model.rectifier_velocity_grid()
    C = np.asarray(term["reference"]["coefficients"])
    g_ref = rectifier_fit(v, G @ C.T @ Basis.from_dict(term["reference"]["velocity_basis"]).evaluate(v).T)[0]
    g = model.reflex_gain_threshold(rho, knee_corrected=False)[0]  # read alike
    assert np.max(np.abs(g_ref / g - 1)) < 0.05
    # the shift is the largest difference of the alternatives' gains to that reference
    shifts = []
    for s in term["structures"]:
        Cs = np.asarray(s["coefficients"])
        shifts.append(rectifier_fit(v, G @ Cs.T @ Basis.from_dict(s["velocity_basis"]).evaluate(v).T)[0] - g_ref)
    assert np.allclose(reflex_structural_shift(model, rho), np.abs(shifts).max(axis=0))


def test_without_a_selection_there_is_no_reflex_term(simple_reflex):
    """The term counts the reflex structures the selection could have chosen; a structure
    the caller fixed (or the 1 kHz path given explicitly, where selection is skipped) has none."""
    d, _, _, rho = simple_reflex
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for model in (identify(d, high_rate_reflex=True), identify(d, structure="fixed")):
            add_structural_uncertainty(model, d)
            assert "reflex" not in model.uncertainty["structural"]
            assert np.all(reflex_structural_shift(model, rho) == 0)


def test_the_model_file_round_trips_the_reflex_term(simple_reflex, tmp_path):
    _, model, _, rho = simple_reflex
    model.save(tmp_path / "m.json")
    loaded = LPVPCModel.load(tmp_path / "m.json")
    a, b = model.reflex_gain_interval(rho), loaded.reflex_gain_interval(rho)
    assert np.array_equal(a.lower, b.lower) and np.array_equal(a.upper, b.upper)
    assert np.all(reflex_structural_shift(loaded, rho) > 0)
    # a hand-edited file whose reflex refits do not match their bases is refused with the place named
    d = json.loads((tmp_path / "m.json").read_text())
    d["uncertainty"]["structural"]["reflex"]["structures"][0]["coefficients"][0].append(1.0)
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"structural\.reflex\.structures\[0\]\.coefficients has "):
        LPVPCModel.load(tmp_path / "bad.json")


def test_the_explicit_1khz_path_counts_the_model_rate_path_for_viscosity(simple_reflex):
    """high_rate_reflex=True given: the selection never compared the reflex velocity paths, so
    the viscosity interval spans the model structure refitted with model-rate reflex columns;
    K's interval is not widened by it. A model whose path the selection chose counts its own
    estimate against the refit of its structure the same way."""
    d, selected, _, rho = simple_reflex
    assert selected.uncertainty["structural"]["path"]["quantities"] == ["viscosity"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(d, high_rate_reflex=True)
    search, start, fixed = structure_search(model, d)
    add_structural_uncertainty(model, d, search, search.run(start, fixed))
    st = model.uncertainty["structural"]
    assert st["path"]["quantities"] == ["viscosity"]
    bad = json.loads(json.dumps(model.to_dict()))
    bad["uncertainty"]["structural"]["path"]["quantities"] = ["stiffness?"]
    with pytest.raises(ModelFileError, match=r"structural\.path\.quantities must be a list drawn from viscosity"):
        LPVPCModel.from_dict(bad)
    # by hand: the shift is the model's viscosity minus that of the model-rate refit of its structure
    from lpvpc.models.basis import Basis
    from lpvpc.identification.structural_uncertainty import _refit_irf
    from lpvpc.models.uncertainty import lag_moment_weights

    G = Basis.from_dict(st["basis"]).evaluate(rho)
    w = lag_moment_weights(model, "viscosity", st["lags"])
    ref = np.einsum("l,lj,rj->r", w, _refit_irf(search, start), G)
    shift = np.einsum("l,lj,rj->r", w, np.asarray(st["path"]["shift"]), G)
    assert np.allclose(ref + shift, model.viscosity(rho), rtol=1e-9, atol=1e-12)
    assert np.all(structural_shift(model, "viscosity", rho) >= np.abs(shift) - 1e-12)
    bare = copy.deepcopy(model)
    bare.uncertainty["structural"].pop("path")
    a, b = model.viscosity_interval(rho), bare.viscosity_interval(rho)
    assert np.all(a.upper - a.lower >= b.upper - b.lower) and np.any(a.upper - a.lower > b.upper - b.lower)
    k, kb = model.elastic_stiffness_interval(rho), bare.elastic_stiffness_interval(rho)
    assert np.array_equal(k.lower, kb.lower) and np.array_equal(k.upper, kb.upper)


def test_the_model_rate_estimate_against_the_joint_refit_covers_the_viscosity():
    """At the model rate the model's IRF is the orthogonal projection's (the unstructured reflex
    space projected out); the joint refit with the rank-1 reflex puts the viscosity elsewhere,
    and the data hardly choose. On a population draw (PRBS, low reflex threshold) whose
    viscosity interval missed at 6 of 9 positions, counting that shift covers it at 7 or more."""
    from lpvpc.simulation.population import draw_subject, simulate_subject

    s = draw_subject(147, stiffness="polynomial")
    sim = simulate_subject(s)
    d = pair_trials(sim.pt, sim.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(d)
    assert model.high_rate is None  # the model-rate reflex chosen
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    bare = copy.deepcopy(model)
    bare.uncertainty["structural"].pop("path")
    covered = lambda iv: int(np.sum((iv.lower <= s.params.viscosity) & (s.params.viscosity <= iv.upper)))  # noqa: E731
    assert covered(bare.viscosity_interval(rho)) <= 4 and covered(model.viscosity_interval(rho)) >= 7
    k, kb = model.elastic_stiffness_interval(rho), bare.elastic_stiffness_interval(rho)
    assert np.array_equal(k.lower, kb.lower) and np.array_equal(k.upper, kb.upper)
