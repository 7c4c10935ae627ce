"""Channel skew (issue 22): a torque channel recorded late is undone at the file's rate before
decimation, estimated from the record (none on the virtual subject, which has no skew; the
imposed skew when one channel of its 1 kHz record is shifted), recorded in the model
and reused by ``lpvpc predict``; bad values are one-line errors (CLI exit 2).

Real recordings are not needed (the pilot trial's figures are in benchmarks/results/real_pilot.txt).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dataclasses

from lpvpc.errors import DataError, LpvpcWarning
from lpvpc.identification.channel_skew import MIN_RESIDUAL_REDUCTION, estimate_channel_skew, load_aligned
from lpvpc.cli import main as cli_main
from lpvpc.io import load_identification_data, pair_trials
from lpvpc.models.model import LPVPCModel, vaf
from lpvpc.simulation.simulate import simulate_pair
from lpvpc.io.trial import Trial

REPO = Path(__file__).resolve().parents[1]


def shifted(trial, n=1, channel="torque"):
    """``trial`` (1 kHz) with one channel written ``n`` samples late (its first value held)."""
    x = getattr(trial, channel)
    late = np.r_[np.full(n, x[0]), x[:-n]]
    return Trial(trial.time, late if channel == "position" else trial.position,
                 late if channel == "torque" else trial.torque, dict(trial.channels), trial.name)


@pytest.fixture(scope="module")
def subject():
    return simulate_pair("multilevel", seed=0, duration=60.0)  # 1 kHz trials, no skew


def test_skew_is_undone_at_the_file_rate_before_decimation(subject):
    """channel_skew=1 ms delays the 1 kHz position channels by one whole sample before the
    decimation: the same data as files whose position was written 1 ms late; 0 changes nothing."""
    pt, ut = subject.pt, subject.ut
    aligned = pair_trials(pt, ut, channel_skew=1e-3)
    by_hand = pair_trials(shifted(pt, channel="position"), shifted(ut, channel="position"))
    assert np.allclose(aligned.position, by_hand.position, rtol=0, atol=1e-12)
    assert np.allclose(aligned.scheduling, by_hand.scheduling, rtol=0, atol=1e-12)
    assert np.array_equal(aligned.torque, by_hand.torque)
    assert np.allclose(aligned.high_rate.position, by_hand.high_rate.position, rtol=0, atol=1e-12)
    assert aligned.meta["channel_skew_s"] == 1e-3
    plain, zero = pair_trials(pt, ut), pair_trials(pt, ut, channel_skew=0.0)
    assert np.array_equal(plain.position, zero.position) and "channel_skew_s" not in zero.meta
    # a fraction of a model sample is a real change at 100 Hz (not rounded away)
    assert np.max(np.abs(aligned.position - plain.position)) > 0.05 * np.std(np.diff(plain.position))


@pytest.mark.parametrize("value, words", [(0.5, r"within \+-0\.02 s"), (float("nan"), "finite"),
                                          ("soon", "give seconds"), ("auto", "load_aligned")])
def test_bad_channel_skew_is_named(subject, value, words):
    with pytest.raises(ValueError, match=words):
        load_identification_data(pt=subject.pt, ut=subject.ut, channel_skew=value)
    with pytest.raises(ValueError, match=words):
        pair_trials(subject.pt, subject.ut, channel_skew=value)


@pytest.mark.slow
def test_estimate_recovers_a_simulated_skew_and_finds_none_without_one(subject):
    """The virtual subject's 1 kHz torque written 1 ms late (one sample): the estimate recovers
    the skew and lining up removes well over MIN_RESIDUAL_REDUCTION of the residual; on the
    record as simulated the reduction stays below it, so "auto" changes nothing."""
    late = estimate_channel_skew(pair_trials(shifted(subject.pt), shifted(subject.ut)))
    clean = estimate_channel_skew(pair_trials(subject.pt, subject.ut))
    print(f"torque 1 ms late: estimate {late.delay * 1e3:.2f} ms, residual reduction {100 * late.residual_reduction:.1f} %;"
          f" no skew: {clean.delay * 1e3:.2f} ms, {100 * clean.residual_reduction:.2f} %")
    assert abs(late.delay - 1e-3) < 0.5e-3 and late.chosen == late.delay
    assert late.residual_reduction > 2 * MIN_RESIDUAL_REDUCTION
    assert clean.residual_reduction < 0.5 * MIN_RESIDUAL_REDUCTION and clean.chosen == 0.0
    # "auto" on the skew-free files: the same data as no alignment at all
    auto = load_aligned(pt=subject.pt, ut=subject.ut, channel_skew="auto")
    plain = load_identification_data(pt=subject.pt, ut=subject.ut)
    assert np.array_equal(auto.position, plain.position) and "channel_skew_s" not in auto.meta
    assert auto.meta["channel_skew_choice"]["chosen_s"] == 0.0


def _subprocess(*argv):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=True, text=True,
                          env=env, timeout=300)


def test_model_records_the_skew_and_predict_reuses_it(subject, tmp_path):
    """lpvpc identify --channel-skew-ms 1: the model records 1 ms; lpvpc predict (and validate's
    loader) load new files with it (the same VAF as the library on data loaded with channel_skew=1 ms)."""
    d = tmp_path

    def main(argv):
        return cli_main([str(a) for a in argv])

    assert main(["simulate", "--out", str(d / "data"), "--seed", "0", "--duration", "40"]) == 0
    pt, ut = d / "data" / "ident_PT.csv", d / "data" / "ident_UT.csv"
    assert main(["identify", "--pt", pt, "--ut", ut, "-o", d / "m.json", "--channel-skew-ms", "1",
                 "--structure", "fixed"]) == 0
    model = LPVPCModel.load(d / "m.json")
    assert model.conventions["channel_skew_s"] == pytest.approx(1e-3)
    npt, nut = d / "data" / "novel_PT.csv", d / "data" / "novel_UT.csv"
    assert main(["predict", d / "m.json", "--pt", npt, "--ut", nut, "--json", d / "p.json"]) == 0
    data = load_identification_data(pt=npt, ut=nut, channel_skew=1e-3)
    expected = vaf(data.torque, model.predict(data, warn=False).total)
    assert json.loads((d / "p.json").read_text())["vaf"] == pytest.approx(expected, abs=1e-9)
    # the files loaded without a skew: the model lines them up itself (the same torque), and
    # data built in memory, which cannot be read again, are predicted as they are, with a warning
    raw = load_identification_data(pt=npt, ut=nut)
    assert np.array_equal(model.predict(raw).total, model.predict(data, warn=False).total)
    with pytest.warns(LpvpcWarning, match="lined up by 0.00 ms"):
        unaligned = model.predict(dataclasses.replace(raw, origin=None)).total
    assert not np.allclose(unaligned, model.predict(data, warn=False).total)
    with pytest.raises(DataError, match="channel skew"):  # another skew given explicitly: refused
        model.predict(load_identification_data(pt=npt, ut=nut, channel_skew=0.0))
    from lpvpc.validation.harness import load_record  # validate's loading: the same alignment

    assert np.array_equal(load_record(model, npt, nut).measured.position, data.position)
    # the validation report says the records were lined up, before any figure
    assert main(["validate", d / "m.json", "--pt", npt, "--ut", nut, "--report", d / "report"]) == 0
    html = (d / "report" / "report.html").read_text()
    assert "Channel skew: the rig's torque channel lags its position channel by 1.00 ms" in html
    assert "<details" in html and html.index("Channel skew") > html.index("<details")  # in the folded details


@pytest.mark.parametrize("value", ["25", "abc", "nan"])
def test_cli_bad_skew_is_one_line_exit_2(tmp_path, value):
    r = _subprocess("identify", "x.csv", "-o", tmp_path / "m.json", "--channel-skew-ms", value)
    lines = [ln for ln in r.stderr.strip().splitlines() if not ln.startswith("lpvpc: [")]
    assert r.returncode == 2 and len(lines) == 1 and "--channel-skew-ms" in lines[0], r.stderr


def test_load_aligned_passes_a_given_skew_through(subject):
    a = load_aligned(pt=subject.pt, ut=subject.ut, channel_skew=1e-3)
    b = load_identification_data(pt=subject.pt, ut=subject.ut, channel_skew=1e-3)
    assert np.array_equal(a.position, b.position) and a.meta["channel_skew_s"] == 1e-3


@pytest.fixture(scope="module")
def late_files(subject, tmp_path_factory):
    """The subject's 1 kHz trials written as CSV files with the torque channel one sample (1 ms) late."""
    from lpvpc.io import write_trial_csv

    d = tmp_path_factory.mktemp("late")
    for name, trial in (("PT", subject.pt), ("UT", subject.ut)):
        write_trial_csv(shifted(trial), d / f"{name}.csv")
    return d / "PT.csv", d / "UT.csv"


