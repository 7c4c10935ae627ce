"""Plumbing shared by the commands: argument types and groups, loading a record, the output
checks of report folders, and library messages rewritten in command-line syntax."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..errors import LpvpcError
from ..report_html import command_line_syntax

PROG = "lpvpc"
# Exit status for unreadable/unwritable paths: bad input, like the package's input errors.
OSERROR_STATUS = 2


class _UsageError(LpvpcError):
    """A combination of options argparse cannot check (printed like any other error)."""

    exit_status = 2


def _one_line(text) -> str:
    return " ".join(str(text).split())


def write_report_folder(folder, what: str, write):
    """Write a report into ``folder`` as a whole (``write(stage)`` builds it in a staged folder
    that replaces ``folder`` when done) and print where its page is; ``what`` names the
    command on the progress line."""
    from ..io.outputs import staged_folder
    from ..progress import report as progress

    progress(f"{what}: writing the report")
    with staged_folder(folder) as stage:
        page = write(stage)
    print(f"report:    {Path(folder) / Path(page).relative_to(stage)}")


def _err(message) -> None:
    print(f"{PROG}: error: {_one_line(command_line_syntax(message))}", file=sys.stderr)


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


def _load_for_model(args, model):
    """Data for a saved model: decimated to its rate, with its units and sign conventions."""
    conv = model.conventions or {}
    position_unit = args.position_unit or conv.get("position_unit", "rad")
    torque_sign = args.torque_sign if args.torque_sign is not None else float(conv.get("torque_sign", 1.0))
    data = _load_data(args, target_fs=model.fs, position_unit=position_unit, torque_sign=torque_sign,
                      time_unit=conv.get("time_unit"), channel_skew=conv.get("channel_skew_s", 0.0))
    return data


def _second_record_flags(args, option) -> list:
    """The options of a command's second record (``_second_record``) that were given."""
    dest = option.replace("-", "_")
    return [f"--{option}{s.replace('_', '-')}" for s in ("", "_pt", "_ut") if getattr(args, dest + s, None)]


def _second_record(args, option, what, n, *, required):
    """A command's second record, given as its first is: ``--OPTION DATA<n>`` (a PT - UT file;
    with --stationary the stationary trial) or ``--OPTION-pt PT<n>`` and ``--OPTION-ut UT<n>``
    (improve's ``--heldout``, the held-out record; diagnose's ``--reference``, the record the
    model was identified on). Returns ``args`` with those files as DATA, --pt and --ut, for
    the loaders that read the first (``_load_data``, ``_load_for_model``: the same
    --stationary, units and file choices); None when none is given and not ``required``. A
    file and a pair together, or half a pair, are refused in one line; ``what`` names the
    record in those lines ("held-out": "missing the held-out record")."""
    dest = option.replace("-", "_")
    data, pt, ut = (getattr(args, dest + s, None) for s in ("", "_pt", "_ut"))
    flag, file, pair = f"--{option}", f"--{option} DATA{n}", f"--{option}-pt PT{n} --{option}-ut UT{n}"
    if data and (pt or ut):
        raise _UsageError(f"give either {file} or {flag}-pt and {flag}-ut, not both")
    if not (data or pt or ut) and not required:
        return None
    if not data:
        if args.stationary and (ut or not pt):
            raise _UsageError(f"--stationary: give the {what} stationary trial with {flag}-pt PT{n} (or {file}), "
                              f"without {flag}-ut")
        if not args.stationary and not (pt and ut):
            raise _UsageError(f"missing the {what} record: give {pair} (or a PT - UT file with a scheduling column "
                              f"as {file})")
    return argparse.Namespace(**{**vars(args), "data": data, "pt": pt, "ut": ut})


def check_report_folder(folder, markers, force) -> None:
    """A report folder is replaced as a whole: refuse a non-empty folder that holds no
    previous report (none of ``markers``) unless ``--force``."""
    folder = Path(folder)
    if force or not folder.is_dir() or any((folder / m).exists() for m in markers) or not any(folder.iterdir()):
        return
    raise _UsageError(f"report folder {folder} holds files but no previous report ({', '.join(markers)}); it is "
                      "replaced as a whole: give another folder, or --force to replace it")


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


def _effect_names():
    from ..models.effects import CATALOG

    return list(CATALOG)


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


# --------------------------------------------------------------------------- held-out part of one record


