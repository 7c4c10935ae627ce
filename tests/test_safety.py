"""Nothing lost, nothing run that should not be (issue 14).

Hostile model files are refused with one line (exit 2) before anything is built from
them; outputs never replace inputs; outputs are written atomically and cleaned up on
SIGINT/SIGTERM; external programs get paths, never options; a built FMU is checked;
extra CSV columns of any type are ignored. Every run of a hostile input goes through a
subprocess with a timeout, so a regression fails instead of hanging the suite.
"""

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpvpc.errors import DataError, ModelFileError
from lpvpc.models.model import LPVPCModel

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 120  # s: any hostile case must be refused long before this


def _cli(*argv, cwd=None, timeout=TIMEOUT):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=timeout)


def _one_line(r):
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {r.stderr[-2000:]!r}"
    assert lines[0].startswith("lpvpc: error: "), lines[0]
    assert "Traceback" not in r.stderr
    return lines[0]


@pytest.fixture(scope="module")
def base(model_file):
    return json.loads(Path(model_file).read_text())


def _set(path, value):
    def change(d):
        *head, last = path
        for k in head:
            d = d[k]
        d[last] = value
    return change


def _unstable(d):
    d["reflex"]["A"] = [[1.5, 0.0], [0.0, 0.5]] if len(d["reflex"]["A"]) == 2 else d["reflex"]["A"]


