"""Diagnosis and the improve loop on the virtual subject (issue 5, "Must show").

Identification on the multilevel record of seed s, diagnosis and held-out VAF on the
novel record of seed s + 1 (100 Hz, SNR 18 dB), as in benchmarks/bench_diagnose.py,
which runs the same checks over more seeds (12 for false alarms, 5 per effect).
"""

import dataclasses
import json
import re

import numpy as np
import pytest

from lpvpc.simulation import simulate
from lpvpc.cli import build_parser, main
from lpvpc.cli.diagnose import run as cmd_diagnose
from lpvpc.cli.improve import run as cmd_improve
from lpvpc.io import Trial, pair_trials
from lpvpc.diagnosis.diagnose import BlockCV, diagnose, paired_test, robust_paired_test, write_report
from lpvpc.diagnosis.candidates import SMALL_GAIN as SMALL_GAIN_SHARE, passes
from lpvpc.models.effects import signals_from_data
from lpvpc.identification.identify import identify
from lpvpc.diagnosis.improve import Ladder, Rung, improve
from lpvpc.diagnosis.improve import write_report as write_ladder
from lpvpc.models.model import vaf
from lpvpc.simulation.simulate import simulate_pair, write_dataset


def _pairs(seed, effects=(), modify=None):
    out = []
    for kind, s in (("multilevel", seed), ("novel", seed + 1)):
        pair = simulate_pair(kind, seed=s, effects=effects)
        pt, ut = modify(pair) if modify else (pair.pt, pair.ut)
        data = pair_trials(pt, ut)  # with the UT trial's EMG as extra['emg_ut']
        out.append(data)
    return out


def cut(data, a, b):
    """A copy of samples ``a:b`` of a record, every channel (a copy: ``clean``'s records are
    shared by the tests)."""
    from lpvpc.io import PerturbationData

    return PerturbationData(data.position[a:b].copy(), data.torque[a:b].copy(), data.scheduling[a:b].copy(),
                            data.fs, {k: v[a:b].copy() for k, v in data.extra.items()}, data.source, data.meta)


def _heldout_vaf(model, data):
    pred = model.predict(data.position, data.scheduling, warn=False, signals=signals_from_data(data))
    return vaf(data.torque, pred.total)


_CLEAN = {}


def clean(seed):
    """(model, held-out data, diagnosis) without a hidden effect, cached per seed."""
    if seed not in _CLEAN:
        ident, novel = _pairs(seed)
        # structure fixed: these tests are about the diagnosis (with the default's selected
        # structure, a 32-s record's surrogate missed the model's prediction by 0.54 VAF points)
        model = identify(ident, structure="fixed")
        _CLEAN[seed] = (model, novel, diagnose(model, novel))
    return _CLEAN[seed]


# hidden truth: (simulator effects, user's estimator settings, expected candidate, seed)
SCENARIOS = {
    "drift": (("drift",), {}, "drift", 0),
    "nonlinear_viscosity": (("nonlinear_viscosity",), {}, "nonlinear_viscosity", 0),
    "direction_dependent_stiffness": (("direction_dependent_stiffness",), {}, "direction_dependent_stiffness", 0),
    "background_activation": (("background_activation",), {}, "background_activation", 0),
    "position_dependent_reflex_dynamics": (("position_dependent_reflex_dynamics",), {},
                                           "position_dependent_reflex_dynamics", 0),
    "reflex_habituation": (("reflex_habituation",), {}, "reflex_habituation", 1),
    "activation_reflex_gain": (("activation_reflex_gain",), {}, "activation_reflex_gain", 0),
    "amplitude_dependent_stiffness": (("amplitude_dependent_stiffness",), {}, "amplitude_dependent_stiffness", 0),
    # (not allowed to the selection, which otherwise chooses it itself: lpvpc.identification.identify allow_effects)
    "stress_relaxation": (("stress_relaxation",), {"allow_effects": ()}, "stress_relaxation", 0),
    # (relaxation not allowed: with the delay fixed wrong, the selection chose it as a patch, 2.2 % less
    # CV error, and the delay's diagnosed gain fell to +0.12 pp, not significant; open, see issue 22 work)
    "wrong_reflex_delay": ((), {"reflex_delay": 0.08, "allow_effects": ()}, "reflex_delay", 0),
    "irf_too_short": ((), {"irf_lags": 1}, "irf_length", 0),
    "intrinsic_order_too_low": ((), {"intrinsic_order": 2}, "intrinsic_basis_order", 2),
    "reflex_order_too_low": ((), {"reflex_order": 0}, "reflex_basis_order", 0),
}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_hidden_effect_is_ranked_first_significant_and_adding_it_recovers_the_vaf(name):
    effects, settings, expected, seed = SCENARIOS[name]
    ident, novel = _pairs(seed, effects)
    ladder = improve(ident, novel, settings=settings, max_steps=1)
    d = ladder.rungs[0].diagnosis
    top = d.candidates[0]
    assert top.effect == expected, d.answer()
    assert top.significant and top.vaf_gain >= d.settings["min_gain"]
    assert d.top is top and expected in d.answer()
    # adding it (a real refit on the identification record) brings the held-out VAF back
    # to within 1 point of the base model on data without the effect
    step = ladder.rungs[1]
    assert step.kept and (step.change.get("effect") == expected or expected in str(step.label))
    clean_vaf = clean(seed)[2].vaf
    assert step.heldout_vaf >= clean_vaf - 1.0, (step.heldout_vaf, clean_vaf)
    assert step.heldout_vaf > ladder.rungs[0].heldout_vaf


