"""Effects chosen per record by the structure's cross-validation (issue 22, decision 1):
stress relaxation is an on/off candidate of the default selection. Chosen on a record of
the virtual subject that has it, not chosen on a clean one (moving and stationary
records); when chosen, the short-range and relaxed stiffness are in the identify summary,
the model file (round trip) and the validation report, each labelled, in N m/rad; a bad
``--allow-effect`` is one line and exit 2.

The records are the files a user would have: simulated, written as CSV by ``lpvpc
simulate`` and read by ``lpvpc identify``.
"""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from lpvpc.cli import main
from lpvpc.io import pair_trials, stationary_perturbation
from lpvpc.models.effects import RELAXED_LABEL, SHORT_RANGE_LABEL, relaxation_stiffnesses
from lpvpc.identification.identify import identify
from lpvpc.models.model import LPVPCModel
from lpvpc.models.modelfile import check_model_dict
from lpvpc.simulation.simulate import simulate_pair

EFFECT = "stress_relaxation"
SEED = 1  # a development seed (benchmarks/bench_effect_selection.py reports seeds 100-109)


def _quiet_identify(data, **settings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(data, **settings)


@pytest.fixture(scope="module")
def relaxation_run(tmp_path_factory):
    """``lpvpc simulate`` with stress relaxation, then ``lpvpc identify`` at defaults: (model
    path, identify's printed summary)."""
    folder = tmp_path_factory.mktemp("relaxation")
    sim = folder / "sim"
    assert main(["simulate", "--out", str(sim), "--seed", str(SEED), "--fs", "100", "--duration", "120",
                 "--effect", EFFECT, "-q"]) == 0
    out = folder / "model.json"
    proc = subprocess.run([sys.executable, "-m", "lpvpc.cli", "identify", "--pt", str(sim / "ident_PT.csv"),
                           "--ut", str(sim / "ident_UT.csv"), "-o", str(out)], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    return out, proc.stdout


def test_relaxation_chosen_on_a_record_with_it(relaxation_run):
    path, _ = relaxation_run
    model = LPVPCModel.load(path)
    entry = model.fit["structure_selection"]["effects"]
    assert entry["allowed"] == [EFFECT] and entry["chosen"] == [EFFECT]
    assert entry["cv"][EFFECT]["cv_vaf_on"] > entry["cv"][EFFECT]["cv_vaf_off"]
    assert [fe.name for fe in model.effects] == [EFFECT]
    # the torque relaxes: the relaxed stiffness is below the short-range one at every position
    # (the subject keeps 60 % of it)
    short, relaxed = relaxation_stiffnesses(model, np.linspace(*model.scheduling_range, 5))
    assert np.all(relaxed < short) and np.all(relaxed > 0.2 * short)


def test_relaxation_time_chosen_stored_and_exported(relaxation_run, tmp_path):
    """The relaxation's time is chosen per record from the grid (the subject's is 0.6 s; K
    trades with it), stored with the term, and the exported step averages over that time."""
    from lpvpc.export import exporter as export
    from lpvpc.models.effects import model_relaxation_times
    from lpvpc.identification.selection import RELAXATION_VARIANTS, variant_label
    from lpvpc.simulation.simulate import SubjectParams

    path, _ = relaxation_run
    model = LPVPCModel.load(path)
    entry = model.fit["structure_selection"]["effects"]
    times = model_relaxation_times(model)
    label = variant_label(times, model.effects[0].basis.order)
    assert entry["cv"][EFFECT]["variant"] == label
    assert set(entry["cv"][EFFECT]["variants"]) == {variant_label(t, o) for t, o in RELAXATION_VARIANTS}
    assert 0.3 <= times[0] <= 1.0 and len(times) == 1  # one time near the subject's 0.6 s
    # accuracy against the virtual subject: short-range K, and its interval carries the time's spread
    sim = simulate_pair("multilevel", seed=SEED, fs_out=100.0, effects=(EFFECT,))
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    K = SubjectParams().incremental_stiffness(rho, sim.truth["perturbation_amplitude"])
    # (the catalog's three times, forced: K worst -43 % on this seed, relaxed_stiffness_causes.txt; now 1-3 %)
    assert np.max(np.abs(model.elastic_stiffness(rho) / K - 1)) < 0.06
    k_lo, k_hi = model.elastic_stiffness_interval(rho)
    assert np.all((k_lo <= K) & (K <= k_hi))
    structures = model.uncertainty["structural"]["structures"]
    assert any(s["settings"].get(f"effect:{EFFECT}", label) != label for s in structures)
    # the CasADi step averages over the model's own time: it reproduces numpy's prediction
    import casadi

    n = 3000
    pos, sched = (np.asarray(sim.pt.position[:n]) - np.asarray(sim.ut.position[:n]),
                                 np.asarray(sim.ut.position[:n]))
    step = casadi.Function.load(str(export.export_casadi(model, tmp_path / "m.casadi", variant="exact")))
    out = export.trajectory_function(step, n)(state=np.zeros(step.size1_in("state")),
                                              **export.replay_inputs(model, pos, sched, "exact"))
    ref = model.predict(pos, sched, warn=False).total
    lat = export.latency_samples(model, "exact")
    tq = np.asarray(out["torque"]).ravel()
    if lat:
        tq, ref = tq[lat:], ref[:-lat]
    assert np.max(np.abs(tq - ref)) <= 1e-9 * np.max(np.abs(ref))
    assert f"relaxation_average[{times[0]:g} s]" in json.loads((tmp_path / "m.casadi.json").read_text())["state_layout"]


def test_forced_relaxation_chooses_its_term_unless_given():
    """Stress relaxation forced (effects=) keeps the structure as given, but its term is chosen
    like the selection's (the catalog's three times put K 8.5 % off on a relaxing subject,
    covered 30.6 %); a term given is kept as given."""
    from lpvpc.models.effects import model_relaxation_times
    from lpvpc.simulation.simulate import SubjectParams

    sim = simulate_pair("multilevel", seed=SEED, fs_out=100.0, effects=(EFFECT,))
    data = pair_trials(sim.pt, sim.ut)
    model = _quiet_identify(data, effects=(EFFECT,))
    entry = model.fit["structure_selection"]["relaxation_term"]
    assert entry["chosen"] == [EFFECT] and len(model_relaxation_times(model)) == 1
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    K = SubjectParams().incremental_stiffness(rho, sim.truth["perturbation_amplitude"])
    assert np.max(np.abs(model.elastic_stiffness(rho) / K - 1)) < 0.08  # (measured: worst -5.7 %)
    k_lo, k_hi = model.elastic_stiffness_interval(rho)
    assert np.all((k_lo <= K) & (K <= k_hi))
    given = _quiet_identify(data, effects=(EFFECT,), relaxation_times=(0.3, 1.0, 3.0), relaxation_order=1)
    assert model_relaxation_times(given) == (0.3, 1.0, 3.0) and "relaxation_term" not in given.fit["structure_selection"]


def test_summary_shows_both_stiffnesses_labelled(relaxation_run):
    _, out = relaxation_run
    lines = out.splitlines()
    short = [ln for ln in lines if SHORT_RANGE_LABEL in ln]
    relaxed = [ln for ln in lines if RELAXED_LABEL in ln]
    assert len(short) == len(relaxed) == 1
    assert short[0].rstrip().endswith("N m/rad") and relaxed[0].rstrip().endswith("N m/rad")
    assert any(ln.startswith("effects cv:") and f"{EFFECT} chosen" in ln for ln in lines)


def test_model_file_holds_both_stiffnesses_and_round_trips(relaxation_run, tmp_path):
    path, _ = relaxation_run
    d = json.loads(path.read_text())
    entry = d["fit"]["stiffness"]
    assert entry["short_range"]["label"] == SHORT_RANGE_LABEL and entry["relaxed"]["label"] == RELAXED_LABEL
    assert entry["short_range"]["unit"] == entry["relaxed"]["unit"] == "N m/rad"
    model = LPVPCModel.load(path)
    short, relaxed = relaxation_stiffnesses(model, np.array(entry["scheduling"]))
    assert np.allclose(entry["short_range"]["values"], short) and np.allclose(entry["relaxed"]["values"], relaxed)
    again = tmp_path / "again.json"
    model.save(again)
    assert json.loads(again.read_text())["fit"]["stiffness"] == entry
    assert LPVPCModel.load(again).to_dict() == model.to_dict()
    # a file whose entry is broken is refused, naming the entry
    bad = json.loads(path.read_text())
    bad["fit"]["stiffness"]["relaxed"]["values"] = bad["fit"]["stiffness"]["relaxed"]["values"][:-1]
    with pytest.raises(Exception, match="fit.stiffness.relaxed.values"):
        check_model_dict(bad)
    bad = json.loads(path.read_text())
    bad["fit"]["stiffness"]["short_range"]["unit"] = "N m/deg"
    with pytest.raises(Exception, match="fit.stiffness.short_range.unit"):
        check_model_dict(bad)


def test_validation_report_table_shows_both_stiffnesses(relaxation_run):
    from lpvpc.validation.report import _physiology_table

    model = LPVPCModel.load(relaxation_run[0])
    html = _physiology_table(model)
    assert f"{SHORT_RANGE_LABEL}, K (N m/rad)" in html and f"{RELAXED_LABEL} (N m/rad)" in html


def test_diagnosis_report_table_is_the_validation_reports(relaxation_run, tmp_path):
    """The diagnosis report of a model with stress relaxation opens with the validation
    report's physiology table, both stiffnesses included (the two reports once built it each
    their own way, and only the validation report's had the relaxed stiffness)."""
    from lpvpc.validation.report import _physiology_parts

    path = relaxation_run[0]
    sim = path.parent / "sim"
    assert main(["diagnose", str(path), "--pt", str(sim / "novel_PT.csv"), "--ut", str(sim / "novel_UT.csv"),
                 "--report", str(tmp_path / "diagnosis"), "-q"]) == 0
    table = _physiology_parts(LPVPCModel.load(path))[0]
    assert f"{RELAXED_LABEL} (N m/rad)" in table
    assert table in (tmp_path / "diagnosis" / "report.html").read_text()


def test_not_chosen_on_a_clean_record():
    sim = simulate_pair("multilevel", seed=SEED, duration=120.0, fs_out=100.0)
    model = _quiet_identify(pair_trials(sim.pt, sim.ut))
    assert model.fit["structure_selection"]["effects"]["chosen"] == []
    assert not model.effects and "stiffness" not in model.fit
    assert model.uncertainty  # a model without the effect keeps its intervals


@pytest.mark.parametrize("effects, chosen", [((EFFECT,), [EFFECT]), ((), [])])
def test_stationary_trial_chooses_on_contiguous_blocks(effects, chosen):
    sim = simulate_pair("stationary", seed=SEED, duration=60.0, fs_out=100.0, effects=effects)
    model = _quiet_identify(stationary_perturbation(sim.pt))
    sel = model.fit["structure_selection"]
    assert sel["skipped"].startswith("stationary") and sel["effects"]["chosen"] == chosen
    if chosen:  # one operating position: one value each; the subject keeps 60 % (within 25 % of that)
        e = model.fit["stiffness"]
        ratio = e["relaxed"]["values"][0] / e["short_range"]["values"][0]
        assert len(e["scheduling"]) == 1 and 0.45 < ratio < 0.75


def test_allow_effects_off_and_structure_fixed_offer_nothing():
    sim = simulate_pair("stationary", seed=SEED, duration=60.0, fs_out=100.0, effects=(EFFECT,))
    data = stationary_perturbation(sim.pt)
    off = _quiet_identify(data, allow_effects=())
    assert not off.effects and "effects" not in off.fit["structure_selection"]
    fixed = _quiet_identify(data, structure="fixed")
    assert not fixed.effects and "structure_selection" not in fixed.fit
    forced = _quiet_identify(data, effects=(EFFECT,), allow_effects=())  # named by the user: always on
    assert [fe.name for fe in forced.effects] == [EFFECT] and "stiffness" in forced.fit


def test_python_bad_allowed_effect_is_a_clear_error():
    sim = simulate_pair("stationary", seed=SEED, duration=20.0, fs_out=100.0)
    data = stationary_perturbation(sim.pt)
    with pytest.raises(ValueError, match="unknown effect 'bogus'"):
        identify(data, allow_effects=("bogus",))
    with pytest.raises(ValueError, match="'drift' cannot be chosen by the cross-validation"):
        identify(data, allow_effects=("drift",))


@pytest.mark.parametrize("name, says", [("bogus", "unknown effect 'bogus'"),
                                        ("drift", "cannot be chosen by the cross-validation")])
def test_cli_bad_allowed_effect_is_one_line_exit_2(tmp_path, name, says):
    proc = subprocess.run([sys.executable, "-m", "lpvpc.cli", "identify", "--pt", str(tmp_path / "missing.csv"),
                           "--allow-effect", name, "-o", str(tmp_path / "m.json")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "m.json").exists()


def test_improve_keeps_the_effect_the_base_selection_chose():
    """``improve`` refits every step at the base model's chosen structure; an effect its
    selection switched on stays in every step (it had been dropped: two changes in one step)."""
    from lpvpc.diagnosis.improve import improve

    pairs = [pair_trials(*(lambda s: (s.pt, s.ut))(simulate_pair(kind, seed=s, duration=120.0, fs_out=100.0,
                                                                  effects=(EFFECT,))))
             for kind, s in (("multilevel", SEED), ("novel", SEED + 1))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ladder = improve(*pairs, max_steps=1)
    base = ladder.rungs[0]
    assert base.model.fit["structure_selection"]["effects"]["chosen"] == [EFFECT]
    assert base.effects == (EFFECT,) and base.label == f"base model + {EFFECT}"
    assert all(EFFECT in r.effects and EFFECT in [fe.name for fe in r.model.effects] for r in ladder.rungs)
    # with the term it chose (the catalog's, refitted in a later step, would change the base too)
    from lpvpc.models.effects import model_relaxation_times

    assert all(model_relaxation_times(r.model) == model_relaxation_times(base.model) for r in ladder.rungs)
    assert base.settings["relaxation_times"] == base.model.settings["relaxation_times"]
