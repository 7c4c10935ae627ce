"""Structure selection scored forward in time (lpvpc.identification.selection): folds that fit on
the earlier record and predict a later stretch, both scores in the selection record, and the
choice rule that serves both criteria."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lpvpc.identification import selection as S
from lpvpc.identification.identify import LPVPCEstimator
from lpvpc.identification.subspace import companion_form
from lpvpc.io import pair_trials
from lpvpc.simulation.simulate import simulate_pair

SETTINGS = {"irf_length": 0.03, "intrinsic_order": 3, "reflex_order": 1, "velocity_order": 3,
            "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}


@pytest.fixture(scope="module")
def record():
    sim = simulate_pair("multilevel", seed=3, duration=60.0, fs_out=100.0)
    return pair_trials(sim.pt, sim.ut)


def _search(d, y=None, **kw):
    A, C = companion_form(np.poly([0.9, 0.8])[1:])
    dyn = (A, C, np.array([1.0, 0.4, 0.05]))
    return S.StructureSearch(d.position, d.torque if y is None else y, d.scheduling, d.fs, dyn,
                             search={k: (v,) for k, v in SETTINGS.items()}, **kw)


def test_forward_folds_train_only_before_the_scored_stretch_and_end_at_the_record_end():
    folds = S.forward_folds(1000, 3, 0.1, gap=4)
    assert [(s.start, s.stop) for _, s in folds] == [(700, 800), (800, 900), (900, 1000)]
    for train, scored in folds:
        assert train.start == 0 and train.stop == scored.start - 4  # expanding window, a gap of the IRF lags


def test_forward_score_never_uses_torque_after_the_scored_stretch(record):
    """Changing the torque after fold k's scored stretch (and in the gap before it) leaves fold
    k's forward error unchanged; changing it inside the training rows changes it."""
    search = _search(record)
    base = search.score(SETTINGS).forward_sse
    assert len(base) == S.FORWARD_FOLDS and np.all(base > 0)
    (train, scored) = search.forward[0]
    y = record.torque.copy()
    rng = np.random.default_rng(0)
    y[scored.stop:] += 5.0 * rng.standard_normal(len(y) - scored.stop)  # later data: nonsense
    y[train.stop:scored.start] += 5.0  # the gap
    later = _search(record, y).score(SETTINGS).forward_sse
    assert later[0] == pytest.approx(base[0], rel=1e-9)
    assert not np.isclose(later[-1], base[-1], rtol=1e-3)  # later folds do see it (trained on it or scored on it)
    y = record.torque.copy()
    y[: train.stop // 2] += 1.0 * rng.standard_normal(train.stop // 2)
    assert not np.isclose(_search(record, y).score(SETTINGS).forward_sse[0], base[0], rtol=1e-3)


def test_forward_score_equals_an_explicit_fit_on_the_earlier_rows(record):
    """The last forward fold's error from normal equations equals a least-squares fit of the
    candidate's columns on the training rows, predicting the scored rows (no extrapolation there)."""
    search = _search(record)
    train, scored = search.forward[-1]
    D = search.design
    rho = record.scheduling
    assert rho[scored].min() >= rho[train].min() and rho[scored].max() <= rho[train].max()
    # rebuild the candidate's regressor from the design (the same largest regressor, recomputed)
    p, y = record.position, record.torque
    Gi, Gr = D.G_i.evaluate(rho), D.G_r.evaluate(rho)
    X = D._regressor(Gi, Gr)
    idx, cur = search.columns(SETTINGS)
    Xc = X[:, idx] + X[:, cur]
    scale = np.linalg.norm(Xc[train], axis=0)
    theta = np.linalg.lstsq(Xc[train] / scale, y[train], rcond=None)[0] / scale
    sse = float(np.sum((y[scored] - Xc[scored] @ theta) ** 2))
    assert search.score(SETTINGS).forward_sse[-1] == pytest.approx(sse, rel=1e-4)
    del p


def test_selection_record_and_summary_carry_both_scores(record):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = LPVPCEstimator().fit(record).model_
    sel = m.fit["structure_selection"]
    assert "forward in time" in sel["method"] and sel["rule"] == S.CHOICE_RULE
    assert 50.0 < sel["chosen_cv_vaf"] <= 100.0 and 50.0 < sel["chosen_forward_vaf"] <= 100.0
    assert sel["n_forward_folds"] == S.FORWARD_FOLDS and set(sel["forward_best"]) == set(sel["chosen"])
    assert all("forward_vaf" in row and "cv_vaf" in row for row in sel["table"])
    text = str(m.summary())
    assert "later %" in text and f"{sel['chosen_forward_vaf']:.2f}" in text


def test_choice_rule_serves_both_criteria_where_they_disagree():
    """A virtual subject whose reflex habituates: its later stretch differs from its earlier
    one, and the structure best on left-out levels is not the one best forward in time. The
    leave-one-level-out rule's pick is far from the best forward; the rule on both picks one
    that scores at least as well on each criterion, at the best worse rank of all scored."""
    sim = simulate_pair("multilevel", seed=0, duration=90.0, fs_out=100.0, effects=("reflex_habituation",))
    d = pair_trials(sim.pt, sim.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = LPVPCEstimator(structure="fixed").fit(d).model_
    search = S.StructureSearch(d.position, d.torque, d.scheduling, d.fs, (m.A, m.C[None, :], np.append(m.B, m.D)))
    start = {"irf_length": 0.04, "intrinsic_order": 5, "reflex_order": 2, "velocity_order": 4,
             "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}
    scored = search.run(start).scored
    best = max(scored, key=lambda s: s.cv_vaf)
    fbest = max(scored, key=lambda s: s.forward_vaf)
    assert best.settings != fbest.settings  # the two criteria disagree
    level, both = S.choose(scored, "level"), S.choose(scored, "both")
    assert not S._within(level, fbest, forward=True)  # one criterion alone: poor forward in time
    assert both.cv_vaf >= level.cv_vaf and both.forward_vaf >= level.forward_vaf
    rank = {id(s): i for i, s in enumerate(sorted(scored, key=lambda s: -s.cv_vaf))}
    frank = {id(s): i for i, s in enumerate(sorted(scored, key=lambda s: -s.forward_vaf))}
    worst = {id(s): max(rank[id(s)], frank[id(s)]) for s in scored}
    assert worst[id(both)] == min(worst.values()) < worst[id(level)]


def test_unknown_rule_is_refused(record):
    with pytest.raises(ValueError, match="rule must be one of"):
        _search(record, rule="median")
    with pytest.raises(ValueError, match="rule must be one of"):
        S.choose([], "median")
