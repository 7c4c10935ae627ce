"""The ``lpvpc`` command line.

::

    lpvpc simulate --out DIR [--seed N] [--snr DB] [--fs 1000|100] [--effect NAME ...] [--duration S]
    lpvpc simulate --out DIR --population-seed N [--effect NAME [--form FORM]] [--fs 1000|100] [--duration S]
    lpvpc simulate --out DIR --cohort N [--null] [--population-seed FIRST] [--fs HZ] [--duration S]
    lpvpc study MANIFEST.csv -o DIR [-j N | --scheduler ADDRESS] [--heldout FRACTION] [--compare REF OTHER]
    lpvpc identify (--pt PT.csv --ut UT.csv [--pt PT2 --ut UT2 ...] | DATA.csv [DATA2 ...]
                    | --pt PT.mat --stationary) -o model.json [estimator settings]
                   [--effect NAME ...] [--position-unit rad|deg] [--torque-sign 1|-1] [--fs HZ]
                   [--variable NAME] [--channel ROLE=NAME ...] [--channel-skew-ms MS|auto]
    lpvpc predict model.json (--pt PT.csv --ut UT.csv | DATA.csv) [--json metrics.json]
                  [--out predicted.csv] [--causal] [--position-unit rad|deg] [--torque-sign 1|-1]
    lpvpc export model.json [--casadi F.casadi] [--fmu F.fmu] [--fmi 2|3] [--exact] [--fmi-type cs|me]
    lpvpc whole-joint model.json --ut UT.csv -o whole.json [--cutoff HZ] [--order N] [--fmu F.fmu]
                      [--fmi 2|3] [--fmi-type cs|me] [--casadi F.casadi] [--closed-loop [--pt PT.csv]
                      [--position-delay-ms MS|auto]]
    lpvpc validate model.json --pt PT.csv --ut UT.csv --report DIR [--min-vaf X] [--fmu F.fmu]
                   [--fmi 2|3] [--actuator-fmu F.fmu] [--actuator-param NAME=VALUE ...] [--no-calibrate]
                   [--coupling iterate|delay] [--no-band-limit-command] [--fmu-variant exact|causal]
                   [--route-tolerance TOL] [--whole-joint whole.json]
    lpvpc diagnose model.json (--pt PT.csv --ut UT.csv | DATA.csv) [--json diagnosis.json] [--report DIR]
    lpvpc improve (--pt PT.csv --ut UT.csv | DATA.csv) (--heldout-pt PT2.csv --heldout-ut UT2.csv |
                  --heldout DATA2.csv) --report DIR [--stationary] [--json ladder.json] [--max-steps N]
                  [--effect NAME ...]

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
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from .. import __version__
from ..errors import LpvpcError, LpvpcWarning
from ..io.outputs import CommandIO, atomic_path, staged_folder, write_text
from ..progress import report as progress

PROG = "lpvpc"
# Exit status for unreadable/unwritable paths: bad input, like the package's input errors.
OSERROR_STATUS = 2


class _UsageError(LpvpcError):
    """A combination of options argparse cannot check (printed like any other error)."""

    exit_status = 2


def _one_line(text) -> str:
    return " ".join(str(text).split())


#: The library names its fixes in Python (keywords); on the command line they read as the
#: options that do the same. Pattern -> replacement, applied in order.
CLI_SYNTAX = (
    (r"channels=\{'(\w+)': COLUMN\}( \(--channel \w+=COLUMN\))?", r"--channel \1=COLUMN"),
    (r"\bchannel_skew=0 given\b", "--channel-skew-ms 0"),
    (r"\btarget_fs=None\b", "--fs 0"),
    (r"\btarget_fs=", "--fs "),
    (r"\bstationary=True\b", "--stationary"),
    (r"\bhigh_rate_reflex=True\b", "--high-rate-reflex"),
    (r"\bhigh_rate_reflex=False\b", "--model-rate-reflex"),
    (r"\bpt=PT\b", "--pt PT"),
    (r"\but=UT\b", "--ut UT"),
    (r"\bthe pt and ut arguments\b", "the --pt and --ut files"),
    # a keyword, not a field of a file ("conventions.torque_sign")
    (r"(?<![.\w])(position_unit|time_unit|torque_sign|velocity_order|intrinsic_order|reflex_order|state_order|"
     r"max_state_order|irf_lags|irf_length|reflex_delay|causal_lags|max_iter|relaxation_times|relaxation_order)"
     r"\b(='?([\w.+-]+)'?)?",
     lambda m: "--" + m.group(1).replace("_", "-") + (f" {m.group(3)}" if m.group(3) else "")),
    # a message that gave both syntaxes: once
    (r"\((--[^,()]+), \1\)", r"(\1)"),
    (r"(--[\w-]+ [^\s()]+) \(\1\)", r"\1"),  # "--torque-sign -1 (torque_sign=-1)": once
)


def cli_syntax(message) -> str:
    """A library message with its Python keywords as command-line options.

    >>> cli_syntax("pass position_unit='deg' if it is in degrees; or target_fs=None")
    'pass --position-unit deg if it is in degrees; or --fs 0'
    >>> cli_syntax("read it as stationary (stationary=True, --stationary); conventions.torque_sign must be 1")
    'read it as stationary (--stationary); conventions.torque_sign must be 1'
    >>> cli_syntax("identify again with --torque-sign -1 (torque_sign=-1)")
    'identify again with --torque-sign -1'
    """
    import re

    text = str(message)
    for pattern, replacement in CLI_SYNTAX:
        text = re.sub(pattern, replacement, text)
    return text


def _err(message) -> None:
    print(f"{PROG}: error: {_one_line(cli_syntax(message))}", file=sys.stderr)


def _os_message(exc: OSError) -> str:
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


# --------------------------------------------------------------------------- loading


def _listed(value) -> list:
    return list(value) if isinstance(value, list) else [] if value is None else [value]


def _load_data(args, *, target_fs, position_unit, torque_sign, time_unit=None, channel_skew=0.0):
    """PerturbationData from DATA, --pt/--ut or --pt --stationary (SI units after the
    loader); several files (identify) are joined as trials of one identification; the
    channel skew (s; "auto": chosen by a scan before loading; None: not given, for identify
    to line up itself) undone at the files' rate (lpvpc.identification.channel_skew)."""
    from ..identification.channel_skew import load_aligned
    from ..io import load_identification_data

    data, pts, uts = _listed(args.data), _listed(args.pt), _listed(args.ut)
    stationary = getattr(args, "stationary", False)
    if data and (pts or uts):
        raise _UsageError("give either DATA or --pt and --ut, not both")
    if stationary:
        if data and not (pts or uts):  # DATA --stationary: the stationary trial's file itself
            data, pts = [], data
        if data or uts:
            raise _UsageError("--stationary reads one perturbed trial, DATA or --pt, recorded without UT")
        if not pts:
            raise _UsageError("missing --pt")
    elif not data:
        if not (pts and uts):
            if pts:
                raise _UsageError("missing --ut: give the unperturbed trial with --ut UT, or --stationary if the PT "
                                  "trial was recorded around one fixed position without a UT trial")
            raise _UsageError("missing --pt: give the perturbed trial with --pt PT" if uts else
                              "missing DATA or --pt and --ut: give the perturbed and the unperturbed trial as "
                              "--pt PT --ut UT (or a PT - UT file with a scheduling column as DATA)")
        if len(pts) != len(uts):
            raise _UsageError(f"{len(pts)} --pt but {len(uts)} --ut: give the trials in PT/UT pairs")
    channels = _channel_options(args)
    kw = dict(position_unit=position_unit, torque_sign=torque_sign, target_fs=target_fs,
              variable=getattr(args, "variable", None), channels=channels,
              time_unit=getattr(args, "time_unit", None) or time_unit or "s", channel_skew=channel_skew)

    def one(items):  # a single file as itself, several as a list (trials of one identification)
        return items[0] if len(items) == 1 else items

    from ..errors import DataError

    load = load_aligned if channel_skew == "auto" else load_identification_data
    try:
        if data:
            return load(data=one(data), **kw)
        return load(pt=one(pts), ut=one(uts) if uts else None, stationary=stationary, **kw)
    except DataError as exc:
        if target_fs is None or hasattr(args, "fs"):
            raise
        # a command without --fs reads at a saved model's rate: keeping the file's rate is identify's option
        fix = (f"the model was identified at {target_fs:g} Hz: give data recorded at that rate or faster, or "
               f"identify a model at the file's own rate (lpvpc identify --fs 0)")
        problems = [p.replace("pass target_fs=None to keep the rate", fix) for p in exc.problems]
        if problems == exc.problems:
            raise
        raise DataError(problems, source=exc.source) from None


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
    "diagnose": CommandIO(inputs={"MODEL": "model", **_DATA}, files={"--json": "json"},
                          folders={"--report": "report"}),
    "improve": CommandIO(inputs={**_DATA, "--heldout": "heldout", "--heldout-pt": "heldout_pt",
                                 "--heldout-ut": "heldout_ut"},
                         files={"-o": "output", "--json": "json"}, folders={"--report": "report"}, models=("-o",)),
}


