"""Tests of lpvpc.io: loaders, checks, decimation, PT-UT pairing."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import scipy.io

from lpvpc.io import (
    PerturbationData,
    Trial,
    check_trial,
    decimate_trial,
    load_identification_data,
    load_perturbation_file,
    load_trial,
    pair_trials,
    write_perturbation_csv,
    write_trial_csv,
)
from lpvpc.errors import DataError, InsufficientExcitationError, UnitWarning

FS = 1000.0


def make_trials(seed=0, n=3000, fs=FS, emg=False):
    """A UT on a slow trajectory and a PT = UT + small random perturbation (rad, N m)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    ut_pos = -0.1 + 0.2 * np.sin(2 * np.pi * 0.2 * t)
    ut_tq = 2.0 + 5.0 * ut_pos + 0.01 * rng.standard_normal(n)
    pert = 0.03 * np.sin(2 * np.pi * 3.0 * t) + 0.01 * np.sin(2 * np.pi * 7.0 * t)
    pt_pos = ut_pos + pert
    pt_tq = ut_tq + 40.0 * pert + 0.01 * rng.standard_normal(n)
    ch = {"emg": np.abs(rng.standard_normal(n))} if emg else {}
    return Trial(t, pt_pos, pt_tq, ch, "pt"), Trial(t.copy(), ut_pos, ut_tq, {}, "ut"), pert


def simple_trial(n=200, fs=FS, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    return Trial(t, 0.1 * rng.standard_normal(n), rng.standard_normal(n), {}, "x")


def amplitude(x, f, fs):
    """Amplitude of the f Hz component of x by least squares on sin/cos."""
    t = np.arange(len(x)) / fs
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, x, rcond=None)
    return float(np.hypot(c[0], c[1]))


# --------------------------------------------------------------------------- round trips


def test_csv_round_trip(tmp_path):
    pt, _, _ = make_trials(emg=True)
    pt.channels["command"] = pt.position * 0.5
    path = tmp_path / "pt.csv"
    write_trial_csv(pt, path)
    back = load_trial(path)
    assert back.name == "pt"
    np.testing.assert_allclose(back.time, pt.time, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.position, pt.position, rtol=1e-9)
    np.testing.assert_allclose(back.torque, pt.torque, rtol=1e-9)
    assert set(back.channels) == {"emg", "command"}
    np.testing.assert_allclose(back.channels["emg"], pt.channels["emg"], rtol=1e-9)
    assert back.fs == pytest.approx(FS)


@pytest.mark.parametrize("orientation", ["row", "column"])
def test_mat_round_trip(tmp_path, orientation):
    pt, _, _ = make_trials()
    shape = (1, -1) if orientation == "row" else (-1, 1)
    path = tmp_path / "pt.mat"
    scipy.io.savemat(
        path,
        {
            "time": pt.time.reshape(shape),
            "position": pt.position.reshape(shape),
            "torque": pt.torque.reshape(shape),
            "scheduling": pt.position.reshape(shape),
            "subject_notes": np.array(["ignored"]),
        },
    )
    back = load_trial(path)
    np.testing.assert_array_equal(back.position, pt.position)
    np.testing.assert_array_equal(back.torque, pt.torque)
    np.testing.assert_array_equal(back.channels["scheduling"], pt.position)
    assert "subject_notes" not in back.channels


def test_mat_matrix_variable_rejected(tmp_path):
    path = tmp_path / "bad.mat"
    scipy.io.savemat(path, {"time": np.arange(10.0), "position": np.zeros((10, 2)), "torque": np.zeros(10)})
    with pytest.raises(DataError, match=r"no position channel .*position \(matrix, 10 samples: 1, 2\)"):
        load_trial(path)


def test_perturbation_csv_round_trip_is_exact(tmp_path):
    pt, ut, _ = make_trials(emg=True)
    data = pair_trials(pt, ut)
    path = tmp_path / "pert.csv"
    write_perturbation_csv(data, path)
    back = load_perturbation_file(path)
    assert back.fs == 100.0
    assert back.data_hash == data.data_hash
    np.testing.assert_array_equal(back.extra["emg"], data.extra["emg"])
    np.testing.assert_array_equal(back.time, data.time)