# (change, words the one-line error must contain)
HOSTILE = {
    "delay-1e5": (_set(("reflex", "delay"), 100_000), "MAX_DELAY"),
    "delay-1e9": (_set(("reflex", "delay"), 10**9), "MAX_DELAY"),
    "delay-3.9": (_set(("reflex", "delay"), 3.9), "integer"),
    "delay-0": (_set(("reflex", "delay"), 0), "reflex.delay"),
    "lag-1e9": (lambda d: d["intrinsic"]["lags"].__setitem__(0, -10**9), "MAX_LAG"),
    "duplicate-lags": (lambda d: d["intrinsic"]["lags"].__setitem__(1, d["intrinsic"]["lags"][0]), "duplicate"),
    "1e6-coefficients": (_set(("intrinsic", "H"), [[0.0] * 900] * 1000), "MAX_COEFFICIENTS"),
    "basis-order-1e6": (_set(("reflex", "velocity_basis", "order"), 10**6), "MAX_BASIS_ORDER"),
    "fs-0": (_set(("fs",), 0), "fs"),
    "fs-negative": (_set(("fs",), -100.0), "fs"),
    "fs-true": (_set(("fs",), True), "fs must be a number"),
    "fs-string": (_set(("fs",), "100"), "fs must be a number"),
    "torque-sign-2": (_set(("conventions", "torque_sign"), 2), "torque_sign"),
    "torque-sign-text": (_set(("conventions", "torque_sign"), "minus"), "torque_sign"),
    "position-unit": (_set(("conventions", "position_unit"), "furlong"), "position_unit"),
    "unstable-reflex": (_unstable, "spectral radius"),
    "huge-coefficient": (lambda d: d["intrinsic"]["H"][0].__setitem__(0, 1e300), "MAX_ABS_VALUE"),
    "bool-coefficient": (lambda d: d["reflex"]["B"].__setitem__(0, True), "must be a number"),
    "string-coefficient": (lambda d: d["reflex"]["Omega"][0].__setitem__(0, "1.0"), "must be a number"),
    "ragged": (lambda d: d["intrinsic"]["H"][0].pop(), "rows of different lengths"),
    "basis-range-reversed": (_set(("intrinsic", "basis", "lo"), 5.0), "MIN_BASIS_SPAN"),
    "basis-extra-field": (_set(("intrinsic", "basis", "evil"), 1), "unknown field"),
    "A-not-square": (_set(("reflex", "A"), [[0.5, 0.1]]), "reflex.A"),
    "settings-order-huge": (_set(("settings", "intrinsic_order"), 10**9), "settings.intrinsic_order"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_model_refused_in_process(case, base):
    change, words = HOSTILE[case]
    d = copy.deepcopy(base)
    change(d)
    with pytest.raises(ModelFileError) as exc:
        LPVPCModel.from_dict(json.loads(json.dumps(d)), source="m.json")
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_valid_models_still_load(base, model_file):
    m = LPVPCModel.load(model_file)
    assert m.to_dict()["reflex"] == base["reflex"]


def _write_hostile(tmp_path, base, case):
    change, words = HOSTILE[case]
    d = copy.deepcopy(base)
    change(d)
    path = tmp_path / f"{case}.json"
    path.write_text(json.dumps(d))
    return path, words


@pytest.mark.parametrize("case", ["delay-1e5", "1e6-coefficients", "lag-1e9", "unstable-reflex", "fs-true",
                                  "delay-3.9", "torque-sign-text", "huge-coefficient"])
def test_hostile_model_export_refused_quickly(case, base, tmp_path):
    """As a process, with a timeout: exit 2, one line naming the limit, nothing written."""
    path, words = _write_hostile(tmp_path, base, case)
    r = _cli("export", path, "--casadi", tmp_path / "out.casadi", "--fmu", tmp_path / "out.fmu", cwd=tmp_path)
    assert r.returncode == 2, r.stderr[-2000:]
    assert words in _one_line(r)
    assert not (tmp_path / "out.casadi").exists() and not (tmp_path / "out.fmu").exists()


@pytest.mark.parametrize("case", ["fs-0", "torque-sign-2", "position-unit", "unstable-reflex"])
def test_hostile_model_predict_refused(case, base, tmp_path, subject):
    from lpvpc.io import write_trial_csv

    pt, ut = tmp_path / "PT.csv", tmp_path / "UT.csv"
    write_trial_csv(subject["novel_pair"].pt, pt)
    write_trial_csv(subject["novel_pair"].ut, ut)
    path, words = _write_hostile(tmp_path, base, case)
    r = _cli("predict", path, "--pt", pt, "--ut", ut, cwd=tmp_path)
    assert r.returncode == 2 and words in _one_line(r)


def _write_text_model(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_deep_nesting_dev_zero_and_oversized(tmp_path, base):
    deep = _write_text_model(tmp_path, "deep.json", '{"format": "lpvpc-model", "fit": '
                             + "[" * 100_000 + "]" * 100_000 + "}")
    shallow_deep = copy.deepcopy(base)
    shallow_deep["fit"]["x"] = json.loads("[" * 50 + "]" * 50)
    deep2 = _write_text_model(tmp_path, "deep2.json", json.dumps(shallow_deep))
    big = tmp_path / "big.json"
    with open(big, "w") as fh:
        fh.write('{"format": "lpvpc-model", "pad": "')
        fh.write("x" * (9 * 1024 * 1024))
        fh.write('"}')
    dup = _write_text_model(tmp_path, "dup.json", json.dumps(base)[:-1] + ', "fs": 1000.0}')
    for path, words in ((deep, "MAX_NESTING_DEPTH"), (deep2, "MAX_NESTING_DEPTH"), ("/dev/zero", "regular file"),
                        (tmp_path, "regular file"), (big, "MAX_FILE_BYTES"), (dup, "duplicate key")):
        r = _cli("export", path, "--casadi", tmp_path / "o.casadi", cwd=tmp_path, timeout=60)
        assert r.returncode == 2, (path, r.stderr[-500:])
        assert words in _one_line(r), path


def test_fuzz_model_loader_small(base):
    """A few hundred seeded random mutations of a real model: each loads or is refused
    with one line (no other exception). The benchmark runs thousands."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        from bench_fuzz_model import fuzz
    finally:
        sys.path.pop(0)
    result = fuzz(base, n_cases=300, seed=14)
    assert result["tracebacks"] == [], result["tracebacks"][:3]
    assert result["loaded"] + result["refused"] == 300
    assert result["refused"] > 100 and result["loaded"] > 0


# --------------------------------------------------------------------------- outputs vs inputs
@pytest.fixture(scope="module")
def short_csv(subject, tmp_path_factory):
    """The first 20 s of the novel record as PT/UT CSV files (valid input: were an output
    written over them, the command would succeed)."""
    from lpvpc.io import Trial, write_trial_csv

    folder = tmp_path_factory.mktemp("short")
    n = 20_000
    for key, tr in (("PT", subject["novel_pair"].pt), ("UT", subject["novel_pair"].ut)):
        write_trial_csv(Trial(tr.time[:n], tr.position[:n], tr.torque[:n], {k: v[:n] for k, v in tr.channels.items()},
                              name=tr.name), folder / f"{key}.csv")
    return folder


@pytest.fixture
def files(model_file, short_csv, tmp_path):
    """A model file and a valid PT/UT pair in a fresh folder, a hard link to PT.csv and a
    symbolic link to the model."""
    m = tmp_path / "model.json"
    m.write_bytes(Path(model_file).read_bytes())
    pt, ut = tmp_path / "PT.csv", tmp_path / "UT.csv"
    pt.write_bytes((short_csv / "PT.csv").read_bytes())
    ut.write_bytes((short_csv / "UT.csv").read_bytes())
    (tmp_path / "hard.csv").hardlink_to(pt)
    (tmp_path / "soft.json").symlink_to(m)
    return {"model": m, "pt": pt, "ut": ut, "dir": tmp_path}


OUTPUT_CASES = {
    "identify-o-pt": (["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", "PT.csv"], "PT.csv"),
    "identify-o-hardlink": (["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", "hard.csv"], "PT.csv"),
    "export-fmu-over-model": (["export", "model.json", "--fmu", "model.json"], "model.json"),
    "export-casadi-sidecar": (["export", "model.json", "--casadi", "model"], "model.json"),
    "export-symlink": (["export", "soft.json", "--fmu", "model.json"], "model.json"),
    "predict-out-pt": (["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--out", "PT.csv"], "PT.csv"),
    "predict-json-model": (["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "model.json"],
                           "model.json"),
    "predict-two-outputs": (["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "o.csv",
                             "--out", "o.csv"], "same file"),
    "diagnose-json-model": (["diagnose", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "soft.json"],
                            "model.json"),
    "validate-report-holds-model": (["validate", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--report", "."],
                                    "inside the output folder"),
    "whole-joint-o-model": (["whole-joint", "model.json", "--ut", "UT.csv", "-o", "model.json"], "model.json"),
    "whole-joint-fmu-ut": (["whole-joint", "model.json", "--ut", "UT.csv", "-o", "w.json", "--fmu", "UT.csv"],
                           "UT.csv"),
    "improve-o-heldout": (["improve", "--pt", "PT.csv", "--ut", "UT.csv", "--heldout-pt", "PT.csv", "--heldout-ut",
                           "UT.csv", "--report", "rep", "--max-steps", "0", "-o", "UT.csv"], "UT.csv"),
}


@pytest.mark.parametrize("case", sorted(OUTPUT_CASES))
def test_output_never_replaces_an_input(case, files, capsys, monkeypatch):
    from lpvpc.cli import main

    argv, words = OUTPUT_CASES[case]
    monkeypatch.chdir(files["dir"])
    before = {p.name: p.read_bytes() for p in files["dir"].iterdir() if p.is_file()}
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lpvpc: error: ") and words in lines[0], err
    after = {p.name: p.read_bytes() for p in files["dir"].iterdir() if p.is_file()}
    assert after == before  # nothing replaced, nothing left behind


def test_report_folder_of_other_files_needs_force(files, capsys):
    from lpvpc.cli import main

    d = files["dir"]
    keep = d / "results" / "thesis.tex"
    keep.parent.mkdir()
    keep.write_text("months of work")
    argv = ["diagnose", files["model"], "--pt", files["pt"], "--ut", files["ut"], "--report", d / "results"]
    assert main([str(a) for a in argv]) == 2
    assert "--force" in capsys.readouterr().err and keep.read_text() == "months of work"
    assert main([str(a) for a in argv + ["--force"]]) == 0
    capsys.readouterr()
    assert not keep.exists() and (d / "results" / "diagnosis.json").is_file()  # replaced as a whole
    assert main([str(a) for a in argv]) == 0  # a previous report: replaced without --force
    assert not list(d.glob(".*lpvpc-tmp"))


# --------------------------------------------------------------------------- atomic outputs
def test_staged_folder_is_all_or_nothing(tmp_path):
    from lpvpc.io.outputs import staged_folder

    folder = tmp_path / "report"
    folder.mkdir()
    (folder / "metrics.json").write_text("old run")
    with pytest.raises(RuntimeError):
        with staged_folder(folder) as stage:
            (stage / "metrics.json").write_text("half of a new run")
            raise RuntimeError("failed in the middle")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
    assert (folder / "metrics.json").read_text() == "old run"
    with staged_folder(folder) as stage:
        (stage / "report.html").write_text("new run")
    assert sorted(p.name for p in folder.iterdir()) == ["report.html"]  # nothing of the old run
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path):
    from lpvpc.io.outputs import atomic_path

    target = tmp_path / "model.json"
    target.write_text("previous model")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_text("half a mod")
            raise KeyboardInterrupt
    assert target.read_text() == "previous model" and [p.name for p in tmp_path.iterdir()] == ["model.json"]


def _cli_with_umask(mask, *argv, cwd):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=TIMEOUT, preexec_fn=lambda: os.umask(mask))


@pytest.mark.slow
def test_every_output_has_the_same_mode(model, subject, tmp_path):
    """Model, predict's CSV and JSON, .casadi and sidecar, FMU and the validation report's SSP:
    all 0666 less the umask (the SSP was written 0600)."""
    from lpvpc.export.actuator import build_actuator_fmu
    from lpvpc.io import Trial, write_trial_csv
    from lpvpc.export.exporter import export_fmu
    from lpvpc.validation import validate

    n = 10_000  # 10 s of the novel record
    for key, tr in (("PT", subject["novel_pair"].pt), ("UT", subject["novel_pair"].ut)):
        write_trial_csv(Trial(tr.time[:n], tr.position[:n], tr.torque[:n], {k: v[:n] for k, v in tr.channels.items()},
                              name=tr.name), tmp_path / f"{key}.csv")
    model.save(tmp_path / "model.json")
    r = _cli_with_umask(0o002, "predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "m.json",
                        "--out", "p.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = _cli_with_umask(0o002, "export", "model.json", "--casadi", "s.casadi", "--fmu", "m.fmu", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for name in ("m.json", "p.csv", "s.casadi", "s.casadi.json", "m.fmu"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o664, name
    old = os.umask(0o022)
    try:
        act = build_actuator_fmu(tmp_path / "act.fmu")
        res = validate(model, tmp_path / "PT.csv", tmp_path / "UT.csv", tmp_path / "report",
                       fmu=export_fmu(model, tmp_path / "exact.fmu", variant="exact"), actuator_fmu=act,
                       measure_load_effect=False)
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in (tmp_path / "report").rglob("*") if p.is_file()}
    assert modes["cosimulation.ssp"] == 0o644 and set(modes.values()) == {0o644}, modes
    assert res.files["ssp"] == tmp_path / "report" / "cosimulation.ssp"
    assert not list(tmp_path.glob(".*lpvpc-tmp"))


def _default_sigint():
    """In the child: SIGINT to its default, so that Python turns it into KeyboardInterrupt
    as in a terminal, whatever the test runner's disposition (a shell's background job, as
    `make test &`, ignores SIGINT, and a child would inherit that)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _held_compiler(folder):
    """(CC, marker): gcc behind a wrapper (the CC the FMU build honours) that, once gcc has
    written the library, touches ``marker`` and holds on, so that a signal sent after the
    marker appears always falls inside a compile step, however loaded the machine."""
    marker = Path(folder) / "compiled"
    cc = Path(folder) / "held-gcc"
    cc.write_text(f'#!/bin/sh\ngcc "$@" || exit $?\ntouch "{marker}"\nexec sleep 60\n')
    cc.chmod(0o755)
    return str(cc), marker


def _wait_for_marker(marker, proc, limit=120.0):
    import time

    t0 = time.monotonic()
    while not marker.exists() and proc.poll() is None and time.monotonic() - t0 < limit:
        time.sleep(0.01)
    return marker.exists() and proc.poll() is None


def _wait_for(pattern_dir, pattern, proc, limit=90.0):
    import time

    t0 = time.monotonic()
    while time.monotonic() - t0 < limit and proc.poll() is None:
        if list(Path(pattern_dir).glob(pattern)):
            return True
        time.sleep(0.005)
    return False


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_interrupted_export_leaves_nothing(sig, base, tmp_path):
    """A signal while the compiler runs: exit 128 + signal, one line, no temporary files in
    the target folder or the temporary directory, no FMU.

    The compiler is gcc behind a wrapper (the CC the build honours) that, once gcc has
    written the library, marks that it got there and holds on: the signal then always falls
    inside the compile step, however loaded the machine (a bare gcc can finish between the
    build folder appearing and the signal, and the export then rightly succeeds)."""
    import signal

    d = copy.deepcopy(base)
    (tmp_path / "model.json").write_text(json.dumps(d))
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    (tmp_path / "out").mkdir()
    cc, marker = _held_compiler(tmp_path)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", TMPDIR=str(tmpdir), CC=cc,
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "lpvpc.cli", "export", "model.json", "--fmu", "out/m.fmu"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)
    try:
        assert _wait_for(tmp_path / "out", ".lpvpc_model-*", proc), "the build folder never appeared"
        assert _wait_for_marker(marker, proc), "the compiler never ran"
        proc.send_signal(getattr(signal, sig))
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + getattr(signal, sig), err
    assert len(err.strip().splitlines()) == 1 and ("terminated" if sig == "SIGTERM" else "interrupted") in err
    assert list((tmp_path / "out").iterdir()) == [] and list(tmpdir.iterdir()) == []


@pytest.mark.slow
def test_interrupted_validate_keeps_the_previous_report(model, subject, tmp_path):
    """SIGTERM in the middle of a validation into a folder holding a previous report: the
    previous report stays whole, and no half-built folder is left beside it. The signal
    falls while the model FMU compiles into the half-built report (a held compiler: on a
    loaded machine the validation could otherwise finish first)."""
    import signal

    from lpvpc.io import Trial, write_trial_csv

    n = 20_000
    for key, tr in (("PT", subject["novel_pair"].pt), ("UT", subject["novel_pair"].ut)):
        write_trial_csv(Trial(tr.time[:n], tr.position[:n], tr.torque[:n], {k: v[:n] for k, v in tr.channels.items()},
                              name=tr.name), tmp_path / f"{key}.csv")
    model.save(tmp_path / "model.json")
    report = tmp_path / "report"
    report.mkdir()
    previous = {"metrics.json": '{"pass": true, "model": "previous"}', "report.html": "<p>previous</p>"}
    for name, text in previous.items():
        (report / name).write_text(text)
    held = tmp_path.parent / f"{tmp_path.name}-cc"  # outside the folder whose contents are checked
    held.mkdir()
    cc, marker = _held_compiler(held)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", CC=cc,
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "lpvpc.cli", "validate", "model.json", "--pt", "PT.csv", "--ut",
                             "UT.csv", "--report", "report"], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for_marker(marker, proc), "the model FMU never compiled"
        assert list(tmp_path.glob(".report.*lpvpc-tmp/fmus")), "no half-built report while compiling"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 143 and "terminated" in err, err
    assert {p.name: p.read_text() for p in report.iterdir()} == previous
    assert sorted(p.name for p in tmp_path.iterdir()) == ["PT.csv", "UT.csv", "model.json", "report"]