def check_report_folder(folder, markers, force) -> None:
    """A report folder is replaced as a whole: refuse a non-empty folder that holds no
    previous report (none of ``markers``) unless ``--force``."""
    folder = Path(folder)
    if force or not folder.is_dir() or any((folder / m).exists() for m in markers) or not any(folder.iterdir()):
        return
    raise _UsageError(f"report folder {folder} holds files but no previous report ({', '.join(markers)}); it is "
                      "replaced as a whole: give another folder, or --force to replace it")


def _estimator_defaults() -> dict:
    from ..identification.identify import LPVPCEstimator

    return {k: p.default for k, p in inspect.signature(LPVPCEstimator.__init__).parameters.items()
            if k != "self"}


# --------------------------------------------------------------------------- commands


def _simulate_population(args) -> int:
    """simulate --population-seed N: the population's subject N (lpvpc.simulation.population)."""
    from ..simulation.population import POPULATION_EFFECTS, draw_subject, write_subject

    fixed = [opt for opt, v in (("--seed", args.seed), ("--snr", args.snr), ("--perturbation", args.perturbation),
                                ("--stiffness-family", args.stiffness_family)) if v is not None]
    if fixed:
        raise _UsageError(f"{', '.join(fixed)} cannot be given with --population-seed (the subject draws them)")
    if args.population_seed < 0:
        raise _UsageError(f"--population-seed must be >= 0, got {args.population_seed}")
    if len(args.effect) > 1:
        raise _UsageError("--population-seed takes at most one --effect")
    effect = args.effect[0] if args.effect else None
    if effect is not None and effect not in POPULATION_EFFECTS:
        raise _UsageError(f"unknown population effect {effect!r} (known: {', '.join(POPULATION_EFFECTS)})")
    if args.form is not None and (effect is None or args.form not in POPULATION_EFFECTS[effect]):
        known = f"{effect}'s forms: {', '.join(POPULATION_EFFECTS[effect])}" if effect else "--form needs --effect"
        raise _UsageError(f"unknown form {args.form!r} ({known})")
    subject = draw_subject(args.population_seed, effect, args.form)
    paths = write_subject(subject, args.out, fs_out=args.fs, duration=args.duration)
    eff = f", effect {effect} ({subject.form})" if effect else ""
    print(f"population subject {args.population_seed}: {args.duration:g} s at {args.fs:g} Hz, SNR {subject.snr_db:.1f} dB, "
          f"perturbation {subject.design}, stiffness {subject.stiffness_form}{eff}")
    for path in paths.values():
        print(path)
    return 0


def _simulate_cohort(args) -> int:
    """simulate --cohort N: a virtual cohort in two groups with its manifest (lpvpc.study.cohort)."""
    from ..study.cohort import write_cohort

    fixed = [opt for opt, v in (("--seed", args.seed), ("--snr", args.snr), ("--perturbation", args.perturbation),
                                ("--stiffness-family", args.stiffness_family), ("--form", args.form))
             if v is not None] + (["--effect"] if args.effect else [])
    if fixed:
        raise _UsageError(f"{', '.join(fixed)} cannot be given with --cohort (the population draws the subjects)")
    if args.cohort < 2:
        raise _UsageError(f"--cohort needs at least 2 subjects (one per group), got {args.cohort}")
    first = args.population_seed or 0
    if first < 0:
        raise _UsageError(f"--population-seed must be >= 0, got {first}")
    paths = write_cohort(args.out, args.cohort, first_seed=first, null=args.null, duration=args.duration, fs=args.fs)
    what = "null cohort (no difference)" if args.null else "cohort (patient: K x1.5 toward dorsiflexion, reflex gain x2)"
    print(f"virtual {what}: {args.cohort} subjects, population seeds {first}..{first + args.cohort - 1}, "
          f"{args.duration:g} s at {args.fs:g} Hz")
    for path in paths.values():
        print(path)
    return 0


def cmd_study(args) -> int:
    from ..study import run_study

    if args.jobs < 1:
        raise _UsageError(f"-j must be at least 1, got {args.jobs}")
    if not 0.0 < args.heldout < 1.0:
        raise _UsageError(f"--heldout {args.heldout:g}: give a fraction between 0 and 1 (e.g. 0.3)")
    result = run_study(args.manifest, args.out, jobs=args.jobs, scheduler=args.scheduler, heldout=args.heldout,
                       compare=tuple(args.compare) if args.compare else None)
    print("\n".join(result.summary_lines()))
    return result.exit_status


def cmd_simulate(args) -> int:
    from ..simulation.simulate import EFFECTS, FS_SIM, PERTURBATIONS, write_dataset

    q = FS_SIM / args.fs
    if args.fs <= 0 or abs(q - round(q)) > 1e-9:
        raise _UsageError(f"--fs {args.fs:g} Hz must divide the simulation rate {FS_SIM:g} Hz (e.g. 1000 or 100)")
    if args.duration * args.fs < 100:
        raise _UsageError(f"--duration {args.duration:g} s is too short (need at least 100 samples)")
    if args.cohort is not None:
        return _simulate_cohort(args)
    if args.null:
        raise _UsageError("--null needs --cohort N")
    if args.population_seed is not None:
        return _simulate_population(args)
    if args.form is not None:
        raise _UsageError("--form needs --population-seed")
    for name, default in (("seed", 0), ("snr", 18.0), ("perturbation", "pralds"), ("stiffness_family", "standard")):
        if getattr(args, name) is None:
            setattr(args, name, default)

    unknown = [e for e in args.effect if e not in EFFECTS]
    if unknown:
        raise _UsageError(f"unknown effect {', '.join(map(repr, unknown))} (known: {', '.join(sorted(EFFECTS))})")
    if args.perturbation not in PERTURBATIONS:
        raise _UsageError(f"unknown perturbation {args.perturbation!r} (known: {', '.join(sorted(PERTURBATIONS))})")
    from ..simulation.subject import STIFFNESS_FAMILIES

    if args.stiffness_family not in STIFFNESS_FAMILIES:
        raise _UsageError(f"unknown stiffness family {args.stiffness_family!r} (known: {', '.join(STIFFNESS_FAMILIES)})")
    paths = write_dataset(args.out, seed=args.seed, fs_out=args.fs, snr_db=args.snr,
                          effects=tuple(args.effect), duration=args.duration, perturbation=args.perturbation,
                          stiffness_family=args.stiffness_family)
    effects = f", effects: {', '.join(args.effect)}" if args.effect else ""
    print(f"virtual subject, seed {args.seed}, {args.duration:g} s at {args.fs:g} Hz, SNR {args.snr:g} dB, "
          f"perturbation {args.perturbation}{effects}"
          + ("" if args.stiffness_family == "standard" else f", stiffness {args.stiffness_family}"))
    for path in paths.values():
        print(path)
    return 0


def _check_effect_names(names) -> tuple:
    from ..models.effects import CATALOG, SETTINGS

    names = tuple(names or ())
    unknown = [e for e in names if e not in CATALOG]
    if unknown:
        hint = "; settings candidates (not effects) are changed with their own options" if any(
            e in SETTINGS for e in unknown) else ""
        raise _UsageError(f"unknown effect {', '.join(map(repr, unknown))} (known: {', '.join(CATALOG)}){hint}")
    if len(set(names)) != len(names):
        raise _UsageError(f"effect given twice: {', '.join(names)}")
    return names


def _check_allowed_effects(names) -> tuple:
    """--allow-effect names ("none": no effect is offered to the selection)."""
    from ..identification.selection import cv_effect_problem

    if list(names) == ["none"]:
        return ()
    names = _check_effect_names(names)
    for n in names:
        problem = cv_effect_problem(n)
        if problem:
            raise _UsageError(f"--allow-effect: {problem}")
    return names