def test_perturbation_file_carries_both_trials_emg(tmp_path):
    """An extended model with background activation needs the UT trial's EMG too: a
    perturbation file written from a PT/UT pair keeps it (CSV and MAT)."""
    pt, ut, _ = make_trials(emg=True)
    ut.channels["emg"] = 2.0 + ut.position
    data = pair_trials(pt, ut)
    path = tmp_path / "pert.csv"
    write_perturbation_csv(data, path)
    assert path.read_text().splitlines()[1] == "time,position,torque,scheduling,emg,emg_ut"
    back = load_perturbation_file(path)
    for c in ("emg", "emg_ut"):
        np.testing.assert_array_equal(back.extra[c], data.extra[c])
    mat = tmp_path / "pert.mat"
    scipy.io.savemat(mat, {"time": data.time, "position": data.position, "torque": data.torque,
                           "scheduling": data.scheduling, "emg_ut": data.extra["emg_ut"], "notes": 1.0})
    back = load_perturbation_file(mat)
    np.testing.assert_array_equal(back.extra["emg_ut"], data.extra["emg_ut"])
    assert "emg" not in back.extra


def test_load_perturbation_file_decimates(tmp_path):
    pt, ut, pert = make_trials()
    path = tmp_path / "p.csv"
    cols = np.column_stack([pt.time, pert, pt.torque - ut.torque, ut.position])
    np.savetxt(path, cols, delimiter=",", header="time,position,torque,scheduling", comments="", fmt="%.17g")
    data = load_perturbation_file(path)
    assert data.fs == 100.0 and data.n == 300
    ref = pair_trials(pt, ut)
    np.testing.assert_allclose(data.position, ref.position, atol=1e-12)
    np.testing.assert_allclose(data.scheduling, ref.scheduling, atol=1e-12)


def test_perturbation_file_requires_scheduling(tmp_path):
    pt, _, _ = make_trials()
    path = tmp_path / "p.csv"
    write_trial_csv(pt, path)
    with pytest.raises(DataError) as err:
        load_perturbation_file(path)
    msg = str(err.value)
    # a single trial where PT - UT data are expected: what is missing and the fixes
    assert "no 'scheduling' column" in msg and "looks like one trial (time, position, torque)" in msg
    assert "pt=PT" in msg and "ut=UT" in msg and "stationary=True" in msg
    assert "channels={'scheduling': COLUMN}" in msg


# --------------------------------------------------------------------------- bad input


def test_nan_named_with_channel_index_and_count():
    tr = simple_trial()
    tr.torque[[17, 40, 41]] = np.nan
    with pytest.raises(DataError) as err:
        check_trial(tr)
    assert "channel 'torque': 3 NaN values, first at index 17" in str(err.value)


def test_inf_named():
    tr = simple_trial()
    tr.position[5] = -np.inf
    with pytest.raises(DataError, match=r"channel 'position': 1 inf value, first at index 5"):
        check_trial(tr)


def test_unequal_lengths_named():
    tr = simple_trial()
    tr.torque = tr.torque[:-3]
    with pytest.raises(DataError, match=r"unequal channel lengths: time 200, position 200, torque 197"):
        check_trial(tr)


def test_decreasing_time_named():
    tr = simple_trial()
    tr.time[50], tr.time[51] = tr.time[51], tr.time[50]
    with pytest.raises(DataError) as err:
        check_trial(tr)
    assert re.search(r"not strictly increasing, 1 step <= 0, first at index 51", str(err.value))


def test_uneven_time_named():
    tr = simple_trial()
    tr.time[120:] += 0.0005  # one step of 1.5 ms among 1 ms steps
    with pytest.raises(DataError) as err:
        check_trial(tr)
    msg = str(err.value)
    assert "uneven sampling, 1 step" in msg and "first at index 120" in msg


