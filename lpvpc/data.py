"""Trials, loaders, checks, decimation and PT-UT pairing.

Units: time in s, position in rad, torque in N m, velocity in rad/s, rates in Hz
(SI everywhere). Loaders convert from the lab's units and sign convention on the way in
(``position_unit``, ``torque_sign``); everything after them is SI.

Bad data are never repaired: every check collects all the problems it finds and raises
one :class:`~lpvpc.errors.DataError` that lists them (channel, first index, count).
"""

from __future__ import annotations

import csv
import hashlib
import io
import logging
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.signal

from lpvpc.errors import DataError, InsufficientExcitationError, LpvpcWarning, UnitWarning
from lpvpc.matfiles import split_variable  # noqa: F401 (re-exported)
from lpvpc.segments import Segments

_log = logging.getLogger(__name__)  # notes (e.g. ignored CSV columns); the CLI shows them with --verbose

OPTIONAL_CHANNELS = ("emg", "command", "scheduling")
# EMG columns of a perturbation file (PT - UT already formed): the PT and the UT trial's.
PERTURBATION_EMG = ("emg", "emg_ut")
REQUIRED_CHANNELS = ("time", "position", "torque")
# Channels that hold joint angles: converted by position_unit, checked for degrees.
ANGLE_CHANNELS = ("position", "command", "scheduling")

# Relative deviation of a time step from the median step above which sampling is uneven.
JITTER_TOLERANCE = 1e-3
# ... unless every stamp stays within this fraction of a step of the uniform grid from the
# first to the last stamp: a time column rounded (single precision: 0.4 % of a 1 ms step at
# 60 s) or stamped by a software clock, over samples the converter's clock spaced evenly.
# The samples are then read as uniform, with a warning; a dropped or doubled sample moves
# the grid by half a step or more and stays an error.
GRID_TOLERANCE = 0.1
# Relative tolerance on sampling rates (PT vs UT, and fs as a multiple of target_fs).
RATE_TOLERANCE = 1e-4
# A stationary trial (no UT) holds one operating position: its mean over STATIONARY_WINDOW s
# spans at most STATIONARY_MAX_SPAN rad (the lab's trials: 0.026-0.028 rad; a passive-movement
# trajectory: about 0.6 rad).
STATIONARY_WINDOW = 2.0
STATIONARY_MAX_SPAN = 0.1
# A time column read in s whose rate is below MS_MAX_RATE Hz, but at least MS_MIN_RATE Hz
# once read in ms, was written in milliseconds (1 kHz in ms reads as 1 Hz): refused with the fix.
MS_MAX_RATE = 50.0
MS_MIN_RATE = 50.0
# PT and UT given the wrong way round: the perturbation is then in the "UT" trial. The power
# of each position about its SWAP_WINDOW-s moving average (what is faster than the slow
# movement) tells: correct pairs of the virtual subject, UT/PT 0.0005-0.14 (24 pairs: seeds 0-5,
# both trajectories, both perturbation designs, 60 s at 1 kHz; 100 Hz files alike); swapped,
# the inverse, 7 or more. Refused above SWAP_RATIO.
SWAP_WINDOW = 0.1
SWAP_RATIO = 2.0
# Below this variance (rad^2) of the PT-UT position there is no perturbation to identify from.
MIN_PERTURBATION_VARIANCE = 1e-12
# scipy recommends decimating in stages when the factor exceeds 13.
MAX_STAGE_FACTOR = 13
# Anti-alias FIR per stage: Kaiser window for 80 dB, 30*q+1 taps, cutoff at the new Nyquist rate.
# scipy.signal.decimate's own FIR (Hamming, 20*q+1 taps) has 0.3 % gain error at 5 Hz (q = 10)
# and 53 dB stopband; this one is flat to 1e-4 up to 0.8 of the new Nyquist rate.
FIR_ATTENUATION_DB = 80.0
FIR_TAPS_PER_FACTOR = 30


@dataclass
class Trial:
    """One recorded (or simulated) trial: time (s), position (rad), torque (N m) and
    optional extra channels (``emg``, ``command`` (rad), ``scheduling`` (rad))."""

    time: np.ndarray
    position: np.ndarray
    torque: np.ndarray
    channels: dict = field(default_factory=dict)
    name: str = ""

    @property
    def fs(self) -> float:
        """Sampling rate in Hz, derived from the time vector."""
        return float((len(self.time) - 1) / (self.time[-1] - self.time[0]))

    def __repr__(self):
        n = len(self.time)
        rate = f" at {self.fs:g} Hz ({float(self.time[-1] - self.time[0]):.1f} s)" if n > 1 and self.time[-1] != self.time[0] else ""
        channels = f"; channels {', '.join(self.channels)}" if self.channels else ""
        return (f"Trial({_short(self.name)!r}: {n} samples{rate}; position {_span(self.position)} rad, torque "
                f"{_span(self.torque)} N m{channels})")


