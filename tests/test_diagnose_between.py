"""Between-record candidates (lpvpc.diagnosis.between): an effect whose signal differs in level
between the identification record and the diagnosed one, but hardly moves within the latter.

The subject is a population draw whose background activation drifts, each trial with its own
start and end: the held-out record sits at another activation level than the identification
record, so the model carries the wrong stiffness over while the within-record candidates see
an activation that barely changes.
"""

import warnings

import numpy as np
import pytest

import lpvpc
from lpvpc.diagnosis.between import SCOPE, refit_settings
from lpvpc.models.effects import signals_from_data, with_model_activation
from lpvpc.simulation.population import draw_subject, simulate_subject

pytestmark = pytest.mark.filterwarnings("ignore")


def _records(seed, effect):
    s = draw_subject(seed, effect=effect)
    sims = {k: simulate_subject(s, k) for k in ("multilevel", "novel")}
    return s, sims, {k: lpvpc.pair_trials(v.pt, v.ut) for k, v in sims.items()}


@pytest.fixture(scope="module")
def drifting():
    """A subject whose activation level differs between the two records (both pathways scaled)."""
    s, sims, pairs = _records(10106, "background_activation")
    assert s.effect_params["time_course"] == "drift" and not s.effect_params["shared"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(pairs["multilevel"])
    return s, sims, pairs, model


def test_the_activation_levels_of_the_two_records_differ(drifting):
    """The premise: the true activation of the held-out record lies outside the identification
    record's, and the EMG-derived estimate says so."""
    _, sims, pairs, model = drifting
    true = {k: sims[k].activation["PT"] for k in sims}
    assert true["novel"].max() < true["multilevel"].min()
    est = {k: signals_from_data(with_model_activation(pairs[k], model))["activation"] for k in pairs}
    assert est["novel"].mean() < 0.6 * est["multilevel"].mean()


def test_between_records_names_the_activation_the_record_alone_cannot(drifting):
    _, _, pairs, model = drifting
    alone = lpvpc.diagnose(model, pairs["novel"])
    assert not any(c.effect in ("background_activation", "activation_reflex_gain") for c in alone.significant)
    # the gap the record alone leaves says how to give the identification record, in both doors
    assert any("--reference DATA0" in n and "reference=" in n for n in alone.notes()), alone.notes()
    d = lpvpc.diagnose(model, pairs["novel"], reference=pairs["multilevel"])
    top = d.top
    assert top is not None and top.scope == SCOPE and top.signals == ("activation",)
    assert top.effect in ("background_activation", "activation_reflex_gain")
    assert top.vaf_gain > 1.0  # pp: most of what the record's own refit explains beyond the model
    assert "between records" in d.answer() and d.to_dict()["candidates"][0]["scope"] == SCOPE
    # the gain is the effect model's (fitted on the identification record) over the model's, on this record
    st, eff = refit_settings(model)
    fitted = lpvpc.LPVPCEstimator(**st, effects=eff + (top.effect,)).fit(
        with_model_activation(pairs["multilevel"], model)).model_
    assert fitted.effects and fitted.effects[0].name == top.effect


def test_improve_adds_it_and_the_held_out_error_falls(drifting):
    _, _, pairs, _ = drifting
    ladder = lpvpc.improve(pairs["multilevel"], pairs["novel"], max_steps=1)
    step = ladder.rungs[1]
    assert step.kept and step.change["effect"] in ("background_activation", "activation_reflex_gain")
    assert step.heldout_vaf > ladder.rungs[0].heldout_vaf + 1.0


def test_a_clean_subject_has_nothing_between_its_records():
    """No effect: the structure refitted on the held-out record explains it no better than the
    model, so no between-record candidate is even fitted, and nothing is named."""
    _, _, pairs = _records(50001, None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(pairs["multilevel"])
    d = lpvpc.diagnose(model, pairs["novel"], reference=pairs["multilevel"])
    assert d.significant == [] and not any(c.scope == SCOPE for c in d.candidates)
    assert d.surrogate_vaf - d.vaf < 0.15


def test_refit_settings_refit_the_same_model(drifting):
    """The refit with no effect added reproduces the model (one thing changes at a time)."""
    _, _, pairs, model = drifting
    st, eff = refit_settings(model)
    again = lpvpc.LPVPCEstimator(**st, effects=eff).fit(pairs["multilevel"]).model_
    rho = np.linspace(*model.scheduling_range, 5)
    assert np.allclose(again.elastic_stiffness(rho), model.elastic_stiffness(rho), rtol=1e-4)  # the poles refined again from their start


def test_a_reference_that_is_not_the_models_record_is_refused(drifting):
    """A reference at another rate, or not a record at all: one clear error naming it."""
    from lpvpc.errors import DataError

    _, sims, pairs, model = drifting
    slow = lpvpc.pair_trials(sims["multilevel"].pt, sims["multilevel"].ut, target_fs=50.0)
    with pytest.raises(DataError, match="reference record"):
        lpvpc.diagnose(model, pairs["novel"], reference=slow)
    with pytest.raises(TypeError, match="reference must be the identification record"):
        lpvpc.diagnose(model, pairs["novel"], reference="ident_PT.csv")


def test_the_between_record_fits_say_nothing_about_the_users_model(drifting):
    """The candidates' fits on the identification record are the diagnosis's own: their notes
    (no intervals, a negative reflex gain) would read as if about the model diagnosed."""
    _, _, pairs, model = drifting
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = lpvpc.diagnose(model, pairs["novel"], reference=pairs["multilevel"])
    assert any(c.scope == SCOPE for c in d.significant)  # the fits ran
    notes = [str(w.message) for w in caught if issubclass(w.category, lpvpc.LpvpcWarning)]
    assert notes == [], notes