def test_position_dependent_reflex_dynamics_strong(monkeypatch):
    """Three times the virtual subject's range (wn 5.3-48 rad/s, a benchmark-only effect)."""

    def strong(s):
        s.reflex_wn = s.params.reflex_wn * 3.0 ** ((s.theta + 0.1) / 0.3)
        return {"ratio": 3.0}

    monkeypatch.setitem(simulate.EFFECTS, "strong_reflex_dynamics", ("wn ratio 3", strong))
    ident, novel = _pairs(2, ("strong_reflex_dynamics",))
    d = diagnose(identify(ident), novel)
    assert d.candidates[0].effect == "position_dependent_reflex_dynamics" and d.candidates[0].significant
    extended = identify(ident, effects=("position_dependent_reflex_dynamics",))
    assert _heldout_vaf(extended, novel) >= clean(2)[2].vaf - 1.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_false_alarm_without_a_hidden_effect(seed):
    d = clean(seed)[2]
    assert not d.significant, [(c.effect, c.vaf_gain, c.p_value) for c in d.significant]
    assert d.answer().startswith("Nothing significant")


def test_effect_outside_the_catalog_gets_signal_and_pathway():
    """Reflex gain modulated by the slow movement's velocity (not in the catalog)."""

    def modulated(pair):
        vs = np.gradient(pair.ut.position) * 1000.0
        extra = 0.6 * np.tanh(vs / 0.05) * (pair.components["pt_reflex"] - pair.components["ut_reflex"])
        pt = pair.pt
        return Trial(pt.time, pt.position, pt.torque + extra, dict(pt.channels), pt.name), pair.ut

    ident, novel = _pairs(0, modify=modulated)
    d = diagnose(identify(ident), novel)
    assert not d.significant
    top = d.dependence[0]
    assert (top["signal"], top["pathway"]) == ("scheduling_velocity", "reflex")
    assert "depends most on scheduling_velocity" in d.answer() and "reflex pathway" in d.answer()


def test_diagnosis_json_and_where_it_fails(tmp_path):
    ident, novel = _pairs(0, ("drift",))
    d = diagnose(identify(ident), novel)
    path = write_report(d, novel, tmp_path / "rep")
    assert path.is_file() and (tmp_path / "rep" / "residual.png").is_file()
    j = json.loads((tmp_path / "rep" / "diagnosis.json").read_text())
    cands = j["candidates"]
    for c in cands:
        assert {"effect", "vaf_gain", "significant", "explanation"} <= set(c)
    rest = [c["vaf_gain"] for c in cands if c["available"] and not c["significant"]]
    assert rest == sorted(rest, reverse=True)  # after the significant ones (conditional order)
    assert cands[0]["effect"] == "drift" and cands[0]["significant"] is True
    assert {c["effect"] for c in cands} >= {"drift", "reflex_delay", "irf_length", "background_activation",
                                           "reflex_habituation", "activation_reflex_gain"}
    assert j["design"] == "refit" and j["signal_leak_r2"]["emg"] > 0.5 > j["signal_leak_r2"]["activation"]
    # where: the model fitted to a drifting subject has an average stiffness, so its
    # relative error is largest at the start or the end of the trial
    bins = j["where"]["time"]["bins"]
    worst = min(bins, key=lambda b: b["vaf"])
    assert worst in (bins[0], bins[-1])
    assert set(j["where"]) >= {"position", "velocity", "slow_movement", "time", "frequency", "events",
                               "whiteness", "cross_correlation"}
    cc = j["where"]["cross_correlation"]["velocity"]
    assert cc["lags_s"][0] < 0 < cc["lags_s"][1]  # negative lags included
    assert j["signal_dependence"][0]["signal"] == "trial_time"


def test_block_cv_equals_explicit_least_squares():
    rng = np.random.default_rng(3)
    n = 400
    A, B = rng.standard_normal((n, 3)), rng.standard_normal((n, 2)) * [1e3, 1e-2]
    y = A @ [1.0, -2.0, 0.5] + B @ [1e-3, 30.0] + 0.1 * rng.standard_normal(n)
    cv = BlockCV(y, folds=4)
    cv.add("a", A)
    cv.add("b", B)
    r, rss = cv.fit(["a", "b"])
    X = np.hstack([A, B])
    for f, (i, j) in enumerate(zip(cv.edges[:-1], cv.edges[1:])):
        train = np.r_[0:i, j:n]
        beta = np.linalg.lstsq(X[train], y[train], rcond=None)[0]
        assert np.allclose(r[i:j], y[i:j] - X[i:j] @ beta, atol=1e-6)
        assert rss[f] == pytest.approx(np.sum((y[train] - X[train] @ beta) ** 2), rel=1e-6)


