"""The ``lpvpc`` command line.

::

    lpvpc simulate --out DIR [--seed N] [--snr DB] [--fs 1000|100] [--effect NAME ...] [--duration S]
    lpvpc simulate --out DIR --population-seed N [--effect NAME [--form FORM]] [--fs 1000|100] [--duration S]
    lpvpc simulate --out DIR --cohort N [--null] [--within] [--population-seed FIRST] [--fs HZ] [--duration S]
    lpvpc study MANIFEST.csv -o DIR [-j N | --scheduler ADDRESS] [--heldout FRACTION] [--compare REF OTHER]
                [--diagnose]
    lpvpc identify (--pt PT.csv --ut UT.csv [--pt PT2 --ut UT2 ...] | DATA.csv [DATA2 ...]
                    | --pt PT.mat --stationary) -o model.json [estimator settings]
                   [--effect NAME ...] [--position-unit rad|deg] [--torque-sign 1|-1] [--fs HZ]
                   [--variable NAME] [--channel ROLE=NAME ...] [--channel-skew-ms MS|auto]
                   [--hold-out FRACTION|START:STOP]
    lpvpc predict model.json (--pt PT.csv --ut UT.csv | DATA.csv) [--json metrics.json]
                  [--out predicted.csv] [--causal] [--position-unit rad|deg] [--torque-sign 1|-1]
    lpvpc export model.json [--casadi F.casadi] [--fmu F.fmu] [--fmi 2|3] [--exact] [--fmi-type cs|me]
    lpvpc whole-joint model.json --ut UT.csv -o whole.json [--cutoff HZ] [--order N] [--fmu F.fmu]
                      [--fmi 2|3] [--fmi-type cs|me] [--casadi F.casadi] [--closed-loop [--pt PT.csv]
                      [--position-delay-ms MS|auto]]
    lpvpc validate model.json --pt PT.csv --ut UT.csv --report DIR [--min-vaf X] [--fmu F.fmu]
                   [--fmi 2|3] [--actuator-fmu F.fmu] [--actuator-param NAME=VALUE ...] [--no-calibrate]
                   [--coupling iterate|delay] [--no-band-limit-command] [--fmu-variant exact|causal]
                   [--route-tolerance TOL] [--whole-joint whole.json] [--hold-out [FRACTION|START:STOP]]
    lpvpc diagnose model.json (--pt PT.csv --ut UT.csv | DATA.csv) [--json diagnosis.json] [--report DIR]
                   [--hold-out [FRACTION|START:STOP] | --reference-pt PT0.csv --reference-ut UT0.csv |
                   --reference DATA0.csv]
    lpvpc improve (--pt PT.csv --ut UT.csv | DATA.csv) (--heldout-pt PT2.csv --heldout-ut UT2.csv |
                  --heldout DATA2.csv | --hold-out FRACTION|START:STOP) --report DIR [--stationary]
                  [--json ladder.json] [--max-steps N] [--effect NAME ...]

``study`` exits with status 1 when a record failed (the others are finished); ``validate`` with 1
when a threshold fails (``--min-vaf``, route agreement).
Errors of the package (bad data, corrupt model file, ...) and unreadable or unwritable
paths are printed as one line ``lpvpc: error: <message>`` on stderr, with exit status 2
for bad input (1 for other failures); out-of-range and unit warnings as one line
``lpvpc: warning: <message>`` each. Command-line usage errors exit 2.

Outputs (:mod:`lpvpc.io.outputs`): every command's inputs and outputs are declared in
:data:`COMMAND_IO` and checked before any work: no output may be, link to or contain one of
the command's inputs, and its folder must exist and be writable (exit 2, one line); files
are written to a temporary file and renamed, report folders built beside and swapped in;
``--force`` (validate, diagnose, improve) replaces a report folder that holds files but no
previous report; a model (identify, whole-joint, improve ``-o``) replaces only a model file
of ours unless ``--force``. SIGTERM takes the Ctrl-C clean-up path (exit 143; Ctrl-C 130).
``lpvpc -v COMMAND ...`` prints the library's notes (e.g. CSV columns that were ignored).
``--hold-out`` (identify, validate, diagnose, improve) keeps a later stretch of one record out
of identification and uses it as the held-out record (:func:`lpvpc.io.hold_out`); identify
records it in the model file (``fit["hold_out"]``), and a bare ``--hold-out`` in validate and
diagnose takes that stretch. ``diagnose --reference`` (or ``--reference-pt``/``--reference-ut``)
gives the record the model was identified on, as improve has it, to try the effects whose
signal can differ between records (:func:`lpvpc.diagnosis.diagnose.diagnose`'s ``reference``).

Layout: each command is a module of this package (:mod:`lpvpc.cli.identify`, ...) with
``add_parser(sub)``, which registers its options, and ``run(args) -> int``, which checks them,
calls the library and prints; the plumbing they share (argument types and groups, loading a
record, messages in command-line syntax) is in ``_common``, running a command (warnings,
progress lines, SIGTERM) in ``_running``. Building the parser imports no heavy module: each
command imports the library where it runs.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import warnings

from .. import __version__
from ..errors import LpvpcError, LpvpcWarning
from ..io.outputs import CommandIO
from . import diagnose, export, identify, improve, predict, simulate, study, validate, whole_joint
from ._common import OSERROR_STATUS, PROG, _err, _os_message
from ._running import Terminated, _ProgressLines, _show_notes, _show_warning, _terminate_as_interrupt

#: The commands in the order ``lpvpc --help`` lists them, each a module with ``add_parser(sub)``
#: and ``run(args) -> int``.
COMMANDS = (simulate, study, identify, predict, export, validate, whole_joint, diagnose, improve)

# What each command reads and writes ({option: argparse dest}): the one output policy
# (lpvpc.io.outputs.CommandIO) checks these before the command runs. A new command or file
# option needs its entry here (tests/test_output_policy.py fails without it).
_DATA = {"DATA": "data", "--pt": "pt", "--ut": "ut"}
COMMAND_IO = {
    "simulate": CommandIO(folders={"--out": "out"}),
    "study": CommandIO(inputs={"MANIFEST": "manifest"}, folders={"-o": "out"}),
    "identify": CommandIO(inputs=_DATA, files={"-o": "output"}, models=("-o",)),
    "predict": CommandIO(inputs={"MODEL": "model", **_DATA}, files={"--json": "json", "--out": "out"}),
    "export": CommandIO(inputs={"MODEL": "model"}, files={"--casadi": "casadi", "--fmu": "fmu"},
                        sidecars={"--casadi": (".json",)}, regular=("--fmu", "--casadi"), make_folders=("--fmu",)),
    "whole-joint": CommandIO(inputs={"MODEL": "model", "--ut": "ut", "--pt": "pt"},
                             files={"-o": "out", "--fmu": "fmu", "--casadi": "casadi"},
                             sidecars={"--casadi": (".json",)}, regular=("--fmu",), make_folders=("--fmu",),
                             models=("-o",)),
    "validate": CommandIO(inputs={"MODEL": "model", "DATA": "data", "--pt": "pt", "--ut": "ut", "--fmu": "fmu",
                                  "--actuator-fmu": "actuator_fmu", "--whole-joint": "whole_joint"},
                          folders={"--report": "report"}),
    "diagnose": CommandIO(inputs={"MODEL": "model", **_DATA, "--reference": "reference",
                                  "--reference-pt": "reference_pt", "--reference-ut": "reference_ut"},
                          files={"--json": "json"}, folders={"--report": "report"}),
    "improve": CommandIO(inputs={**_DATA, "--heldout": "heldout", "--heldout-pt": "heldout_pt",
                                 "--heldout-ut": "heldout_ut"},
                         files={"-o": "output", "--json": "json"}, folders={"--report": "report"}, models=("-o",)),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Identify position-dependent (LPV parallel-cascade) models of ankle stiffness "
                    "from a perturbed (PT) and an unperturbed (UT) trial; predict, and export them.",
        epilog="Units: time s, position rad, torque N m. Exit status 2 for bad input.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress lines on stderr (validate, improve, diagnose and identify print them)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="print notes on stderr (e.g. CSV columns that were ignored)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run the command line; returns the exit status (argparse usage errors: SystemExit 2)."""
    if "numpy" not in sys.modules:
        # As a program: one BLAS thread unless the user sets otherwise. The identification's
        # tall QR and least squares gain little from threads, and on a busy machine OpenBLAS
        # threads oversubscribe the cores (a 2-minute record on a loaded 2-core machine:
        # 51 s with threads, 2.6 s without). Only effective before numpy is imported.
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    previous = _terminate_as_interrupt()
    try:
        return _run(args)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _run(args) -> int:
    if getattr(args, "verbose", False):
        _show_notes()
    if not getattr(args, "quiet", False):
        with _ProgressLines():
            return _run_command(args)
    return _run_command(args)


def _run_command(args) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("always", LpvpcWarning)
        warnings.showwarning = _show_warning(warnings.showwarning)
        try:
            COMMAND_IO[args.command].check(args)  # before any work: no output over an input
            return args.func(args)
        except LpvpcError as exc:
            _err(exc)
            return exc.exit_status
        except OSError as exc:
            _err(_os_message(exc))
            return OSERROR_STATUS
        except MemoryError:
            _err(f"out of memory in {args.command} (input too large for this machine)")
            return 2
        except Terminated:
            _err("terminated")
            return 128 + signal.SIGTERM
        except KeyboardInterrupt:
            _err("interrupted")
            return 130
