"""The Trial record (one recording: time, position, torque and optional channels) and its
checks.

Units: time in s, position in rad, torque in N m, rates in Hz. Bad data are never repaired:
:func:`check_trial` collects every problem it finds and raises one
:class:`~lpvpc.errors.DataError` that lists them (channel, first index, count). Readers
(:mod:`lpvpc.io.readers`), decimation and pairing all build on this record.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import DataError, LpvpcWarning


OPTIONAL_CHANNELS = ("emg", "command", "scheduling")
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
#: Relative tolerance on sampling rates (PT vs UT, and fs as a multiple of target_fs).
RATE_TOLERANCE = 1e-4



def check_model_rate(fs, model_fs, *, what: str = "data", source=None, tolerance: float = RATE_TOLERANCE) -> None:
    """Refuse data whose sampling rate is not the model's: the one rate check of every door
    that gives a model a record (``lpvpc predict``, the diagnosis, the validation harness).

    Parameters
    ----------
    fs : float
        Sampling rate of the data, Hz.
    model_fs : float
        The model's sampling rate, Hz.
    what : str
        What the data are, for the message ("data", "record").
    source : str, optional
        The file the data came from, named in the error.
    tolerance : float
        Largest relative difference accepted (default :data:`~lpvpc.io.trial.RATE_TOLERANCE`).

    Raises
    ------
    DataError
        The rates differ by more than ``tolerance`` of the model's.

    Examples
    --------
    >>> check_model_rate(100.0, 100.0)
    >>> check_model_rate(1000.0, 100.0, source="later.csv")
    Traceback (most recent call last):
    ...
    lpvpc.errors.DataError: later.csv: sampling rate 1000 Hz of the data differs from the model's 100 Hz
    """
    if abs(float(fs) - float(model_fs)) > tolerance * float(model_fs):
        raise DataError(f"sampling rate {float(fs):g} Hz of the {what} differs from the model's {float(model_fs):g} Hz",
                        source=source or None)

@dataclass
class Trial:
    """One recorded (or simulated) trial: time (s), position (rad), torque (N m) and
    optional extra channels.

    Parameters
    ----------
    time : numpy.ndarray
        Time stamps (s), evenly spaced.
    position : numpy.ndarray
        Joint position (rad).
    torque : numpy.ndarray
        Joint torque (N m).
    channels : dict, optional
        Extra channels of the same length (``emg``, ``command`` (rad), ``scheduling``
        (rad)).
    name : str, default ""
        The trial's name in messages."""

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
    """Write a trial as CSV with header ``time,position,torque[,emg,command,scheduling]``.

    Parameters
    ----------
    trial : Trial
        The trial (SI units).
    path : str or pathlib.Path
        The CSV file (a temporary file renamed into place).
    """
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

    Parameters
    ----------
    t : array_like
        Time stamps (s).

    Returns
    -------
    float
        The largest deviation, in grid steps.

    Examples
    --------
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

    Parameters
    ----------
    trial : Trial
        The trial to check.

    Returns
    -------
    list of str
        One message per problem.

    Examples
    --------
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
    """Raise one :class:`~lpvpc.errors.DataError` listing every problem of ``trial``; return it if usable.

    Checks: NaN/inf per channel, unequal channel lengths, time not strictly increasing,
    uneven sampling (a step deviating from the median step by more than 1e-3 of it, unless
    every stamp lies within 0.1 step of the uniform grid: then an LpvpcWarning), fewer than
    2 samples.

    Parameters
    ----------
    trial : Trial
        The trial to check.
    source : str, optional
        Prefixes the message; default the trial's name.

    Returns
    -------
    Trial
        ``trial`` itself, when usable.

    Raises
    ------
    lpvpc.errors.DataError
        Every problem of the trial, in one message.
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