def cmd_identify(args) -> int:
    defaults = _estimator_defaults()
    settings = {k: getattr(args, k) for k in defaults if getattr(args, k, None) is not None}
    if "effects" in settings:
        settings["effects"] = _check_effect_names(settings["effects"])
    if "allow_effects" in settings:
        settings["allow_effects"] = _check_allowed_effects(settings["allow_effects"])
    if "relaxation_times" in settings:
        settings["relaxation_times"] = tuple(settings["relaxation_times"])
    if args.state_order == "auto":
        settings.pop("state_order")
    elif "state_order" in settings:
        settings["state_order"] = int(settings["state_order"])
    if settings.get("structure", "cv") == "cv":  # (the default) what the user wrote is not selected
        from ..identification.selection import REFLEX_PATH_SETTINGS, SEARCH

        settings["structure_fixed"] = tuple(k for k in settings if k in SEARCH or k == "irf_lags"
                                            or k in REFLEX_PATH_SETTINGS)
    from ..identification.identify import LPVPCEstimator

    try:  # a bad setting in one line, before any file is read
        LPVPCEstimator(**settings).check_settings()
    except ValueError as exc:
        raise _UsageError(str(exc)) from None
    target_fs = None if args.fs == 0 else args.fs
    skew = _channel_skew(args.channel_skew_ms)
    load = dict(target_fs=target_fs, position_unit=args.position_unit, torque_sign=args.torque_sign)
    # "auto" (the default): the loader is not given a skew, and the fit lines up a late torque
    # channel itself (lpvpc.identification.identify, as Python's identify does)
    data = _load_data(args, **load, channel_skew=None if skew == "auto" else skew)
    t0 = time.perf_counter()
    est = _identified(data, settings)
    elapsed = time.perf_counter() - t0
    model = est.model_
    model.save(args.output)

    fit = model.fit
    lo, hi = model.scheduling_range
    q = data.meta.get("decimation", 1)
    via = f" via {data.meta['resampled_to']:g} Hz" if "resampled_to" in data.meta else ""
    rate = f"{data.fs:g} Hz" + (f" (decimated from {data.meta['fs_original']:g} Hz{via})" if q > 1 else "")
    trials = f"{len(data.segments)} trials, " if data.segments else ""
    print(f"data:        {trials}{data.n} samples at {rate}, {data.n / data.fs:.1f} s, "
          f"position range {lo:+.3f}..{hi:+.3f} rad")
    if data.meta.get("stationary"):
        ops = data.meta.get("operating_points", [data.meta.get("operating_point")])
        print(f"stationary:  no UT trial; operating point {', '.join(f'{x:+.4f}' for x in ops)} rad "
              f"(the trial's mean position; its mean torque removed)")
    for line in model.summary().lines:
        print(cli_syntax(line))
    if model.effects:
        print(f"effects:     {', '.join(fe.name for fe in model.effects)} (extra inputs: "
              f"{', '.join(model.signals) or 'none'})")
    print(f"time:        {elapsed:.2f} s")
    print(f"model:       {args.output} (hash {model.model_hash[:12]})")
    return 0


def _identified(data, settings):
    """The fitted estimator (identify's fit, with its progress line when it takes long)."""
    from ..identification.identify import LPVPCEstimator, with_base_model_activation

    data = with_base_model_activation(data, settings)  # activation as predict estimates it (one extra fit)
    est = LPVPCEstimator(**settings)
    # most fits take a second or two: a line only when this one takes longer
    with _progress_after(IDENTIFY_QUIET_S, f"identify: fitting {data.n} samples at {data.fs:g} Hz"
                         + (f" (reflex state order chosen among {est.min_state_order}..{est.max_state_order})"
                            if est.state_order is None else "") + " ..."), warnings.catch_warnings():
        # a skew found where --channel-skew-ms was given gets identify's own 'skew:' line instead
        warnings.filterwarnings("ignore", message="the torque channel lags the position channel")
        est.fit(data)
    return est


#: s: identify shows its progress line only when the fit has not finished by then
IDENTIFY_QUIET_S = 3.0


class _progress_after:
    """Report ``message`` as progress if the block is still running after ``seconds``."""

    def __init__(self, seconds, message):
        import threading

        self.timer = threading.Timer(seconds, progress, (message,))
        self.timer.daemon = True

    def __enter__(self):
        self.timer.start()

    def __exit__(self, *exc):
        self.timer.cancel()
        return False


def cmd_predict(args) -> int:
    import numpy as np

    from ..io import check_model_rate
    from ..models.model import LPVPCModel, vaf

    model = LPVPCModel.load(args.model)
    conv = model.conventions or {}
    position_unit = args.position_unit or conv.get("position_unit", "rad")
    torque_sign = args.torque_sign if args.torque_sign is not None else float(conv.get("torque_sign", 1.0))
    data = _load_data(args, target_fs=model.fs, position_unit=position_unit, torque_sign=torque_sign,
                      time_unit=conv.get("time_unit"), channel_skew=conv.get("channel_skew_s", 0.0))
    check_model_rate(data.fs, model.fs, source=data.source)
    signals = {}
    if model.effects:  # an extended model takes its extra channels from the data
        from ..models.effects import signals_from_data

        signals = signals_from_data(data, model)  # activation with the model's reflex drive, as improve fits it
    pred = model.predict(data, causal=args.causal, signals=signals)  # a 1 kHz reflex model: its 1 kHz path
    measured = data.torque
    metrics = {
        "vaf": vaf(measured, pred.total),
        "rmse": float(np.sqrt(np.mean((measured - pred.total) ** 2))),
        "n_samples": int(data.n),
        "fs": float(data.fs),
        "out_of_range_fraction": float(pred.out_of_range_fraction),
        "causal": bool(args.causal),
        "model_hash": model.model_hash,
        "data_hash": data.data_hash,
        "model": str(args.model),
        "data": data.source,
        "data_files": {"data": str(args.data)} if args.data is not None else {
            k: str(v) for k, v in (("pt", args.pt), ("ut", args.ut)) if v is not None},
        "units": {"vaf": "%", "rmse": "N m", "fs": "Hz"},
        "lpvpc_version": __version__,
    }
    form = "causal" if args.causal else "two-sided"
    print(f"VAF {metrics['vaf']:.2f} %  RMSE {metrics['rmse']:.3g} N m  ({data.n} samples at {data.fs:g} Hz, "
          f"{form} intrinsic IRF)")
    if args.json:
        write_text(args.json, json.dumps(metrics, indent=1) + "\n")
        print(f"metrics:   {args.json}")
    if args.out:
        cols = [data.time, measured, pred.total, pred.intrinsic, pred.reflex, data.position, data.scheduling]
        with atomic_path(args.out) as tmp:
            np.savetxt(tmp, np.column_stack(cols), delimiter=",", fmt="%.10g", comments="",
                       header="time,measured,predicted,intrinsic,reflex,position,scheduling")
        print(f"predicted: {args.out} (time s; torques N m; position, scheduling rad)")
    return 0