def test_identify_scans_its_record_and_lines_up_a_late_torque(subject, late_files):
    """Every identify scans its own record (one regressor, the model's structure and reflex
    dynamics held). Files loaded without a skew: the 1 ms late torque is found, the files read
    again lined up and the model fitted again, the same model as from files loaded with that
    skew; a skew given explicitly is kept, with a warning naming the fix; the record as
    simulated shows none and gets no warning."""
    import warnings

    from lpvpc.errors import LpvpcWarning
    from lpvpc.identification.identify import identify

    late = load_identification_data(pt=late_files[0], ut=late_files[1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = identify(late)
    assert not [w for w in caught if "lags the position channel" in str(w.message)]
    found = m.fit["channel_skew"]
    print(f"late: {found['estimate_s'] * 1e3:.2f} ms, {100 * found['residual_reduction']:.1f} %")
    assert 0.5e-3 < found["chosen_s"] < 2e-3 and found["residual_reduction"] > 1.5 * MIN_RESIDUAL_REDUCTION
    assert m.conventions["channel_skew_s"] == found["chosen_s"]
    aligned = load_identification_data(pt=late_files[0], ut=late_files[1], channel_skew=found["chosen_s"])
    m_aligned = identify(aligned)
    rho = np.linspace(*m.scheduling_range, 7)
    assert np.array_equal(m.elastic_stiffness(rho), m_aligned.elastic_stiffness(rho))
    assert m.fit["vaf"] == m_aligned.fit["vaf"]
    assert np.array_equal(load_aligned(pt=late_files[0], ut=late_files[1]).position, aligned.position)
    # the skew given as none: kept, and the warning names the skew to load the files with
    with pytest.warns(LpvpcWarning, match=r"lags the position channel by about .* channel_skew="):
        m_late = identify(load_identification_data(pt=late_files[0], ut=late_files[1], channel_skew=0.0))
    assert "channel_skew_s" not in m_late.conventions
    assert m.fit["vaf"] > m_late.fit["vaf"] + 0.03
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        clean = identify(pair_trials(subject.pt, subject.ut))
    assert clean.fit["channel_skew"]["chosen_s"] == 0.0
    assert clean.fit["channel_skew"]["residual_reduction"] < 0.5 * MIN_RESIDUAL_REDUCTION
    assert not [w for w in caught if "lags the position channel" in str(w.message)]
    # predicting records not lined up like the model's: loaded files are lined up, data that
    # cannot be read again get a warning naming the skew to load them with
    assert np.array_equal(m.predict(late).total, m.predict(aligned).total)
    with pytest.warns(LpvpcWarning, match="channel_skew="):
        m.predict(dataclasses.replace(late, origin=None))
    with warnings.catch_warnings():
        warnings.simplefilter("error", LpvpcWarning)
        m.predict(aligned)


def test_the_scan_of_trials_joined_is_the_scan_of_the_whole_record():
    """Each trial's first and last samples, where the record-edge rules stand in, are left out
    of the scan: the same record cut into 4 trials scans like the whole record and, without a
    skew, finds none. (Kept, the trials' first samples read -1.2 ms as a skew here.)"""
    import warnings

    from lpvpc.io.identification_data import join_trials
    from lpvpc.identification.identify import identify
    from lpvpc.identification.skew_scan import scan_channel_skew

    sim = simulate_pair("multilevel", seed=4, duration=60.0)
    whole = pair_trials(sim.pt, sim.ut)
    cuts = np.linspace(0, whole.n, 5).astype(int)
    joined = join_trials([whole.segment(a, b) for a, b in zip(cuts[:-1], cuts[1:])])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(joined)
    a, b = scan_channel_skew(model, joined), scan_channel_skew(model, whole)
    assert abs(a.delay - b.delay) < 0.2e-3 and abs(a.residual_reduction - b.residual_reduction) < 0.005
    assert model.fit["channel_skew"]["chosen_s"] == 0.0 and a.chosen == 0.0


def test_a_peak_at_the_grid_end_is_no_skew():
    """A fit that still improves at the end of the candidates is a model mismatch, not a skew:
    nothing is chosen, however much of the residual the end removes."""
    from lpvpc.identification.channel_skew import ChannelSkew

    cand = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) * 1e-3
    rising = ChannelSkew(2e-3, cand, np.array([90.0, 91.0, 92.0, 93.0, 94.0]))
    peaked = ChannelSkew(1e-3, cand, np.array([90.0, 91.0, 92.0, 94.0, 93.0]))
    assert rising.residual_reduction > MIN_RESIDUAL_REDUCTION and rising.chosen == 0.0
    assert peaked.chosen == 1e-3


def test_cli_identify_lines_up_a_late_torque_by_default(late_files, tmp_path, capsys):
    """lpvpc identify (no --channel-skew-ms): the fit's scan finds the late torque, the files are
    reloaded lined up at 1 kHz and refitted, the model records the skew and the summary says so;
    --channel-skew-ms 0 keeps the record as it is."""
    pt, ut = late_files
    assert cli_main(["identify", "--pt", str(pt), "--ut", str(ut), "-o", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr()
    model = LPVPCModel.load(tmp_path / "m.json")
    assert 0.5e-3 < model.conventions["channel_skew_s"] < 2e-3
    assert "skew:        torque channel +" in out.out and "found by the fit's scan" in out.out
    assert "lags the position channel" not in out.err  # undone, so no advice to undo it
    assert cli_main(["identify", "--pt", str(pt), "--ut", str(ut), "-o", str(tmp_path / "m0.json"),
                     "--channel-skew-ms", "0"]) == 0
    assert "channel_skew_s" not in LPVPCModel.load(tmp_path / "m0.json").conventions
    assert "skew:        none applied (--channel-skew-ms 0); the fit's scan finds" in capsys.readouterr().out


def test_cli_improve_lines_up_both_records(late_files, tmp_path, capsys):
    """lpvpc improve finds the late torque on the identification record, as identify does, and
    lines up the held-out record by the same skew; its final model records it."""
    pt, ut = late_files
    assert cli_main(["improve", "--pt", str(pt), "--ut", str(ut), "--heldout-pt", str(pt), "--heldout-ut", str(ut),
                     "--report", str(tmp_path / "improve"), "--max-steps", "1", "-o", str(tmp_path / "f.json")]) == 0
    out = capsys.readouterr().out
    assert "skew:      torque channel +" in out and "lined up in both records" in out
    assert 0.5e-3 < LPVPCModel.load(tmp_path / "f.json").conventions["channel_skew_s"] < 2e-3


def test_stationary_records_and_models_with_effects_are_not_scanned(subject):
    """Where the scan's regressor is not the model's (a stationary trial's LTI fit, a model with
    an effect) it took the misfit for a skew on the virtual subject: those fits are not scanned."""
    import warnings

    from lpvpc.identification.identify import identify

    sim = simulate_pair("stationary", seed=0, duration=40.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        still = identify(load_identification_data(pt=sim.pt, stationary=True))
        extended = identify(pair_trials(subject.pt, subject.ut), effects=("nonlinear_viscosity",))
        plain = identify(pair_trials(subject.pt, subject.ut), structure="fixed")
    assert "channel_skew" not in still.fit and "channel_skew" not in extended.fit
    assert "channel_skew" in plain.fit  # (the same record without the effect is scanned)