def test_small_jitter_accepted():
    tr = simple_trial()
    rng = np.random.default_rng(3)
    tr.time = tr.time + rng.uniform(-1e-7, 1e-7, tr.time.shape)  # 2e-4 of a step at most
    assert check_trial(tr) is tr


def test_rounded_or_jittering_time_stamps_read_as_uniform_with_a_warning(tmp_path):
    """A time column in single precision (60 s at 1 kHz: steps off by up to 0.4 %) or from a
    software clock (+-5 % of a step) over evenly clocked samples: read as uniform, said in a
    warning; a dropped sample stays an error."""
    from lpvpc.errors import LpvpcWarning

    n = 60000
    t = np.arange(n) / 1000.0
    x = 0.01 * np.sin(2 * np.pi * t)
    for stamps in (t.astype(np.float32).astype(float), t + np.random.default_rng(0).uniform(-5e-5, 5e-5, n)):
        path = tmp_path / "t.csv"
        write_trial_csv(Trial(stamps, x, 3 * x), path)
        with pytest.warns(LpvpcWarning, match=r"t\.csv: time stamps jitter by up to .* % of a step about a uniform "
                                              r"grid .*read as sampled uniformly at 1000 Hz"):
            trial = load_trial(path)
        assert trial.fs == pytest.approx(1000.0, rel=1e-6) and len(trial.time) == n
    dropped = np.delete(t, 30000)
    with pytest.raises(DataError, match="uneven sampling, 1 step"):
        check_trial(Trial(dropped, np.delete(x, 30000), np.delete(x, 30000)))


def test_too_few_samples():
    with pytest.raises(DataError, match=r"fewer than 2 samples \(1\)"):
        check_trial(Trial(np.array([0.0]), np.array([0.0]), np.array([0.0])))


def test_all_problems_listed_at_once():
    tr = simple_trial()
    tr.torque[3] = np.nan
    tr.position[7] = np.inf
    tr.time[9] = tr.time[8]
    with pytest.raises(DataError) as err:
        check_trial(tr, source="trial.csv")
    # the repeated time stamp is a zero step and the next one is a double step: both reported
    assert len(err.value.problems) == 4
    assert "not strictly increasing, 1 step <= 0, first at index 9" in str(err.value)
    assert "uneven sampling, 1 step" in str(err.value)
    assert str(err.value).startswith("trial.csv: ")