# --------------------------------------------------------------------------- paths are paths
@pytest.mark.slow
def test_fmu_path_starting_with_a_dash_and_the_built_fmu_check(model_file, tmp_path):
    """gcc gets absolute paths: an FMU written as '-out/m.fmu' is a real FMU there; a library
    without FMI functions is refused before it is written."""
    import zipfile

    from fmpy import read_model_description

    from lpvpc.errors import ExportError
    from lpvpc.export.fmu_build import check_built_fmu

    (tmp_path / "model.json").write_bytes(Path(model_file).read_bytes())
    r = _cli("export", "model.json", "--fmu=-out/m.fmu", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    fmu = tmp_path / "-out" / "m.fmu"
    md = read_model_description(str(fmu))
    folder = tmp_path / "unpacked"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(folder)
    check_built_fmu(folder, md.coSimulation.modelIdentifier)  # the real one passes
    lib = folder / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    src = tmp_path / "empty.c"
    src.write_text("int lpvpc_not_fmi(void) { return 0; }\n")
    subprocess.run(["gcc", "-shared", "-fPIC", str(src), "-o", str(lib)], check=True, timeout=60)
    with pytest.raises(ExportError, match="not usable"):
        check_built_fmu(folder, md.coSimulation.modelIdentifier)


# --------------------------------------------------------------------------- CSV extra columns
def test_csv_extra_text_columns_are_ignored(tmp_path, caplog):
    import logging

    from lpvpc.io import load_trial
    from lpvpc.errors import DataError

    n = 40
    rows = ["time,position,notes,torque,trigger"]
    rows += [f'{k / 100},{0.01 * k},"subject said, ""ok""",{0.5 * k},{"A" if k % 2 else 3}' for k in range(n)]
    path = tmp_path / "notes.csv"
    path.write_text("\n".join(rows) + "\n")
    with caplog.at_level(logging.INFO, logger="lpvpc"):
        trial = load_trial(path)
    np.testing.assert_allclose(trial.position, 0.01 * np.arange(n))
    np.testing.assert_allclose(trial.torque, 0.5 * np.arange(n))
    assert "ignored column(s) notes, trigger" in caplog.text
    plain = tmp_path / "plain.csv"  # unquoted text: the fast path
    plain.write_text("time,notes,position,torque\n" + "".join(f"{k / 100},fine,{0.01 * k},{k}\n" for k in range(n)))
    assert len(load_trial(plain).position) == n
    rows[5] = rows[5].replace(f"{0.5 * 4}", "n/a")  # a required column still strictly checked
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"column 'torque': 1 value not a number, first at line 6"):
        load_trial(path)


