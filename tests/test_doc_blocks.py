"""Every code block of the README and the user guide does what it shows.

Python blocks (```python, and ```pycon or ``>>>`` blocks) run verbatim: a page is a
tutorial, so its blocks run in order in one namespace, in a temporary working directory
holding the files the page assumes (the fixture table :data:`PAGE_FILES`: the virtual
subject that ``lpvpc simulate --out subject`` writes, a model file from ``lpvpc identify``,
an exported FMU, MATLAB files in the lab's format). A block that cannot run here is marked
in the markdown just before its fence with ``<!-- doc-test: skip (reason) -->`` and is
reported as skipped with that reason.

Shell blocks: every ``lpvpc ...`` line (``$ lpvpc ...`` in console blocks, and indented
code blocks) is parsed by the command line's own argument parser and must be accepted.
A synopsis line (``[--seed N]``, ``--fmi 2|3``, ``[...]``) is read as one concrete command:
optional groups included, the first alternative taken, a metavariable of a typed option
replaced by a valid value. A flag typed with an en or em dash ("–ut") is refused.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import re
import shlex
import shutil
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from lpvpc.cli import build_parser
from lpvpc.cli import main as cli_main

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs" / "guide").glob("*.md"))]
FENCE = re.compile(r"^```([\w-]*)[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)
SKIP = re.compile(r"<!--\s*doc-test:\s*skip\s*\((.+?)\)\s*-->\s*$")
PYTHON = ("python", "py", "pycon")
SHELL = ("sh", "bash", "shell", "console", "")
DASHES = ("\u2013", "\u2014", "\u2012", "\u2212")  # en dash, em dash, figure dash, minus sign


# --------------------------------------------------------------------------- reading pages


@dataclass
class Block:
    page: str  # path relative to the repository
    line: int  # line of the opening fence
    lang: str
    text: str
    skip: str | None = None

    @property
    def name(self) -> str:
        return f"{self.page}:{self.line}"


def _rel(path: Path) -> str:
    return path.relative_to(REPO).as_posix() if path.is_relative_to(REPO) else path.as_posix()


def blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a markdown page, with their skip markers."""
    text = path.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        before = text[:m.start()].rstrip("\n").splitlines()
        previous = next((ln for ln in reversed(before) if ln.strip()), "")
        skip = SKIP.search(previous)
        out.append(Block(_rel(path), text.count("\n", 0, m.start()) + 1, m.group(1).lower(), m.group(2),
                         skip.group(1) if skip else None))
    return out


def _python_source(block: Block) -> str:
    """The code of a Python block; a pycon (``>>>``) block's prompts and output removed."""
    lines = block.text.splitlines()
    if block.lang != "pycon" and not any(ln.startswith(">>>") for ln in lines):
        return block.text
    code = [ln[4:] for ln in lines if ln.startswith((">>> ", "... ")) or ln in (">>>", "...")]
    return "\n".join(code) + "\n"


def python_blocks(path: Path) -> list[Block]:
    return [b for b in blocks(path) if b.lang in PYTHON or (b.lang == "" and b.text.lstrip().startswith(">>>"))]


def shell_commands(path: Path) -> list[tuple[str, str]]:
    """(``page:line``, command) for each ``lpvpc`` command line of the page's shell blocks
    and indented code blocks, continuation lines joined."""
    rel = _rel(path)
    found = []
    text = path.read_text(encoding="utf-8")
    for b in blocks(path):
        if b.lang not in SHELL:
            continue
        found += _commands(b.text.splitlines(), b.line + 1, rel, console=b.lang == "console")
    # indented (4-space) code blocks outside fences
    outside = FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text).splitlines()
    indented = [ln[4:] if ln.startswith("    ") else None for ln in outside]
    for i, ln in enumerate(indented):
        if ln is not None and ln.startswith("lpvpc ") and (i == 0 or indented[i - 1] is None or
                                                          not indented[i - 1].rstrip().endswith("\\")):
            found += _commands([x or "" for x in indented[i:]], i + 1, rel, console=False, first_only=True)
    return found


