"""Settings candidates of the diagnosis (lpvpc.diagnosis.candidates) on the virtual subject
under the PRBS design (every step one size, no quiet windows): a setting the user gave stays
a candidate when the diagnosis holds the model fixed; one the model's cross-validation chose
does not.

Identification on the multilevel record of seed s, diagnosis on the novel record of seed
s + 1 (100 Hz, SNR 18 dB), as in benchmarks/bench_diagnose.py --perturbation prbs.
"""

import pytest

from lpvpc.io import pair_trials
from lpvpc.diagnosis.diagnose import diagnose
from lpvpc.identification.identify import identify
from lpvpc.simulation.simulate import simulate_pair


def _prbs_pairs(seed):
    return [pair_trials(p.pt, p.ut) for p in (simulate_pair(kind, seed=s, perturbation="prbs")
                                              for kind, s in (("multilevel", seed), ("novel", seed + 1)))]


@pytest.mark.slow
def test_a_reflex_basis_the_user_fixed_too_low_is_named_with_the_model_held_fixed():
    # reflex order 0 in rho (the subject's reflex gain and threshold change with position): the
    # refit of that structure on the held-out record fails (about 91 % against the model's 93 %),
    # so the diagnosis holds the model; the setting was the user's, so it is still tested
    ident, novel = _prbs_pairs(4)
    model = identify(ident, reflex_order=0)
    d = diagnose(model, novel, design="fixed")
    top = d.top
    assert d.design == "fixed"
    assert top is not None and top.effect == "reflex_basis_order" and top.kind == "setting"
    assert top.variant == {"reflex_order": 2}
    assert top.vaf_gain > 1.0
    chosen = {c.effect: c for c in d.candidates}
    # the settings the model's own cross-validation chose stay out, held fixed or not
    assert not chosen["irf_length"].available and "cross-validation" in chosen["irf_length"].reason


@pytest.mark.slow
def test_given_settings_held_fixed_raise_no_alarm_on_a_clean_record():
    # the whole structure given (no selection): every settings candidate is tested on the
    # residual of the model held fixed; on a clean record none is significant (their gains
    # were +-0.01 pp on seeds 40-49)
    ident, novel = _prbs_pairs(40)
    model = identify(ident, structure="fixed")
    d = diagnose(model, novel, design="fixed")
    settings = [c for c in d.candidates if c.kind == "setting" and c.available]
    assert {c.effect for c in settings} >= {"reflex_delay", "intrinsic_basis_order", "reflex_basis_order"}
    assert not [c.effect for c in d.significant]
    assert max(c.vaf_gain for c in settings) < 0.1


def _strong_reflex_dynamics(s):
    """bench_diagnose's 3x entry: reflex natural frequency 16 * 3**((theta + 0.1) / 0.3) rad/s."""
    s.reflex_wn = s.params.reflex_wn * 3.0 ** ((s.theta + 0.1) / 0.3)
    return {"ratio": 3.0}


@pytest.mark.slow
def test_wide_position_dependent_reflex_dynamics_is_not_taken_for_a_delay_under_prbs(monkeypatch):
    # natural frequency 5.3-48 rad/s over the range: with the effect's position weights of
    # order 2 the delay entry was named first on this seed (+1.76 against +1.85 pp, tied)
    from lpvpc.simulation import simulate

    monkeypatch.setitem(simulate.EFFECTS, "strong_reflex_dynamics", ("wn ratio 3", _strong_reflex_dynamics))
    ident, novel = [pair_trials(p.pt, p.ut) for p in (
        simulate_pair(kind, seed=s, perturbation="prbs", effects=("strong_reflex_dynamics",))
        for kind, s in (("multilevel", 3), ("novel", 4)))]
    d = diagnose(identify(ident), novel)
    top = d.top
    assert top is not None and top.effect == "position_dependent_reflex_dynamics"
    delay = next(c for c in d.candidates if c.effect == "position_dependent_reflex_delay")
    assert top.vaf_gain > delay.vaf_gain + 0.2 and not top.tied_with