# --------------------------------------------------------------------------- bounded prediction
@pytest.mark.parametrize("causal", [False, True])
def test_prediction_in_blocks_equals_the_whole_record(causal, subject, model, monkeypatch):
    """Prediction builds lagged positions block by block (memory bounded for any record
    length); the blocks' edges change nothing, also for an extended model."""
    from lpvpc.models import equations as eq
    from lpvpc.models.effects import signals_from_data
    from lpvpc.identification.identify import LPVPCEstimator

    data = subject["novel"]
    extended = LPVPCEstimator(effects=("drift", "position_dependent_reflex_dynamics")).fit(subject["ident"]).model_
    for m, sig in ((model, None), (extended, signals_from_data(data))):
        whole = m.predict(data.position, data.scheduling, causal=causal, signals=sig, warn=False)
        monkeypatch.setattr(eq, "BLOCK_CELLS", 1)  # blocks of 1024 samples
        parts = m.predict(data.position, data.scheduling, causal=causal, signals=sig, warn=False)
        monkeypatch.undo()
        assert len(eq.blocks(data.n, len(m.lags))) == 1 and data.n > 4 * 1024
        np.testing.assert_allclose(parts.total, whole.total, rtol=0, atol=1e-12 * np.max(np.abs(whole.total)))
        for k in whole.effects:
            np.testing.assert_allclose(parts.effects[k], whole.effects[k], rtol=0, atol=1e-12)