def _commands(lines, first_line, rel, console, first_only=False):
    out = []
    i = 0
    while i < len(lines):
        ln = lines[i].strip()
        start = i
        if console:
            if not ln.startswith("$ "):
                i += 1
                continue
            ln = ln[2:].strip()
        while ln and re.match(r"[A-Z_][A-Z0-9_]*=\S*\s", ln):  # VAR=value before the command
            ln = ln.split(None, 1)[1]
        if not ln.startswith("lpvpc "):
            i += 1
            if first_only:
                break
            continue
        # continuation: a trailing backslash, or an indented line of further options
        while i + 1 < len(lines) and (ln.endswith("\\") or re.match(r"\s+[\[-]", lines[i + 1])):
            ln = ln.rstrip("\\").rstrip() + " " + lines[i + 1].strip()
            i += 1
        out.append((f"{rel}:{first_line + start}", ln))
        i += 1
        if first_only:
            break
    return out


# --------------------------------------------------------------------------- shell lines


def _subparser(parser, name):
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            return action.choices.get(name)
    return None


def _option_action(parser, flag):
    for action in parser._actions:
        if flag in action.option_strings:
            return action
    return None


def _synopsis_group(content: str) -> str:
    """One concrete reading of an optional group's content: the first alternative of each
    ``a|b``; a group without options (``[...]``, ``[settings]``) is left out."""
    if not re.search(r"(^|\s)-", content):
        return ""
    return " ".join(tok.split("|")[0] for tok in content.split())


def command_argv(command: str) -> list[str]:
    """The argv (without ``lpvpc``) of one command line as written in the docs."""
    words = shlex.split(command, comments=True)
    assert words[0] == "lpvpc"
    line = " ".join(shlex.quote(w) if not re.search(r"[\[\]|]", w) else w for w in words[1:])
    if re.search(r"[\[\]|]|(^|\s)\.\.\.(\s|$)", line):  # a synopsis
        while "[" in line:
            line = re.sub(r"\[([^\[\]]*)\]", lambda m: " " + _synopsis_group(m.group(1)) + " ", line)
        line = re.sub(r"(^|\s)\.\.\.(?=\s|$)", " ", line)
        line = " ".join(tok.split("|")[0] if not tok.startswith("'") else tok for tok in line.split())
        argv = shlex.split(line)
        return _fill_metavariables(argv)
    return words[1:]


def _fill_metavariables(argv: list[str]) -> list[str]:
    """A synopsis's metavariable (an upper-case word such as N, DB, X, NAME) after an option
    that takes a typed or restricted value stands for any valid value: the first choice, or 1."""
    parser = build_parser()
    sub = _subparser(parser, argv[0]) if argv else None
    out = list(argv)
    for i in range(1, len(out)):
        if not re.fullmatch(r"[A-Z][A-Z0-9_]*", out[i]) or not out[i - 1].startswith("-"):
            continue
        action = _option_action(sub, out[i - 1]) if sub else None
        if action is None:
            continue
        if action.choices:
            out[i] = str(next(iter(action.choices)))
        elif action.type not in (None, str):
            out[i] = "1"
    return out


def _bad_alternatives(command: str, name: str) -> list[str]:
    """In a synopsis's ``--opt a|b|c``, every alternative must be one of the option's choices."""
    sub = _subparser(build_parser(), name)
    bad = []
    for flag, values in re.findall(r"(--?[\w-]+)\s+([^\s\[\]|]+(?:\|[^\s\[\]|]+)+)", command):
        action = _option_action(sub, flag) if sub else None
        if action is not None and action.choices:
            bad += [f"{flag} {v}" for v in values.split("|") if v not in {str(c) for c in action.choices}]
    return bad


def parse_error(command: str) -> str | None:
    """None if the command line's arguments are accepted by lpvpc's parser, else why not."""
    dashed = [w for w in command.split() if w.startswith(DASHES)]
    if dashed:
        return f"flag written with a typographic dash instead of '-': {dashed}"
    argv = command_argv(command)
    bad = _bad_alternatives(command, argv[0] if argv else "")
    if bad:
        return f"alternatives not among the option's choices: {bad}"
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code not in (0, None):  # --version and --help exit 0
            message = stderr.getvalue().strip().splitlines()
            return f"argv {argv} refused: {message[-1] if message else exc.code}"
    return None