def test_paired_test():
    rng = np.random.default_rng(0)
    r0 = rng.standard_normal(6000)
    assert paired_test(r0, r0.copy(), 100.0)[1] == 1.0
    t, p = paired_test(r0, 0.9 * r0, 100.0)
    assert t > 5 and p < 1e-6
    t, p = paired_test(r0, r0 + 0.05 * rng.standard_normal(6000), 100.0)
    assert p > 1e-3



def test_robust_paired_test_keeps_its_power_when_one_block_swings_the_other_way():
    # a candidate better by 6 % of the squared residual in 59 of 60 2-s blocks, much worse in
    # one (a slow signal extrapolated into a held-out fold): the batch-means t test loses it
    rng = np.random.default_rng(1)
    r0 = rng.standard_normal(12000)
    r1 = 0.97 * r0
    r1[5000:5200] = 2.0 * r0[5000:5200]
    t, p_plain = paired_test(r0, r1, 100.0)
    t_robust, p_robust, p_mean = robust_paired_test(r0, r1, 100.0)
    assert t_robust == t and p_mean == p_plain and p_plain > 0.1 and p_robust < 1e-6
    # an improvement confined to the first 6 s (habituation-like): the signed rank sees few
    # blocks, the t test carries it; the robust p is at most twice the t test's (Bonferroni)
    r1 = r0.copy()
    r1[:600] = 0.1 * r0[:600]
    p_plain, p_robust = paired_test(r0, r1, 100.0)[1], robust_paired_test(r0, r1, 100.0)[1]
    assert p_robust == pytest.approx(min(1.0, 2 * p_plain))
    # no improvement (a candidate fitting noise): not significant either way
    for seed in range(5):
        r1 = r0 + 0.05 * np.random.default_rng(10 + seed).standard_normal(12000)
        assert robust_paired_test(r0, r1, 100.0)[1] > 0.5


def test_small_gains_are_judged_on_the_mean_test_alone():
    # a gain between 0.6 and 1 x min_gain needs the t test's p ten times below the level:
    # a signed-rank p that small (most blocks improve a little) is not enough
    assert passes(0.12, 5e-4, 0.15, 1e-2)
    assert not passes(0.12, 5e-4, 0.15, 1e-2, p_mean=5e-3)
    assert passes(0.12, 5e-4, 0.15, 1e-2, p_mean=5e-4)
    assert passes(0.2, 5e-3, 0.15, 1e-2, p_mean=0.2)  # a large gain: the robust p decides


def test_reflex_pathway_effects_pass_at_a_lower_floor():
    # a catalog effect on the reflex pathway passes with REFLEX_GAIN x min_gain when its mean
    # gain is strongly established; an intrinsic effect or a reflex setting with the same gain
    # and p does not, nor the reflex effect at the level alone
    from lpvpc.diagnosis.candidates import REFLEX_GAIN, STRONG_EVIDENCE, CandidateResult, _passes

    g = REFLEX_GAIN * 0.15 + 0.005
    strong = 0.5e-2 / STRONG_EVIDENCE  # below level / STRONG_EVIDENCE at level 1e-2
    assert 0 < REFLEX_GAIN < SMALL_GAIN_SHARE
    assert passes(g, strong, 0.15, 1e-2, reflex=True) and not passes(g, strong, 0.15, 1e-2)
    assert not passes(g, 5e-3, 0.15, 1e-2, reflex=True)  # at the level alone: not established
    assert not passes(g, 2e-2, 0.15, 1e-2, reflex=True)  # the level still holds
    assert not passes(REFLEX_GAIN * 0.15 - 0.005, 1e-13, 0.15, 1e-2, reflex=True)  # under the floor
    assert passes(2 * g, strong, 0.3, 1e-2, reflex=True) and not passes(g, strong, 0.3, 1e-2, reflex=True)  # scales
    # an EMG-derived signal carries the reflex's own output: such a reflex effect keeps min_gain
    kinds = {("effect", "reflex", ("trial_time",)): True, ("effect", "reflex", ()): True,
             ("effect", "intrinsic", ()): False, ("setting", "reflex", ()): False,
             ("effect", "reflex", ("activation",)): False}
    for (kind, pathway, signals), expected in kinds.items():
        r = CandidateResult("x", kind, pathway, "", p_value=strong, p_mean=strong, signals=signals)
        assert _passes(r, g, 0.15, 1e-2) is expected, (kind, pathway, signals)