def test_hostile_whole_joint_file_refused(model, subject, tmp_path):
    from lpvpc.export.whole_joint import WholeJointModel, fit_whole_joint

    d = fit_whole_joint(model, subject["ident_pair"].ut).to_dict()
    for change, words in ((_set(("quasi_static", "basis", "order"), 10**6), "MAX_BASIS_ORDER"),
                          (_set(("cutoff",), True), "cutoff"), (_set(("cutoff",), 1e9), "cutoff"),
                          (_set(("quasi_static", "coefficients"), [1e300]), "MAX_ABS_VALUE"),
                          (_set(("model", "reflex", "delay"), 10**9), "MAX_DELAY")):
        bad = copy.deepcopy(d)
        change(bad)
        with pytest.raises(ModelFileError, match=words):
            WholeJointModel.from_dict(json.loads(json.dumps(bad)), "w.json")
    with pytest.raises(ModelFileError, match="regular file"):
        WholeJointModel.load("/dev/zero")


@pytest.mark.parametrize("fs", ["-5", "nan", "inf"])
def test_identify_rate_must_be_a_rate(fs, capsys):
    from lpvpc.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["identify", "x.csv", "-o", "m.json", "--fs", fs])
    assert exc.value.code == 2 and "--fs" in capsys.readouterr().err


