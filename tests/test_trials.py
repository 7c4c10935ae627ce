"""Several trials in one identification: joined end to end, nothing crosses a seam."""

from __future__ import annotations

import numpy as np
import pytest

from lpvpc.models import equations as eq
from lpvpc.cli import main
from lpvpc.io import (
    PerturbationData,
    join_trials,
    load_identification_data,
    pair_trials,
    write_perturbation_csv,
)
from lpvpc.errors import DataError
from lpvpc.identification.identify import identify
from lpvpc.models.intrinsic import intrinsic_regressor
from lpvpc.models.model import LPVPCModel, vaf
from lpvpc.io.segments import Segments
from lpvpc.simulation.simulate import simulate_pair
from lpvpc.identification.subspace import hankel_rows, streamed_r


def _data(n, seed, fs=100.0):
    rng = np.random.default_rng(seed)
    return PerturbationData(0.02 * rng.standard_normal(n), rng.standard_normal(n),
                            np.linspace(-0.3, 0.1, n), fs, source=f"trial{seed}")


# --------------------------------------------------------------------------- the segments concept


def test_segments_must_tile_the_record():
    assert Segments((), 10).bounds == [(0, 10)]
    for bad in ([(0, 4), (5, 10)], [(0, 4), (4, 9)], [(1, 10)], [(0, 0), (0, 10)]):
        with pytest.raises(ValueError, match="do not tile"):
            Segments(bad, 10)
    with pytest.raises(ValueError, match="do not tile"):
        PerturbationData(np.zeros(10), np.zeros(10), np.zeros(10), 100.0, segments=((0, 4), (5, 10)))


def test_regressors_are_built_trial_by_trial():
    """Rows of the joint regressors are the rows each trial gives on its own: lags, velocities
    and the reflex delay never reach into the neighbouring trial."""
    a, b = _data(300, 1), _data(200, 2)
    joint = join_trials([a, b])
    assert joint.segments == ((0, 300), (300, 500))
    seg = Segments.of(joint, joint.n)
    lags = list(range(-3, 4))
    G = np.column_stack([np.ones(joint.n), joint.scheduling])
    Psi = seg.map(intrinsic_regressor, joint.position, G, lags=lags)
    np.testing.assert_array_equal(Psi[:300], intrinsic_regressor(a.position, G[:300], lags))
    np.testing.assert_array_equal(Psi[300:], intrinsic_regressor(b.position, G[300:], lags))
    dvel = seg.map(eq.delayed_velocity, joint.position, fs=100.0, delay=4)
    np.testing.assert_array_equal(dvel[300:], eq.delayed_velocity(b.position, 100.0, 4))
    # naive concatenation would reach across: the first rows of b differ
    assert not np.array_equal(intrinsic_regressor(joint.position, G, lags)[300:303], Psi[300:303])


def test_moesp_hankel_rows_stay_inside_trials():
    rng = np.random.default_rng(0)
    u, y = rng.standard_normal((90, 2)), rng.standard_normal(90)
    s = 3
    seg = Segments([(0, 40), (40, 90)], 90)
    R = streamed_r(u, u[:, :1], y, s, chunk=7, segments=seg)
    rows = np.vstack([hankel_rows(u[a:b], u[a:b, :1], y[a:b], 0, (b - a) - 2 * s + 1, s) for a, b in seg])
    assert len(rows) == 90 - 2 * (2 * s - 1)  # 2s - 1 rows fewer per trial, none spanning the seam
    np.testing.assert_allclose(np.abs(R), np.abs(np.linalg.qr(rows, mode="r")), atol=1e-12)


# --------------------------------------------------------------------------- joining and loading