def write_trial_csv(trial: Trial, path) -> None:
    """Write a trial as CSV with header ``time,position,torque[,emg,command,scheduling]``."""
    names = ["time", "position", "torque"] + [c for c in OPTIONAL_CHANNELS if c in trial.channels]
    cols = [trial.time, trial.position, trial.torque] + [trial.channels[c] for c in names[3:]]
    from .outputs import atomic_path

    with atomic_path(path) as tmp:  # temporary file + rename
        np.savetxt(tmp, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.10g")


# --------------------------------------------------------------------------- checks


def _span(x) -> str:
    """'lo..hi' of an array for a repr (an empty or non-finite one as such)."""
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return "empty"
    if not np.all(np.isfinite(x)):
        return "with non-finite values"
    return f"{float(x.min()):+.4g}..{float(x.max()):+.4g}"


def _short(text, limit: int = 60) -> str:
    text = str(text)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _plural(count: int, word: str) -> str:
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def _finite_problems(name: str, x: np.ndarray) -> list[str]:
    """NaN and inf in one channel, each with count and first index."""
    problems = []
    for label, bad in (("NaN", np.isnan(x)), ("inf", np.isinf(x))):
        count = int(np.count_nonzero(bad))
        if count:
            first = int(np.flatnonzero(bad)[0])
            problems.append(f"channel '{name}': {_plural(count, label + ' value')}, first at index {first}")
    return problems


def grid_deviation(t) -> float:
    """Largest distance of the time stamps from the uniform grid through the first and the
    last one, in steps of that grid (0 for uniform sampling).

    >>> t = np.arange(6) / 1000.0
    >>> round(grid_deviation(t + np.array([0, 2e-5, -3e-5, 0, 1e-5, 0])), 6)  # jitter by 3 % of a step
    0.03
    """
    t = np.asarray(t, dtype=float)
    step = (t[-1] - t[0]) / (len(t) - 1)
    return float(np.max(np.abs(t - (t[0] + step * np.arange(len(t))))) / step)


def _uneven_steps(dt: np.ndarray, step: float) -> np.ndarray:
    """Steps deviating from ``step`` by more than JITTER_TOLERANCE of it."""
    return np.abs(dt - step) > JITTER_TOLERANCE * step


def _time_problems(t: np.ndarray) -> list[str]:
    """Non-increasing and unevenly spaced time stamps (index = sample that breaks the rule);
    stamps that only jitter about a uniform grid (GRID_TOLERANCE) are not a problem."""
    problems = []
    dt = np.diff(t)
    finite = np.isfinite(dt)
    nonincreasing = finite & (dt <= 0)
    count = int(np.count_nonzero(nonincreasing))
    if count:
        first = int(np.flatnonzero(nonincreasing)[0]) + 1
        problems.append(
            f"channel 'time': not strictly increasing, {_plural(count, 'step')} <= 0, "
            f"first at index {first} ({t[first - 1]:.10g} s -> {t[first]:.10g} s)"
        )
    positive = finite & (dt > 0)
    if np.any(positive):
        step = float(np.median(dt[positive]))
        # Steps already reported as non-increasing are not counted again as uneven.
        uneven = positive & _uneven_steps(dt, step)
        count = int(np.count_nonzero(uneven))
        if count and not problems and grid_deviation(t) <= GRID_TOLERANCE:
            count = 0  # jitter about a uniform grid: check_trial warns
        if count:
            first = int(np.flatnonzero(uneven)[0]) + 1
            problems.append(
                f"channel 'time': uneven sampling, {_plural(count, 'step')} differ from the median "
                f"step {step:.6g} s by more than {JITTER_TOLERANCE:.0e} of it, first at index {first} "
                f"(step {dt[first - 1]:.6g} s)"
            )
    return problems


def trial_problems(trial: Trial) -> list[str]:
    """Every problem of a trial as a list of messages (empty if the trial is usable).

    >>> t = np.arange(5) / 100.0  # s
    >>> trial_problems(Trial(t, np.array([0.0, np.nan, 0.0, np.nan, 0.0]), np.zeros(5)))
    ["channel 'position': 2 NaN values, first at index 1"]
    >>> trial_problems(Trial(t, np.zeros(5), np.zeros(5)))
    []
    """
    channels = {"time": trial.time, "position": trial.position, "torque": trial.torque}
    channels.update(trial.channels)
    problems: list[str] = []
    arrays: dict[str, np.ndarray] = {}
    for name, values in channels.items():
        try:
            x = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            problems.append(f"channel '{name}': not numeric")
            continue
        if x.ndim != 1:
            problems.append(f"channel '{name}': expected a vector, got shape {x.shape}")
            continue
        arrays[name] = x
    lengths = {name: len(x) for name, x in arrays.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{name} {n}" for name, n in lengths.items())
        problems.append(f"unequal channel lengths: {listed}")
    n = lengths.get("time", 0)
    if "time" in arrays and n < 2:
        problems.append(f"fewer than 2 samples ({n})")
    for name, x in arrays.items():
        problems += _finite_problems(name, x)
    if "time" in arrays and n >= 2:
        problems += _time_problems(arrays["time"])
    return problems


def check_trial(trial: Trial, source=None) -> Trial:
    """Raise one :class:`DataError` listing every problem of ``trial``; return it if usable.

    Checks: NaN/inf per channel, unequal channel lengths, time not strictly increasing,
    uneven sampling (a step deviating from the median step by more than 1e-3 of it, unless
    every stamp lies within 0.1 step of the uniform grid: then an LpvpcWarning), fewer than
    2 samples. ``source`` (default: the trial's name) prefixes the message.
    """
    problems = trial_problems(trial)
    where = str(source) if source is not None else (trial.name or None)
    if problems:
        raise DataError(problems, source=where)
    t = np.asarray(trial.time, dtype=float)
    steps = np.diff(t)
    if np.any(_uneven_steps(steps, float(np.median(steps)))):  # accepted above: jitter about a uniform grid
        warnings.warn(f"{where + ': ' if where else ''}time stamps jitter by up to {100 * grid_deviation(t):.2g} % of "
                      f"a step about a uniform grid (a rounded or software-clock time column); read as sampled "
                      f"uniformly at {trial.fs:.6g} Hz", LpvpcWarning, stacklevel=2)
    return trial


# --------------------------------------------------------------------------- reading files


def _read_csv(path: Path, channels=None) -> dict[str, np.ndarray]:
    """Columns of a CSV file with one header row (leading ``#`` comment lines are skipped).
    ``channels`` maps roles to the file's own column names (``{"position": "Pert (rad)"}``,
    case-insensitive); a column already named after a mapped role is then not read.
    A file larger than the per-variable limit (:func:`lpvpc.matfiles.max_variable_bytes`,
    1 GiB unless set) is refused before it is read."""
    from .matfiles import max_variable_bytes, over_limit

    limit = max_variable_bytes()
    size = os.path.getsize(path)
    if size > limit:  # the text is held in memory below: bounded by the limit, not by the file
        raise DataError([over_limit("the file", size, limit)], source=str(path))
    try:
        text = path.read_text(encoding="utf-8-sig")  # tolerate a BOM (spreadsheet exports)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError([f"cannot read file: {exc}"], source=str(path)) from exc
    lines = text.splitlines()
    header_at = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            # numpy.savetxt's default writes the header as a comment: accept that too.
            names = [c.strip().lower() for c in stripped.lstrip("#").split(",")]
            if "time" in names:
                header_at = i
                break
            continue
        header_at = i
        break
    if header_at is None:
        raise DataError(["empty file (no header row)"], source=str(path))
    names = [c.strip().lower() for c in lines[header_at].strip().lstrip("#").split(",")]
    if channels:
        names = _renamed_columns(names, channels, path)
    duplicates = sorted({c for c in names if names.count(c) > 1})
    problems = [f"duplicate column '{c}'" for c in duplicates]
    problems += [f"empty column name at position {i + 1}" for i, c in enumerate(names) if not c]
    if problems:
        raise DataError(problems, source=str(path))
    body = [ln for ln in lines[header_at + 1:] if ln.strip() and not ln.lstrip().startswith("#")]
    # Columns the loaders know are read as numbers; any other column (a text notes column,
    # a trigger, a label) is ignored, whatever it holds. Every row still needs every field.
    known = set(REQUIRED_CHANNELS + OPTIONAL_CHANNELS + PERTURBATION_EMG)
    use = [i for i, c in enumerate(names) if c in known]
    ignored = [c for c in names if c not in known]
    if ignored:
        _log.info("%s: ignored column(s) %s (not channels lpvpc reads)", path, ", ".join(ignored))
    if not body or not use:
        return _Table({names[i]: np.empty(0) for i in use}, names)
    values = None
    if '"' not in text and all(ln.count(",") == len(names) - 1 for ln in body):
        try:
            values = np.loadtxt(body, delimiter=",", ndmin=2, dtype=float, usecols=use)
        except ValueError:
            values = None
    if values is None:  # quoted fields, ragged or unparsable rows: the careful parse
        values, problems = _csv_rows(body, names, use, first_line=header_at + 2)
        if problems:
            raise DataError(problems, source=str(path))
    return _Table({names[i]: values[:, k] for k, i in enumerate(use)}, names)


def _renamed_columns(names: list[str], channels: dict, path: Path) -> list[str]:
    """The header with each mapped column renamed to its role (columns that carried a
    mapped role's name before are renamed away, so they are not read)."""
    known = set(REQUIRED_CHANNELS + OPTIONAL_CHANNELS + PERTURBATION_EMG)
    problems = []
    unknown = sorted(set(channels) - known)
    if unknown:
        problems.append(f"unknown channel role(s) {', '.join(unknown)} (roles: {', '.join(sorted(known))})")
    wanted = {str(col).strip().lower(): role for role, col in channels.items()}
    for col, role in wanted.items():
        if col not in names:
            problems.append(f"no column '{col}' for {role} (columns found: {', '.join(names)})")
    if len(wanted) < len(channels):
        problems.append("two roles name the same column")
    if problems:
        raise DataError(problems, source=str(path))
    mapped = set(wanted.values())
    return [wanted[c] if c in wanted else f"{c} (not read: --channel {c}=...)" if c in mapped else c for c in names]


class _Table(dict):
    """Channels read from a file; ``columns``: every column of the file (also those ignored)."""

    def __init__(self, channels, columns):
        super().__init__(channels)
        self.columns = list(columns)


def _csv_rows(body: list[str], names: list[str], use: list[int], first_line: int):
    """Slow parse (quoted fields allowed), after the fast one failed: the ``use`` columns as
    an array, or the problems (which rows and fields are bad).

    Line numbers are approximate when comment or blank lines sit between data rows.
    """
    wrong_width: list[int] = []
    unparsable: dict[str, list[int]] = {}
    rows = []
    for k, row in enumerate(csv.reader(io.StringIO("\n".join(body)))):
        line = first_line + k
        if len(row) != len(names):
            wrong_width.append(line)
            continue
        out = []
        for i in use:
            try:
                out.append(float(row[i]))
            except ValueError:
                unparsable.setdefault(names[i], []).append(line)
        rows.append(out)
    problems = []
    if wrong_width:
        problems.append(
            f"{_plural(len(wrong_width), 'row')} without {len(names)} fields, first at line {wrong_width[0]}"
        )
    for name, at in unparsable.items():
        problems.append(f"column '{name}': {_plural(len(at), 'value')} not a number, first at line {at[0]}")
    if problems:
        return None, problems
    return np.array(rows, dtype=float).reshape(len(rows), len(use)), []


def _read_mat(path: Path, required, optional, variable=None, channels=None) -> dict[str, np.ndarray]:
    """Channels of a MATLAB file by role (``time``, ``position``, ...): the lab's ``nldat``
    objects, structs, matrices or plain vectors, v4 to v7.3 (:mod:`lpvpc.matfiles`)."""
    from lpvpc.matfiles import needed_variables, read_mat, select_channels

    skipped: list = []  # variables over the size limit, not read
    records = read_mat(path, needed_variables(variable, channels), skipped)
    try:
        return select_channels(records, required, optional, channels=channels, variable=variable, source=str(path))
    except DataError as exc:
        if skipped:
            raise DataError(list(exc.problems) + skipped, source=str(path)) from None
        raise


def _path_and_variable(path, variable):
    path, named = split_variable(path)
    return path, (named if named is not None else variable)


def _read_table(path, required=REQUIRED_CHANNELS, optional=OPTIONAL_CHANNELS, *, variable=None,
                channels=None) -> tuple[dict[str, np.ndarray], Path]:
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".mat"):
        raise DataError([f"unknown file extension '{path.suffix}' (expected .csv or .mat)"], source=str(path))
    if not path.is_file():
        raise DataError(["no such file"], source=str(path))
    if os.path.getsize(path) == 0:
        raise DataError(["empty file"], source=str(path))
    if suffix == ".csv":
        if variable is not None:
            raise DataError([f"a variable ({variable}) names a variable in .mat files; a CSV file holds one table"],
                            source=str(path))
        return _read_csv(path, channels), path
    return _read_mat(path, required, optional, variable, channels), path


def _require(table: dict, required, path) -> None:
    missing = [c for c in required if c not in table]
    if missing:
        found = ", ".join(getattr(table, "columns", table)) or "none"
        listed = ", ".join(f"'{c}'" for c in missing)
        raise DataError([f"missing required column{'s' if len(missing) > 1 else ''} {listed} (columns found: "
                         f"{found}); a column named otherwise is chosen with channels={{'{missing[0]}': COLUMN}} "
                         f"(--channel {missing[0]}=COLUMN)"], source=str(path))


# --------------------------------------------------------------------------- units and signs


def _check_settings(position_unit: str, torque_sign: float) -> float:
    if position_unit not in ("rad", "deg"):
        raise ValueError(f"position_unit must be 'rad' or 'deg', got {position_unit!r}")
    torque_sign = float(torque_sign)
    if not math.isfinite(torque_sign) or torque_sign == 0:
        raise ValueError(f"torque_sign must be a finite non-zero number, got {torque_sign!r}")
    return torque_sign


def _degree_channels(trial: Trial, channels=ANGLE_CHANNELS) -> list[tuple]:
    """(channel, max |value|, range) of the angle channels (read as rad) that look like degrees."""
    found = []
    for name in channels:
        x = trial.position if name == "position" else trial.channels.get(name)
        if x is None or len(x) == 0 or not np.all(np.isfinite(x)):
            continue
        peak = float(np.max(np.abs(x)))
        span = float(np.ptp(x))
        # An ankle moves within about +-0.9 rad; 2*pi or a 3 rad range is not radians.
        if peak > 2 * np.pi or span > 3.0:
            found.append((name, peak, span))
    return found


def _warn_if_degrees(trial: Trial, source: str, channels=ANGLE_CHANNELS) -> None:
    """Warn (UnitWarning) for each angle channel whose values look like degrees."""
    for name, peak, span in _degree_channels(trial, channels):
        warnings.warn(f"{source}: channel '{name}' looks like degrees (max |value| {peak:.4g}, range {span:.4g}) "
                      f"but position_unit='rad'; pass position_unit='deg' if it is in degrees", UnitWarning,
                      stacklevel=4)


def _refuse_degrees(trials, position_unit: str) -> None:
    """Identification data in degrees read as rad would give a model 57 times too soft:
    refuse (DataError naming the fix) rather than warn."""
    if position_unit != "rad":
        return
    found = []
    for t in trials:
        channels = _degree_channels(t)
        if channels:
            name, peak, span = channels[0]
            more = "".join(f", '{c[0]}'" for c in channels[1:])
            found.append(f"{t.name or 'data'}: '{name}' (max |value| {peak:.4g}, range {span:.4g}){more}")
    if found:
        raise DataError([f"angles look like degrees but are read as rad: {'; '.join(found)}; pass "
                         f"position_unit='deg' if the files are in degrees"])


def _milliseconds_hint(fs: float) -> str:
    """The fix when a rate read from a time column in s looks like a time column in ms."""
    if fs < MS_MAX_RATE and fs * 1000.0 >= MS_MIN_RATE:
        return (f"the time column looks like milliseconds (steps of {1 / fs:.4g}: {1000 * fs:.6g} Hz if in ms): "
                f"pass time_unit='ms'")
    return ""


def _check_time_unit(time_unit: str) -> float:
    """Seconds per unit of the time column."""
    if time_unit not in ("s", "ms"):
        raise ValueError(f"time_unit must be 's' or 'ms', got {time_unit!r}")
    return 1.0 if time_unit == "s" else 1e-3


def _refuse_swap(pt: Trial, ut: Trial, source: str) -> None:
    """The perturbation belongs to PT: refuse a pair whose UT position holds more power
    faster than the slow movement than its PT position (the trials were given swapped)."""
    import scipy.ndimage

    w = max(3, int(round(SWAP_WINDOW * pt.fs)))

    def fast_power(x):
        x = np.asarray(x, dtype=float)
        if len(x) <= 2 * w:
            return 0.0
        return float(np.var((x - scipy.ndimage.uniform_filter1d(x, w, mode="nearest"))[w:-w]))

    p_pt, p_ut = fast_power(pt.position), fast_power(ut.position)
    if p_ut > SWAP_RATIO * p_pt:
        ratio = f"{p_ut / p_pt:.3g} times" if p_pt > 0 else "more than"
        raise DataError([f"PT and UT look swapped: the trial given as UT ({ut.name or '?'}) carries the perturbation "
                         f"(power of its position faster than the slow movement is {ratio} the PT trial's); "
                         f"swap the pt and ut arguments"], source=source)


def _to_si(trial: Trial, position_unit: str, torque_sign: float, source: str, time_unit: str = "s") -> Trial:
    """Convert angle channels to rad, time to s and apply the torque sign; warn about likely degrees."""
    torque_sign = _check_settings(position_unit, torque_sign)
    seconds = _check_time_unit(time_unit)
    if position_unit == "rad":
        _warn_if_degrees(trial, source)
    scale = np.pi / 180.0 if position_unit == "deg" else 1.0
    channels = {
        k: (np.asarray(v, dtype=float) * scale if k in ANGLE_CHANNELS else np.asarray(v, dtype=float))
        for k, v in trial.channels.items()
    }
    return Trial(
        time=np.asarray(trial.time, dtype=float) * seconds,
        position=np.asarray(trial.position, dtype=float) * scale,
        torque=np.asarray(trial.torque, dtype=float) * torque_sign,
        channels=channels,
        name=trial.name,
    )


def _name(path: Path, variable) -> str:
    return f"{path.stem}:{variable}" if variable else path.stem


def _trial_from_table(table, path, name, required, extra_channels=()) -> Trial:
    _require(table, required, path)
    channels = {c: table[c] for c in OPTIONAL_CHANNELS + tuple(extra_channels) if c in table}
    trial = Trial(table["time"], table["position"], table["torque"], channels, name or path.stem)
    check_trial(trial, source=str(path))
    return trial


def load_trial(path, *, position_unit: str = "rad", torque_sign: float = +1.0, name=None, variable=None,
               channels=None, time_unit: str = "s") -> Trial:
    """Load one trial from CSV or MATLAB ``.mat`` (v4 to v7.3, the lab's ``nldat`` objects too).

    Required columns/variables: ``time`` (s), ``position``, ``torque``; optional ``emg``,
    ``command``, ``scheduling``; other columns are ignored. ``position_unit`` ("rad" or
    "deg") is the unit of position, command and scheduling in the file; ``torque_sign``
    multiplies torque (N m) to bring the lab's sign convention to the package's.
    In a .mat file ``variable`` names the variable (e.g. an ``nldat`` object; also
    ``"file.mat:NAME"``) and ``channels`` maps roles to channel names
    (``{"position": "pos1", "torque": "tq1"}``); what they leave open is chosen
    automatically when only one choice fits (:func:`lpvpc.matfiles.select_channels`), and
    time comes from a ``time`` channel or the variable's sample period; ``time_unit`` ("s" or
    "ms") is the unit of a time column.
    Raises DataError listing every problem; warns (UnitWarning) when radians look like degrees.
    """
    _check_settings(position_unit, torque_sign)
    _check_time_unit(time_unit)
    path, variable = _path_and_variable(path, variable)
    table, path = _read_table(path, variable=variable, channels=channels)
    trial = _trial_from_table(table, path, name or _name(path, variable), REQUIRED_CHANNELS)
    return _to_si(trial, position_unit, torque_sign, str(path), time_unit)


# --------------------------------------------------------------------------- decimation


def _stage_factors(q: int) -> list[int]:
    """Split a decimation factor into stages of at most 13 (largest first)."""
    primes = []
    rest = q
    p = 2
    while p * p <= rest:
        while rest % p == 0:
            primes.append(p)
            rest //= p
        p += 1
    if rest > 1:
        primes.append(rest)
    stages: list[int] = []
    # Greedy packing of prime factors (largest first) into stages <= 13; a prime > 13 is its own stage.
    for p in sorted(primes, reverse=True):
        for i, s in enumerate(stages):
            if s * p <= MAX_STAGE_FACTOR:
                stages[i] = s * p
                break
        else:
            stages.append(p)
    return sorted(stages, reverse=True)


def decimation_factor(fs: float, target_fs, source=None) -> int:
    """Integer factor from ``fs`` to ``target_fs`` (Hz); 1 if ``target_fs`` is None.

    Raises DataError if ``fs`` is below ``target_fs`` or not an integer multiple of it.

    >>> decimation_factor(1000.0, 100.0), decimation_factor(1000.0, None)  # Hz
    (10, 1)
    >>> decimation_factor(1000.0, 300.0)
    Traceback (most recent call last):
    ...
    lpvpc.errors.DataError: ...
    """
    if target_fs is None:
        return 1
    target_fs = float(target_fs)
    if not target_fs > 0:
        raise ValueError(f"target_fs must be positive or None, got {target_fs!r}")
    if fs < target_fs * (1 - RATE_TOLERANCE):
        fix = _milliseconds_hint(fs) or "pass target_fs=None to keep the rate"
        raise DataError([f"sampling rate {fs:.6g} Hz is below the target rate {target_fs:.6g} Hz: {fix}"],
                        source=source)
    q = round(fs / target_fs)
    if abs(fs - q * target_fs) > RATE_TOLERANCE * fs:
        raise DataError(
            [f"sampling rate {fs:.6g} Hz is not an integer multiple of the target rate {target_fs:.6g} Hz"],
            source=source,
        )
    return int(q)


def _antialias_fir(q: int) -> np.ndarray:
    """Linear-phase low-pass FIR for decimation by ``q`` (unit DC gain)."""
    return scipy.signal.firwin(
        FIR_TAPS_PER_FACTOR * q + 1, 1.0 / q, window=("kaiser", scipy.signal.kaiser_beta(FIR_ATTENUATION_DB))
    )


def decimate_signal(x, q: int) -> np.ndarray:
    """Anti-aliased zero-phase FIR decimation by ``q``; output sample k is input sample k*q.

    Same polyphase zero-phase path as ``scipy.signal.decimate(x, q, ftype="fir",
    zero_phase=True)`` (``resample_poly``), with a sharper, flatter filter.

    A 1 Hz sine sampled at 1 kHz keeps its shape at 100 Hz; a 300 Hz one is removed, not aliased:

    >>> t = np.arange(5000) / 1000.0  # s
    >>> slow, fast = np.sin(2 * np.pi * t), np.sin(2 * np.pi * 300 * t)
    >>> y = decimate_signal(slow + fast, 10)
    >>> len(y), bool(np.max(np.abs(y - slow[::10])[50:-50]) < 1e-3)
    (500, True)
    """
    if q == 1:
        return np.asarray(x, dtype=float).copy()
    x = np.asarray(x, dtype=float)
    n = len(x)
    # scipy pads with zeros at both ends; a signal far from zero (a joint angle of -0.4 rad)
    # would droop toward zero there. Removing the line through the end points makes both ends
    # zero; it is added back afterwards, so the operation stays linear (same on PT-UT as on PT, UT).
    ramp = np.linspace(x[0], x[-1], n) if n > 1 else x.copy()
    y = x - ramp
    for stage in _stage_factors(q):
        y = scipy.signal.resample_poly(y, 1, stage, window=_antialias_fir(stage))
    return y + ramp[::q]


def multiple_rate(fs: float, target_fs) -> float:
    """The rate (Hz) a file at ``fs`` is brought to before decimation to ``target_fs``: ``fs``
    itself when it is an integer multiple of ``target_fs`` (or ``target_fs`` is None, or
    above ``fs``: decimation_factor says so), else the largest multiple below it.

    >>> multiple_rate(1000.0, 100.0), multiple_rate(1024.0, 100.0), multiple_rate(250.0, 100.0)
    (1000.0, 1000.0, 200.0)
    """
    if target_fs is None or fs < float(target_fs) * (1 - RATE_TOLERANCE):
        return float(fs)
    target_fs = float(target_fs)
    q = round(fs / target_fs)
    if abs(fs - q * target_fs) <= RATE_TOLERANCE * fs:
        return float(fs)
    return float(math.floor(fs / target_fs) * target_fs)


def resample_trial(trial: Trial, fs_new: float) -> Trial:
    """Every channel of ``trial`` resampled to ``fs_new`` (Hz) by a rational factor with a
    zero-phase polyphase anti-alias FIR (the decimation's filter design), for files whose
    rate is not a multiple of the model rate (1024 Hz -> 1000 Hz: 125/128; 250 Hz -> 200 Hz:
    4/5). Time restarts from the first stamp at the new step.

    A 3 Hz sine at 1024 Hz keeps its shape at 1000 Hz:

    >>> t = np.arange(2048) / 1024.0
    >>> x = np.sin(2 * np.pi * 3 * t)
    >>> r = resample_trial(Trial(t, x, x), 1000.0)
    >>> len(r.time), r.fs, bool(np.max(np.abs(r.position - np.sin(2 * np.pi * 3 * r.time))[40:-40]) < 1e-4)
    (2000, 1000.0, True)
    """
    from fractions import Fraction

    ratio = Fraction(float(fs_new) / trial.fs).limit_denominator(1000)
    up, down = ratio.numerator, ratio.denominator
    n_out = -(-len(trial.time) * up // down)
    if n_out < 2:
        raise DataError([f"fewer than 2 samples after resampling to {fs_new:g} Hz"], source=trial.name or None)
    fs_out = trial.fs * up / down

    def one(x):
        x = np.asarray(x, dtype=float)
        ramp = np.linspace(x[0], x[-1], len(x))  # as decimate_signal: no droop toward zero at the ends
        out_ramp = np.linspace(x[0], x[-1], n_out)
        y = scipy.signal.resample_poly(x - ramp, up, down, window=_antialias_fir(max(up, down)))  # gain up: scipy
        return y[:n_out] + out_ramp

    return Trial(
        time=float(trial.time[0]) + np.arange(n_out) / fs_out,
        position=one(trial.position),
        torque=one(trial.torque),
        channels={k: one(v) for k, v in trial.channels.items()},
        name=trial.name,
    )


def to_multiple_rate(trial: Trial, target_fs) -> Trial:
    """``trial`` itself when its rate is a multiple of ``target_fs`` (Hz), else resampled to
    the largest multiple below (:func:`multiple_rate`, :func:`resample_trial`): what every
    reader does before decimating (identification, validation, the whole-joint fit).

    >>> t, u = np.arange(1024) / 1024.0, np.arange(1000) / 1000.0  # 1 s at 1024 and at 1000 Hz
    >>> at_1024, at_1000 = Trial(t, np.sin(t), np.cos(t)), Trial(u, np.sin(u), np.cos(u))
    >>> to_multiple_rate(at_1024, 100.0).fs, to_multiple_rate(at_1000, 100.0) is at_1000
    (1000.0, True)
    """
    fs = multiple_rate(trial.fs, target_fs)
    return trial if fs == trial.fs else resample_trial(trial, fs)


def decimate_trial(trial: Trial, target_fs) -> Trial:
    """Decimate every channel of ``trial`` to ``target_fs`` (Hz) with the same anti-alias filter.

    ``target_fs`` None or equal to the trial's rate returns an unchanged copy. The trial's
    rate must be an integer multiple of ``target_fs`` (DataError otherwise); time keeps
    every q-th stamp, so output sample k is aligned with input sample k*q.
    """
    q = decimation_factor(trial.fs, target_fs, source=trial.name or None)
    n_out = -(-len(trial.time) // q)
    if n_out < 2:
        raise DataError(
            [f"fewer than 2 samples after decimation by {q} ({len(trial.time)} -> {n_out})"],
            source=trial.name or None,
        )
    return Trial(
        time=np.asarray(trial.time, dtype=float)[::q].copy(),
        position=decimate_signal(trial.position, q),
        torque=decimate_signal(trial.torque, q),
        channels={k: decimate_signal(v, q) for k, v in trial.channels.items()},
        name=trial.name,
    )


# --------------------------------------------------------------------------- identification data


@dataclass
class HighRate:
    """The perturbation position (rad) and scheduling (rad) at the file's own rate ``fs``
    (Hz), kept beside model-rate data decimated from it (:class:`PerturbationData`).

    The reflex rectifier acts on velocity pulses about 20 ms wide: at 1 kHz they are
    resolved, at 100 Hz smoothed, and the rectifier's threshold is not observable there.
    Identification therefore evaluates the reflex nonlinearity on the delayed velocity at
    this rate and decimates its output (:mod:`lpvpc.reflex`). Sample ``k * q`` here is
    model-rate sample ``k`` (q = ``fs`` / model rate). ``segments``: trial bounds at this
    rate when trials are joined. Memory: two float64 arrays at the file's rate (16 bytes
    per sample: 1.9 MB for 2 minutes at 1 kHz).

    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=2.0)  # 1 kHz trials
    >>> data = pair_trials(sim.pt, sim.ut)  # decimated to 100 Hz, the 1 kHz signals kept
    >>> data.fs, data.high_rate.fs, data.n, data.high_rate.n
    (100.0, 1000.0, 200, 2000)
    """

    position: np.ndarray
    scheduling: np.ndarray
    fs: float
    segments: tuple = ()

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=float)
        self.scheduling = np.asarray(self.scheduling, dtype=float)
        self.fs = float(self.fs)
        self.segments = tuple((int(a), int(b)) for a, b in self.segments)
        if len(self.segments) == 1:
            self.segments = ()

    @property
    def n(self) -> int:
        return len(self.position)

    def __repr__(self):
        trials = f" in {len(self.segments)} trials" if self.segments else ""
        return f"HighRate({self.n} samples{trials} at {self.fs:g} Hz)"


@dataclass
class PerturbationData:
    """Identification data: perturbation position ``position`` (rad), perturbation torque
    ``torque`` (N m), scheduling variable ``scheduling`` (rho, rad), sampling rate ``fs`` (Hz).

    ``extra`` holds other channels aligned with them (``time`` (s), ``emg``,
    ``ut_velocity`` (rad/s) ...); ``source`` says where the data came from; ``meta`` records
    the loading settings (``position_unit``, ``torque_sign``, ``fs_original``,
    ``decimation``) so a model can report them. ``segments`` lists the ``(start, stop)``
    sample ranges of the trials when several are joined (:func:`join_trials`; empty: one
    trial); identification builds its regressors trial by trial (:mod:`lpvpc.segments`).
    ``high_rate`` (:class:`HighRate` or None) keeps the perturbation position and the
    scheduling at the file's rate when it was decimated (the reflex nonlinearity is
    identified there).
    """

    position: np.ndarray
    torque: np.ndarray
    scheduling: np.ndarray
    fs: float
    extra: dict = field(default_factory=dict)
    source: str = ""
    meta: dict = field(default_factory=dict)
    segments: tuple = ()
    high_rate: HighRate | None = None

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=float)
        self.torque = np.asarray(self.torque, dtype=float)
        self.scheduling = np.asarray(self.scheduling, dtype=float)
        self.fs = float(self.fs)
        problems = []
        if not (math.isfinite(self.fs) and self.fs > 0):
            problems.append(f"sampling rate must be positive and finite, got {self.fs}")
        arrays = {"position": self.position, "torque": self.torque, "scheduling": self.scheduling}
        arrays.update({k: np.asarray(v) for k, v in self.extra.items() if np.ndim(v) == 1})
        lengths = {k: len(v) for k, v in arrays.items()}
        if len(set(lengths.values())) > 1:
            problems.append("unequal channel lengths: " + ", ".join(f"{k} {n}" for k, n in lengths.items()))
        for name in ("position", "torque", "scheduling"):
            x = arrays[name]
            if x.ndim != 1:
                problems.append(f"channel '{name}': expected a vector, got shape {x.shape}")
            else:
                problems += _finite_problems(name, x)
        if problems:
            raise DataError(problems, source=self.source or None)
        self.segments = tuple((int(a), int(b)) for a, b in self.segments)
        if len(self.segments) == 1:
            self.segments = ()
        Segments(self.segments, self.n)  # they must tile the record
        if self.high_rate is not None:
            self._check_high_rate()

    @property
    def decimation(self) -> int:
        """Factor q from the high-rate signals to this record (1 without them)."""
        return 1 if self.high_rate is None else int(round(self.high_rate.fs / self.fs))

    def _check_high_rate(self):
        hr, q = self.high_rate, self.decimation
        problems = []
        if q < 2 or abs(hr.fs - q * self.fs) > RATE_TOLERANCE * hr.fs:
            problems.append(f"high-rate signals at {hr.fs:.6g} Hz are not an integer multiple (> 1) of {self.fs:.6g} Hz")
        elif hr.scheduling.shape != hr.position.shape or hr.position.ndim != 1:
            problems.append(f"high-rate position and scheduling differ in shape: {hr.position.shape}, {hr.scheduling.shape}")
        else:
            hs = list(hr.segments) or [(0, hr.n)]
            ms = list(self.segments) or [(0, self.n)]
            if len(hs) != len(ms) or any(-(-(b - a) // q) != d - c for (a, b), (c, d) in zip(hs, ms)):
                problems.append(f"high-rate record ({hr.n} samples in {len(hs)} trial(s) at {hr.fs:.6g} Hz) does not "
                                f"decimate by {q} to the {self.n} samples in {len(ms)} trial(s) at {self.fs:.6g} Hz")
            Segments(hr.segments, hr.n)
            for name, x in (("high-rate position", hr.position), ("high-rate scheduling", hr.scheduling)):
                problems += _finite_problems(name, x)
        if problems:
            raise DataError(problems, source=self.source or None)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.position)

    def __repr__(self):
        # one line a user can read; the arrays are in the attributes
        trials = f" in {len(self.segments)} trials" if self.segments else ""
        high = f", {self.high_rate.fs:g} Hz signals kept" if self.high_rate is not None else ""
        extra = [k for k in self.extra if k != "time"]
        return (f"PerturbationData({self.n} samples{trials} at {self.fs:g} Hz ({self.n / self.fs:.1f} s{high}); "
                f"position {_span(self.position)} rad, torque {_span(self.torque)} N m, scheduling "
                f"{_span(self.scheduling)} rad" + (f"; extra {', '.join(extra)}" if extra else "")
                + (f"; source {_short(self.source)!r}" if self.source else "") + ")")

    @property
    def time(self) -> np.ndarray:
        """Time stamps (s): ``extra['time']`` if present, else ``arange(n) / fs``."""
        if "time" in self.extra:
            return np.asarray(self.extra["time"], dtype=float)
        return np.arange(self.n) / self.fs

    @property
    def data_hash(self) -> str:
        """sha256 (hex) of position, torque, scheduling and fs as little-endian float64 bytes."""
        h = hashlib.sha256()
        h.update(np.int64(self.n).astype("<i8").tobytes())
        for x in (self.position, self.torque, self.scheduling):
            h.update(np.ascontiguousarray(x, dtype="<f8").tobytes())
        h.update(np.float64(self.fs).astype("<f8").tobytes())
        if self.segments:  # the same samples cut into trials are other data
            h.update(np.asarray(self.segments, dtype="<i8").tobytes())
        return h.hexdigest()

    def segment(self, start: int | None = None, stop: int | None = None) -> "PerturbationData":
        """Samples ``start:stop`` (e.g. to hold out the last part of a record for validation)."""
        sl = slice(start, stop)
        extra = {k: (np.asarray(v)[sl] if np.ndim(v) == 1 and len(v) == self.n else v) for k, v in self.extra.items()}
        lo, hi, _ = sl.indices(self.n)
        segments = [(max(a, lo) - lo, min(b, hi) - lo) for a, b in self.segments if min(b, hi) > max(a, lo)]
        high = None
        if self.high_rate is not None:
            high = _high_rate_slice(self.high_rate, self.decimation, list(self.segments) or [(0, self.n)], lo, hi)
        return PerturbationData(
            self.position[sl], self.torque[sl], self.scheduling[sl], self.fs, extra,
            f"{self.source}[{'' if start is None else start}:{'' if stop is None else stop}]", dict(self.meta),
            tuple(segments), high,
        )


def _high_rate_slice(hr: HighRate, q: int, model_segments, lo: int, hi: int) -> HighRate:
    """The high-rate samples of model-rate samples lo..hi-1 (trial by trial: a trial's last
    model sample may stand for fewer than q high-rate samples)."""
    high_segments = list(hr.segments) or [(0, hr.n)]
    pieces, bounds, start = [], [], 0
    for (a, b), (ha, hb) in zip(model_segments, high_segments):
        ka, kb = max(a, lo), min(b, hi)
        if kb <= ka:
            continue
        s0, s1 = ha + (ka - a) * q, min(ha + (kb - a) * q, hb)
        pieces.append((s0, s1))
        bounds.append((start, start + s1 - s0))
        start += s1 - s0
    idx = np.concatenate([np.arange(s0, s1) for s0, s1 in pieces]) if pieces else np.arange(0)
    return HighRate(hr.position[idx], hr.scheduling[idx], hr.fs, tuple(bounds))


def _check_perturbation(position: np.ndarray, source: str) -> None:
    var = float(np.var(position)) if len(position) else 0.0
    if not np.any(position) or var < MIN_PERTURBATION_VARIANCE:
        raise InsufficientExcitationError(
            f"no perturbation: {source}: variance of the perturbation position is {var:.3g} rad^2 "
            f"(< {MIN_PERTURBATION_VARIANCE:g}); are the PT and UT trials the same recording?"
        )


def _output_rate(fs: float, target_fs) -> float:
    # Report the nominal target rate, not fs/q with round-off from the time stamps, so the
    # data hash does not depend on how the time column was rounded in a file.
    return float(target_fs) if target_fs is not None else fs


def _resampled(fs_file, fs_now, target_fs) -> dict:
    """``{"resampled_to": the multiple of target_fs}`` when the file's rate was resampled."""
    return {} if fs_now == fs_file else {"resampled_to": multiple_rate(fs_file, target_fs)}


def pair_trials(pt: Trial, ut: Trial, *, target_fs=100.0) -> PerturbationData:
    """Perturbation data from a perturbed (PT) and an unperturbed (UT) trial.

    position = PT position - UT position (rad), torque = PT torque - UT torque (N m),
    scheduling = UT position (rad), all decimated with one anti-alias FIR filter to
    ``target_fs`` (Hz; None keeps the rate). Extra channels: ``time`` (s, from PT),
    ``ut_velocity`` (rad/s, gradient of the decimated UT position), ``emg`` from PT and
    ``emg_ut`` from UT if present (decimated as given with the same filter: rectify/envelope
    raw EMG first).
    Raises DataError (problems of both trials, different lengths or rates) or
    InsufficientExcitationError (no perturbation).
    """
    source = f"PT={pt.name or '?'}, UT={ut.name or '?'}"
    problems = [f"PT: {p}" for p in trial_problems(pt)] + [f"UT: {p}" for p in trial_problems(ut)]
    if problems:
        raise DataError(problems, source=source)
    if len(pt.time) != len(ut.time):
        problems.append(f"PT and UT differ in length: PT has {len(pt.time)} samples, UT has {len(ut.time)}")
    if abs(pt.fs - ut.fs) > RATE_TOLERANCE * max(pt.fs, ut.fs):
        problems.append(f"PT and UT differ in sampling rate: PT {pt.fs:.6g} Hz, UT {ut.fs:.6g} Hz")
    if problems:
        raise DataError(problems, source=source)
    _refuse_swap(pt, ut, source)

    ut_position = np.asarray(ut.position, dtype=float)
    channels = {"scheduling": ut_position}
    if "emg" in pt.channels:
        channels["emg"] = pt.channels["emg"]
    if "emg" in ut.channels:
        channels["emg_ut"] = ut.channels["emg"]
    # Decimation is linear: decimating PT-UT equals the difference of the decimated trials,
    # and position and torque go through the same filter.
    diff = Trial(
        time=np.asarray(pt.time, dtype=float),
        position=np.asarray(pt.position, dtype=float) - ut_position,
        torque=np.asarray(pt.torque, dtype=float) - np.asarray(ut.torque, dtype=float),
        channels=channels,
        name=source,
    )
    fs_file = float(pt.fs)
    diff = to_multiple_rate(diff, target_fs)  # e.g. 1024 Hz: first to 1000 Hz, then decimated by 10
    q = decimation_factor(diff.fs, target_fs, source=source)
    low = decimate_trial(diff, target_fs) if q > 1 else diff
    fs = _output_rate(diff.fs, target_fs)
    _check_perturbation(low.position, source)
    extra = {"time": low.time, "ut_velocity": np.gradient(low.channels["scheduling"]) * fs}
    for k in ("emg", "emg_ut"):
        if k in low.channels:
            extra[k] = low.channels[k]
    meta = {"fs_original": fs_file, "decimation": q, **_resampled(fs_file, diff.fs, target_fs)}
    high = HighRate(diff.position, diff.channels["scheduling"], meta.get("resampled_to", fs_file)) if q > 1 else None
    return PerturbationData(low.position, low.torque, low.channels["scheduling"], fs, extra, source, meta,
                            high_rate=high)


def load_perturbation_file(path, *, position_unit: str = "rad", torque_sign: float = 1.0,
                           target_fs=100.0, variable=None, channels=None, time_unit: str = "s") -> PerturbationData:
    """Load perturbation data already computed as PT-UT from one CSV or ``.mat`` file.

    Required columns: ``time`` (s), ``position`` (perturbation, rad), ``torque``
    (perturbation, N m), ``scheduling`` (rho, rad); optional ``emg`` (of the PT trial) and
    ``emg_ut`` (of the UT trial). Units, sign and decimation as in :func:`load_trial` and
    :func:`pair_trials`; ``variable`` and ``channels`` as in :func:`load_trial` (the lab's
    pilot file: ``io`` holds ``posPert1``, ``tqPert1``, and ``sv`` the scheduling position:
    found without options).
    """
    _check_settings(position_unit, torque_sign)
    path, variable = _path_and_variable(path, variable)
    table, path = _read_table(path, REQUIRED_CHANNELS + ("scheduling",), PERTURBATION_EMG, variable=variable,
                              channels=channels)
    _refuse_single_trial(table, path)
    trial = _trial_from_table(table, path, _name(path, variable), REQUIRED_CHANNELS + ("scheduling",), PERTURBATION_EMG)
    trial = _to_si(trial, position_unit, torque_sign, str(path), time_unit)
    fs_file = float(trial.fs)
    trial = to_multiple_rate(trial, target_fs)  # e.g. 1024 Hz: first to 1000 Hz, then decimated by 10
    q = decimation_factor(trial.fs, target_fs, source=str(path))
    low = decimate_trial(trial, target_fs) if q > 1 else trial
    fs = _output_rate(trial.fs, target_fs)
    _check_perturbation(low.position, str(path))
    extra = {"time": low.time, "ut_velocity": np.gradient(low.channels["scheduling"]) * fs}
    extra.update({c: low.channels[c] for c in PERTURBATION_EMG if c in low.channels})
    meta = {"position_unit": position_unit, "torque_sign": float(torque_sign),
            "fs_original": fs_file, "decimation": q, **_resampled(fs_file, trial.fs, target_fs)}
    high = HighRate(trial.position, trial.channels["scheduling"], meta.get("resampled_to", fs_file)) if q > 1 else None
    return PerturbationData(low.position, low.torque, low.channels["scheduling"], fs, extra, str(path), meta,
                            high_rate=high)


def _refuse_single_trial(table, path) -> None:
    """A PT (or UT) trial given where perturbation data (PT - UT with its scheduling) are
    expected: name what is missing and the fix, not only the missing column."""
    if "scheduling" not in table and all(c in table for c in REQUIRED_CHANNELS):
        raise DataError(["no 'scheduling' column: this looks like one trial (time, position, torque), not "
                         "perturbation data (PT - UT with the unperturbed position as 'scheduling'); pass it as "
                         "pt=PT with its unperturbed trial as ut=UT, or with stationary=True if it was recorded "
                         "around one fixed position without a UT trial (a scheduling column named otherwise: "
                         "channels={'scheduling': COLUMN})"], source=str(path))


def stationary_perturbation(pt: Trial, *, target_fs=100.0) -> PerturbationData:
    """Perturbation data from one perturbed trial around a fixed operating position recorded
    without a UT trial (the commonest experiment in the field, e.g. the lab's
    ``experimental_data.mat``).

    The UT trial of such an experiment would hold the joint at the operating position: a
    constant position and a constant torque. Both are taken as the PT trial's means, so
    position = PT position - its mean (rad), torque = PT torque - its mean (N m), and
    scheduling = the mean position (constant; the model is then position-independent).
    The mean and not a low-pass: the perturbation itself reaches down to the lowest
    frequencies (the lab's trials keep about half their peak-to-peak range below 0.5 Hz),
    and that slow part carries the elastic stiffness. Removing the torque mean also removes
    the mean of the rectified reflex torque, which the model then cannot attribute (the
    same as the lab's own stationary analysis, which removes it too). ``meta`` records
    ``stationary``, ``operating_point`` (rad) and ``torque_offset`` (N m).

    >>> t = np.arange(3000) / 1000.0  # a 3 s trial held at -0.1 rad, 1 kHz
    >>> rng = np.random.default_rng(0)
    >>> pos = -0.1 + 0.02 * np.sign(np.sin(2 * np.pi * 3 * t))
    >>> data = stationary_perturbation(Trial(t, pos, 40 * pos + 0.01 * rng.standard_normal(3000)))
    >>> data.fs, round(data.meta["operating_point"], 3), bool(np.ptp(data.scheduling) == 0.0)
    (100.0, -0.1, True)
    """
    problems = trial_problems(pt)
    if problems:
        raise DataError(problems, source=pt.name or "PT")
    w = int(round(STATIONARY_WINDOW * pt.fs))
    if len(pt.position) > w > 0:  # a moving trial read as stationary would be nonsense
        slow = np.convolve(pt.position, np.ones(w) / w, mode="valid")
        if np.ptp(slow) > STATIONARY_MAX_SPAN:
            raise DataError([f"not a stationary trial: its {STATIONARY_WINDOW:g}-s mean position spans "
                             f"{np.ptp(slow):.3f} rad (more than {STATIONARY_MAX_SPAN:g} rad for one operating "
                             f"position); give the UT trial recorded with it instead"], source=pt.name or "PT")
    op, tq0 = float(np.mean(pt.position)), float(np.mean(pt.torque))
    ut = Trial(np.asarray(pt.time, dtype=float), np.full(len(pt.time), op), np.full(len(pt.time), tq0), {},
               "constant operating point")
    out = pair_trials(pt, ut, target_fs=target_fs)
    out.source = f"{pt.name or 'PT'} (stationary at {op:+.4f} rad)"
    out.meta.update(stationary=True, operating_point=op, torque_offset=tq0)
    return out


def join_trials(trials) -> PerturbationData:
    """Several trials' perturbation data as one record for a joint identification.

    The arrays are put end to end and ``segments`` marks each trial, so that identification
    builds every regressor trial by trial and nothing (IRF lags, velocities, the reflex
    delay and dynamics, MOESP Hankel blocks) reaches from one trial into the next
    (:mod:`lpvpc.segments`). The trials must share the sampling rate (that of their files
    too), the position unit and the torque sign (DataError otherwise); extra channels
    (``time``, ``emg``, ...) are kept when every trial has them.
    """
    trials = list(trials)
    if not trials:
        raise DataError(["no trials given"])
    if len(trials) == 1:
        return trials[0]
    problems = []
    label = [f"trial {i + 1} ({d.source or '?'})" for i, d in enumerate(trials)]
    for what, values in (("sampling rate", [d.meta.get("fs_original", d.fs) for d in trials]),
                         ("sampling rate after decimation", [d.fs for d in trials])):
        if max(values) - min(values) > RATE_TOLERANCE * max(values):
            problems.append(f"trials differ in {what}: " + ", ".join(f"{lb} {v:.6g} Hz" for lb, v in zip(label, values))
                            + "; resample them to one rate")
            break
    for key in ("position_unit", "torque_sign"):
        values = [d.meta.get(key) for d in trials]
        if len({v for v in values if v is not None}) > 1:
            problems.append(f"trials differ in {key}: " + ", ".join(f"{lb} {v}" for lb, v in zip(label, values)))
    if problems:
        raise DataError(problems)
    segments, start = [], 0
    for d in trials:
        segments += [(start + a, start + b) for a, b in (d.segments or ((0, d.n),))]
        start += d.n
    common = [k for k, v in trials[0].extra.items()
              if all(np.ndim(d.extra.get(k)) == 1 and len(d.extra[k]) == d.n for d in trials)]
    extra = {k: np.concatenate([np.asarray(d.extra[k], dtype=float) for d in trials]) for k in common}
    meta = dict(trials[0].meta)
    meta["trials"] = [d.source for d in trials]
    for key in ("operating_point", "torque_offset"):
        meta.pop(key, None)
        if all(key in d.meta for d in trials):
            meta[key + "s"] = [d.meta[key] for d in trials]
    return PerturbationData(
        np.concatenate([d.position for d in trials]), np.concatenate([d.torque for d in trials]),
        np.concatenate([d.scheduling for d in trials]), trials[0].fs, extra,
        " + ".join(d.source or "?" for d in trials), meta, tuple(segments), _joined_high_rate(trials),
    )


def _joined_high_rate(trials) -> HighRate | None:
    """The trials' high-rate signals end to end (None unless every trial has them)."""
    if any(d.high_rate is None for d in trials):
        return None
    bounds, start = [], 0
    for d in trials:
        for a, b in d.high_rate.segments or ((0, d.high_rate.n),):
            bounds.append((start + a, start + b))
        start += d.high_rate.n
    return HighRate(np.concatenate([d.high_rate.position for d in trials]),
                    np.concatenate([d.high_rate.scheduling for d in trials]), trials[0].high_rate.fs, tuple(bounds))


def load_identification_data(pt=None, ut=None, data=None, *, position_unit: str = "rad",
                             torque_sign: float = 1.0, target_fs=100.0, variable=None, channels=None,
                             stationary: bool = False, time_unit: str = "s") -> PerturbationData:
    """The one entry point: either ``pt`` and ``ut`` (paths or Trials) or ``data`` (a path to
    a perturbation file, or a PerturbationData returned as is).

    ``position_unit`` and ``torque_sign`` describe the inputs (applied to Trials too);
    ``target_fs`` (Hz, None keeps the rate); ``variable`` and ``channels`` choose within
    .mat files (:func:`load_trial`; a path ``"file.mat:NAME"`` names its own variable).
    Several trials: lists for ``pt`` and ``ut`` (paired in order) or for ``data``, joined by
    :func:`join_trials` for one joint identification. ``stationary=True``: ``pt`` alone, a
    perturbed trial (or a list) around a fixed operating position recorded without UT
    (:func:`stationary_perturbation`). Wrong combinations raise DataError.

    ``time_unit`` ("s" or "ms") is the unit of the time columns. The mistakes that would
    give a wrong model are refused (DataError naming the fix): angles that look like
    degrees read as rad, a time column that looks like milliseconds read as s, PT and UT
    swapped (the perturbation in the UT trial).
    """
    given = [k for k, v in (("pt", pt), ("ut", ut), ("data", data)) if v is not None]
    allowed = (["pt"],) if stationary else (["pt", "ut"], ["data"])
    if given not in allowed:
        want = "pt alone (a stationary trial has no UT)" if stationary else "either both pt and ut, or data alone"
        raise DataError([f"give {want}; got {', '.join(given) or 'nothing'}"])
    torque_sign = _check_settings(position_unit, torque_sign)
    _check_time_unit(time_unit)
    kw = dict(position_unit=position_unit, torque_sign=torque_sign, target_fs=target_fs, variable=variable,
              channels=channels, stationary=stationary, time_unit=time_unit)
    if any(isinstance(v, (list, tuple)) for v in (pt, ut, data)):
        if data is not None:
            return join_trials([load_identification_data(data=d, **kw) for d in data])
        pts = list(pt) if isinstance(pt, (list, tuple)) else [pt]
        uts = list(ut) if isinstance(ut, (list, tuple)) else [ut] * len(pts) if stationary else [ut]
        if len(pts) != len(uts):
            raise DataError([f"{len(pts)} PT trials but {len(uts)} UT trials: give them in pairs"])
        return join_trials([load_identification_data(pt=a, ut=b if not stationary else None, **kw)
                            for a, b in zip(pts, uts)])
    if data is not None:
        if isinstance(data, PerturbationData):
            return data
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnitWarning)  # degrees: refused below instead
            out = load_perturbation_file(data, position_unit=position_unit, torque_sign=torque_sign,
                                         target_fs=target_fs, variable=variable, channels=channels,
                                         time_unit=time_unit)
        _refuse_degrees([Trial(out.time, out.position, out.torque, {"scheduling": out.scheduling}, out.source)],
                        position_unit)
        _refuse_milliseconds(out, time_unit)
        if time_unit != "s":
            out.meta["time_unit"] = time_unit
        return out
    trials = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)  # degrees: refused below instead
        for label, item in (("PT", pt), ("UT", ut)):
            if item is None:
                continue
            if isinstance(item, Trial):
                trials.append(_to_si(item, position_unit, torque_sign, item.name or label, time_unit))
            else:
                trials.append(load_trial(item, position_unit=position_unit, torque_sign=torque_sign,
                                         variable=variable, channels=channels, time_unit=time_unit))
    _refuse_degrees(trials, position_unit)
    if stationary:
        out = stationary_perturbation(trials[0], target_fs=target_fs)
    else:
        out = pair_trials(trials[0], trials[1], target_fs=target_fs)
    _refuse_milliseconds(out, time_unit)
    out.meta.update(position_unit=position_unit, torque_sign=torque_sign)
    if time_unit != "s":
        out.meta["time_unit"] = time_unit
    return out


def _refuse_milliseconds(data: PerturbationData, time_unit: str) -> None:
    """A time column in ms read as s at target_fs=None (which keeps the rate) gives a model
    at 1 Hz: refuse it as the decimation does."""
    hint = _milliseconds_hint(data.meta.get("fs_original", data.fs)) if time_unit == "s" else ""
    if hint:
        raise DataError([f"sampling rate {data.meta.get('fs_original', data.fs):.6g} Hz: {hint}"],
                        source=data.source or None)


def write_perturbation_csv(data: PerturbationData, path) -> None:
    """Write ``time,position,torque,scheduling[,emg][,emg_ut]`` (s, rad, N m, rad) so
    that :func:`load_perturbation_file` reads it back exactly (17 significant digits)."""
    names = ["time", "position", "torque", "scheduling"]
    cols = [data.time, data.position, data.torque, data.scheduling]
    for c in PERTURBATION_EMG:
        if c in data.extra:
            names.append(c)
            cols.append(data.extra[c])
    np.savetxt(
        path, np.column_stack(cols), delimiter=",", fmt="%.17g", comments="",
        header="# lpvpc perturbation data; units: time s, position rad, torque N m, scheduling rad\n"
        + ",".join(names),
    )