def test_improve_report(tmp_path):
    ident, novel = _pairs(0, ("nonlinear_viscosity",))
    ladder = improve(ident, novel, max_steps=2)
    assert isinstance(ladder, Ladder) and all(isinstance(r, Rung) for r in ladder.rungs)
    assert [r.label for r in ladder.rungs] == ["base model", "+ nonlinear_viscosity"]
    assert ladder.stopped == "nothing significant left"
    base, final = ladder.rungs
    assert ladder.kept == ladder.rungs and ladder.final is final and final.kept
    assert final.change == {"effect": "nonlinear_viscosity"} and final.effects == ("nonlinear_viscosity",)
    assert final.diagnosis.top is None and base.diagnosis.top.effect == "nonlinear_viscosity"
    assert final.heldout_vaf > base.heldout_vaf and final.heldout_rmse < base.heldout_rmse  # %, N m
    assert "nonlinear_viscosity" in ladder.table().splitlines()[1]  # the base rung names the next step
    # the step keeps the structure the base model's cross-validation chose (the extended model is not selected)
    chosen = base.model.fit["structure_selection"]["chosen"]
    path = (base.model.fit["structure_selection"].get("reflex_path") or {}).get("chosen", {})  # 1 kHz records
    assert final.settings == {**chosen, **path, "state_order": base.model.fit["state_order"], "structure": "fixed"}
    assert final.model.settings["intrinsic_order"] == chosen["intrinsic_order"]
    assert final.model.settings["irf_lags"] == round(chosen["irf_length"] * final.model.fs)
    summary = ladder.to_dict()
    assert summary["final"] == {"effects": ["nonlinear_viscosity"], "settings": final.settings,
                                "heldout_vaf": round(final.heldout_vaf, 3)}
    assert summary["steps"][1] == final.to_dict() and final.to_dict()["model_hash"] == final.model.model_hash
    path = write_ladder(ladder, novel, tmp_path / "imp")
    text = (tmp_path / "imp" / "improve.md").read_text()
    assert "held-out VAF" in text and "ladder.png" in text and "residual_step1.png" in text
    page = path.read_text()
    assert path.name == "report.html" and "Step 1: + nonlinear_viscosity" in page
    assert page.count("data:image/png;base64,") >= 3 and not re.search(r'(src|href)="(https?:)?//', page)
    j = json.loads((tmp_path / "imp" / "ladder.json").read_text())
    assert [s["heldout_vaf"] for s in j["steps"]] == sorted(s["heldout_vaf"] for s in j["steps"])


def test_cli_diagnose_and_improve(tmp_path, capsys):
    paths = write_dataset(tmp_path / "data", seed=0, fs_out=100.0, effects=("direction_dependent_stiffness",))
    model = tmp_path / "model.json"
    assert main(["identify", "--pt", str(paths["ident_PT"]), "--ut", str(paths["ident_UT"]), "-o", str(model)]) == 0
    capsys.readouterr()
    # the commands' handlers, as main calls them once the command line is parsed
    assert cmd_diagnose(build_parser().parse_args([
        "diagnose", str(model), "--pt", str(paths["novel_PT"]), "--ut", str(paths["novel_UT"]),
        "--json", str(tmp_path / "d.json"), "--report", str(tmp_path / "drep")])) == 0
    out = capsys.readouterr().out
    assert "Missing: direction_dependent_stiffness" in out
    assert json.loads((tmp_path / "d.json").read_text())["candidates"][0]["effect"] == "direction_dependent_stiffness"
    assert cmd_improve(build_parser().parse_args([
        "improve", "--pt", str(paths["ident_PT"]), "--ut", str(paths["ident_UT"]),
        "--heldout-pt", str(paths["novel_PT"]), "--heldout-ut", str(paths["novel_UT"]),
        "--report", str(tmp_path / "imp"), "-o", str(tmp_path / "final.json")])) == 0
    out = capsys.readouterr().out
    assert "+ direction_dependent_stiffness" in out and "nothing significant left" in out
    assert (tmp_path / "imp" / "improve.md").is_file()
    from lpvpc.models.model import LPVPCModel

    assert [fe.name for fe in LPVPCModel.load(tmp_path / "final.json").effects] == ["direction_dependent_stiffness"]
    assert (tmp_path / "imp" / "report.html").is_file() and (tmp_path / "drep" / "report.html").is_file()
    assert main(["diagnose", str(tmp_path / "missing.json"), "--pt", str(paths["novel_PT"]),
                 "--ut", str(paths["novel_UT"])]) == 2


def test_reflex_bursts_in_the_emg_do_not_leak_into_the_activation_feature():
    """The perturbed trial's EMG carries reflex bursts (simulate.emg_envelope); the raw
    channel is explained by the model's reflex drive, the background activation taken
    between the bursts is not, and a reflex effect is not blamed on activation."""
    from lpvpc.diagnosis.diagnose import Surrogate, signal_leaks

    model, novel, d = clean(0)
    leaks = signal_leaks(Surrogate(model, novel))
    assert leaks["emg"] > 0.5 and leaks["activation"] < 0.05 and leaks["emg_ut"] < 0.05
    ident, novel = _pairs(0, ("position_dependent_reflex_dynamics",))
    d = diagnose(identify(ident), novel)
    assert not {c.effect for c in d.significant} & {"background_activation", "activation_reflex_gain"}


