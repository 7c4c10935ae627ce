"""One output policy for every command (issue 26): no output is, links to or contains an
input, whatever form the input is given in; outputs are checked before any work.

The matrix test runs every subcommand with every input form (CSV, .mat, .mat:VARIABLE,
relative and absolute paths, a symbolic and a hard link) against every output option
pointed at that input (by name, absolute path, a symbolic or a hard link; folders: the
folder holding it), in-process through ``lpvpc.cli.main``: each refusal must be one line,
exit 2, and leave every file as it was. A few cases run as processes for the real exit
status. Every test runs under an alarm, so a regression fails instead of hanging.
"""

import hashlib
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from lpvpc.cli import build_parser, main
from lpvpc.io.outputs import input_file

REPO = Path(__file__).resolve().parents[1]
LIMIT_S = 120  # s per test: refusals cost CLI start-up only


@pytest.fixture(autouse=True)
def _alarm():
    def expired(signum, frame):
        raise TimeoutError(f"test exceeded {LIMIT_S} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(LIMIT_S)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


def _trial_struct(tr, n):
    return {"time": tr.time[:n], "position": tr.position[:n], "torque": tr.torque[:n]}


@pytest.fixture(scope="module")
def source(subject, model_file, tmp_path_factory):
    """Valid inputs (20 s of the novel record): PT/UT as CSV and as the variables pt, ut of
    s.mat, a perturbation file D.csv (and its held-out stand-in D2.csv), the model, and
    stand-ins for FMU and whole-joint inputs."""
    from lpvpc.io import Trial, load_identification_data, write_perturbation_csv, write_trial_csv

    folder = tmp_path_factory.mktemp("policy_source")
    n = 20_000
    pair = subject["novel_pair"]
    for key, tr in (("PT", pair.pt), ("UT", pair.ut)):
        write_trial_csv(Trial(tr.time[:n], tr.position[:n], tr.torque[:n], {}, name=key), folder / f"{key}.csv")
    scipy.io.savemat(folder / "s.mat", {"pt": _trial_struct(pair.pt, n), "ut": _trial_struct(pair.ut, n)})
    write_perturbation_csv(load_identification_data(pt=folder / "PT.csv", ut=folder / "UT.csv"), folder / "D.csv")
    (folder / "PT2.csv").write_bytes((folder / "PT.csv").read_bytes())  # held-out stand-ins
    (folder / "UT2.csv").write_bytes((folder / "UT.csv").read_bytes())
    (folder / "D2.csv").write_bytes((folder / "D.csv").read_bytes())
    (folder / "model.json").write_bytes(Path(model_file).read_bytes())
    (folder / "m.fmu").write_bytes(b"PK stand-in")
    (folder / "act.fmu").write_bytes(b"PK stand-in")
    (folder / "wj.json").write_text("{}")
    return folder


def _snapshot(folder):
    """{relative path: (inode, size, mtime_ns, mode)} of every file and link under ``folder``."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(folder))] = (st.st_ino, st.st_size, st.st_mtime_ns, st.st_mode)
    return out


def _hashes(folder):
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and not p.is_symlink()}


@pytest.fixture
def work(source, tmp_path, monkeypatch):
    for p in source.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    monkeypatch.chdir(tmp_path)
    return tmp_path


# Each command with valid arguments: {label: value}; inputs name the files above, outputs
# fresh paths. The data options are read in one of the forms of DATA_FORMS.
BASE = {
    "identify": {"--pt": "PT.csv", "--ut": "UT.csv", "-o": "new.json"},
    "identify DATA": {"DATA": "D.csv", "-o": "new.json"},
    "predict": {"MODEL": "model.json", "--pt": "PT.csv", "--ut": "UT.csv", "--json": "new.json", "--out": "new.csv"},
    "predict DATA": {"MODEL": "model.json", "DATA": "D.csv", "--json": "new.json", "--out": "new.csv"},
    "export": {"MODEL": "model.json", "--casadi": "new.casadi", "--fmu": "new.fmu"},
    "whole-joint": {"MODEL": "model.json", "--ut": "UT.csv", "-o": "new.json", "--fmu": "new.fmu",
                    "--casadi": "new.casadi"},
    "validate": {"MODEL": "model.json", "--pt": "PT.csv", "--ut": "UT.csv", "--report": "newrep",
                 "--fmu": "m.fmu", "--actuator-fmu": "act.fmu", "--whole-joint": "wj.json"},
    "diagnose": {"MODEL": "model.json", "--pt": "PT.csv", "--ut": "UT.csv", "--json": "new.json",
                 "--report": "newrep"},
    "diagnose DATA": {"MODEL": "model.json", "DATA": "D.csv", "--json": "new.json", "--report": "newrep"},
    "diagnose reference": {"MODEL": "model.json", "--pt": "PT2.csv", "--ut": "UT2.csv", "--reference-pt": "PT.csv",
                           "--reference-ut": "UT.csv", "--json": "new.json", "--report": "newrep"},
    "diagnose reference DATA": {"MODEL": "model.json", "DATA": "D2.csv", "--reference": "D.csv",
                                "--json": "new.json", "--report": "newrep"},
    "improve": {"--pt": "PT.csv", "--ut": "UT.csv", "--heldout-pt": "PT2.csv", "--heldout-ut": "UT2.csv",
                "--report": "newrep", "--json": "new.json", "-o": "new2.json", "--max-steps": "0"},
    "improve DATA": {"DATA": "D.csv", "--heldout": "D2.csv", "--report": "newrep", "--json": "new.json",
                     "-o": "new2.json", "--max-steps": "0"},
}
DATA_OPTIONS = ("DATA", "--pt", "--ut", "--heldout", "--heldout-pt", "--heldout-ut", "--reference", "--reference-pt",
                "--reference-ut")


def _argv(command, values):
    name = command.split()[0]
    positional = [values[k] for k in ("MODEL", "DATA") if k in values]
    options = [x for k, v in values.items() if k not in ("MODEL", "DATA") for x in (k, v)]
    return [name, *positional, *options]


def _input_forms(label, value, folder):
    """(form name, value) pairs that all read the file ``value``, and that file's name."""
    forms = [("relative", value), ("absolute", str(folder / value)), ("symlink", "in_link" + Path(value).suffix),
             ("hard link", "in_hard" + Path(value).suffix)]
    if label in DATA_OPTIONS:
        var = "ut" if "ut" in label else "pt"
        forms += [(".mat", "s.mat"), (".mat:VARIABLE", f"s.mat:{var}"),
                  (".mat:VARIABLE absolute", f"{folder / 's.mat'}:{var}")]
    return forms


def _output_aliases(kind, target, folder):
    """Values of an output option that lead to the input file ``target``."""
    if kind == "folder":
        return [".", str(folder), "dir_link"]
    suffix = Path(target).suffix
    aliases = [target, str(folder / target), "out_link" + suffix, "out_hard" + suffix]
    if kind == "sidecar":  # --casadi F writes F.json: F.json is the input
        aliases = [a[: -len(".json")] for a in aliases if a.endswith(".json")]
    return aliases


def _unlink(folder):
    for name in ("in_link", "in_hard", "out_link", "out_hard"):
        for p in folder.glob(name + "*"):
            p.unlink()


def _links(folder, value, target):
    """Create the input and output links for one case (to the file ``target``)."""
    _unlink(folder)
    suffix = Path(target).suffix
    (folder / ("in_link" + suffix)).symlink_to(folder / target)
    (folder / ("out_link" + suffix)).symlink_to(folder / target)
    os.link(folder / target, folder / ("in_hard" + suffix))
    os.link(folder / target, folder / ("out_hard" + suffix))
    if not (folder / "dir_link").exists():
        (folder / "dir_link").symlink_to(folder)


# What each command writes (written out here, independently of the code's declarations).
OUTPUTS = {
    "identify": [("-o", "file")],
    "predict": [("--json", "file"), ("--out", "file")],
    "export": [("--casadi", "file"), ("--fmu", "file"), ("--casadi", "sidecar")],
    "whole-joint": [("-o", "file"), ("--fmu", "file"), ("--casadi", "file")],
    "validate": [("--report", "folder")],
    "diagnose": [("--json", "file"), ("--report", "folder")],
    "improve": [("-o", "file"), ("--json", "file"), ("--report", "folder")],
}
INPUTS = {"MODEL", "DATA", "--pt", "--ut", "--heldout", "--heldout-pt", "--heldout-ut", "--reference",
          "--reference-pt", "--reference-ut", "--fmu", "--actuator-fmu",
          "--whole-joint"}


def _cases(command, folder):
    base = BASE[command]
    outputs = OUTPUTS[command.split()[0]]
    for in_label, in_value in base.items():
        if in_label not in INPUTS or (in_label, "file") in outputs:
            continue
        for form, value in _input_forms(in_label, in_value, folder):
            target = "s.mat" if value.split(os.sep)[-1].startswith("s.mat") else in_value
            for out_label, kind in outputs:
                for alias in _output_aliases(kind, target, folder):
                    values = dict(base, **{in_label: value, out_label: alias})
                    # the line names the output (a sidecar: its own path) and the input's file
                    named = [alias + ".json"] if kind == "sidecar" else [alias]
                    named += [str(input_file(value))] if kind != "folder" else []
                    yield f"{in_label} {form} ({value}) vs {out_label} {alias}", values, target, named


COMMANDS = sorted(BASE)


def _trap_work(m, trap):
    """Replace what reads inputs (the work) by ``trap``."""
    import lpvpc.io
    import lpvpc.io.identification_data
    import lpvpc.models.model
    import lpvpc.io.readers
    import lpvpc.simulation.simulate
    import lpvpc.validation

    m.setattr(lpvpc.models.model.LPVPCModel, "load", trap)
    # where the loaders are defined and where they are re-exported: a call through either is caught
    for module in (lpvpc.io, lpvpc.io.readers, lpvpc.io.identification_data):
        for name in ("load_identification_data", "load_trial"):
            if hasattr(module, name):
                m.setattr(module, name, trap)
    m.setattr(lpvpc.simulation.simulate, "write_dataset", trap)
    m.setattr(lpvpc.validation, "validate", trap)


@pytest.mark.parametrize("command", COMMANDS)
def test_no_output_over_any_input_form(command, work, capsys, monkeypatch):
    """Every input form against every output option: refused with one line naming both
    files, exit 2, before any work (the loaders are replaced by traps), nothing changed."""
    def trap(*a, **k):
        raise AssertionError("work started before the outputs were checked")

    hashes = _hashes(work)
    failures, n = [], 0
    for case, values, target, named in _cases(command, work):
        _links(work, values, target)
        before = _snapshot(work)
        with monkeypatch.context() as m:
            _trap_work(m, trap)
            try:
                status = main(_argv(command, values))
            except (AssertionError, SystemExit) as exc:
                status = f"{type(exc).__name__}: {exc}"
        err = capsys.readouterr().err.strip().splitlines()
        n += 1
        problems = []
        if status != 2:
            problems.append(f"status {status}")
        if len(err) != 1 or not err[0].startswith("lpvpc: error: ") or not all(w in err[0] for w in named):
            problems.append(f"stderr {err}")
        if _snapshot(work) != before:
            problems.append("files changed")
        if problems:
            failures.append(f"{case}: {'; '.join(problems)}")
    _unlink(work)
    assert _hashes(work) == hashes
    assert n >= 20 and not failures, f"{len(failures)} of {n} cases:\n" + "\n".join(failures[:20])


def test_two_outputs_of_one_command_and_an_output_inside_a_report(work, capsys):
    for argv, words in (
        (["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "o.csv", "--out", "o.csv"],
         "same file"),
        (["improve", "--pt", "PT.csv", "--ut", "UT.csv", "--heldout-pt", "PT.csv", "--heldout-ut", "UT.csv",
          "--report", "rep", "-o", "rep/model2.json"], "inside the output folder --report rep"),
        (["export", "model.json", "--casadi", "x.casadi", "--fmu", "x.casadi.json"], "same file"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err


def test_every_command_declares_its_files():
    """By construction: every subcommand has a declaration, and every option that takes a
    file or folder (by its metavar) is declared as an input, output file or output folder."""
    from lpvpc.cli import COMMAND_IO

    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "identify" in a.choices)
    assert set(sub.choices) == set(COMMAND_IO)
    path_like = re.compile(r"\.(json|csv|fmu|casadi|mat)$|^(DIR|PT[02]?|UT[02]?|DATA[02]?|F\.fmu|FILE\..*)$")
    for name, p in sub.choices.items():
        io = COMMAND_IO[name]
        declared = {*io.inputs.values(), *io.files.values(), *io.folders.values()}
        for action in p._actions:
            if isinstance(action.metavar, str) and path_like.search(action.metavar):
                assert action.dest in declared, f"{name}: {action.dest} ({action.metavar}) is not declared"


# --------------------------------------------------------------------------- early checks
EARLY = {
    "missing folder": (["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", "nowhere/model.json"],
                       "nowhere/model.json", "does not exist"),
    "a file as folder": (["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--json", "PT.csv/m.json"],
                         "PT.csv/m.json", "is not a folder"),
    "a folder as file": (["export", "model.json", "--casadi", "adir"], "adir", "is a folder"),
    "a file as report": (["diagnose", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--report", "afile.txt"],
                         "afile.txt", "is a file"),
    "simulate into a file": (["simulate", "--out", "afile.txt"], "afile.txt", "is a file"),
    "fmu to a device": (["export", "model.json", "--fmu", "/dev/null"], "/dev/null", "not a regular file"),
    "casadi to a device": (["export", "model.json", "--casadi", "/dev/stdout"], "/dev/stdout", "not a regular file"),
}


@pytest.mark.parametrize("case", sorted(EARLY))
def test_outputs_checked_before_work(case, work, capsys, monkeypatch):
    """Unwritable outputs are one line naming the user's path (no hidden temporary file),
    exit 2, before any input is read (the loaders are traps)."""
    def trap(*a, **k):
        raise AssertionError("work started before the outputs were checked")

    _trap_work(monkeypatch, trap)
    (work / "adir").mkdir()
    (work / "afile.txt").write_text("notes")
    argv, path, words = EARLY[case]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and path in err[0] and words in err[0] and "lpvpc-tmp" not in err[0], err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_refused_before_work(work, capsys):
    ro = work / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", "ro/model.json"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "ro/model.json" in err[0] and "not writable" in err[0], err
    finally:
        ro.chmod(0o755)


# --------------------------------------------------------------------------- as processes
def _cli(*argv, cwd, timeout=LIMIT_S, capture=True, **kw):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=capture, text=True,
                          cwd=cwd, env=env, timeout=timeout, **kw)


@pytest.mark.parametrize("argv", [
    ["whole-joint", "model.json", "--ut", "s.mat:ut", "-o", "s.mat"],
    ["improve", "--pt", "s.mat:pt", "--ut", "s.mat:ut", "--heldout-pt", "h.mat:pt", "--heldout-ut", "h.mat:ut",
     "--report", "rep", "-o", "s.mat", "--json", "h.mat"],
    ["identify", "--pt", "s.mat:pt", "--ut", "hard.mat:ut", "-o", "s.mat"],
    ["predict", "model.json", "--pt", "s.mat:pt", "--ut", "UT.csv", "--json", "link.mat"],
], ids=["whole-joint", "improve", "identify-hardlink", "predict-symlink"])
def test_issue_cases_as_processes(argv, work):
    """The issue's two recordings lost (whole-joint and improve wrote over s.mat and h.mat):
    refused, exit 2, one line naming both, both recordings intact."""
    (work / "h.mat").write_bytes((work / "s.mat").read_bytes())
    os.link(work / "s.mat", work / "hard.mat")
    (work / "link.mat").symlink_to(work / "s.mat")
    hashes = _hashes(work)
    r = _cli(*argv, cwd=work)
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lpvpc: error: ") and "s.mat" in lines[0], r.stderr
    assert _hashes(work) == hashes and not (work / "rep").exists()


# --------------------------------------------------------------------------- special files, modes
PREDICT = ["predict", "model.json", "--pt", "PT.csv", "--ut", "UT.csv"]


def test_fifo_with_a_reader_gets_the_output(work, capsys):
    """--json into a FIFO a reader waits on: the reader gets the whole JSON, the FIFO stays
    a FIFO (it was replaced by a regular file and the reader got nothing)."""
    import json
    import stat

    fifo = work / "metrics.fifo"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    try:
        assert main([*PREDICT, "--json", str(fifo)]) == 0
        out, _ = reader.communicate(timeout=30)
    finally:
        reader.kill()
        reader.wait()
    metrics = json.loads(out)
    assert metrics["n_samples"] > 0 and "vaf" in metrics
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    assert not list(work.glob(".*lpvpc-tmp"))
    capsys.readouterr()


def test_dev_stdout_and_a_device(work, tmp_path_factory):
    """--json /dev/stdout writes into the command's standard output, after the lines printed
    before it (into a pipe and into a redirected file, which keeps its inode); /dev/null is
    written into, never replaced; an FMU (built beside its target) to /dev/stdout is refused."""
    import json
    import stat

    r = _cli(*PREDICT, "--json", "/dev/stdout", "--out", "/dev/null", cwd=work)
    assert r.returncode == 0, r.stderr
    first, _, rest = r.stdout.partition("\n")
    assert first.startswith("VAF ") and json.loads(rest[: rest.rindex("}") + 1])["n_samples"] > 0
    assert os.path.islink("/dev/stdout") and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    log = tmp_path_factory.mktemp("stdout") / "run.log"
    with open(log, "w") as fh:
        inode = os.fstat(fh.fileno()).st_ino
        r = _cli(*PREDICT, "--json", "/dev/stdout", cwd=work, stdout=fh, capture=False, stderr=subprocess.PIPE)
    assert r.returncode == 0, r.stderr
    text = log.read_text()
    assert text.startswith("VAF ") and '"vaf"' in text and "metrics:   /dev/stdout" in text
    assert log.stat().st_ino == inode
    r = _cli("export", "model.json", "--fmu", "/dev/stdout", cwd=work)
    assert r.returncode == 2 and "not a regular file" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK):  # a regular file under /dev: replaced
        shm = Path("/dev/shm") / f"lpvpc-test-{os.getpid()}.json"
        try:
            shm.write_text("old content " * 1000)
            assert _cli(*PREDICT, "--json", shm, cwd=work).returncode == 0
            assert json.loads(shm.read_text())["n_samples"] > 0
        finally:
            shm.unlink(missing_ok=True)


def test_replaced_file_keeps_its_mode_and_owner(work, model, capsys):
    """A model file made private (0600) stays 0600 when it is rewritten (it became 0644);
    an output the CLI rewrites keeps its mode too; a new file gets 0666 less the umask."""
    private = work / "private.json"
    private.write_text("{}")
    private.chmod(0o600)
    model.save(private)
    assert private.stat().st_mode & 0o777 == 0o600
    shared = work / "m.json"
    shared.write_text("{}")
    shared.chmod(0o640)
    assert main([*PREDICT, "--json", "m.json"]) == 0
    assert shared.stat().st_mode & 0o777 == 0o640 and '"vaf"' in shared.read_text()
    old = os.umask(0o027)
    try:
        model.save(work / "new.json")
    finally:
        os.umask(old)
    assert (work / "new.json").stat().st_mode & 0o777 == 0o640
    if os.geteuid() == 0:  # owner and group follow where permitted (root may give them away)
        os.chown(private, 1234, 2345)
        model.save(private)
        st = private.stat()
        assert (st.st_uid, st.st_gid, st.st_mode & 0o777) == (1234, 2345, 0o600)
    capsys.readouterr()


# --------------------------------------------------------------------------- a model over a non-model
MODEL_WRITERS = {
    "identify": ["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", "victim.csv"],
    "whole-joint": ["whole-joint", "model.json", "--ut", "UT.csv", "-o", "victim.csv"],
    "improve": ["improve", "--pt", "PT.csv", "--ut", "UT.csv", "--heldout-pt", "PT2.csv", "--heldout-ut", "UT2.csv",
                "--report", "newrep", "-o", "victim.csv", "--max-steps", "0"],
}


@pytest.mark.parametrize("command", sorted(MODEL_WRITERS))
def test_model_never_written_over_a_recording(command, work, capsys, monkeypatch):
    """Every command that saves a model refuses, before any work, an existing file that is not
    a model file of ours (a recording given as -o by mistake): one line, exit 2, the file
    unchanged; --force lets it through the check (the work then starts: the trap fires)."""
    def trap(*a, **k):
        raise AssertionError("work started")

    _trap_work(monkeypatch, trap)
    victim = work / "victim.csv"
    victim.write_bytes((work / "UT2.csv").read_bytes())
    before = victim.read_bytes()
    assert main(MODEL_WRITERS[command]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "victim.csv" in err[0] and "not an lpvpc model file" in err[0] and "--force" in err[0]
    assert victim.read_bytes() == before
    with pytest.raises(AssertionError, match="work started"):
        main([*MODEL_WRITERS[command], "--force"])
    assert victim.read_bytes() == before


def test_a_model_may_replace_a_model(work, capsys, monkeypatch):
    """The check lets a model replace a model file of ours (a re-run), an empty file and a new path."""
    from lpvpc.cli import COMMAND_IO
    from lpvpc.io.outputs import is_model_file

    assert is_model_file(work / "model.json") and not is_model_file(work / "PT.csv")
    (work / "empty.json").write_text("")
    parser = build_parser()
    for out in ("model.json", "empty.json", "fresh.json"):
        args = parser.parse_args(["identify", "--pt", "PT.csv", "--ut", "UT.csv", "-o", out])
        COMMAND_IO["identify"].check(args)  # no error