# --------------------------------------------------------------------------- bounded loaders (issue 26)
def _v73_with_junk(path, pair, n=20_000):
    """A -v7.3 file (written by mat-io) with structs pt and ut (time, position, torque) and an
    unrelated variable 'junk' that declares 10^9 doubles (7.45 GiB) but holds none: a file
    well under 1 MB."""
    import h5py
    from matlab_files import write_mat

    write_mat(path, {k: {"time": tr.time[:n], "position": tr.position[:n], "torque": tr.torque[:n]}
                     for k, tr in (("pt", pair.pt), ("ut", pair.ut))}, version="v7.3")
    with h5py.File(path, "a") as f:
        ds = f.create_dataset("junk", shape=(1, 10**9), dtype="f8", chunks=(1, 10**6))
        ds.attrs["MATLAB_class"] = np.bytes_("double")
    assert path.stat().st_size < 1 << 20
    return path


def _v5_compressed_junk(n_values=400_000_000):
    """A compressed v5 element whose double array 'junk' declares ``n_values`` values (3.2 GB)
    and carries none: what a hostile 100-byte addition to a .mat file can claim."""
    import struct
    import zlib

    data_bytes = 8 * n_values
    body = (struct.pack("<II", 6, 8) + struct.pack("<II", 6, 0)  # array flags: mxDOUBLE_CLASS
            + struct.pack("<II", 5, 8) + struct.pack("<ii", 1, n_values)  # dimensions 1 x n
            + struct.pack("<I", (4 << 16) | 1) + b"junk"  # name, a small data element
            + struct.pack("<II", 9, data_bytes))  # miDOUBLE, no data follows
    inner = struct.pack("<II", 14, len(body) + data_bytes) + body
    packed = zlib.compress(inner)
    return struct.pack("<II", 15, len(packed)) + packed