def test_candidate_reading_a_leaking_signal_is_not_named(monkeypatch):
    """A candidate whose signal the reflex drive explains (here: the activation feature
    replaced by the raw perturbed-trial EMG) is refused with the reason, not named."""
    from lpvpc.models import effects as fx

    real = fx.background_emg
    monkeypatch.setattr(fx, "background_emg", lambda emg, position, fs, **kw: np.asarray(emg, dtype=float))
    ident, novel = _pairs(0, ("position_dependent_reflex_dynamics",))
    d = diagnose(identify(ident), novel)
    assert d.leaks["activation"] > 0.5
    act = next(c for c in d.candidates if c.effect == "activation_reflex_gain")
    assert not act.significant
    assert real is not fx.background_emg


def test_conditional_ranking_names_both_pathways_of_activation():
    """Activation that scales intrinsic stiffness AND reflex gain: the intrinsic entry is
    ranked first, the reflex one is re-scored given it; the answer names pathway and signal."""
    ident, novel = _pairs(0, ("background_activation",))
    d = diagnose(identify(ident), novel)
    top = d.candidates[0]
    assert top.effect == "background_activation" and top.significant
    assert "intrinsic pathway and the signal activation" in d.answer()
    for c in d.significant[1:]:
        assert c.given[0] == "background_activation" and c.conditional_gain >= d.settings["min_gain"]


def test_short_record_is_refused_and_a_narrow_one_holds_the_model_fixed(tmp_path, capsys):
    model, novel, _ = clean(0)
    from lpvpc.errors import InsufficientExcitationError

    with pytest.raises(InsufficientExcitationError, match=r"too short for a diagnosis: 15.0 s.*at least 20 s"):
        diagnose(model, cut(novel, 0, 1500))
    d = diagnose(model, cut(novel, 0, 3200), design="fixed")
    assert d.design == "fixed" and d.notes()[0].startswith("Model held fixed")
    # what the gains are measured against: the model itself, not a refit of its structure
    assert d.base_description().startswith("model held fixed") and "refitted" not in d.base_description()
    assert "refitted" in diagnose(model, novel).base_description()
    assert d.surrogate_vaf == pytest.approx(vaf(cut(novel, 0, 3200).torque, d.prediction), abs=0.5)
    assert all(abs(c.vaf_gain) <= 100 - d.surrogate_vaf for c in d.candidates if c.available)
    assert not d.significant
    # mostly outside the identified range: refused
    lo, hi = model.scheduling_range
    far = cut(novel, 0, 3200)
    far.scheduling[:] = hi + 0.2
    with pytest.raises(InsufficientExcitationError, match="outside the model's identified range"):
        diagnose(model, far)


def test_the_surrogate_set_up_is_the_one_diagnose_scores_against():
    """diagnosis_surrogate is diagnose's own set-up: the same base residual on a record it
    refits and on one it holds fixed, and a candidate's columns added to it gain what diagnose
    reports; an unknown design is refused by name."""
    from lpvpc.diagnosis.candidates import _effect_candidate
    from lpvpc.diagnosis.diagnose import diagnosis_surrogate

    model, novel, d = clean(0)
    for data, design in ((novel, "refit"), (cut(novel, 0, 3200), "fixed")):
        setup = diagnosis_surrogate(model, data, design="auto")
        r0, _ = setup.surrogate.cv.fit(setup.surrogate.base)
        dd = d if data is novel else diagnose(model, data)
        assert setup.surrogate.design == dd.design == design
        assert np.allclose(r0, dd.base_residual)
        assert setup.reason == dd.design_reason
        # a column added to it is scored as diagnose scores its candidates: its marginal gain
        c = next(c for c in dd.candidates if c.effect == "nonlinear_viscosity")
        X, _ = _effect_candidate(setup.surrogate, "nonlinear_viscosity")
        setup.surrogate.cv.add("column", X)
        r1, _ = setup.surrogate.cv.fit(setup.surrogate.base + ["column"])
        assert 100 * (r0 @ r0 - r1 @ r1) / setup.surrogate.sst == pytest.approx(c.vaf_gain, rel=1e-9, abs=1e-12)
    with pytest.raises(ValueError, match="design must be 'auto', 'refit' or 'fixed', not 'bogus'"):
        diagnosis_surrogate(model, novel, design="bogus")