def cmd_export(args) -> int:
    from ..models.model import LPVPCModel

    if not (args.casadi or args.fmu):
        raise _UsageError("nothing to export: give --casadi FILE and/or --fmu FILE")
    model = LPVPCModel.load(args.model)
    try:
        from ..export import exporter as export
    except ModuleNotFoundError as exc:
        if exc.name != "lpvpc.export":
            raise
        raise LpvpcError("export is not available in this installation (module lpvpc.export.exporter missing)") from None
    variant = "exact" if args.exact else (args.variant or export.DEFAULT_VARIANT)
    if args.casadi:
        t0 = time.perf_counter()
        path = export.export_casadi(model, args.casadi, variant=variant)
        print(f"CasADi step function ({variant}): {path or args.casadi}  [{time.perf_counter() - t0:.2f} s]")
        import casadi

        from ..models.effects import SIGNALS

        units = {"position": "rad", "scheduling": "rad", "velocity": "rad/s", "acceleration": "rad/s^2",
                 "state": "the previous step's next_state", **{k: u for k, (u, _) in SIGNALS.items()}}
        step = casadi.Function.load(str(path or args.casadi))
        print(f"  inputs:  {', '.join(f'{n} ({units.get(n, chr(45))})' for n in step.name_in())}")
        print(f"  outputs: {', '.join(f'{n} (N m)' if n.startswith('torque') else n for n in step.name_out())}")
    if args.fmu:
        t0 = time.perf_counter()
        path = export.export_fmu(model, args.fmu, fmi_version=args.fmi, variant=variant, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange, a time event per sample"
        print(f"FMU (FMI {args.fmi}.0 {kind}, {variant}): {path or args.fmu}  "
              f"[{time.perf_counter() - t0:.2f} s]")
        for line in _fmu_interface(path or args.fmu, model):
            print(line)
    if args.casadi or args.fmu:
        lat = export.latency_samples(model, variant)
        lo, hi = model.scheduling_range
        print(f"latency:     {lat} sample{'s' if lat != 1 else ''} ({lat / model.fs:g} s at {model.fs:g} Hz) for the "
              f"{variant} variant; scheduling outside [{lo:+.3f}, {hi:+.3f}] rad: {model.beyond_range}")
    return 0


def _fmu_interface(path, model) -> list:
    """Lines naming the FMU's inputs and outputs with their units, as its modelDescription
    declares them; an extra input (EMG) with its level at identification (the same unit)."""
    from fmpy import read_model_description

    md = read_model_description(str(path))
    levels = model.provenance.get("signal_levels") or {}

    def one(v):
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or "1"
        level = (f"; RMS {levels[v.name]:.3g} at identification: give it in that unit" if v.name in levels else "")
        return f"{v.name} ({unit}{level})"

    by = {c: [one(v) for v in md.modelVariables if v.causality == c and v.name not in ("latency", "sample_period")]
          for c in ("input", "output")}
    return [f"  inputs:  {', '.join(by['input'])}", f"  outputs: {', '.join(by['output'])}"]


def cmd_whole_joint(args) -> int:
    from ..export import whole_joint as W
    from ..models.model import LPVPCModel

    if args.pt and not args.closed_loop:
        raise _UsageError("--pt is used by --closed-loop only (the whole-joint curve is fitted to the UT trial)")
    if args.position_delay_ms is not None and not args.closed_loop:
        raise _UsageError("--position-delay-ms is used by --closed-loop only")
    model = LPVPCModel.load(args.model)
    conv = model.conventions or {}
    ut = _trial_with_conventions(args.ut, args, conv)
    try:
        wj = W.fit_whole_joint(model, ut, cutoff=args.cutoff, order=args.order)
    except ValueError as exc:  # a cutoff outside (0, fs/2)
        raise _UsageError(str(exc)) from None
    if args.closed_loop:
        return _closed_loop(args, wj, ut, conv)
    wj.save(args.out)
    print(f"whole-joint model: {args.out} (quasi-static curve VAF {wj.fit['quasi_static_vaf']:.2f} % on the UT "
          f"trial; low-pass {wj.cutoff:g} Hz; step/FMU latency {W.latency_samples(wj)} samples)")
    if args.casadi:
        print(f"CasADi step function (angle -> torque): {W.export_whole_joint_casadi(wj, args.casadi)}")
    if args.fmu:
        t0 = time.perf_counter()
        path = W.export_whole_joint_fmu(wj, args.fmu, fmi_version=args.fmi, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange"
        print(f"FMU (FMI {args.fmi}.0 {kind}, angle -> torque): {path}  [{time.perf_counter() - t0:.2f} s]")
    return 0


def _trial_with_conventions(path, args, conv):
    """One trial read with the command line's units and torque sign, else the model's own
    (whole-joint's UT trial and --closed-loop's PT trial alike)."""
    from ..io import load_trial

    return load_trial(path, position_unit=args.position_unit or conv.get("position_unit", "rad"),
                      time_unit=args.time_unit or conv.get("time_unit", "s"),
                      torque_sign=float(args.torque_sign if args.torque_sign is not None else conv.get("torque_sign", 1)),
                      variable=args.variable, channels=_channel_options(args),
                      degrees="refuse")  # a model is fitted to it


def _closed_loop(args, wj, ut, conv) -> int:
    """lpvpc whole-joint --closed-loop: the causal closed-loop form (lpvpc.export.closed_loop)."""
    from ..export import closed_loop as CL

    if args.pt:
        pt = _trial_with_conventions(args.pt, args, conv)
        trials, source = [pt, ut], "the PT and UT trials"
    else:
        trials, source = [CL.distillation_trial(wj, ut)], "the two-sided model's torque (no --pt given)"
    delay = _position_delay(args, wj, conv)
    cl = CL.fit_closed_loop(wj, trials, position_delay=delay)
    cl.save(args.out)
    if delay:
        print(f"position channel delayed by {delay * 1e3:.2f} ms to meet the torque channel's (fit only; the model "
              "answers the plant's angle without delay)")
    print(f"closed-loop model: {args.out} (fitted to {source}: VAF {cl.fit['vaf_with_inertia']:.2f} %; inertia "
          f"{cl.inertia:.5g} kg m^2, for the plant; no latency)")
    if args.casadi:
        print(f"CasADi tick function (angle, angular_velocity -> torque): {CL.export_closed_loop_casadi(cl, args.casadi)}")
    if args.fmu:
        t0 = time.perf_counter()
        path = CL.export_closed_loop_fmu(cl, args.fmu, fmi_version=args.fmi, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange"
        print(f"FMU (FMI {args.fmi}.0 {kind}, angle and angular_velocity -> torque, constant output inertia): "
              f"{path}  [{time.perf_counter() - t0:.2f} s]")
    return 0


def _channel_skew(text):
    """--channel-skew-ms: a number (ms) or 'auto', as the loaders' channel_skew (s or 'auto')."""
    if text is None or text == "auto":  # (the default: found by identify's scan, lpvpc.identification.channel_skew)
        return "auto"
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value) or abs(value) > 20.0:
        raise _UsageError(f"--channel-skew-ms {text!r}: give milliseconds within +-20 (the torque channel's lag "
                          f"behind the position channel), or auto")
    return value * 1e-3


def _position_delay(args, wj, conv) -> float:
    """--position-delay-ms: a number (ms), or 'auto' (estimated from the PT/UT files)."""
    from ..export import closed_loop as CL
    from ..io import load_identification_data

    text = args.position_delay_ms
    if text is None:
        return 0.0
    if text != "auto":
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value) or abs(value) > 20.0:
            raise _UsageError(f"--position-delay-ms {text!r}: give milliseconds within +-20, or auto")
        return value * 1e-3
    if not args.pt:
        raise _UsageError("--position-delay-ms auto estimates the delay from the PT and UT trials: give --pt")
    data = load_identification_data(
        pt=args.pt, ut=args.ut, target_fs=wj.fs, position_unit=args.position_unit or conv.get("position_unit", "rad"),
        time_unit=args.time_unit or conv.get("time_unit", "s"), variable=args.variable, channels=_channel_options(args),
        torque_sign=float(args.torque_sign if args.torque_sign is not None else conv.get("torque_sign", 1)))
    return CL.estimate_channel_skew(data).delay


def _actuator_param(text):
    name, sep, value = text.partition("=")
    try:
        x = float(value)
    except ValueError:
        x = None
    if not sep or not name.strip() or x is None:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a number, got {text!r}")
    return name.strip(), x


def cmd_validate(args) -> int:
    try:
        from lpvpc.validation import CosimSettings, validate
        from lpvpc.validation.compare import worst_route_difference
    except ModuleNotFoundError as exc:
        if exc.name != "validation":
            raise
        raise LpvpcError("the validation harness is not available in this installation (package 'validation' "
                         "missing)") from None
    if args.stationary:
        if args.data and not (args.pt or args.ut):  # DATA --stationary: the stationary trial's file itself
            args.data, args.pt = None, args.data
        if args.data or args.ut or not args.pt:
            raise _UsageError("--stationary validates one perturbed trial, DATA or --pt, recorded without UT")
    elif args.data and (args.pt or args.ut):
        raise _UsageError("give either DATA or --pt and --ut, not both")
    elif not args.data and not (args.pt and args.ut):
        raise _UsageError("missing --ut: give the held-out unperturbed trial with --ut UT, or --stationary if the PT "
                          "trial was recorded around one fixed position without a UT trial" if args.pt else
                          "missing --pt: give the held-out perturbed trial with --pt PT" if args.ut else
                          "missing DATA or --pt and --ut: give the held-out perturbed and unperturbed trials as "
                          "--pt PT --ut UT (or a PT - UT file with a scheduling column as DATA)")
    check_report_folder(args.report, ("metrics.json", "report.html"), args.force)
    channels = _channel_options(args)
    settings = CosimSettings(coupling=args.coupling)
    result = validate(args.model, args.pt, args.ut, args.report, fmu=args.fmu, fmi_version=args.fmi,
                      actuator_fmu=args.actuator_fmu, actuator_parameters=dict(args.actuator_param),
                      calibrate=not args.no_calibrate, settings=settings, min_vaf=args.min_vaf,
                      band_limit_command=args.band_limit_command, fmu_variant=args.fmu_variant,
                      route_tolerance=args.route_tolerance, position_unit=args.position_unit,
                      torque_sign=args.torque_sign, time_unit=args.time_unit,
                      command_line=" ".join([PROG, *sys.argv[1:]]),
                      whole_joint=args.whole_joint, variable=args.variable, channels=channels, data=args.data,
                      stationary=args.stationary)
    m = result.metrics
    ag = m["route_agreement"]
    sched = m["scheduling"]
    cos = m["cosim"]
    print(f"VAF offline {m['vaf']:.2f} %, FMU replay {m['vaf_fmu']:.2f} %, co-simulation {m['vaf_cosim']:.2f} %  "
          f"(RMSE {m['rmse']:.3g} / {m['rmse_fmu']:.3g} / {m['rmse_cosim']:.3g} N m; {m['n_samples']} samples at "
          f"{m['fs']:g} Hz)")
    worst = worst_route_difference(ag)
    print(f"routes:      CasADi and FMU vs numpy agree to {worst:.1e} (tolerance {ag['tolerance']:.0e}); "
          f"co-simulation {m['vaf_cosim'] - m['vaf_fmu']:+.2f} VAF points vs FMU replay")
    if cos["model_fmu_variant"] == "exact":
        print(f"model FMU:   exact variant, latency {cos['model_fmu_latency_samples']} samples removed; the causal "
              f"(closed-loop) form reaches {m['vaf_causal']:.2f} % offline")
    print(f"co-sim:      {cos['real_time_factor']:.0f}x real time; perturbation tracking VAF "
          f"{cos['tracking']['perturbation_position_vaf']:.3f} %")
    if sched["flagged"]:
        o = sched["out_of_range"]["numpy"]
        if sched["one_position"]:  # "outside [op, op]" says nothing: how far from the one position
            print(f"range:       identified at one operating position, {sched['identified_range'][0]:+.3f} rad; the "
                  f"record lies up to {1e3 * sched['max_excursion']:.1f} mrad from it (offline RMSE {o['rmse']:.3g} N m)")
        else:
            print(f"range:       {100 * sched['out_of_range_fraction']:.2f} % of the record outside the identified "
                  f"scheduling range [{sched['identified_range'][0]:+.3f}, {sched['identified_range'][1]:+.3f}] rad "
                  f"(offline RMSE there {o['rmse']:.3g} N m)")
    for check in m["checks"]:
        if not check["pass"]:
            print(f"FAILED:      {check['name']}: {check['value']:.4g} (threshold {check['threshold']:.4g})")
    print(f"report:      {Path(result.files['report']).resolve()}")
    print(f"metrics:     {Path(result.files['metrics']).resolve()}")
    if "whole_joint" in m:
        w = m["whole_joint"]
        print(f"whole joint: total-torque VAF {w['vaf_total']:.2f} % (FMU {w['vaf_total_fmu']:.2f} %), perturbation "
              f"part {w['vaf_perturbation']:.2f} % (two-input model {w['vaf_two_input']:.2f} %)")
    if result.files.get("ssp"):
        print(f"ssp:         {Path(result.files['ssp']).resolve()}")
    if result.files.get("portable_ssp"):
        print(f"ssp:         {Path(result.files['portable_ssp']).resolve()} (libcosim, ECOS)")
    print(f"result:      {'pass' if result.passed else 'FAIL'}")
    return 0 if result.passed else 1


def _load_for_model(args, model):
    """Data for a saved model: decimated to its rate, with its units and sign conventions."""
    conv = model.conventions or {}
    position_unit = args.position_unit or conv.get("position_unit", "rad")
    torque_sign = args.torque_sign if args.torque_sign is not None else float(conv.get("torque_sign", 1.0))
    data = _load_data(args, target_fs=model.fs, position_unit=position_unit, torque_sign=torque_sign,
                      time_unit=conv.get("time_unit"), channel_skew=conv.get("channel_skew_s", 0.0))
    return data


def cmd_diagnose(args) -> int:
    from ..diagnosis.diagnose import diagnose, format_table, write_report
    from ..models.model import LPVPCModel

    if args.report:
        check_report_folder(args.report, ("diagnosis.md", "diagnosis.json"), args.force)
    model = LPVPCModel.load(args.model)
    data = _load_for_model(args, model)
    progress(f"diagnose: fitting and scoring every candidate of the catalog by cross-validation on {data.n} "
             f"samples (about 10-30 s)")
    diag = diagnose(model, data)
    print(f"data:      {data.n} samples at {data.fs:g} Hz ({data.source})")
    print(f"model:     VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m on these data; {diag.base_description()}")
    print(format_table(diag))
    print(f"answer:    {diag.answer()}")
    for note in diag.notes():
        print(f"note:      {note}")
    pos = diag.where["position"]["bins"]
    worst = max(pos, key=lambda b: b["residual_rms"]) if pos else None
    if worst:
        print(f"where:     largest residual at positions {worst['bin']} rad (RMS {worst['residual_rms']:.3g} N m, "
              f"{worst['relative_rms']:.2f} x the mean)")
    cc = [f"{k} (lag {c['at_lag_s']:+.2f} s)" for k, c in diag.where["cross_correlation"].items() if c["outside_band"]]
    if cc:
        print(f"           residual correlated with {', '.join(cc)} beyond the 99 % band")
    print(f"time:      {diag.timings['total']:.2f} s")
    if args.json:
        with atomic_path(args.json) as tmp:
            diag.save(tmp)
        print(f"diagnosis: {args.json}")
    if args.report:
        progress("diagnose: writing the report")
        with staged_folder(args.report) as stage:
            page = write_report(diag, data, stage)
        print(f"report:    {Path(args.report) / Path(page).relative_to(stage)}")
    return 0


def cmd_improve(args) -> int:
    from ..diagnosis.improve import improve, write_report

    effects = _check_effect_names(args.effect)
    target_fs = None if args.fs == 0 else args.fs
    check_report_folder(args.report, ("improve.md",), args.force)
    # the held-out record as the identification record is given: a PT - UT file, a PT/UT pair or a stationary trial
    if args.heldout and (args.heldout_pt or args.heldout_ut):
        raise _UsageError("give either --heldout DATA2 or --heldout-pt and --heldout-ut, not both")
    if not args.heldout:
        if args.stationary and (args.heldout_ut or not args.heldout_pt):
            raise _UsageError("--stationary: give the held-out stationary trial with --heldout-pt PT2 (or --heldout "
                              "DATA2), without --heldout-ut")
        if not args.stationary and not (args.heldout_pt and args.heldout_ut):
            raise _UsageError("missing the held-out record: give --heldout-pt PT2 --heldout-ut UT2 (or a PT - UT "
                              "file with a scheduling column as --heldout DATA2)")
    held_args = argparse.Namespace(**{**vars(args), "data": args.heldout, "pt": args.heldout_pt,
                                      "ut": args.heldout_ut})
    units = dict(position_unit=args.position_unit, torque_sign=args.torque_sign, time_unit="s")
    # a late torque channel lined up in both records as identify does (the rig's: found on the identification record)
    ident = _load_data(args, target_fs=target_fs, channel_skew=_channel_skew(args.channel_skew_ms), **units)
    skew = ident.meta.get("channel_skew_s", 0.0)
    held = _load_data(held_args, target_fs=ident.fs, channel_skew=skew, **units)
    if skew:
        print(f"skew:      torque channel {skew * 1e3:+.2f} ms behind position, lined up in both records", flush=True)

    def show(r):
        head = "step  model" if r.index == 0 else None
        if head:
            print(f"{'step':>4}  {'model':44} {'held-out VAF':>12} {'RMSE (N m)':>11}   fit + diagnosis")
        times = f"{r.fit_time:.1f} s + {r.diagnosis_time:.1f} s" if r.diagnosis is not None else f"{r.fit_time:.1f} s"
        note = "" if r.kept else "   (not kept: no held-out gain)"
        print(f"{r.index:>4}  {r.label[:44]:44} {r.heldout_vaf:>10.2f} % {r.heldout_rmse:>11.4f}   {times}{note}",
              flush=True)
        if r.kept and r.diagnosis is not None:
            top = r.diagnosis.top
            print(f"      diagnosis: {r.diagnosis.answer() if top is None else top.effect + ' significant, +' + format(top.vaf_gain, '.2f') + ' pp held-out'}",
                  flush=True)

    ladder = improve(ident, held, settings={"effects": effects} if effects else None, max_steps=args.max_steps,
                     progress=show)
    first, last = ladder.rungs[0], ladder.final
    changed = {k: v for k, v in last.settings.items() if first.settings.get(k) != v}  # from the base's structure
    print(f"stopped:   {ladder.stopped}")
    print(f"result:    held-out VAF {first.heldout_vaf:.2f} % -> {last.heldout_vaf:.2f} %, RMSE "
          f"{first.heldout_rmse:.4f} -> {last.heldout_rmse:.4f} N m; final model: "
          f"{', '.join(fe.name for fe in last.model.effects or ()) or 'no effects'}"
          + (f"; settings changed: {', '.join(f'{k}={v}' for k, v in changed.items())}" if changed else ""))
    if args.output:
        model = last.model
        model.conventions.setdefault("position_unit", args.position_unit)
        model.conventions.setdefault("torque_sign", args.torque_sign)
        if args.time_unit != "s":
            model.conventions.setdefault("time_unit", args.time_unit)
        model.save(args.output)
        print(f"model:     {args.output} (hash {model.model_hash[:12]})")
    if args.json:
        write_text(args.json, json.dumps(ladder.to_dict(), indent=1) + "\n")
        print(f"ladder:    {args.json}")
    progress("improve: writing the report")
    with staged_folder(args.report) as stage:
        page = write_report(ladder, held, stage)
    print(f"report:    {Path(args.report) / Path(page).relative_to(stage)}")
    return 0


# --------------------------------------------------------------------------- parser


def _positive_float(text):
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not x > 0:
        raise argparse.ArgumentTypeError(f"must be positive: {text!r}")
    return x


def _rate(text):
    """--fs of identify/improve: a finite rate in Hz, or 0 (keep the file's rate)."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise argparse.ArgumentTypeError(f"must be a positive rate in Hz, or 0 to keep the file's rate: {text!r}")
    return x


def _sign(text):
    try:
        x = float(text)
    except ValueError:
        x = None
    if x not in (1.0, -1.0):
        raise argparse.ArgumentTypeError(f"must be 1 or -1: {text!r}")
    return x


def _state_order(text):
    if text == "auto":
        return text
    try:
        m = int(text)
    except ValueError:
        m = 0
    if m < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer or 'auto': {text!r}")
    return m


def _add_convention_args(p, from_model: bool):
    """--position-unit and --torque-sign: given for new data (identify, improve), or
    defaulting to the conventions recorded in the model (predict, validate, diagnose)."""
    if from_model:
        p.add_argument("--position-unit", choices=("rad", "deg"), default=None,
                       help="unit of positions in the files (default: as at identification)")
        p.add_argument("--torque-sign", type=_sign, default=None, metavar="1|-1",
                       help="torque sign convention of the files (default: as at identification)")
    else:
        p.add_argument("--position-unit", choices=("rad", "deg"), default="rad",
                       help="unit of positions in the files (default rad)")
        p.add_argument("--torque-sign", type=_sign, default=1.0, metavar="1|-1",
                       help="multiplies the files' torque into the package's convention (default 1)")


def _add_quiet_arg(p):
    # SUPPRESS: a subcommand's default must not override ``lpvpc -q COMMAND``
    p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="no progress lines on stderr")


def _add_time_unit_arg(p, default):
    p.add_argument("--time-unit", choices=("s", "ms"), default=default,
                   help="unit of the files' time column (default s" + ("" if default else
                                                                        "; a saved model's as at identification") + ")")


def _channel_options(args) -> dict | None:
    """--channel ROLE=NAME options as {role: name} (None when none are given)."""
    from ..io.matfiles import parse_channel_options

    try:
        return parse_channel_options(getattr(args, "channel", None)) or None
    except ValueError as exc:
        raise _UsageError(f"--channel: {exc}") from None


def _add_file_choice_args(p):
    """--variable and --channel: which .mat variable and which columns or channels hold each role."""
    p.add_argument("--variable", metavar="NAME",
                   help="variable to read in .mat files, e.g. an nldat object (or write FILE.mat:NAME)")
    p.add_argument("--channel", action="append", default=[], metavar="ROLE=NAME",
                   help="channel of a .mat file or column of a CSV file for a role (position, torque, scheduling, "
                        "time, emg, command), e.g. --channel torque=tq1, --channel 'scheduling=sv.Ankle Position "
                        "(rad)' or --channel 'torque=Torque (N m)' (repeatable)")


def _add_data_args(p, what, several: bool = False, time_unit=None):
    """DATA | --pt/--ut | --pt --stationary, and the .mat choices; ``several``: repeatable
    (trials of one identification); ``time_unit``: the default of --time-unit (None: a saved
    model's)."""
    more = " (several: trials of one identification)" if several else ""
    p.add_argument("data", nargs="*" if several else "?", metavar="DATA",
                   help=f"{what}: CSV/.mat file with perturbation position, torque and a scheduling column{more}")
    p.add_argument("--pt", action="append" if several else "store", metavar="PT",
                   help="perturbed trial (CSV or .mat: time, position, torque)"
                        + ("; repeat with --ut for several PT/UT pairs" if several else ""))
    p.add_argument("--ut", action="append" if several else "store", metavar="UT",
                   help="unperturbed trial on the same trajectory")
    p.add_argument("--stationary", action="store_true",
                   help="DATA or --pt alone: a perturbed trial around one fixed operating position recorded "
                        "without UT; the operating point is its mean position (and torque)")
    _add_time_unit_arg(p, default=time_unit)
    _add_file_choice_args(p)


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

    p = sub.add_parser("simulate", help="write a virtual-subject data set with its truth",
                       formatter_class=_SimulateHelp,
                       description="Simulate the virtual subject: identification and novel PT/UT trials, "
                                   "truth.json and truth_*.npz.")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--population-seed", type=int, default=None, metavar="N",
                   help="simulate subject N of the population of virtual subjects (parameters, stiffness shape, "
                        "noise, EMG and perturbation design drawn from published ranges; docs/guide/population.md); "
                        "--effect then names one population effect and --form its form")
    p.add_argument("--form", default=None, metavar="FORM",
                   help="with --population-seed and --effect: the effect's form (default: drawn)")
    p.add_argument("--snr", type=float, default=None, metavar="DB",
                   help="SNR of the perturbation torque in dB (default 18; inf: no noise)")
    p.add_argument("--fs", type=_positive_float, default=1000.0, metavar="HZ",
                   help="output sampling rate, 1000 or 100 Hz (default 1000)")
    p.add_argument("--effect", action="extend", nargs="+", default=[], metavar="NAME",
                   help="switch on a physical effect the LPV-PC model lacks (repeatable): {simulated_effects}")
    p.add_argument("--duration", type=_positive_float, default=120.0, metavar="S",
                   help="length of each trial in s (default 120)")
    p.add_argument("--perturbation", default=None, metavar="NAME",
                   help="pralds: levels uniform in +-0.04 rad (default); lab_pulses: the lab pilot trial's "
                        "design, holds alternating between 0 and +-0.02..0.04 rad; prbs: +-0.04 rad switching "
                        "every 50-150 ms (no quiet windows)")
    p.add_argument("--stiffness-family", default=None, metavar="NAME",
                   help="shape of the elastic stiffness K(theta): standard (default), sum_of_exponentials "
                        "(steeper textbook form), piecewise (piecewise linear with a kink), polynomial (a cubic)")
    p.add_argument("--cohort", type=int, default=None, metavar="N",
                   help="write a virtual cohort of N population subjects in two groups (patient: K x1.5 toward "
                        "dorsiflexion, reflex gain x2) with manifest.csv and truth.json for lpvpc study; "
                        "--population-seed gives the first subject's seed (default 0)")
    p.add_argument("--null", action="store_true", help="with --cohort: no difference between the groups")
    p.set_defaults(func=cmd_simulate)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)

    p = sub.add_parser("study", help="identify a cohort of records, compare groups, write tables and a report",
                       description="Identify every record of a manifest (in parallel, cached by content), "
                                   "validate each on its held-out later part, and compare the groups: "
                                   "records.csv, groups.csv and report.html in DIR (docs/guide/study.md).")
    p.add_argument("manifest", metavar="MANIFEST", help="CSV: record,subject,group,pt,ut (or data) and optional "
                                                        "torque_sign,position_unit,stationary,heldout")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="study folder (created; its cache is kept)")
    p.add_argument("-j", "--jobs", type=int, default=1, metavar="N", help="records identified at once (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask scheduler (e.g. tcp://host:8786; "
                                                          "needs pip install 'lpvpc[study]')")
    p.add_argument("--heldout", type=float, default=0.3, metavar="FRACTION",
                   help="later fraction of each record held out (default 0.3; a manifest row's heldout overrides)")
    p.add_argument("--compare", nargs=2, metavar=("REF", "OTHER"),
                   help="the two groups to compare (OTHER - REF; default: each group against the first)")
    p.set_defaults(func=cmd_study)
    _add_quiet_arg(p)

    d = _estimator_defaults()
    _given = ", unless given here"
    p = sub.add_parser("identify", help="identify an LPV-PC model and save it as JSON",
                       description="Identify an LPV-PC model (subspace method) and save it as JSON.")
    _add_data_args(p, "instead of --pt/--ut", several=True)
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--force", action="store_true",
                   help="write -o even over an existing file that is not a model file (refused otherwise)")
    p.add_argument("--irf-length", type=_positive_float, metavar="S",
                   help=f"half-width of the intrinsic IRF in s (default {d['irf_length']:g} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--irf-lags", type=int, dest="irf_lags", metavar="L",
                   help="intrinsic IRF spans lags -L..L samples (overrides --irf-length)")
    p.add_argument("--basis", choices=("chebyshev", "legendre", "gaussian"),
                   help=f"basis family in the scheduling variable (default {d['basis']})")
    p.add_argument("--intrinsic-order", type=int, metavar="N",
                   help=f"basis order of the IRF weights (default {d['intrinsic_order']} with --structure fixed; with "
                        f"--structure cv, the default, cross-validation chooses it among 2 to 7 unless given here)")
    p.add_argument("--reflex-order", type=int, metavar="N",
                   help=f"basis order of the reflex nonlinearity in position (default {d['reflex_order']} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--velocity-order", type=int, metavar="N",
                   help=f"polynomial order of the reflex nonlinearity in velocity (default {d['velocity_order']} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--reflex-delay", type=_positive_float, metavar="S",
                   help=f"reflex delay in s (default {d['reflex_delay']} with --structure fixed; chosen by "
                        f"cross-validation otherwise{_given}; a stationary trial's by BIC among 40-80 ms)")
    p.add_argument("--high-rate-reflex", dest="high_rate_reflex", action="store_const", const=True, default=None,
                   help="identify the reflex nonlinearity on the file's own rate (e.g. 1 kHz) delayed velocity "
                        "instead of the model rate's (better reflex trends on the virtual subject, worse held-out "
                        "prediction on the lab's pilot trial; default: chosen per record by the structure selection)")
    p.add_argument("--model-rate-reflex", dest="high_rate_reflex", action="store_const", const=False,
                   help="identify the reflex nonlinearity on the model rate's delayed velocity (not selected)")
    p.add_argument("--high-rate-velocity-basis", choices=("chebyshev", "legendre", "hinge"),
                   help="velocity basis of the high-rate reflex nonlinearity (default: chosen between chebyshev 4 "
                        "and hinge 8)")
    p.add_argument("--high-rate-velocity-order", type=int, choices=range(1, 13), metavar="N",
                   help="its order, 1-12")
    p.add_argument("--state-order", type=_state_order, metavar="M|auto",
                   help="order of the reflex dynamics (default auto: from the singular values and BIC)")
    p.add_argument("--max-state-order", type=int, metavar="M",
                   help=f"largest order tried by auto (default {d['max_state_order']})")
    p.add_argument("--horizon", type=int, metavar="S",
                   help=f"block rows of the MOESP Hankel matrices (default {d['horizon']})")
    p.add_argument("--causal-lags", type=int, metavar="LC",
                   help="lags 0..LC of the causal intrinsic IRF used by the FMU (default L + 2)")
    p.add_argument("--tol", type=_positive_float, help=f"separable least-squares tolerance (default {d['tol']:g})")
    p.add_argument("--max-iter", type=int, metavar="N",
                   help=f"separable least-squares iterations (default {d['max_iter']})")
    _add_convention_args(p, from_model=False)
    p.add_argument("--fs", type=_rate, default=100.0, metavar="HZ",
                   help="rate to identify at: data are decimated to it (default 100; 0 keeps the file's rate)")
    p.add_argument("--channel-skew-ms", metavar="MS|auto",
                   help="the torque channel's lag behind the position channel in ms (a recording artefact), "
                        "undone at the file's rate before decimation; auto (default): found by the fit's scan of "
                        "its own record (one least-squares solve), the files reloaded and refitted when lining the "
                        "channels up removes at least 2 %% of the residual variance; 0: none (docs: data guide, "
                        "channel skew)")
    p.add_argument("--structure", choices=("fixed", "cv"),
                   help="cv (default): choose IRF half-width, basis orders, reflex delay, curvature term and "
                        "extrapolation rule by leave-one-level-out cross-validation (options given here stay fixed); "
                        "fixed: the settings as given")
    p.add_argument("--extrapolation", dest="scheduling_extrapolation", choices=("clip", "linear"),
                   help="beyond the identified position range the bases are held (clip) or continued linearly; "
                        "default: chosen by the structure selection (--structure cv), clip with --structure fixed")
    p.add_argument("--effect", dest="effects", action="extend", nargs="+", default=None, metavar="NAME",
                   help="add an effect of the catalog (repeatable): " + ", ".join(_effect_names()))
    p.add_argument("--allow-effect", dest="allow_effects", action="extend", nargs="+", default=None, metavar="NAME",
                   help="an effect the cross-validation may switch on (repeatable; default stress_relaxation; "
                        "'none': no effect)")
    p.add_argument("--relaxation-times", dest="relaxation_times", type=_positive_float, nargs="+", default=None,
                   metavar="S", help="stress relaxation's averaging times in s (default: chosen per record by the "
                                     "cross-validation among single times of 0.3-3 s and the catalog's 0.3 1 3)")
    p.add_argument("--relaxation-order", dest="relaxation_order", type=int, default=None, metavar="N",
                   help="order in position of stress relaxation's weights (default: with the times)")
    _add_quiet_arg(p)
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("predict", help="predict torque with a saved model and report the VAF",
                       description="Predict the perturbation torque of a record with a saved model. Data are "
                                   "decimated to the model's rate; units and sign default to the model's.")
    p.add_argument("model", metavar="MODEL.json")
    _add_data_args(p, "instead of --pt/--ut")
    p.add_argument("--json", metavar="METRICS.json",
                   help="write vaf (%%), rmse (N m), n_samples, out_of_range_fraction, model_hash, data_hash")
    p.add_argument("--out", metavar="PREDICTED.csv",
                   help="write time, measured, predicted, intrinsic, reflex torques (and position, scheduling)")
    p.add_argument("--causal", action="store_true",
                   help="use the causal intrinsic IRF (what the default FMU runs)")
    _add_convention_args(p, from_model=True)
    p.set_defaults(func=cmd_predict)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)

    p = sub.add_parser("export", help="export a saved model as a CasADi function and/or an FMU",
                       description="Export a saved model as a CasADi step function and/or an FMI "
                                   "co-simulation FMU.")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("--casadi", metavar="FILE.casadi", help="write the CasADi step function")
    p.add_argument("--fmu", metavar="FILE.fmu", help="write an FMU")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the FMU (default 2)")
    p.add_argument("--variant", choices=("sampled", "causal", "exact"), default=None,
                   help="sampled (default): inputs position and scheduling only, velocity and acceleration by "
                        "central differences inside, so a latency of half the difference stencil: 2 samples for "
                        "models identified by this version (5 points), 1 for older files (3 points); the same timing "
                        "in every co-simulation master (the FMU's description states its timing contract); "
                        "causal: also velocity and acceleration inputs, no latency when the master sets inputs "
                        "before reading outputs (closed loop with an actuator that supplies them); exact: the "
                        "two-sided IRF, latency L samples (its lags -L..L). export prints the model's latency")
    p.add_argument("--exact", action="store_true", help="same as --variant exact")
    p.add_argument("--fmi-type", choices=("cs", "me"), default="cs",
                   help="cs: co-simulation (default); me: Model Exchange, sampled with a time event every 1/fs "
                        "(for tools that import Model Exchange only)")
    p.set_defaults(func=cmd_export)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)

    p = sub.add_parser("validate", help="validate a model on a held-out record: routes, co-simulation, report",
                       description="Validate a saved model on a held-out PT/UT record: predict it offline, through "
                                   "CasADi and the model FMU, co-simulate the model FMU with the actuator FMU, and "
                                   "write DIR/report.html, DIR/metrics.json, DIR/figures and the co-simulation "
                                   "set-up as DIR/cosimulation.ssp (SSP 1.0). Exit status 1 when a "
                                   "threshold fails, 2 for bad input.")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("data", nargs="?", metavar="DATA",
                   help="instead of --pt/--ut: one PT - UT file with perturbation position, torque and a scheduling "
                        "column; the co-simulation drives the scheduling as UT and the scheduling plus the "
                        "perturbation as PT, and loads the PT actuator with the model's torque only (the file has "
                        "no UT torque)")
    p.add_argument("--pt", metavar="PT", help="held-out perturbed trial (CSV or .mat)")
    p.add_argument("--ut", metavar="UT", help="held-out unperturbed trial on the same trajectory")
    p.add_argument("--stationary", action="store_true",
                   help="DATA or --pt alone: a perturbed trial around one fixed operating position recorded "
                        "without UT; the UT actuator holds its mean position, loaded by its mean torque")
    p.add_argument("--report", required=True, metavar="DIR", help="folder for report.html, metrics.json, figures/")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report")
    p.add_argument("--min-vaf", type=float, metavar="X",
                   help="fail (exit 1) when vaf, vaf_fmu or vaf_cosim is below X percent")
    p.add_argument("--fmu", metavar="F.fmu", help="validate this model FMU, either variant (default: export one, "
                                                  "see --fmu-variant)")
    p.add_argument("--fmu-variant", choices=("exact", "causal", "sampled"), default="exact",
                   help="model FMU to export and validate: exact (the identified two-sided model; its declared "
                        "latency is removed when comparing; default) or causal (velocity and acceleration inputs, for closed loop)")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the exported FMUs (default 2)")
    p.add_argument("--actuator-fmu", metavar="F.fmu", help="actuator FMU (default: the project's actuator)")
    p.add_argument("--actuator-param", type=_actuator_param, action="append", default=[], metavar="NAME=VALUE",
                   help="fix an actuator parameter (repeatable); fixed servo parameters are not calibrated")
    p.add_argument("--no-calibrate", action="store_true",
                   help="do not fit the servo bandwidth and damping to the record's command and position")
    p.add_argument("--band-limit-command", action=argparse.BooleanOptionalAction, default=True,
                   help="low-pass the record's command (zero-phase) to the model's band before it drives the "
                        "actuators (default: on; --no-band-limit-command drives them with the full-band command)")
    p.add_argument("--coupling", choices=("iterate", "delay"), default="iterate",
                   help="load-torque coupling: iterate to convergence (default) or a one-step delay")
    p.add_argument("--route-tolerance", type=_positive_float, default=1e-9, metavar="TOL",
                   help="largest max|a-b|/max|b| of the CasADi and FMU routes vs numpy (default 1e-9)")
    p.add_argument("--whole-joint", metavar="WHOLE.json",
                   help="also validate this whole-joint model (lpvpc whole-joint) on the PT trial's total torque")
    _add_convention_args(p, from_model=True)
    _add_time_unit_arg(p, default=None)
    _add_file_choice_args(p)
    _add_quiet_arg(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("whole-joint", help="joint angle in, total torque out: fit the quasi-static curve, export",
                       description="Build the whole-joint model of a saved LPV-PC model: the quasi-static "
                                   "torque-angle curve fitted to the UT trial at the operating angle (a causal "
                                   "low-pass of the joint angle) plus the LPV-PC model of the angle minus it. "
                                   "Save it as JSON; optionally export it as a CasADi step and an FMU (input "
                                   "angle in rad, output torque in N m, latency L samples).")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("--ut", required=True, metavar="UT", help="the unperturbed trial the model was identified with")
    p.add_argument("-o", "--out", required=True, metavar="WHOLE.json", help="write the whole-joint model here")
    p.add_argument("--force", action="store_true",
                   help="write -o even over an existing file that is not a model file (refused otherwise)")
    p.add_argument("--cutoff", type=_positive_float, default=0.5, metavar="HZ",
                   help="cutoff of the operating-angle low-pass (default 0.5 Hz)")
    p.add_argument("--order", type=int, default=5, metavar="N", help="order of the quasi-static curve (default 5)")
    p.add_argument("--fmu", metavar="FILE.fmu", help="write the whole-joint FMU")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the FMU (default 2)")
    p.add_argument("--fmi-type", choices=("cs", "me"), default="cs",
                   help="cs: co-simulation (default); me: Model Exchange, a time event per sample")
    p.add_argument("--casadi", metavar="FILE.casadi", help="write the whole-joint CasADi step function")
    p.add_argument("--closed-loop", action="store_true",
                   help="the closed-loop form instead (for a plant that the torque moves): inputs angle (rad) and "
                        "angular_velocity (rad/s), no latency, inertia declared apart (docs/guide/closed_loop.md)")
    p.add_argument("--pt", metavar="PT", help="with --closed-loop: fit it to the PT and UT trials (default: to the "
                                              "two-sided model's torque)")
    p.add_argument("--position-delay-ms", metavar="MS|auto",
                   help="with --closed-loop: the torque channel's lag behind the position channel in the recording "
                        "(a measurement artefact, undone for the fit only); auto: estimated from --pt and --ut")
    _add_convention_args(p, from_model=True)
    _add_time_unit_arg(p, default=None)
    _add_file_choice_args(p)
    p.set_defaults(func=cmd_whole_joint)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)

    p = sub.add_parser("diagnose", help="where does a model fail on held-out data, and which effect is missing",
                       description="Analyse the residual of a saved model on a record it was not fitted to, and "
                                   "fit and score every candidate effect of the catalog by cross-validated "
                                   "held-out VAF gain with a significance test.")
    p.add_argument("model", metavar="MODEL.json")
    _add_data_args(p, "instead of --pt/--ut")
    p.add_argument("--json", metavar="DIAGNOSIS.json", help="write the diagnosis (candidates in rank order)")
    p.add_argument("--report", metavar="DIR", help="write DIR/report.html (self-contained), diagnosis.json, "
                                                   "diagnosis.md and the figures")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report")
    _add_convention_args(p, from_model=True)
    _add_quiet_arg(p)
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("improve", help="fit, diagnose, add the top significant effect, refit, until none is left",
                       description="The improve loop on an identification record and a held-out record; writes "
                                   "DIR/report.html (and improve.md) with the ladder of models (held-out VAF and RMSE), residual "
                                   "plots before and after each step, and each step's diagnosis.")
    _add_data_args(p, "identification record", time_unit="s")
    p.add_argument("--heldout", metavar="DATA2", help="held-out record as a PT - UT file with a scheduling column "
                                                        "(or, with --stationary, the held-out stationary trial)")
    p.add_argument("--heldout-pt", metavar="PT2", help="held-out perturbed trial")
    p.add_argument("--heldout-ut", metavar="UT2", help="held-out unperturbed trial")
    p.add_argument("--report", required=True, metavar="DIR", help="report folder (created)")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report, and "
                        "-o even if it is not a model file")
    p.add_argument("--json", metavar="LADDER.json", help="write the ladder as JSON")
    p.add_argument("-o", "--output", metavar="MODEL.json", help="save the final model")
    p.add_argument("--max-steps", type=int, default=6, metavar="N", help="at most N refits (default 6)")
    p.add_argument("--effect", action="extend", nargs="+", default=[], metavar="NAME",
                   help="effects the starting model already has (repeatable): " + ", ".join(_effect_names()))
    _add_convention_args(p, from_model=False)
    p.add_argument("--fs", type=_rate, default=100.0, metavar="HZ",
                   help="rate to identify at (default 100; 0 keeps the file's rate)")
    p.add_argument("--channel-skew-ms", metavar="MS|auto",
                   help="the torque channel's lag behind the position channel in ms, undone in both records at the "
                        "files' rate; auto (default): found as identify finds it, on the identification record "
                        "(one extra fit); 0: none")
    _add_quiet_arg(p)
    p.set_defaults(func=cmd_improve)
    return parser