def _limited(*argv, cwd, address_space=2 << 30, env=None):
    """The CLI as a process with a 2 GiB address-space limit (Python, numpy, CasADi and the
    loaders need about 0.4 GiB): a 7.45 GiB allocation fails instead of swapping the machine."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))

    e = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
             PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), **(env or {}))
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env=e, timeout=TIMEOUT, preexec_fn=limit)


def test_v73_declared_size_is_never_allocated(subject, model_file, tmp_path):
    """The issue's file: 'identify' tried to allocate 7.45 GiB for an unrelated variable.
    Reading pt and ut (named, or found automatically) never touches it; naming it is one
    line naming the limit; the limit is settable."""
    import tracemalloc

    from lpvpc.io import load_trial

    path = _v73_with_junk(tmp_path / "s.mat", subject["novel_pair"])
    tracemalloc.start()
    try:
        named = load_trial(f"{path}:pt")
        found = load_trial(path, variable="ut")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert named.time.size == found.time.size == 20_000 and peak < 50e6, peak
    with pytest.raises(DataError) as err:
        load_trial(f"{path}:junk")
    msg = str(err.value)
    assert "'junk' declares 7.45 GiB" in msg and "LPVPC_MAX_VARIABLE_BYTES" in msg and "\n" not in msg

    m = tmp_path / "model.json"
    m.write_bytes(Path(model_file).read_bytes())
    r = _limited("predict", m, "--pt", f"{path}:pt", "--ut", f"{path}:ut", cwd=tmp_path)
    assert r.returncode == 0 and "VAF" in r.stdout, r.stderr[-2000:]
    r = _limited("predict", m, "--pt", "s.mat:junk", "--ut", "s.mat:ut", cwd=tmp_path)
    assert r.returncode == 2 and "MAX_VARIABLE_BYTES" in _one_line(r), r.stderr[-2000:]
    # a lower limit, from the environment: now pt itself (480 kB) is over it
    r = _limited("predict", m, "--pt", "s.mat:pt", "--ut", "s.mat:ut", cwd=tmp_path,
                 env={"LPVPC_MAX_VARIABLE_BYTES": "100000"})
    assert r.returncode == 2 and "'pt' declares 469 KiB" in _one_line(r) and "97.7 KiB" in _one_line(r)


def test_v5_declared_size_checked_in_compressed_elements(subject, tmp_path):
    """A compressed v5 variable declaring 3.2 GB (the element holds 60 bytes) is skipped when
    another variable is read, and one line naming the limit when it is asked for."""
    import tracemalloc

    import scipy.io

    from lpvpc.io import load_trial
    from lpvpc.io.matfiles import declared_sizes

    n = 20_000
    path = tmp_path / "s5.mat"
    scipy.io.savemat(path, {k: {"time": tr.time[:n], "position": tr.position[:n], "torque": tr.torque[:n]}
                            for k, tr in (("pt", subject["novel_pair"].pt), ("ut", subject["novel_pair"].ut))},
                     do_compression=True)
    with open(path, "ab") as f:
        f.write(_v5_compressed_junk())
    sizes = declared_sizes(path)
    assert sizes["junk"] >= 3_200_000_000 and sizes["pt"] < 1_000_000, sizes
    tracemalloc.start()
    try:
        assert load_trial(f"{path}:pt").time.size == n
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6, peak
    with pytest.raises(DataError, match=r"'junk' declares 2.98 GiB of data, over the limit of 1 GiB"):
        load_trial(f"{path}:junk")


def test_csv_over_the_limit_refused_before_reading(tmp_path, monkeypatch):
    from lpvpc.io import load_trial

    path = tmp_path / "big.csv"
    path.write_text("time,position,torque\n" + "".join(f"{k / 1000},0.01,0.5\n" for k in range(5000)))
    assert load_trial(path).time.size == 5000
    monkeypatch.setenv("LPVPC_MAX_VARIABLE_BYTES", "10000")
    with pytest.raises(DataError, match=r"the file declares .* KiB of data, over the limit of 9.77 KiB"):
        load_trial(path)
    monkeypatch.setenv("LPVPC_MAX_VARIABLE_BYTES", "lots")
    with pytest.raises(DataError, match="LPVPC_MAX_VARIABLE_BYTES='lots' must be a positive number"):
        load_trial(path)