def test_diagnose_and_improve_reports_render_in_chromium(tmp_path):
    """report.html of diagnose and improve: self-contained, every figure loads, nothing
    wider than the 1280-px page (tests/report_browser.py). Screenshots go to
    $LPVPC_SCREENSHOT_DIR when set."""
    import os
    from pathlib import Path

    from report_browser import assert_layout_ok, check_page

    shots = Path(os.environ.get("LPVPC_SCREENSHOT_DIR") or tmp_path)
    ident, novel = _pairs(0, ("background_activation",))
    ladder = improve(ident, novel, max_steps=2)
    page = write_ladder(ladder, novel, tmp_path / "imp")
    d = ladder.rungs[0].diagnosis
    rep = write_report(d, novel, tmp_path / "diag")
    text = rep.read_text()
    assert "Candidates, ranked" in text and "background_activation" in text and "residual" in text
    # each candidate's note has a full-width row of its own (as a column it wrapped a word per line)
    assert text.count('<tr class="note">') == sum(bool(c.reason) for c in d.candidates) > 0
    check = check_page(rep, shots / "diagnose_report.png")
    assert_layout_ok(check, n_images=2)
    n_img = page.read_text().count("<img")
    check = check_page(page, shots / "improve_report.png")
    assert_layout_ok(check, n_images=n_img)


def test_tied_reflex_timing_candidates_are_reported_as_a_tie():
    """Two rival candidates of TIES whose held-out residuals differ only by noise are a tie;
    a clear difference is not."""
    from lpvpc.diagnosis.candidates import CandidateResult, _mark_ties

    rng = np.random.default_rng(0)
    fs = 100.0
    common = rng.standard_normal(6000)

    def cand(name, resid):
        return CandidateResult(name, "effect", "reflex", "x.", vaf_gain=0.3, residual=resid)

    delay = cand("position_dependent_reflex_delay", common)
    dyn = cand("position_dependent_reflex_dynamics", -common)  # the same squared residual
    _mark_ties([delay], [delay, dyn], fs, 2.0)
    assert delay.tied_with == "position_dependent_reflex_dynamics" and delay.tie_p > 0.05
    # noise-level differences: a tie in most draws (two-sided 5 % test)
    ties = 0
    for _ in range(40):
        a = cand("position_dependent_reflex_delay", common + 0.01 * rng.standard_normal(6000))
        b = cand("position_dependent_reflex_dynamics", common + 0.01 * rng.standard_normal(6000))
        _mark_ties([a], [a, b], fs, 2.0)
        ties += a.tied_with == b.effect
    assert ties >= 32, ties
    better = cand("position_dependent_reflex_delay", 0.8 * common)
    _mark_ties([better], [better, dyn], fs, 2.0)
    assert better.tied_with == ""


def test_a_reflex_gain_change_tied_between_trial_time_and_activation_is_named_by_trial_time():
    """activation_reflex_gain reads an EMG-derived signal (which carries the reflex's own
    output); when reflex_habituation (trial time) explains the torque about as well, the
    ranking takes habituation, and the two are reported as a tie, also when habituation alone
    does not pass the family-wise test (lab pulses seed 2). A clear win stays."""
    from types import SimpleNamespace

    from lpvpc.diagnosis.candidates import TIES, CandidateResult, _mark_ties, _prefer_underived

    rng = np.random.default_rng(1)
    fs, n = 100.0, 6000
    common = rng.standard_normal(n)
    sur = SimpleNamespace(fs=fs)

    def cand(name, resid, gain=0.5):
        c = CandidateResult(name, "effect", "reflex", "x.", vaf_gain=gain, residual=resid)
        c.conditional_gain, c.p_value = gain, 1e-6
        return c

    act = cand("activation_reflex_gain", common + 0.01 * rng.standard_normal(n), 0.52)
    hab = cand("reflex_habituation", common + 0.01 * rng.standard_normal(n), 0.50)
    scored = [(act, act.residual), (hab, hab.residual)]
    best, _ = _prefer_underived(sur, act, act.residual, scored, 0.15, 0.01, 2.0)
    assert best is hab
    assert frozenset((act.effect, hab.effect)) in TIES
    _mark_ties([hab], [act, hab], fs, 2.0)
    assert hab.tied_with == "activation_reflex_gain"
    clear = cand("activation_reflex_gain", 0.8 * common, 1.5)
    best, _ = _prefer_underived(sur, clear, clear.residual, [(clear, clear.residual), (hab, hab.residual)],
                                0.15, 0.01, 2.0)
    assert best is clear
    # tied, not significant itself (not in the forward selection's pool): taken when its gain is
    # positive at the unadjusted level alpha (act already showed that the reflex gain changes) ...
    weak = cand("reflex_habituation", hab.residual, 0.05)
    weak.p_value = 0.06
    best, _ = _prefer_underived(sur, act, act.residual, [(act, act.residual)], 0.15, 0.01, 2.0,
                                unscored=(weak, weak.residual), alpha=0.1)
    assert best is weak and weak.significant and "in place of activation_reflex_gain" in weak.reason
    # ... and not when its own evidence is weaker than that
    weaker = cand("reflex_habituation", hab.residual, 0.05)
    weaker.p_value = 0.3
    best, _ = _prefer_underived(sur, act, act.residual, [(act, act.residual)], 0.15, 0.01, 2.0,
                                unscored=(weaker, weaker.residual), alpha=0.1)
    assert best is act and not weaker.significant