def _add_hold_out_arg(p):
    """--hold-out: the one definition identify, validate, diagnose and improve share."""
    p.add_argument("--hold-out", dest="hold_out", nargs="?", const=MODEL_HOLD_OUT, default=None,
                   metavar="FRACTION|START:STOP",
                   help="keep a later stretch of the one record given out of identification and use it as the "
                        "held-out record: a fraction (0.3: the last 30 %%) or START:STOP in s from the record's start "
                        "(STOP empty: to its end). identify fits the part before it, prints the held-out VAF and "
                        "records the stretch in the model file; validate, diagnose and improve take the held-out "
                        "record from it (validate and diagnose: --hold-out without a value takes the stretch the "
                        "model recorded)")


#: --hold-out given without a value: the stretch the model recorded at identification
MODEL_HOLD_OUT = "as-recorded"


def _hold_out_value(text):
    """--hold-out's text as lpvpc.hold_out takes it: a fraction in (0, 1), or (start, stop) in
    s with stop None for the record's end."""
    given = f"--hold-out {text}"
    if Path(text).exists():  # "--hold-out DATA": the record taken as the option's value
        raise _UsageError(f"{given}: give the fraction or START:STOP after --hold-out, and the record {text} before it")
    if ":" in text:
        a, _, b = text.partition(":")
        try:
            start, stop = float(a), (float(b) if b.strip() else None)
        except ValueError:
            raise _UsageError(f"{given}: START and STOP must be seconds from the record's start, e.g. 84:120 "
                              f"(or 84: to its end)") from None
        if not math.isfinite(start) or (stop is not None and not math.isfinite(stop)):
            raise _UsageError(f"{given}: START and STOP must be finite seconds")
        if start <= 0:
            raise _UsageError(f"{given}: START must lie after the record's start (> 0 s): identification keeps "
                              f"what lies before it")
        if stop is not None and stop <= start:
            raise _UsageError(f"{given}: STOP must come after START")
        return start, stop
    try:
        fraction = float(text)
    except ValueError:
        raise _UsageError(f"{given}: give a fraction (e.g. 0.3: the last 30 % held out) or START:STOP in s") from None
    if not 0.0 < fraction < 1.0:
        raise _UsageError(f"{given}: a fraction must lie between 0 and 1 (e.g. 0.3: the last 30 % held out)")
    return fraction


def _hold_out_text(value) -> str:
    """A hold-out value as --hold-out takes it (the inverse of _hold_out_value)."""
    if isinstance(value, (tuple, list)):
        start, stop = value
        return f"{start:g}:" + ("" if stop is None else f"{stop:g}")
    return f"{value:g}"


def _record_files(args) -> list:
    """The files of the record given (DATA or --pt/--ut), as absolute paths: what a model's
    recorded hold-out is matched against."""
    items = [*_listed(getattr(args, "data", None)), *_listed(getattr(args, "pt", None)),
             *_listed(getattr(args, "ut", None))]
    return [str(Path(x).resolve()) for x in items]


def _only_one_record(args, command) -> None:
    if len(_listed(args.data)) > 1 or len(_listed(args.pt)) > 1:
        raise _UsageError(f"{command} --hold-out splits one record: give one DATA file or one --pt/--ut pair")


def _held_out_for_model(args, model):
    """validate's and diagnose's --hold-out value: a bare --hold-out takes the stretch the model
    recorded; a different value on the record the model was identified from is refused (it
    would predict data the model was fitted to, or not the stretch the model held out)."""
    recorded = (model.fit or {}).get("hold_out")
    if args.hold_out == MODEL_HOLD_OUT:
        if not recorded:
            raise _UsageError("--hold-out without a value takes the stretch the model held out at identification, "
                              "and this model records none: give --hold-out FRACTION or START:STOP")
        value = recorded["value"]
        return tuple(value) if isinstance(value, list) else value
    value = _hold_out_value(args.hold_out)
    if recorded and recorded.get("files") == _record_files(args):
        mine = tuple(recorded["value"]) if isinstance(recorded["value"], list) else recorded["value"]
        if mine != value:
            a, b = recorded["held_out_s"]
            raise _UsageError(f"--hold-out {args.hold_out}: the model was identified on this record with --hold-out "
                              f"{_hold_out_text(mine)} (held out {a:.1f}..{b:.1f} s); give --hold-out alone (or "
                              f"--hold-out {_hold_out_text(mine)}) to use that stretch")
    return value
