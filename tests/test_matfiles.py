"""The lab's MATLAB files: nldat class objects, structs, matrices, -v7.3; choosing channels.

Every file here is written by the test (tests/matlab_files.py); none needs ../shared/real/
(the one check of the real file skips when it is absent).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from matlab_files import nldat, write_mat, write_v73_plain

from lpvpc.cli import main
from lpvpc.io import (
    load_identification_data,
    load_perturbation_file,
    load_trial,
    pair_trials,
)
from lpvpc.errors import DataError
from lpvpc.io.matfiles import read_mat
from lpvpc.models.model import LPVPCModel

FS = 1000.0


def _real_file(name="experimental_data.mat"):
    """The lab's recording, if present: $LPVPC_REAL_DATA or shared/real next to the checkout."""
    root = Path(__file__).resolve().parents[1]
    folders = [Path(os.environ["LPVPC_REAL_DATA"])] if os.environ.get("LPVPC_REAL_DATA") else []
    folders += [root.parent / "shared" / "real", root.parent.parent / "shared" / "real"]
    return next((f / name for f in folders if (f / name).is_file()), Path("absent") / name)


REAL = _real_file()


def stationary_trial(seed, op=0.15, n=3000):
    """Position (rad) around one operating position and a torque (N m) answering it."""
    rng = np.random.default_rng(seed)
    pert = 0.03 * np.sign(np.sin(2 * np.pi * np.cumsum(rng.uniform(0, 8, n)) / FS))
    pos = op + pert
    tq = -3.0 + 40.0 * pert + 0.05 * rng.standard_normal(n)
    return np.column_stack([pos, tq])


def _one_error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lpvpc: error: "), err
    return err[0]


@pytest.fixture
def lab_file(tmp_path):
    """Like the lab's experimental_data.mat: two nldat objects (pos1, tq1) at 1 kHz."""
    trials = {"z_df": stationary_trial(0, 0.15), "z_pf": stationary_trial(1, 0.075)}
    path = write_mat(tmp_path / "experimental.mat", {k: nldat(v, ["pos1", "tq1"], 1 / FS) for k, v in trials.items()})
    return path, trials


# --------------------------------------------------------------------------- nldat objects


@pytest.mark.parametrize("style", ["classdef", "oldstyle"])
@pytest.mark.parametrize("version", ["v7", "v7.3"])
def test_nldat_trial_read_by_variable(tmp_path, style, version):
    x = stationary_trial(2)
    path = write_mat(tmp_path / "z.mat", {"z_df": nldat(x, ["pos1", "tq1"], 1 / FS, start=2.0, style=style),
                                          "z_pf": nldat(x[::-1], ["pos1", "tq1"], 1 / FS, style=style)},
                     version=version)
    trial = load_trial(path, variable="z_df")
    np.testing.assert_array_equal(trial.position, x[:, 0])
    np.testing.assert_array_equal(trial.torque, x[:, 1])
    np.testing.assert_allclose(trial.time, 2.0 + np.arange(len(x)) / FS, rtol=0, atol=1e-12)  # domainStart, domainIncr
    assert trial.fs == pytest.approx(FS)
    assert trial.name == "z:z_df"
    # the variable can be named with the path too
    np.testing.assert_array_equal(load_trial(f"{path}:z_pf").position, x[::-1, 0])


def test_several_variables_are_an_error_listing_them(lab_file):
    path, _ = lab_file
    with pytest.raises(DataError) as err:
        load_trial(path)
    msg = str(err.value)
    assert "ambiguous torque channel: z_df.tq1, z_pf.tq1" in msg and "variable=NAME" in msg
    assert "z_df (nldat, 3000 samples at 1000 Hz: pos1, tq1)" in msg
    assert "z_pf (nldat, 3000 samples at 1000 Hz: pos1, tq1)" in msg
    with pytest.raises(DataError, match=r"no variable 'z_xx' with channels \(found: z_df"):
        load_trial(path, variable="z_xx")


