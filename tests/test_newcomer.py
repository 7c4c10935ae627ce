"""The mistakes a newcomer makes in the first hour (issue 25), each caught with the likely
cause and the fix in the interface's own syntax: command-line options on the command line,
keywords in Python. Where the input is refused, no model file is written.

The files are the virtual subject's trials written as CSV, changed the way a user's
files go wrong (degrees, a time column in ms, PT and UT swapped, EMG in mV).
"""

import csv
import warnings

import numpy as np
import pytest

from lpvpc.cli import main
from lpvpc.io import load_identification_data, load_trial, write_trial_csv
from lpvpc.errors import DataError, OutOfRangeWarning, UnitWarning
from lpvpc.simulation.simulate import simulate_pair

DURATION = 30.0  # s: enough to identify, quick


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def _error_line(err) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("lpvpc: error: ")]
    assert len(lines) == 1, err
    return lines[0]


def _rewrite(src, dst, column, f):
    """Copy a CSV with one column changed by ``f``."""
    with open(src, newline="") as fh:
        rows = list(csv.reader(fh))
    i = rows[0].index(column)
    for r in rows[1:]:
        r[i] = repr(float(f(float(r[i]))))
    with open(dst, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return dst


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("newcomer")
    sim = simulate_pair("multilevel", seed=3, duration=DURATION)
    pt, ut = d / "PT.csv", d / "UT.csv"
    write_trial_csv(sim.pt, pt)
    write_trial_csv(sim.ut, ut)
    out = {"dir": d, "pt": pt, "ut": ut}
    for key, column, f in (("deg", "position", np.degrees), ("ms", "time", lambda t: 1000.0 * t)):
        out[f"pt_{key}"] = _rewrite(pt, d / f"PT_{key}.csv", column, f)
        out[f"ut_{key}"] = _rewrite(ut, d / f"UT_{key}.csv", column, f)
    return out


def test_swapped_pt_and_ut_are_refused_naming_the_swap(files, capsys):
    model = files["dir"] / "swapped.json"
    status, _, err = _cli(["identify", "--pt", files["ut"], "--ut", files["pt"], "-o", model], capsys)
    line = _error_line(err)
    assert status == 2 and "PT and UT look swapped" in line and "swap the --pt and --ut files" in line
    assert not model.exists()
    with pytest.raises(DataError, match="swap the pt and ut arguments"):
        load_identification_data(pt=files["ut"], ut=files["pt"])
    assert load_identification_data(pt=files["pt"], ut=files["ut"]).n == DURATION * 100  # the right way round


def test_positions_in_degrees_are_refused_with_the_unit_option(files, capsys):
    model = files["dir"] / "deg.json"
    status, _, err = _cli(["identify", "--pt", files["pt_deg"], "--ut", files["ut_deg"], "-o", model], capsys)
    line = _error_line(err)
    assert status == 2 and "look like degrees" in line and "--position-unit deg" in line
    assert "position_unit" not in line  # the CLI speaks in options
    assert not model.exists()
    with pytest.raises(DataError, match="position_unit='deg'"):
        load_identification_data(pt=files["pt_deg"], ut=files["ut_deg"])
    status, _, _ = _cli(["identify", "--pt", files["pt_deg"], "--ut", files["ut_deg"], "-o", model,
                         "--position-unit", "deg"], capsys)
    assert status == 0 and model.exists()


def test_held_out_records_in_degrees_are_refused_by_validate_and_whole_joint(files, capsys):
    """A record in degrees read as rad gave validate a report with VAF -1.2e7 % and exit 0
    (only a warning): the commands that use a record against a model refuse it as identify does."""
    model = files["dir"] / "for_degrees.json"
    assert _cli(["identify", "--pt", files["pt"], "--ut", files["ut"], "-o", model, "-q"], capsys)[0] == 0
    report, whole = files["dir"] / "deg_report", files["dir"] / "deg_whole.json"
    for argv, out in ((["validate", model, "--pt", files["pt_deg"], "--ut", files["ut_deg"], "--report", report],
                       report),
                      (["whole-joint", model, "--ut", files["ut_deg"], "-o", whole], whole)):
        status, _, err = _cli(argv, capsys)
        line = _error_line(err)
        assert status == 2 and "look like degrees" in line and "--position-unit deg" in line, line
        assert not out.exists()
    status, _, _ = _cli(["whole-joint", model, "--ut", files["ut_deg"], "-o", whole, "--position-unit", "deg"],
                        capsys)
    assert status == 0 and whole.exists()
    with pytest.warns(UnitWarning, match="looks like degrees"):  # the plain loader still only warns
        load_trial(files["pt_deg"])


def test_time_in_milliseconds_is_refused_with_the_time_unit_option(files, capsys):
    model = files["dir"] / "ms.json"
    for extra in ([], ["--fs", "0"]):  # decimated to 100 Hz, or kept at the file's rate
        status, _, err = _cli(["identify", "--pt", files["pt_ms"], "--ut", files["ut_ms"], "-o", model, *extra],
                              capsys)
        line = _error_line(err)
        assert status == 2 and "looks like milliseconds" in line and "--time-unit ms" in line, line
        assert "target_fs" not in line
        assert not model.exists()
    with pytest.raises(DataError, match="time_unit='ms'"):
        load_identification_data(pt=files["pt_ms"], ut=files["ut_ms"])
    status, out, _ = _cli(["identify", "--pt", files["pt_ms"], "--ut", files["ut_ms"], "-o", model,
                           "--time-unit", "ms"], capsys)
    assert status == 0 and model.exists() and "decimated from 1000 Hz" in out
    ms = load_identification_data(pt=files["pt_ms"], ut=files["ut_ms"], time_unit="ms")
    assert ms.data_hash == load_identification_data(pt=files["pt"], ut=files["ut"]).data_hash


def test_forgotten_ut_names_stationary_and_a_trial_as_data_names_what_is_missing(files, capsys):
    model = files["dir"] / "missing.json"
    status, _, err = _cli(["identify", "--pt", files["pt"], "-o", model], capsys)
    line = _error_line(err)
    assert status == 2 and "missing --ut" in line and "--stationary" in line
    status, _, err = _cli(["identify", files["pt"], "-o", model], capsys)
    line = _error_line(err)
    assert status == 2 and "looks like one trial" in line
    assert "--pt PT" in line and "--ut UT" in line and "--stationary" in line
    assert not model.exists()


def test_emg_in_millivolts_for_a_model_fitted_in_volts_warns(tmp_path, capsys):
    """A model with an activation effect, fed EMG 1000 times the level it was fitted on."""
    volts = simulate_pair("multilevel", seed=4, duration=40.0, effects=("background_activation",))
    millivolts = simulate_pair("multilevel", seed=4, duration=40.0, effects=("background_activation",),
                               emg_unit="mV")
    paths = {}
    for label, sim in (("V", volts), ("mV", millivolts)):
        paths[label] = (tmp_path / f"PT_{label}.csv", tmp_path / f"UT_{label}.csv")
        write_trial_csv(sim.pt, paths[label][0])
        write_trial_csv(sim.ut, paths[label][1])
    model = tmp_path / "activation.json"
    assert _cli(["identify", "--pt", paths["V"][0], "--ut", paths["V"][1], "--effect", "background_activation",
                 "-o", model], capsys)[0] == 0
    status, _, err = _cli(["predict", model, "--pt", paths["V"][0], "--ut", paths["V"][1]], capsys)
    assert status == 0 and "times as large" not in err  # the unit it was fitted on: no warning
    status, _, err = _cli(["predict", model, "--pt", paths["mV"][0], "--ut", paths["mV"][1]], capsys)
    warning = [ln for ln in err.splitlines() if "times as large" in ln]
    assert status == 0 and len(warning) == 1 and warning[0].startswith("lpvpc: warning: ")
    assert "EMG in mV for V" in warning[0] and "unit of the identification data" in warning[0]
    assert "1e+03 times" in warning[0]  # the activation, 1000 times

    from lpvpc.models.model import LPVPCModel

    fitted = LPVPCModel.load(model)
    data = load_identification_data(pt=paths["mV"][0], ut=paths["mV"][1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        with pytest.warns(UnitWarning, match="far from their level at identification"):
            fitted.predict(data)


# --------------------------------------------------------------------------- progress


def test_validate_prints_its_first_progress_line_within_5_s(files, capsys):
    """``lpvpc validate`` (15-30 s) says what it does from the start: its stderr read line by
    line as the process runs."""
    import os
    import queue
    import subprocess
    import sys
    import threading
    import time
    from pathlib import Path

    model = files["dir"] / "progress.json"
    assert _cli(["identify", "--pt", files["pt"], "--ut", files["ut"], "-o", model], capsys)[0] == 0
    repo = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(repo) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "lpvpc.cli", "validate", str(model), "--pt", str(files["pt"]),
                             "--ut", str(files["ut"]), "--report", str(files["dir"] / "report")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    lines = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put((time.monotonic() - t0, ln)) for ln in proc.stderr],
                              daemon=True)
    reader.start()
    try:
        at, first = lines.get(timeout=30)
    finally:
        proc.terminate()  # the rest of the run is not this test's concern
        proc.wait(timeout=60)
    reader.join(timeout=10)
    assert first.startswith("lpvpc: [") and "validate:" in first, first
    assert at < 5.0, f"first progress line after {at:.1f} s"


def test_quiet_silences_the_progress_lines(files, capsys, monkeypatch):
    import lpvpc.cli.identify

    monkeypatch.setattr(lpvpc.cli.identify, "IDENTIFY_QUIET_S", 0.0)  # identify's line at once, as in a slow fit
    model = files["dir"] / "quiet.json"
    status, _, err = _cli(["identify", "--pt", files["pt"], "--ut", files["ut"], "-o", model], capsys)
    assert status == 0 and "] identify: fitting 3000 samples at 100 Hz" in err, err
    for argv in (["-q", "identify"], ["identify", "-q"], ["--quiet", "identify"]):
        status, out, err = _cli([*argv, "--pt", files["pt"], "--ut", files["ut"], "-o", model], capsys)
        assert status == 0 and "VAF:" in out and "lpvpc: [" not in err, err


def test_every_command_accepts_quiet_after_its_name():
    """``lpvpc simulate --out sim -q`` was an argparse error while ``identify -q`` worked."""
    from lpvpc.cli import build_parser

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert len(commands) >= 8
    for name in commands:
        assert "-q" in commands[name]._option_string_actions, name
    args = parser.parse_args(["simulate", "--out", "sim", "-q"])
    assert args.quiet is True


# --------------------------------------------------------------------------- reports


def _report_text(html: str) -> str:
    """The report's words (tags and embedded images removed)."""
    import re

    return re.sub(r"<[^>]+>", " ", re.sub(r'src="data:[^"]*"', "", html))


def test_improve_report_shows_the_physiology_of_each_step_and_no_repository_paths(tmp_path):
    from lpvpc.io import pair_trials
    from lpvpc.diagnosis.improve import improve, physiology, write_report

    ident, novel = (pair_trials(p.pt, p.ut) for p in (
        simulate_pair(kind, seed=s, duration=60.0, effects=("nonlinear_viscosity",))
        for kind, s in (("multilevel", 5), ("novel", 6))))
    ladder = improve(ident, novel, max_steps=1)
    assert len(ladder.rungs) >= 2, ladder
    page = write_report(ladder, novel, tmp_path / "imp").read_text()
    text = _report_text(page)
    from lpvpc.models.summary import summary_positions

    rho = summary_positions(ladder.rungs[0].model)  # the positions `lpvpc identify` prints
    for r in ladder.rungs:  # each model's K and reflex gain, as the model computes them
        k = physiology(r.model, rho)["K"]
        assert f"{k[2]:.1f}" in text
    assert "what it added" in text and "K (N m/rad)" in text and "reflex gain (N m s/rad)" in text
    assert "Step 0 -&gt; step 1: K" in page  # before and after the step
    md = (tmp_path / "imp" / "improve.md").read_text()
    assert "Step 0 -> step 1: K" in md and "| step | model |" in md
    for where in (page, md):
        assert "benchmarks/" not in where and "README" not in where and "/work/" not in where


def test_validation_report_of_a_model_with_effects_shows_its_intervals(files, tmp_path, capsys):
    """An extended model carries intervals like a base model (issue 22): the report's table
    shows them and the figures draw their bands."""
    from lpvpc.models.model import LPVPCModel
    from lpvpc.validation import validate

    model = tmp_path / "effect.json"
    assert _cli(["identify", "--pt", files["pt"], "--ut", files["ut"], "--effect", "nonlinear_viscosity",
                 "-o", model], capsys)[0] == 0
    loaded = LPVPCModel.load(model)
    assert loaded.has_intervals and [fe.name for fe in loaded.effects] == ["nonlinear_viscosity"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        result = validate(model, files["pt"], files["ut"], tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text()
    text = _report_text(page)
    assert "No confidence intervals" not in text and "In brackets: 95% confidence intervals" in text
    K = loaded.elastic_stiffness_interval([0.0])
    assert "–" in text and np.isfinite(K[0]).all()  # the table's intervals (en dash between the bounds)
    assert "benchmarks/" not in page and "README" not in page
    assert result.metrics["vaf"] > 80


# --------------------------------------------------------------------------- export and help


def test_export_prints_the_fmus_interface_and_the_models_latency(files, tmp_path, capsys):
    from fmpy import read_model_description

    from lpvpc.export.exporter import latency_samples
    from lpvpc.models.model import LPVPCModel

    model = tmp_path / "m.json"
    assert _cli(["identify", "--pt", files["pt"], "--ut", files["ut"], "-o", model], capsys)[0] == 0
    fitted = LPVPCModel.load(model)
    for variant in ("sampled", "exact"):
        fmu = tmp_path / f"{variant}.fmu"
        status, out, _ = _cli(["export", model, "--fmu", fmu, "--variant", variant], capsys)
        assert status == 0
        md = read_model_description(str(fmu))
        inputs = [v for v in md.modelVariables if v.causality == "input"]
        line = next(ln for ln in out.splitlines() if ln.strip().startswith("inputs:"))
        assert all(f"{v.name} ({v.unit})" in line for v in inputs) and len(inputs) == 2  # position, scheduling
        assert "torque (N.m)" in out
        lat = latency_samples(fitted, variant)
        assert f"latency:     {lat} sample" in out
    assert latency_samples(fitted, "sampled") == 2  # this version's 5-point stencil, as export --help says
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    assert "2 samples for models identified by this version" in " ".join(capsys.readouterr().out.split())


def test_simulate_and_identify_help_list_the_effect_catalog(capsys):
    from lpvpc.models.effects import CATALOG
    from lpvpc.simulation.simulate import EFFECTS

    for command in ("simulate", "identify", "improve"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = "".join(capsys.readouterr().out.split())  # argparse wraps names at hyphens
        assert all(name in text for name in CATALOG), command
        if command == "simulate":  # and the simulator's other effects, said to be outside the catalog
            assert all(name in text for name in EFFECTS) and "outsidethecatalog" in text