def test_position_dependent_reflex_delay_is_found_and_named_honestly():
    """The virtual subject's reflex delay grows from 30 to 80 ms toward dorsiflexion: the
    delay entry is significant; on torque it ties with position-dependent reflex dynamics,
    and the perturbed trial's EMG (its bursts move with the delay, not with the dynamics)
    names the delay. Without EMG the answer says the data cannot tell them apart (pathway and
    signal named) instead of pretending. Refitting with it restores the held-out VAF to within
    1 point of the clean model."""
    ident, novel = _pairs(0, ("position_dependent_reflex_delay",))
    ladder = improve(ident, novel, max_steps=1)
    d = ladder.rungs[0].diagnosis
    top = d.top
    assert top is not None and top.effect == "position_dependent_reflex_delay" and top.vaf_gain >= d.settings["min_gain"]
    # a tie on torque (seed 0: p = 1.0) that the EMG breaks: its latency rises with position
    assert top.tied_with == "position_dependent_reflex_dynamics" and top.significant
    sb = top.to_dict()["settled_by"]
    assert sb["signal"] == "emg" and sb["trend"] and sb["latency_hi_ms"] - sb["latency_lo_ms"] >= 30, sb
    assert "the EMG's reflex latency rises from" in d.answer() and "not separable" in d.answer()
    assert ladder.rungs[1].kept and ladder.rungs[1].heldout_vaf >= clean(0)[2].vaf - 1.0
    # the same record without EMG: a tie stays a tie
    bare = dataclasses.replace(novel, extra={k: v for k, v in novel.extra.items() if not k.startswith("emg")})
    d = diagnose(ladder.rungs[0].model, bare)
    top = d.top
    assert top is not None and top.settled_by is None
    if top.tied_with:
        assert ("reflex timing varies with position: delay or dynamics (not separable at this sampling rate), "
                "carried by the reflex pathway and the signal scheduling") in d.answer()


def test_emg_latency_breaks_the_reflex_timing_tie_toward_dynamics(monkeypatch):
    """Reflex dynamics that vary with position (three times the simulator's range, seed 1)
    leave the EMG's reflex latency flat, and the diagnosis names the dynamics. With the
    effect's position weights of order 2 the delay entry scored as well on torque here and the
    EMG settled the tie; with order 3 the torque alone separates them (PRALDS seeds 0-3, lab
    pulses 0, 1, 3), so the tie is posed to the tie-break directly: the delay ahead, the
    dynamics tied with it, the EMG's latency decides."""
    from lpvpc.diagnosis.candidates import _emg_tie_break
    from lpvpc.diagnosis.surrogate import Surrogate
    from lpvpc.models.effects import reflex_latency, with_model_activation

    def strong(s):
        s.reflex_wn = s.params.reflex_wn * 3.0 ** ((s.theta + 0.1) / 0.3)
        return {"ratio": 3.0}

    monkeypatch.setitem(simulate.EFFECTS, "strong_reflex_dynamics", ("wn ratio 3", strong))
    ident, novel = _pairs(1, ("strong_reflex_dynamics",))
    model = identify(ident)
    d = diagnose(model, novel)
    top = d.top
    assert top is not None and top.effect == "position_dependent_reflex_dynamics", d.answer()
    delay = next(c for c in d.candidates if c.effect == "position_dependent_reflex_delay")
    assert not delay.significant
    if top.tied_with:
        assert top.tied_with == "position_dependent_reflex_delay" and not top.settled_by["trend"], top.to_dict()
        assert "the EMG's reflex latency stays at" in d.answer()
    sur = Surrogate(model, with_model_activation(novel, model))
    tied = [(delay, top.residual), (top, top.residual)]  # the same residual: a tie on torque
    top.settled_by = None
    best, _ = _emg_tie_break(sur, delay, top.residual, tied, d.settings["min_gain"], d.settings["alpha"] / 10, 2.0)
    assert best is top and top.settled_by["signal"] == "emg" and not top.settled_by["trend"], top.settled_by
    # the latency estimate itself: flat here, against the model's drive on the undelayed velocity
    from lpvpc.models import equations as eq

    z = eq.reflex_drive(model.velocity_basis.evaluate(eq.velocity(novel.position, novel.fs)),
                        model.reflex_rho_basis.evaluate(novel.scheduling), model.Omega).ravel()
    lat = reflex_latency(novel.extra["emg"], z, novel.scheduling, novel.fs)
    assert abs(lat["latency_hi"] - lat["latency_lo"]) < 0.005 and lat["blocks"] >= 40, lat