def test_stationary_trial_without_ut(lab_file):
    """A perturbed trial around one operating position, no UT: perturbation = position minus
    its mean, torque minus its mean, scheduling = the mean (the operating point)."""
    path, trials = lab_file
    x = trials["z_pf"]
    data = load_identification_data(pt=path, variable="z_pf", stationary=True, target_fs=None)
    op = x[:, 0].mean()
    np.testing.assert_allclose(data.scheduling, op, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data.position, x[:, 0] - op, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data.torque, x[:, 1] - x[:, 1].mean(), rtol=0, atol=1e-12)
    assert data.meta["stationary"] and data.meta["operating_point"] == pytest.approx(op)
    assert data.meta["torque_offset"] == pytest.approx(x[:, 1].mean())
    low = load_identification_data(pt=f"{path}:z_pf", stationary=True)  # decimated to 100 Hz
    assert low.fs == 100.0 and low.n == 300
    np.testing.assert_allclose(low.scheduling, op, rtol=0, atol=1e-12)
    with pytest.raises(DataError, match="give pt alone"):
        load_identification_data(pt=path, ut=path, variable="z_pf", stationary=True)


def test_moving_trial_is_not_read_as_stationary(tmp_path):
    x = stationary_trial(10, n=6000)
    x[:, 0] += 0.3 * np.sin(2 * np.pi * np.arange(6000) / 6000)  # a slow movement of +-0.3 rad
    path = write_mat(tmp_path / "moving.mat", {"z": nldat(x, ["pos1", "tq1"], 1 / FS)})
    with pytest.raises(DataError, match=r"not a stationary trial: its 2-s mean position spans 0\.[45]\d\d rad "
                                        r"\(more than 0\.1 rad"):
        load_identification_data(pt=path, stationary=True)


def test_pilot_format_perturbation_file_equals_csv(tmp_path):
    """The pilot trial's format: nldat 'io' (posPert1, tqPert1: PT - UT) and 'sv' (the
    scheduling position), found without options; the same data as a CSV file."""
    rng = np.random.default_rng(3)
    n = 4000
    t = np.arange(n) / FS
    sv = -0.41 + 0.06 * np.floor(t / 0.5)
    pos = 0.03 * np.sign(rng.standard_normal(n)).cumsum() / 50
    tq = 30 * pos + 0.1 * rng.standard_normal(n)
    mat = write_mat(tmp_path / "pilot.mat", {"io": nldat(np.column_stack([pos, tq]), ["posPert1", "tqPert1"], 1 / FS),
                                             "sv": nldat(sv[:, None], ["Ankle Position (rad)"], 1 / FS)})
    csv = tmp_path / "pilot.csv"
    np.savetxt(csv, np.column_stack([t, pos, tq, sv]), delimiter=",", header="time,position,torque,scheduling",
               comments="", fmt="%.17g")
    a, b = load_perturbation_file(mat), load_perturbation_file(csv)
    assert a.fs == b.fs == 100.0
    assert a.data_hash == b.data_hash
    # explicit names give the same
    c = load_identification_data(data=mat, channels={"position": "io.posPert1", "torque": "tqPert1",
                                                     "scheduling": "sv.Ankle Position (rad)"})
    assert c.data_hash == a.data_hash


def test_cell_of_nldat_trials_as_several_trials(tmp_path):
    """Trials kept as a cell array of nldat objects (or an object array): each is a variable
    trials{k} (trials(k)); a list of them is one joint identification's data."""
    xs = [stationary_trial(8, 0.1), stationary_trial(9, 0.1, n=2000)]
    cell = np.empty((1, 2), dtype=object)
    cell[0, 0], cell[0, 1] = (nldat(x, ["pos1", "tq1"], 1 / FS) for x in xs)
    path = write_mat(tmp_path / "cell.mat", {"trials": cell})
    assert [r.name for r in read_mat(path)] == ["trials{1}", "trials{2}"]
    joint = load_identification_data(pt=[f"{path}:trials{{1}}", f"{path}:trials{{2}}"], stationary=True)
    assert joint.segments == ((0, 300), (300, 500))
    np.testing.assert_allclose(joint.scheduling[:300], xs[0][:, 0].mean(), atol=1e-12)
    np.testing.assert_allclose(joint.scheduling[300:], xs[1][:, 0].mean(), atol=1e-12)