def test_join_trials_checks_rate_and_conventions():
    a, b = _data(300, 1), _data(200, 2, fs=50.0)
    with pytest.raises(DataError, match=r"trials differ in sampling rate: trial 1 \(trial1\) 100 Hz, "
                                        r"trial 2 \(trial2\) 50 Hz; resample them to one rate"):
        join_trials([a, b])
    c = _data(200, 3)
    a.meta["torque_sign"], c.meta["torque_sign"] = 1.0, -1.0
    with pytest.raises(DataError, match="trials differ in torque_sign"):
        join_trials([a, c])
    c.meta["torque_sign"] = 1.0
    joint = join_trials([a, c])
    assert joint.data_hash != PerturbationData(joint.position, joint.torque, joint.scheduling, 100.0).data_hash
    half = joint.segment(250, 350)
    assert half.segments == ((0, 50), (50, 100))
    assert joint.segment(0, 300).segments == ()


def _write_pair(folder, stem, n, fs, seed, length_ut=None):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    ut = -0.1 + 0.2 * np.sin(2 * np.pi * 0.1 * t)
    pt = ut + 0.03 * np.sign(rng.standard_normal(n))
    paths = []
    for name, pos in (("PT", pt), ("UT", ut)):
        m = n if name == "PT" or length_ut is None else length_ut
        path = folder / f"{stem}_{name}.csv"
        np.savetxt(path, np.column_stack([t[:m], pos[:m], 40 * pos[:m] + rng.standard_normal(m)]), delimiter=",",
                   header="time,position,torque", comments="", fmt="%.10g")
        paths.append(path)
    return paths


def test_load_several_pairs(tmp_path):
    p1, u1 = _write_pair(tmp_path, "a", 3000, 1000.0, 1)
    p2, u2 = _write_pair(tmp_path, "b", 2000, 1000.0, 2)
    data = load_identification_data(pt=[p1, p2], ut=[u1, u2])
    assert data.segments == ((0, 300), (300, 500)) and data.fs == 100.0
    one = load_identification_data(pt=p2, ut=u2)
    np.testing.assert_array_equal(data.position[300:], one.position)
    with pytest.raises(DataError, match="2 PT trials but 1 UT trials"):
        load_identification_data(pt=[p1, p2], ut=[u1])


def test_cli_several_pairs_and_their_errors(tmp_path, capsys):
    pairs = [_write_pair(tmp_path, s, 3000, 1000.0, i) for i, s in enumerate("ab")]
    slow = _write_pair(tmp_path, "slow", 1500, 500.0, 5)
    short = _write_pair(tmp_path, "short", 3000, 1000.0, 6, length_ut=2990)
    out = tmp_path / "m.json"

    def run(*argv):
        status = main(["identify", *map(str, argv), "-o", str(out), "--irf-lags", "2", "--intrinsic-order", "1",
                       "--reflex-order", "0", "--velocity-order", "2", "--max-state-order", "2", "--horizon", "4"])
        return status, capsys.readouterr()

    status, res = run("--pt", pairs[0][0], "--ut", pairs[0][1], "--pt", pairs[1][0], "--ut", pairs[1][1])
    assert status == 0, res.err
    assert "2 trials, 600 samples" in res.out
    # the same trials as perturbation files (PT - UT formed), several DATA arguments
    files = []
    for i, (p, u) in enumerate(pairs):
        files.append(tmp_path / f"pert{i}.csv")
        write_perturbation_csv(load_identification_data(pt=p, ut=u), files[-1])
    first = LPVPCModel.load(out)
    status, res = run(*files)
    assert status == 0, res.err
    assert "2 trials, 600 samples" in res.out
    assert LPVPCModel.load(out).provenance["data_hash"] == first.provenance["data_hash"]
    for argv, expected in [
        (["--pt", pairs[0][0], "--ut", pairs[0][1], "--pt", slow[0], "--ut", slow[1]],
         "trials differ in sampling rate: trial 1 (PT=a_PT, UT=a_UT) 1000 Hz, trial 2 (PT=slow_PT, UT=slow_UT) 500 Hz"),
        (["--pt", pairs[0][0], "--ut", pairs[0][1], "--pt", short[0], "--ut", short[1]],
         "PT and UT differ in length: PT has 3000 samples, UT has 2990"),
        (["--pt", pairs[0][0], "--ut", pairs[0][1], "--pt", pairs[1][0]], "2 --pt but 1 --ut"),
    ]:
        out.unlink(missing_ok=True)
        status, res = run(*argv)
        lines = res.err.strip().splitlines()
        assert status == 2 and len(lines) == 1 and lines[0].startswith("lpvpc: error: "), res.err
        assert expected in lines[0]
        assert not out.exists()
    # an output path that is one of the trials' files is refused, whichever trial it is
    before = pairs[1][1].read_bytes()
    assert main(["identify", "--pt", str(pairs[0][0]), "--ut", str(pairs[0][1]), "--pt", str(pairs[1][0]),
                 "--ut", str(pairs[1][1]), "-o", str(pairs[1][1])]) == 2
    assert "is the input --ut #2" in capsys.readouterr().err
    assert pairs[1][1].read_bytes() == before