def _effect_names():
    from ..models.effects import CATALOG

    return list(CATALOG)


class _SimulateHelp(argparse.HelpFormatter):
    """simulate --help: the simulator's effects listed when the help is shown (the simulator
    imports scipy.signal; building the parser must not)."""

    def _get_help_string(self, action):
        text = super()._get_help_string(action)
        return text.replace("{simulated_effects}", _simulated_effects()) if text else text


def _simulated_effects() -> str:
    """The simulator's effects: those of the catalog (identify --effect), then the others."""
    from ..models.effects import CATALOG
    from ..simulation.simulate import EFFECTS

    outside = [e for e in EFFECTS if e not in CATALOG]
    return (", ".join(e for e in CATALOG if e in EFFECTS)
            + (f"; outside the catalog (no model term names them): {', '.join(outside)}" if outside else ""))


# --------------------------------------------------------------------------- main


def _show_warning(original):
    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, LpvpcWarning):
            print(f"{PROG}: warning: {_one_line(cli_syntax(message))}", file=sys.stderr)
        else:
            original(message, category, filename, lineno, file, line)

    return show


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


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that it takes the same clean-up path as
    Ctrl-C (temporary files and folders removed, the compiler killed)."""


def _raise_terminated(signum, frame):
    raise Terminated()


def _terminate_as_interrupt():
    """Install the SIGTERM handler (main thread only); returns the previous one."""
    try:
        return signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread
        return None


def _show_notes() -> None:
    """--verbose: the library's notes (logging, INFO) as lines ``lpvpc: note: ...`` on stderr."""
    import logging

    logger = logging.getLogger("lpvpc")
    if any(getattr(h, "lpvpc_notes", False) for h in logger.handlers):
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{PROG}: note: %(message)s"))
    handler.lpvpc_notes = True
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)


class _ProgressLines:
    """The library's progress (:mod:`lpvpc.progress`) as lines ``lpvpc: [  3.1 s] ...`` on
    stderr while a command runs (seconds since it started)."""

    def __enter__(self):
        import logging

        start = time.perf_counter()

        class Elapsed(logging.Formatter):
            def format(self, record):
                return f"{PROG}: [{time.perf_counter() - start:5.1f} s] {record.getMessage()}"

        self.logger = logging.getLogger("lpvpc.progress")
        self.level = self.logger.level
        self.handler = logging.StreamHandler(sys.stderr)
        self.handler.setFormatter(Elapsed())
        self.logger.addHandler(self.handler)
        self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.level)
        return False


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


if __name__ == "__main__":
    sys.exit(main())