# --------------------------------------------------------------------------- plain arrays, structs, v7.3


def test_v73_plain_file_written_from_the_format(tmp_path):
    rng = np.random.default_rng(4)
    t = np.arange(500) / FS
    pos, tq = 0.02 * rng.standard_normal(500), rng.standard_normal(500)
    path = write_v73_plain(tmp_path / "t73.mat", {"time": t, "position": pos, "torque": tq, "notes": [1.0]})
    trial = load_trial(path)
    np.testing.assert_array_equal(trial.position, pos)
    np.testing.assert_array_equal(trial.torque, tq)
    np.testing.assert_array_equal(trial.time, t)


def test_struct_with_rate_and_matrix_columns(tmp_path):
    rng = np.random.default_rng(5)
    n = 400
    pos, tq = 0.02 * rng.standard_normal(n), rng.standard_normal(n)
    path = write_mat(tmp_path / "s.mat", {"trial": {"ankle_angle": pos, "tq": tq, "fs": 500.0},
                                          "M": np.column_stack([np.arange(n) / 500.0, pos, tq])})
    trial = load_trial(path, variable="trial")  # names containing angle / tq; time from fs
    np.testing.assert_array_equal(trial.position, pos)
    assert trial.fs == pytest.approx(500.0)
    by_column = load_trial(path, variable="M", channels={"time": "1", "position": "2", "torque": "3"})
    np.testing.assert_array_equal(by_column.torque, tq)
    with pytest.raises(DataError, match=r"no time: no 'time' channel and no sample period in M"):
        load_trial(path, variable="M", channels={"position": "2", "torque": "3"})


def test_ambiguous_channels_within_a_variable(tmp_path):
    x = stationary_trial(6)
    path = write_mat(tmp_path / "a.mat", {"z": nldat(np.column_stack([x, x[:, 0]]), ["pos1", "tq1", "pos2"], 1 / FS)})
    with pytest.raises(DataError, match=r"ambiguous position channel: z\.pos1, z\.pos2; name it with "
                                        r"channels=\{'position': NAME\} \(--channel position=NAME\) \(found: z \(nldat"):
        load_trial(path)
    np.testing.assert_array_equal(load_trial(path, channels={"position": "pos2"}).position, x[:, 0])
    with pytest.raises(DataError, match=r"no channel 'pos9' for position \(found: z \(nldat, 3000 samples"):
        load_trial(path, channels={"position": "pos9"})
    with pytest.raises(DataError, match=r"unknown channel role\(s\) angle"):
        load_trial(path, channels={"angle": "pos1"})


def test_no_usable_channel(tmp_path):
    path = write_mat(tmp_path / "none.mat", {"note": "nothing here", "gain": 3.0})
    with pytest.raises(DataError, match=r"none\.mat: no usable channel: the file holds nothing readable"):
        load_trial(path)


def test_variables_of_another_rate_are_an_error(tmp_path):
    x = stationary_trial(7)
    path = write_mat(tmp_path / "r.mat", {"io": nldat(x, ["posPert1", "tqPert1"], 1 / FS),
                                          "sv": nldat(x[:, :1], ["Ankle Position (rad)"], 0.002)})
    with pytest.raises(DataError, match=r"the chosen variables differ in sampling rate: io 1000 Hz, sv 500 Hz"):
        load_perturbation_file(path)


# --------------------------------------------------------------------------- command line


