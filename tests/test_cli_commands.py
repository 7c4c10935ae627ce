"""The command line is a package with one short module per command: each defines
``add_parser(sub)`` (its options) and ``run(args) -> int`` (check them, call the library,
print), and ``build_parser`` registers every one of them; the shared plumbing lives apart.
Also the cohort options ``simulate --cohort N --within`` and ``study --diagnose``."""

import importlib
import inspect
import json
import subprocess
import sys
from pathlib import Path

import pytest

import lpvpc.cli
from lpvpc.cli import COMMAND_IO, COMMANDS, build_parser, main

NAMES = ("simulate", "study", "identify", "predict", "export", "whole_joint", "validate", "diagnose", "improve")
#: lines a command module may have (its options' help texts included)
MAX_LINES = 300


@pytest.mark.parametrize("name", NAMES)
def test_each_command_is_a_short_module_with_add_parser_and_run(name):
    module = importlib.import_module(f"lpvpc.cli.{name}")
    assert module in COMMANDS
    for fn in ("add_parser", "run"):
        assert inspect.isfunction(getattr(module, fn, None)), f"lpvpc.cli.{name} lacks {fn}"
    assert list(inspect.signature(module.run).parameters) == ["args"]
    lines = len(Path(module.__file__).read_text().splitlines())
    assert lines <= MAX_LINES, f"lpvpc/cli/{name}.py has {lines} lines (at most {MAX_LINES}: move plumbing out)"


def test_build_parser_registers_every_command_with_its_run():
    parser = build_parser()
    choices = parser._subparsers._group_actions[0].choices
    assert list(choices) == [m.__name__.rpartition(".")[2].replace("_", "-") for m in COMMANDS]
    assert set(choices) == set(COMMAND_IO)
    for module in COMMANDS:
        command = module.__name__.rpartition(".")[2].replace("_", "-")
        assert choices[command].get_default("func") is module.run, command


def test_the_package_init_keeps_only_main_and_the_parser():
    lines = len(Path(lpvpc.cli.__file__).read_text().splitlines())
    assert lines < 250, lines
    assert not [n for n, v in vars(lpvpc.cli).items() if n.startswith("cmd_") and callable(v)]


def test_python_dash_m_runs_the_package():
    proc = subprocess.run([sys.executable, "-m", "lpvpc.cli", "--version"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.startswith("lpvpc "), proc.stderr


def test_simulate_within_writes_every_subject_in_both_groups(tmp_path, capsys):
    from lpvpc.study.manifest import read_manifest

    assert main(["-q", "simulate", "--out", str(tmp_path / "c"), "--cohort", "2", "--within", "--duration", "20",
                 "--fs", "100"]) == 0
    assert "each recorded in both groups" in capsys.readouterr().out
    rows = read_manifest(tmp_path / "c" / "manifest.csv")
    assert [(r.subject, r.group) for r in rows] == [("S01", "control"), ("S01", "patient"), ("S02", "control"),
                                                    ("S02", "patient")]
    assert json.loads((tmp_path / "c" / "truth.json").read_text())["design"] == "within"
    assert main(["-q", "simulate", "--out", str(tmp_path / "d"), "--within"]) == 2
    assert "--within needs --cohort N" in capsys.readouterr().err


def test_study_diagnose_diagnoses_each_record_on_its_held_out_part(tmp_path, capsys):
    import csv

    from lpvpc.study.cohort import write_cohort

    paths = write_cohort(tmp_path / "cohort", 2, duration=70.0, fs=100.0)  # held out: 21 s, enough to diagnose
    assert build_parser().parse_args(["study", "m.csv", "-o", "x"]).diagnose is False
    assert main(["-q", "study", str(paths["manifest"]), "-o", str(tmp_path / "study"), "--diagnose"]) == 0
    with open(tmp_path / "study" / "records.csv", newline="") as f:
        missing = {row["record"]: row["missing_effect"] for row in csv.DictReader(f)}
    assert set(missing) == {"S01", "S02"}
    assert all(v not in ("", "not diagnosed") for v in missing.values()), missing