SHELL_LINES = [c for page in PAGES for c in shell_commands(page)]


def test_docs_show_lpvpc_commands():
    """The collection finds the commands of the quick start and of the synopses."""
    pages = {name.split(":")[0] for name, _ in SHELL_LINES}
    assert {"README.md", "docs/guide/command_line.md", "docs/guide/fmu_casadi.md"} <= pages
    assert any("--position-delay-ms auto" in c for _, c in SHELL_LINES)  # an indented block
    assert any(c.startswith("lpvpc identify --pt long.mat:pt") for _, c in SHELL_LINES)  # VAR=... $ lpvpc


@pytest.mark.parametrize("where,command", SHELL_LINES, ids=[f"{w}" for w, _ in SHELL_LINES])
def test_shell_line_is_accepted_by_the_parser(where, command):
    problem = parse_error(command)
    assert problem is None, f"{where}: `{command}`: {problem}"


@pytest.mark.parametrize("command,accepted", [
    ("lpvpc identify --pt PT.csv --ut UT.csv -o model.json", True),
    ("lpvpc identify --pt PT.csv \u2013ut UT.csv -o model.json", False),  # en dash
    ("lpvpc identify --pt PT.csv \u2014ut UT.csv -o model.json", False),  # em dash
    ("lpvpc identify --pt PT.csv --ut UT.csv --no-such-option -o model.json", False),
    ("lpvpc export model.json --variant causl", False),
    ("lpvpc export model.json [--fmi 2|3] [--variant sampled|causal|exact]", True),
    ("lpvpc simulate --out DIR [--seed N] [--fs 1000|100] [--effect NAME ...]", True),
    ("lpvpc simulate --out DIR [--seed N] [--colour C]", False),
    ("lpvpc export model.json [--variant sampled|causal|smooth]", False),  # each alternative checked
    ("lpvpc --version", True),
])
def test_the_shell_check_refuses_what_the_parser_refuses(command, accepted):
    assert (parse_error(command) is None) == accepted, parse_error(command)


# --------------------------------------------------------------------------- python blocks