def test_cli_reads_nldat_pairs_like_csv(tmp_path, capsys):
    """A PT/UT pair stored as nldat objects in one .mat file gives the same data as CSV files:
    predict prints the same VAF and data hash."""
    from lpvpc.identification.identify import identify
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=2, duration=40.0)
    mat = write_mat(tmp_path / "s1.mat", {
        name: nldat(np.column_stack([tr.position, tr.torque]), ["Ankle Position", "Ankle Torque"], 1 / FS)
        for name, tr in (("pt", pair.pt), ("ut", pair.ut))})
    model = identify(pair_trials(pair.pt, pair.ut), intrinsic_order=3)
    model.save(tmp_path / "m.json")
    from lpvpc.io import write_trial_csv

    write_trial_csv(pair.pt, tmp_path / "pt.csv")
    write_trial_csv(pair.ut, tmp_path / "ut.csv")
    outs = []
    for argv in (["--pt", f"{mat}:pt", "--ut", f"{mat}:ut"], ["--pt", tmp_path / "pt.csv", "--ut", tmp_path / "ut.csv"]):
        assert main(["predict", str(tmp_path / "m.json"), *map(str, argv), "--json", str(tmp_path / "x.json")]) == 0
        capsys.readouterr()
        import json

        outs.append(json.loads((tmp_path / "x.json").read_text()))
    assert outs[0]["vaf"] == pytest.approx(outs[1]["vaf"], abs=1e-6)
    assert outs[0]["n_samples"] == outs[1]["n_samples"]
    # without the variable, the file's two trials are ambiguous: one line, exit 2
    assert main(["predict", str(tmp_path / "m.json"), "--pt", str(mat), "--ut", str(mat)]) == 2
    line = _one_error_line(capsys)
    assert "ambiguous torque channel: pt.Ankle Torque, ut.Ankle Torque" in line


@pytest.mark.parametrize("argv, expected", [
    (["--pt", "{none}", "--stationary"], "no usable channel"),
    (["--pt", "{lab}", "--stationary"], "ambiguous torque channel: z_df.tq1, z_pf.tq1"),
    (["--pt", "{lab}", "--stationary", "--variable", "z_df", "--channel", "torque=tq7"], "no channel 'tq7'"),
    (["--pt", "{lab}", "--stationary", "--channel", "torque"], "--channel: expected ROLE=NAME"),
    (["--pt", "{lab}", "--ut", "{lab}", "--stationary"], "--stationary reads one perturbed trial"),
    (["{lab}", "--pt", "{lab}", "--stationary"], "give either DATA or --pt and --ut, not both"),
    # a stationary trial read as a moving one: the error points to --stationary
    (["{lab}", "--variable", "z_df"], "no scheduling channel found in variable 'z_df'"),
    (["{lab}", "--variable", "z_df"], "read it as stationary (--stationary)"),  # the CLI names its option only
])
def test_cli_mat_errors_are_one_line(tmp_path, lab_file, capsys, argv, expected):
    none = write_mat(tmp_path / "none.mat", {"note": "nothing"})
    argv = [a.format(none=none, lab=lab_file[0]) for a in argv]
    assert main(["identify", *argv, "-o", str(tmp_path / "m.json")]) == 2
    assert expected in _one_error_line(capsys)
    assert not (tmp_path / "m.json").exists()


def test_cli_reads_a_stationary_trial_given_as_data(tmp_path, lab_file, capsys):
    """`lpvpc identify FILE.mat --variable z_df --stationary` (the file as DATA) is the same
    identification as with --pt."""
    path, _ = lab_file
    for tag, argv in (("data", [str(path)]), ("pt", ["--pt", str(path)])):
        assert main(["identify", *argv, "--variable", "z_df", "--stationary", "-o", str(tmp_path / f"{tag}.json")]) == 0
    capsys.readouterr()
    a, b = (LPVPCModel.load(tmp_path / f"{t}.json") for t in ("data", "pt"))
    assert a.fit["vaf"] == b.fit["vaf"] and a.model_hash == b.model_hash


# --------------------------------------------------------------------------- the lab's real file


@pytest.mark.skipif(not REAL.is_file(), reason="the lab's experimental_data.mat not present ($LPVPC_REAL_DATA or ../shared/real)")
def test_real_lab_file_reads():
    """The lab's own file (when present): five nldat objects, 60,000 x (pos1, tq1) at 1 kHz."""
    records = {r.name: r for r in read_mat(REAL)}
    assert sorted(records) == sorted(["z_df", "z_pf", "z_df2", "z_df3", "z_pf2"])
    for r in records.values():
        assert r.kind == "nldat" and list(r.channels) == ["pos1", "tq1"] and r.n == 60000
        assert r.period == pytest.approx(1e-3)
    data = load_identification_data(pt=REAL, variable="z_df", stationary=True)
    assert data.n == 6000 and data.fs == 100.0
    assert 0.1 < data.meta["operating_point"] < 0.2  # about +0.15 rad