# --------------------------------------------------------------------------- joint identification


def _pieces(data, k):
    cuts = np.linspace(0, data.n, k + 1).astype(int)
    return [data.segment(a, b) for a, b in zip(cuts[:-1], cuts[1:])]


def test_order_of_trials_does_not_matter():
    """Nothing crosses a seam, so the joint problem is the sum of the trials' problems and
    the order of the trials does not change the model; put end to end naively, the same
    pieces give another model (the seams become jumps)."""
    pair = simulate_pair("multilevel", seed=4, duration=60.0)
    pieces = _pieces(pair_trials(pair.pt, pair.ut), 4)
    grid = np.linspace(-0.3, 0.1, 21)
    order = (2, 0, 3, 1)
    a = identify(pieces)  # a list of trials is joined
    b = identify(join_trials([pieces[i] for i in order]))
    Ka, Kb = a.elastic_stiffness(grid), b.elastic_stiffness(grid)
    assert a.fit["n_trials"] == 4 and a.state_order == b.state_order
    assert np.max(np.abs(Ka - Kb) / np.abs(Ka)) < 1e-4
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(a.A)), np.sort_complex(np.linalg.eigvals(b.A)),
                               atol=1e-4)

    def naive(ps):
        return identify(PerturbationData(*(np.concatenate([getattr(p, k) for p in ps])
                                           for k in ("position", "torque", "scheduling")), ps[0].fs))

    Kn = naive(pieces).elastic_stiffness(grid)
    Kn2 = naive([pieces[i] for i in order]).elastic_stiffness(grid)
    assert np.max(np.abs(Kn - Kn2) / np.abs(Kn)) > 1e-3  # the test could fail


@pytest.mark.slow
def test_two_halves_as_two_trials_match_the_whole_record(subject, model):
    """The session's 2-minute record fitted as two trials (its halves) gives the model of the
    whole record: novel-trajectory VAF and K(theta) agree."""
    ident, novel = subject["ident"], subject["novel"]
    halves = join_trials([ident.segment(0, ident.n // 2), ident.segment(ident.n // 2, None)])
    # the whole record's structure, given (the selection on the halves may choose a neighbouring
    # one: K then differed by 2.1 %); what is compared is fitting the same model trial by trial
    same = {**model.fit["structure_selection"]["chosen"], "state_order": model.state_order}
    joint = identify(halves, **same)
    grid = np.linspace(*np.percentile(ident.scheduling, [10, 90]), 41)
    K, K_whole = joint.elastic_stiffness(grid), model.elastic_stiffness(grid)

    def novel_vaf(m):
        return vaf(novel.torque, m.predict(novel.position, novel.scheduling, warn=False).total)

    assert abs(novel_vaf(joint) - novel_vaf(model)) < 0.15
    assert np.max(np.abs(K - K_whole) / np.abs(K_whole)) < 0.02


def test_diagnosis_refuses_joined_trials(model):
    from lpvpc.diagnosis.diagnose import diagnose

    joint = join_trials([_data(400, 1), _data(400, 2)])
    with pytest.raises(DataError, match="the diagnosis takes one trial; got 2 joined trials"):
        diagnose(model, joint)