def test_a_model_that_does_not_carry_over_is_said_to():
    """Stiffness that falls with the slow movement's speed (outside the catalog): the
    identification record mostly holds still and the novel one mostly moves, so the drop is
    nearly constant within the novel record and no candidate can see it; the refitted
    structure beats the model by several points, and the diagnosis says the model does not
    carry over instead of a bare 'nothing significant'. A clean model gets no such note."""
    ident, novel = _pairs(1, ("stiffness_by_slow_speed",))
    d = diagnose(identify(ident), novel)
    assert d.design == "refit" and d.surrogate_vaf - d.vaf > 2.0, (d.vaf, d.surrogate_vaf)
    assert any("do not carry over" in n for n in d.notes()), d.notes()
    assert not any("do not carry over" in n for n in clean(0)[2].notes())
    # What remains within the record (the stiffness recovers around the slow movement's
    # turning points) is a dependence on the slow speed, whichever the direction, through the
    # intrinsic pathway: the probe's rank-based shape resolves the speeds near zero that the
    # record dwells on (a polynomial over the whole velocity range did not, 2/5 seeds).
    top = d.dependence[0]
    assert (top["signal"], top["pathway"]) == ("scheduling_speed", "intrinsic"), d.dependence[:3]
    assert d.signal_finding is top and "depends most on scheduling_speed" in d.answer()


def test_a_gain_that_swings_with_trial_time_is_found_on_its_pathway():
    """Reflex gain 1 + 0.4 sin(2 pi t / 35 s) (outside the catalog): a trend in t and t^2 on
    contiguous folds cannot follow it (0/5 seeds). The trial-time probes are slowly varying
    gains of each pathway scored on interleaved folds: the reflex pathway's is found."""
    ident, novel = _pairs(1, ("oscillating_reflex_gain",))
    d = diagnose(identify(ident), novel)
    assert not d.significant
    top = d.dependence[0]
    assert (top["signal"], top["pathway"], top["folds"]) == ("trial_time", "reflex", "interleaved"), d.dependence[:3]
    assert d.signal_finding is top and "depends most on trial_time" in d.answer() and "reflex pathway" in d.answer()
    # the intrinsic pathway's gain over time explains far less
    intrinsic = next(x for x in d.dependence if (x["signal"], x["form"]) == ("trial_time", "intrinsic"))
    assert intrinsic["vaf_gain"] < 0.5 * top["vaf_gain"]


def test_settings_the_models_cross_validation_chose_are_not_re_decided_on_held_out_data():
    """A selected model's structure was judged on the identification record (one-standard-
    error rule); diagnosis re-deciding it named irf_length significant on 1 of 20 clean
    seeds. Those candidates are unavailable with the reason; a setting the user gave stays a
    candidate (the 'IRF too short' scenario)."""
    ident, novel = _pairs(0)
    selected = identify(ident)
    assert selected.fit["structure_selection"].get("chosen")
    by_name = {c.effect: c for c in diagnose(selected, novel).candidates}
    for name in ("irf_length", "intrinsic_basis_order", "reflex_basis_order", "reflex_delay"):
        assert not by_name[name].available and "chosen by cross-validation" in by_name[name].reason, name
    given = identify(ident, irf_lags=1)  # the user's IRF: judged on the held-out record
    c = {c.effect: c for c in diagnose(given, novel).candidates}["irf_length"]
    assert c.available and c.significant


def test_amplitude_dependence_is_not_a_candidate_when_every_step_has_one_size():
    """Under a PRBS every displacement is +-A: amplitude-dependent stiffness cannot be told
    from stiffness (its columns p|p|, p^3 are A p, A^2 p but for the transitions), so it is
    not scored, with the reason; under PRALDS (levels of every size) it is."""
    for design, available in (("prbs", False), ("pralds", True)):
        ident, held = (pair_trials(p.pt, p.ut) for p in (
            simulate_pair(kind, seed=3, duration=30.0, fs_out=100.0, perturbation=design)
            for kind in ("multilevel", "novel")))
        c = next(c for c in diagnose(identify(ident, structure="fixed"), held).candidates
                 if c.effect == "amplitude_dependent_stiffness")
        assert c.available is available, (design, c.reason)
        assert available or "one size" in c.reason


def _blas_threads_seen(monkeypatch, module, name, call):
    """BLAS thread counts seen inside ``module.name`` while ``call()`` runs with BLAS set to 2
    threads around it, no thread variable set (a notebook's session after BLAS started)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    seen, inner = [], getattr(module, name)

    def spy(*args, **kwargs):
        seen.extend(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
        return inner(*args, **kwargs)

    monkeypatch.setattr(module, name, spy)
    with threadpool_limits(limits=2, user_api="blas"):
        call()
        after = {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    return set(seen), after


def test_diagnose_and_improve_run_on_one_blas_thread_and_restore_the_callers(monkeypatch):
    # the candidates' many small least-squares fits took three times as long on OpenBLAS's
    # default threads in a Python session as from the command line (which runs on one)
    import lpvpc.diagnosis.diagnose as diagnose_module
    import lpvpc.diagnosis.improve as improve_module

    model, novel, _ = clean(0)
    inside, after = _blas_threads_seen(monkeypatch, diagnose_module, "score_candidates",
                                       lambda: diagnose(model, novel))
    assert inside == {1} and after == {2}
    ident, held = _pairs(0)
    inside, after = _blas_threads_seen(monkeypatch, improve_module, "_evaluate",
                                       lambda: improve(ident, held, settings={"structure": "fixed"}, max_steps=1))
    assert inside == {1} and after == {2}