def test_nan_in_file_is_not_dropped(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("time,position,torque\n0,0,0\n0.001,nan,0\n0.002,0,0\n")
    with pytest.raises(DataError, match=r"t\.csv: channel 'position': 1 NaN value, first at index 1"):
        load_trial(path)


def test_missing_column(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("time,angle,torque\n0,0,0\n0.001,0,0\n")
    with pytest.raises(DataError, match=r"missing required column 'position' \(columns found: time, angle, torque\); "
                                        r"a column named otherwise is chosen with channels=\{'position': COLUMN\}"):
        load_trial(path)


def test_csv_columns_chosen_by_name(tmp_path):
    """A lab's own header: channels maps roles to its columns (case-insensitive); a column
    already named after a mapped role is not read."""
    path = tmp_path / "t.csv"
    path.write_text("Time (s),Position,Pert Angle (rad),Torque (N m)\n0,9,0.01,1\n0.001,9,0.02,2\n0.002,9,0.03,3\n")
    trial = load_trial(path, channels={"time": "time (s)", "position": "Pert Angle (rad)", "torque": "TORQUE (N M)"})
    np.testing.assert_array_equal(trial.position, [0.01, 0.02, 0.03])
    np.testing.assert_array_equal(trial.torque, [1, 2, 3])
    np.testing.assert_array_equal(trial.time, [0, 0.001, 0.002])
    for channels, message in (({"position": "pert angle"}, r"no column 'pert angle' for position \(columns found: "),
                              ({"angle": "pert angle (rad)"}, r"unknown channel role\(s\) angle"),
                              ({"position": "position", "torque": "Position"}, "two roles name the same column")):
        with pytest.raises(DataError, match=message):
            load_trial(path, channels=channels)
    with pytest.raises(DataError, match=r"a variable \(z_df\) names a variable in .mat files"):
        load_trial(path, variable="z_df")


def test_perturbation_csv_columns_chosen_by_name(tmp_path):
    """The one-file form (perturbation and scheduling) with the lab's own column names, as
    `lpvpc identify FILE.csv --channel ...` reads it."""
    pt, ut, _ = make_trials()
    ref = pair_trials(pt, ut)
    t = np.arange(ref.n) / ref.fs
    path = tmp_path / "own.csv"
    np.savetxt(path, np.column_stack([t, ref.scheduling, ref.torque, ref.position]), delimiter=",", comments="",
               header="Time (s),Ankle Angle (rad),Tq (N m),Perturbation (rad)")
    data = load_identification_data(data=path, channels={"time": "time (s)", "scheduling": "ankle angle (rad)",
                                                         "torque": "tq (n m)", "position": "perturbation (rad)"})
    np.testing.assert_allclose(data.position, ref.position, atol=1e-12)
    np.testing.assert_allclose(data.scheduling, ref.scheduling, atol=1e-12)
    np.testing.assert_allclose(data.torque, ref.torque, atol=1e-12)


def test_unparsable_value_located(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("time,position,torque\n0,0,0\n0.001,abc,0\n0.002,0,0\n")
    with pytest.raises(DataError, match=r"column 'position': 1 value not a number, first at line 3"):
        load_trial(path)


@pytest.mark.parametrize(
    "name, content, expected",
    [
        ("x.txt", "time\n", "unknown file extension '.txt'"),
        ("empty.csv", "", "empty file"),
        ("nothing.csv", None, "no such file"),
        ("junk.mat", "not a mat file", "cannot read MATLAB file"),
    ],
)
def test_unreadable_files_name_path(tmp_path, name, content, expected):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(DataError) as err:
        load_trial(path)
    assert expected in str(err.value) and str(path) in str(err.value)


def test_pt_ut_different_length():
    pt, ut, _ = make_trials()
    ut = Trial(ut.time[:-10], ut.position[:-10], ut.torque[:-10], {}, "ut")
    with pytest.raises(DataError, match=r"PT has 3000 samples, UT has 2990"):
        pair_trials(pt, ut)


def test_pt_ut_different_rate():
    pt, ut, _ = make_trials()
    ut = Trial(ut.time * 0.5, ut.position, ut.torque, {}, "ut")
    with pytest.raises(DataError, match=r"PT 1000 Hz, UT 2000 Hz"):
        pair_trials(pt, ut)


def test_problems_of_both_trials_collected():
    pt, ut, _ = make_trials()
    pt.torque[10] = np.nan
    ut.position[20] = np.inf
    with pytest.raises(DataError) as err:
        pair_trials(pt, ut)
    assert err.value.problems == [
        "PT: channel 'torque': 1 NaN value, first at index 10",
        "UT: channel 'position': 1 inf value, first at index 20",
    ]


def test_no_perturbation():
    _, ut, _ = make_trials()
    with pytest.raises(InsufficientExcitationError, match="no perturbation"):
        pair_trials(ut, ut)


def test_rate_below_target():
    pt, ut, _ = make_trials(fs=250.0)
    with pytest.raises(DataError, match="not an integer multiple"):  # decimation alone: integer factors
        decimate_trial(pt, 100.0)
    pt, ut, _ = make_trials(fs=50.0, n=300)
    with pytest.raises(DataError, match="below the target rate"):
        pair_trials(pt, ut, target_fs=100.0)
    kept = pair_trials(pt, ut, target_fs=None)
    assert kept.fs == pytest.approx(50.0) and kept.n == 300


def test_wrong_combinations():
    pt, ut, _ = make_trials()
    with pytest.raises(DataError, match="got pt$"):
        load_identification_data(pt=pt)
    with pytest.raises(DataError, match="got pt, ut, data"):
        load_identification_data(pt=pt, ut=ut, data="x.csv")
    with pytest.raises(DataError, match="got nothing"):
        load_identification_data()


# --------------------------------------------------------------------------- units and signs


def test_degrees_warning(tmp_path):
    pt, _, _ = make_trials()
    pt.position = np.degrees(pt.position)
    path = tmp_path / "deg.csv"
    write_trial_csv(pt, path)
    with pytest.warns(UnitWarning, match=r"channel 'position' looks like degrees \(max \|value\| 13\.75"):
        load_trial(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_trial(path, position_unit="deg")  # declared: no warning


def test_degree_conversion(tmp_path):
    pt, _, _ = make_trials()
    pt.channels["scheduling"] = pt.position.copy()
    deg = Trial(pt.time, np.degrees(pt.position), pt.torque, {"scheduling": np.degrees(pt.position)}, "d")
    path = tmp_path / "deg.csv"
    write_trial_csv(deg, path)
    back = load_trial(path, position_unit="deg")
    np.testing.assert_allclose(back.position, pt.position, atol=1e-9)
    np.testing.assert_allclose(back.channels["scheduling"], pt.position, atol=1e-9)
    np.testing.assert_allclose(back.torque, pt.torque, rtol=1e-9)  # torque untouched


def test_torque_sign(tmp_path):
    pt, ut, _ = make_trials()
    paths = []
    for tr in (pt, ut):
        paths.append(tmp_path / f"{tr.name}.csv")
        write_trial_csv(tr, paths[-1])
    back = load_trial(paths[0], torque_sign=-1.0)
    np.testing.assert_allclose(back.torque, -pt.torque, rtol=1e-9)
    plus = load_identification_data(pt=paths[0], ut=paths[1])
    minus = load_identification_data(pt=paths[0], ut=paths[1], torque_sign=-1)
    np.testing.assert_allclose(minus.torque, -plus.torque, atol=1e-12)
    np.testing.assert_allclose(minus.position, plus.position, atol=1e-12)
    assert minus.meta["torque_sign"] == -1.0
    with pytest.raises(ValueError, match="position_unit"):
        load_trial(paths[0], position_unit="grad")


# --------------------------------------------------------------------------- decimation and pairing


def test_decimation_keeps_passband_and_removes_alias():
    n = 20000
    t = np.arange(n) / FS
    slow = np.sin(2 * np.pi * 5.0 * t)
    tone = np.sin(2 * np.pi * 300.0 * t)  # aliases to 0 Hz at 100 Hz sampling
    tr = Trial(t, slow, tone, {"emg": slow + tone}, "dec")
    low = decimate_trial(tr, 100.0)
    assert len(low.time) == n // 10
    np.testing.assert_array_equal(low.time, t[::10])
    inner = slice(50, -50)  # away from the record's ends
    t_low = low.time[inner]
    assert amplitude(low.position[inner], 5.0, 100.0) == pytest.approx(1.0, abs=1e-3)
    # phase kept too: sample k is aligned with input sample 10 k
    np.testing.assert_allclose(low.position[inner], np.sin(2 * np.pi * 5.0 * t_low), atol=2e-3)
    # 300 Hz sampled every 10 ms is 0 Hz: without the anti-alias filter it would be a constant
    # equal to sin(phase) of each sample; the residual must stay below 1e-2 of the input.
    assert np.max(np.abs(low.torque[inner])) < 1e-2
    naive = tone[::10] + np.sin(2 * np.pi * 300.0 * 0.0005)  # check the test can fail: aliased offset
    assert np.max(np.abs(naive)) > 1e-2
    np.testing.assert_allclose(low.channels["emg"], low.position + low.torque, atol=1e-12)


def test_decimation_keeps_offset_at_the_ends():
    # A joint angle far from zero must not droop toward zero at the record's ends.
    t = np.arange(2000) / FS
    tr = Trial(t, np.full_like(t, -0.4), 0.01 * t, {}, "c")
    low = decimate_trial(tr, 100.0)
    np.testing.assert_allclose(low.position, -0.4, atol=1e-12)
    np.testing.assert_allclose(low.torque, 0.01 * low.time, atol=1e-12)


def test_decimation_in_stages():
    t = np.arange(20000) / 2000.0
    tr = Trial(t, np.sin(2 * np.pi * 2.0 * t), np.sin(2 * np.pi * 2.0 * t), {}, "s")
    low = decimate_trial(tr, 100.0)  # factor 20 > 13 -> stages 10 and 2
    assert len(low.time) == 1000
    np.testing.assert_allclose(low.position[20:-20], np.sin(2 * np.pi * 2.0 * low.time[20:-20]), atol=2e-3)


@pytest.mark.parametrize("fs_file, via", [(1024.0, 1000.0), (250.0, 200.0), (1111.0, 1100.0)])
def test_rate_not_a_multiple_of_the_model_rate_is_resampled(tmp_path, fs_file, via):
    """A 1024-Hz (or 250-Hz, 1111-Hz) recording reads with defaults: resampled to the
    largest multiple of 100 Hz below its rate, then decimated as usual; the perturbation
    keeps its amplitude and phase, and an alias above the model's Nyquist rate is removed."""
    n = int(30 * fs_file)
    t = np.arange(n) / fs_file
    ut_pos = -0.1 + 0.2 * np.sin(2 * np.pi * 0.2 * t)
    pert = 0.03 * np.sin(2 * np.pi * 3.0 * t)
    alias = 0.01 * np.sin(2 * np.pi * 0.7 * fs_file / 2 * t)  # above 50 Hz, below the file's Nyquist
    paths = [tmp_path / "pt.csv", tmp_path / "ut.csv"]
    write_trial_csv(Trial(t, ut_pos + pert, 40 * (pert + alias), {}, "pt"), paths[0])
    write_trial_csv(Trial(t, ut_pos, np.zeros(n), {}, "ut"), paths[1])
    data = load_identification_data(pt=paths[0], ut=paths[1])
    assert data.fs == 100.0 and data.meta["fs_original"] == pytest.approx(fs_file)
    assert data.meta["resampled_to"] == via and data.high_rate.fs == via
    assert data.n == pytest.approx(3000, abs=1) and data.high_rate.n == pytest.approx(30 * via, abs=1)
    tm = data.extra["time"]
    inner = slice(50, -50)
    np.testing.assert_allclose(data.position[inner], 0.03 * np.sin(2 * np.pi * 3.0 * tm[inner]), atol=2e-4)
    np.testing.assert_allclose(data.scheduling[inner], -0.1 + 0.2 * np.sin(2 * np.pi * 0.2 * tm[inner]), atol=2e-4)
    np.testing.assert_allclose(data.torque[inner], 40 * data.position[inner], atol=5e-3)  # the alias is gone
    # trials of different file rates stay an error, even though both reach 100 Hz
    other = tmp_path / "pt1k.csv", tmp_path / "ut1k.csv"
    pt, ut, _ = make_trials(n=30000)
    write_trial_csv(pt, other[0])
    write_trial_csv(ut, other[1])
    with pytest.raises(DataError, match="trials differ in sampling rate"):
        load_identification_data(pt=[paths[0], other[0]], ut=[paths[1], other[1]])


def test_pairing_gives_pt_minus_ut():
    pt, ut, pert = make_trials(emg=True)
    data = pair_trials(pt, ut, target_fs=None)
    assert data.fs == pytest.approx(FS) and data.n == 3000
    np.testing.assert_allclose(data.position, pert, atol=1e-12)
    np.testing.assert_allclose(data.torque, pt.torque - ut.torque, atol=1e-12)
    np.testing.assert_array_equal(data.scheduling, ut.position)
    np.testing.assert_array_equal(data.extra["emg"], pt.channels["emg"])

    low = pair_trials(pt, ut)
    assert low.fs == 100.0 and low.n == 300
    inner = slice(20, -20)
    np.testing.assert_allclose(low.position[inner], pert[::10][inner], atol=1e-3)
    np.testing.assert_allclose(low.scheduling[inner], ut.position[::10][inner], atol=1e-4)
    np.testing.assert_array_equal(low.time, pt.time[::10])
    # velocity of the UT position, rad/s
    true_vel = 0.2 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * low.time)
    np.testing.assert_allclose(low.extra["ut_velocity"][inner], true_vel[inner], atol=1e-3)
    assert low.meta["decimation"] == 10


def test_pairing_keeps_ut_emg_as_emg_ut():
    """The UT trial's EMG becomes extra['emg_ut'], decimated with the same filter as PT's."""
    pt, ut, _ = make_trials(emg=True)
    assert "emg_ut" not in pair_trials(pt, ut).extra  # UT without EMG: no emg_ut
    rng = np.random.default_rng(7)
    t = ut.time
    ut_emg = 0.3 + 0.2 * np.sin(2 * np.pi * 0.5 * t) + 0.1 * np.sin(2 * np.pi * 80.0 * t) \
        + 0.01 * np.abs(rng.standard_normal(len(t)))
    ut = Trial(ut.time, ut.position, ut.torque, {"emg": ut_emg}, "ut")

    full = pair_trials(pt, ut, target_fs=None)
    np.testing.assert_array_equal(full.extra["emg_ut"], ut_emg)
    np.testing.assert_array_equal(full.extra["emg"], pt.channels["emg"])

    low = pair_trials(pt, ut)
    assert low.n == 300 and len(low.extra["emg_ut"]) == low.n
    # the same anti-alias filter as every other channel: equal to decimating the UT trial
    ref = decimate_trial(ut, 100.0)
    np.testing.assert_allclose(low.extra["emg_ut"], ref.channels["emg"], atol=1e-12)
    np.testing.assert_allclose(low.extra["emg"], decimate_trial(pt, 100.0).channels["emg"], atol=1e-12)
    # the 80 Hz component (above the new 50 Hz Nyquist rate) is removed, the slow part kept
    inner = slice(20, -20)
    slow = 0.3 + 0.2 * np.sin(2 * np.pi * 0.5 * low.time)
    np.testing.assert_allclose(low.extra["emg_ut"][inner], slow[inner], atol=0.02)
    assert np.abs(low.extra["emg_ut"][inner] - ut_emg[::10][inner]).max() > 0.05
    # load_identification_data goes through the same pairing
    via = load_identification_data(pt=pt, ut=ut)
    np.testing.assert_array_equal(via.extra["emg_ut"], low.extra["emg_ut"])


def test_data_hash_deterministic_and_sensitive():
    pt, ut, _ = make_trials()
    a, b = pair_trials(pt, ut), pair_trials(pt, ut)
    assert a.data_hash == b.data_hash and len(a.data_hash) == 64
    c = PerturbationData(a.position.copy(), a.torque.copy(), a.scheduling.copy(), a.fs)
    assert c.data_hash == a.data_hash  # extra and source do not enter the hash
    c.torque[0] += 1e-12
    assert c.data_hash != a.data_hash
    d = PerturbationData(a.position, a.torque, a.scheduling, 200.0)
    assert d.data_hash != a.data_hash
    np.testing.assert_allclose(d.time, np.arange(a.n) / 200.0)


def test_perturbation_data_validates():
    with pytest.raises(DataError, match="unequal channel lengths"):
        PerturbationData(np.zeros(5), np.zeros(4), np.zeros(5), 100.0)
    with pytest.raises(DataError, match=r"'scheduling': 1 NaN value, first at index 2"):
        PerturbationData(np.zeros(5), np.zeros(5), np.array([0, 0, np.nan, 0, 0]), 100.0)


def test_segment():
    pt, ut, _ = make_trials()
    data = pair_trials(pt, ut)
    tail = data.segment(210)
    assert tail.n == 90
    np.testing.assert_array_equal(tail.position, data.position[210:])
    np.testing.assert_array_equal(tail.time, data.time[210:])


def test_identification_entry_point_with_trials_and_data(tmp_path):
    pt, ut, _ = make_trials()
    from_trials = load_identification_data(pt=pt, ut=ut)
    path = tmp_path / "p.csv"
    write_perturbation_csv(from_trials, path)
    from_file = load_identification_data(data=path)
    assert from_file.data_hash == from_trials.data_hash
    assert load_identification_data(data=from_trials) is from_trials