def test_skip_markers_and_console_sessions_are_read(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n<!-- doc-test: skip (needs the lab's own file) -->\n```python\nopen('lab.mat')\n```\n\n"
                    "```pycon\n>>> x = 1 + 1\n>>> x\n2\n```\n\n```python\ny = 3\n```\n", encoding="utf-8")
    found = python_blocks(page)
    assert [b.skip for b in found] == ["needs the lab's own file", None, None]
    assert _python_source(found[1]) == "x = 1 + 1\nx\n"
    assert found[2].text == "y = 3\n" and found[2].line == 14



def _cli(*argv):
    status = cli_main([str(a) for a in argv])
    assert status == 0, f"lpvpc {' '.join(map(str, argv))}: exit status {status}"


def _subject(d, ctx):
    shutil.copytree(ctx.subject_dir, d / "subject")


def _pt_ut(d, ctx, prefix=""):
    for side in ("PT", "UT"):
        shutil.copy(ctx.subject_dir / f"ident_{side}.csv", d / f"{prefix}{side}.csv")


def _ident_novel(d, ctx):
    for stem in ("ident_PT", "ident_UT", "novel_PT", "novel_UT"):
        shutil.copy(ctx.subject_dir / f"{stem}.csv", d / f"{stem}.csv")


def _model(d, ctx):
    shutil.copy(ctx.model_file, d / "model.json")


def _casadi_causal(d, ctx):
    _model(d, ctx)
    _pt_ut(d, ctx)
    _cli("export", d / "model.json", "--casadi", d / "model_causal.casadi", "--variant", "causal")


def _ankle_fmu(d, ctx):
    _model(d, ctx)
    _pt_ut(d, ctx)
    _cli("whole-joint", d / "model.json", "--ut", d / "UT.csv", "--pt", d / "PT.csv", "-o", d / "cl.json",
         "--fmu", d / "ankle.fmu", "--closed-loop")


def _lab_files(d, ctx):
    """MATLAB files in the lab's format, written from the virtual subject: the pilot's
    perturbation file (nldat io: posPert1, tqPert1; sv: the scheduling), a PT/UT pair in one
    file with named channels, a stationary trial, two CSV trials and a later PT2/UT2 pair."""
    from matlab_files import nldat, write_mat

    from lpvpc.io import load_trial, write_trial_csv
    from lpvpc.simulation.simulate import simulate_pair

    pt, ut = (load_trial(ctx.subject_dir / f"ident_{s}.csv") for s in ("PT", "UT"))
    period = 1.0 / pt.fs
    write_mat(d / "PilotData.mat", {
        "io": nldat(np.column_stack([pt.position - ut.position, pt.torque - ut.torque]),
                    ["posPert1", "tqPert1"], period),
        "sv": nldat(ut.position[:, None], ["Ankle Position (rad)"], period)})
    names = ["Ankle Position", "Ankle Torque"]
    write_mat(d / "s1.mat", {"pt": nldat(np.column_stack([pt.position, pt.torque]), names, period),
                             "ut": nldat(np.column_stack([ut.position, ut.torque]), names, period)})
    rng = np.random.default_rng(0)
    n = 20000  # 20 s at 1 kHz around 0.15 rad
    pert = 0.03 * np.sign(np.sin(2 * np.pi * np.cumsum(rng.uniform(0, 8, n)) * period))
    stationary = np.column_stack([0.15 + pert, -3.0 + 40.0 * pert + 0.05 * rng.standard_normal(n)])
    write_mat(d / "experimental_data.mat", {"z_df": nldat(stationary, ["pos1", "tq1"], period)})
    for stem, seed in (("a", 4), ("b", 5)):
        pair = simulate_pair("multilevel", seed=seed, duration=30.0)
        write_trial_csv(pair.pt, d / f"{stem}_PT.csv")
        write_trial_csv(pair.ut, d / f"{stem}_UT.csv")
    _pt_ut(d, ctx)
    for side in ("PT", "UT"):  # a later record of the same subject
        shutil.copy(ctx.subject_dir / f"novel_{side}.csv", d / f"{side}2.csv")


# What each page assumes in its working directory (pages not listed assume nothing).
PAGE_FILES = {
    "README.md": [_subject],
    "docs/guide/getting_started.md": [_subject],
    "docs/guide/closed_loop.md": [_ankle_fmu],
    "docs/guide/data.md": [_lab_files],
    "docs/guide/fmu_casadi.md": [_casadi_causal],
    "docs/guide/identification.md": [_ident_novel],
    "docs/guide/model_format.md": [_model],
    "docs/guide/python-api.md": [_pt_ut],
    "docs/guide/reflex_intervals.md": [_model],
}

PY_PAGES = [p for p in PAGES if python_blocks(p)]
PY_BLOCKS = [(_rel(p), i) for p in PY_PAGES for i in range(len(python_blocks(p)))]


@dataclass
class PageRun:
    """One page's tutorial in progress: its folder, namespace and what has run."""

    folder: Path
    blocks: list
    namespace: dict = field(default_factory=lambda: {"__name__": "__doc_page__"})
    done: int = 0
    failed: str | None = None


@dataclass
class Context:
    subject_dir: Path
    model_file: Path


@pytest.fixture(scope="session")
def doc_context(tmp_path_factory, model_file):
    """The virtual subject as ``lpvpc simulate --out subject`` writes it, and the session's
    identified model file (conftest: identified from the same seed's data)."""
    from lpvpc.simulation.simulate import write_dataset

    folder = tmp_path_factory.mktemp("doc_subject") / "subject"
    write_dataset(folder, seed=0)
    return Context(folder, Path(model_file))


_RUNS: dict[str, PageRun] = {}


def _page_run(page: str, ctx: Context, tmp_path_factory) -> PageRun:
    if page not in _RUNS:
        folder = tmp_path_factory.mktemp(re.sub(r"\W", "_", page))
        for prepare in PAGE_FILES.get(page, []):
            prepare(folder, ctx)
        _RUNS[page] = PageRun(folder, python_blocks(REPO / page))
    return _RUNS[page]


def _run_block(run: PageRun, block: Block) -> None:
    cwd = os.getcwd()
    os.chdir(run.folder)
    try:
        with warnings.catch_warnings():
            # a user sees warnings; here they would only be noise (e.g. the novel trajectory
            # leaves the identified scheduling range a little)
            warnings.simplefilter("ignore")
            exec(compile(_python_source(block), block.name, "exec"), run.namespace)
    finally:
        os.chdir(cwd)
        import matplotlib.pyplot as plt

        plt.close("all")


def _run_through(run: PageRun, index: int) -> None:
    """Run the page's blocks up to ``index`` that have not run yet (all of them before it
    when one block is selected alone); a failure stops the page."""
    while run.done <= index:
        block = run.blocks[run.done]
        run.done += 1
        if run.failed:
            break
        if block.skip:
            continue
        try:
            _run_block(run, block)
        except BaseException as exc:
            run.failed = f"{block.name}: {type(exc).__name__}: {exc}"
            if run.done - 1 == index:
                raise


@pytest.mark.slow
@pytest.mark.parametrize("page,index", PY_BLOCKS, ids=[f"{p}#{i + 1}" for p, i in PY_BLOCKS])
def test_python_block_runs_verbatim(page, index, doc_context, tmp_path_factory):
    run = _page_run(page, doc_context, tmp_path_factory)
    _run_through(run, index)
    block = run.blocks[index]
    if block.skip:
        pytest.skip(f"{block.name}: {block.skip}")
    if run.failed:
        pytest.fail(f"an earlier block of the page failed ({run.failed})")


def _check_quick_start(ns, folder):
    assert ns["vaf"](ns["test"].torque, ns["pred"].total) > 95.0
    k = np.asarray(ns["model"].elastic_stiffness([-0.3, 0.0, 0.15]))
    assert np.all(k > 0) and k[2] > k[1]  # stiffer toward dorsiflexion
    assert np.all(np.asarray(ns["lo"]) < k) and np.all(k < np.asarray(ns["hi"]))
    assert (folder / "model.fmu").stat().st_size > 0


def _check_fmu_casadi(ns, folder):
    """The checked CasADi step loop and the Model Exchange FMU give the offline causal prediction."""
    model, data = ns["model"], ns["record"]
    # the model-rate signals, as the exports take them (fmu_casadi.md: a model that sees 1 kHz velocity)
    offline = model.predict(dataclasses.replace(data, high_rate=None), causal=True).total
    scale = np.abs(offline).max()
    lag = int(ns["meta"]["latency_samples"])  # the sampled variant's latency, samples
    stepped = np.asarray(ns["torque"], dtype=float).ravel()[lag:]  # call k returns sample k - lag
    np.testing.assert_allclose(stepped, offline[:len(stepped)], rtol=0, atol=1e-9 * scale)
    me = np.asarray(ns["res"]["torque"])[lag:len(offline)]  # the value at t_k is sample k - lag
    np.testing.assert_allclose(me, offline[:len(me)], rtol=0, atol=1e-9 * scale)


# What a page's finished tutorial must have produced.
PAGE_CHECKS = {
    "README.md": _check_quick_start,
    "docs/guide/getting_started.md": _check_quick_start,
    "docs/guide/fmu_casadi.md": _check_fmu_casadi,
}


@pytest.mark.slow
@pytest.mark.parametrize("page", sorted(PAGE_CHECKS))
def test_page_tutorial_gives_what_it_says(page, doc_context, tmp_path_factory):
    run = _page_run(page, doc_context, tmp_path_factory)
    _run_through(run, len(run.blocks) - 1)
    assert not run.failed, run.failed
    PAGE_CHECKS[page](run.namespace, run.folder)


def test_every_page_with_python_has_what_it_needs_listed():
    """Every page named in the fixture table exists and has Python blocks, so the table
    does not silently outlive a page."""
    names = {_rel(p) for p in PY_PAGES}
    assert set(PAGE_FILES) <= names, set(PAGE_FILES) - names
    assert len(PY_BLOCKS) >= 15
