"""The identification data object (:class:`PerturbationData`) and the ways to make it.

PT-UT pairing (:func:`pair_trials`), a stationary trial without UT
(:func:`stationary_perturbation`), a perturbation file already formed as PT - UT
(:func:`load_perturbation_file`), several trials joined end to end (:func:`join_trials`),
and the one entry point that takes any of them (:func:`load_identification_data`).
"""

from __future__ import annotations

import hashlib
import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .conventions import _check_settings, _check_time_unit, _milliseconds_hint, _refuse_degrees, _refuse_swap, _to_si
from .decimation import decimate_trial, decimation_factor, multiple_rate, to_multiple_rate
from ..errors import DataError, InsufficientExcitationError, UnitWarning
from .readers import PERTURBATION_EMG, _name, _path_and_variable, _read_table, _trial_from_table, load_trial
from .segments import Segments
from .trial import RATE_TOLERANCE, REQUIRED_CHANNELS, Trial, _finite_problems, _short, _span, trial_problems


# A stationary trial (no UT) holds one operating position: its mean over STATIONARY_WINDOW s
# spans at most STATIONARY_MAX_SPAN rad (the lab's trials: 0.026-0.028 rad; a passive-movement
# trajectory: about 0.6 rad).
STATIONARY_WINDOW = 2.0
STATIONARY_MAX_SPAN = 0.1
# Below this variance (rad^2) of the PT-UT position there is no perturbation to identify from.
MIN_PERTURBATION_VARIANCE = 1e-12


# ------------------------------------------------------- channel skew (a measurement artefact)

# A torque channel recorded a little later than the position channel (the lab's pilot trial:
# ~1 ms, a tenth of a 100 Hz sample) is lined up at the file's rate, before decimation: the
# position channels are delayed by the skew (lpvpc.identification.channel_skew; docs/guide/data.md).
MAX_CHANNEL_SKEW = 0.02  # s: beyond this a "skew" is a misunderstanding, not a sensor lag


SINC_HALF_WIDTH = 16  # samples each side of the fractional-delay filter (flat to ~0.4 fs)


def delayed(x, fs: float, delay: float) -> np.ndarray:
    """``x`` (sampled at ``fs`` Hz) delayed by ``delay`` s (negative: advanced), any fraction of
    a sample: a Hann-windowed sinc interpolator, the record's end values held beyond its ends.
    Exact for whole samples; for signals band-limited below ~0.4 fs (decimated data) the
    interpolation error is ~1e-4 of the amplitude.

    >>> t = np.arange(200) / 100.0
    >>> y = delayed(np.sin(2 * np.pi * 2 * t), 100.0, 0.0035)
    >>> bool(np.max(np.abs(y[20:180] - np.sin(2 * np.pi * 2 * (t[20:180] - 0.0035)))) < 1e-3)
    True
    """
    x = np.asarray(x, dtype=float)
    shift = delay * fs
    whole = int(np.floor(shift))
    frac = shift - whole
    k = np.arange(-SINC_HALF_WIDTH, SINC_HALF_WIDTH + 1)
    h = np.sinc(k + frac) * (0.5 + 0.5 * np.cos(np.pi * (k + frac) / (SINC_HALF_WIDTH + 1)))
    h /= h.sum()  # unit DC gain: a constant stays constant
    pad = SINC_HALF_WIDTH + abs(whole) + 1
    xp = np.r_[np.full(pad, x[0]), x, np.full(pad, x[-1])]
    y = np.convolve(xp, h[::-1], mode="same")  # y[i] = sum_j h[j] xp[i + j]
    return y[pad - whole: pad - whole + len(x)]


def check_channel_skew(value, allow_auto: bool = False) -> float | str:
    """``channel_skew`` as given: a finite number of seconds within +-MAX_CHANNEL_SKEW, or "auto"
    where ``allow_auto`` (ValueError naming the problem otherwise).

    >>> check_channel_skew(0.001), check_channel_skew("auto", allow_auto=True)
    (0.001, 'auto')
    """
    if isinstance(value, str):
        if value == "auto":
            if allow_auto:
                return value
            # choosing needs identification, which needs this module: not in the loaders
            raise ValueError("channel_skew='auto' is chosen by lpvpc.identification.channel_skew.load_aligned (same arguments); "
                             "give seconds here")
        raise ValueError(f"channel_skew {value!r}: give seconds (e.g. 0.001), or 'auto' to choose it "
                         f"(lpvpc.identification.channel_skew.load_aligned)")
    try:
        skew = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"channel_skew {value!r}: give seconds (e.g. 0.001), or 'auto' to choose it "
                         f"(lpvpc.identification.channel_skew.load_aligned)") from None
    if not math.isfinite(skew) or abs(skew) > MAX_CHANNEL_SKEW:
        raise ValueError(f"channel_skew {value!r} s: give a finite delay within +-{MAX_CHANNEL_SKEW:g} s "
                         f"(+-{MAX_CHANNEL_SKEW * 1e3:g} ms)")
    return skew


def _aligned(trial: Trial, skew: float) -> Trial:
    """``trial`` (at its file's rate) with its position channels (position and, when present,
    scheduling) delayed by ``skew`` s: the torque channel's lag behind them undone."""
    if not skew:
        return trial
    channels = dict(trial.channels)
    if "scheduling" in channels:
        channels["scheduling"] = delayed(channels["scheduling"], trial.fs, skew)
    return Trial(trial.time, delayed(trial.position, trial.fs, skew), trial.torque, channels, trial.name)


# --------------------------------------------------------------------------- identification data


@dataclass
class HighRate:
    """The perturbation position (rad) and scheduling (rad) at the file's own rate ``fs``
    (Hz), kept beside model-rate data decimated from it (:class:`PerturbationData`).

    The reflex rectifier acts on velocity pulses about 20 ms wide: at 1 kHz they are
    resolved, at 100 Hz smoothed, and the rectifier's threshold is not observable there.
    Identification therefore evaluates the reflex nonlinearity on the delayed velocity at
    this rate and decimates its output (:mod:`lpvpc.models.reflex`). Sample ``k * q`` here is
    model-rate sample ``k`` (q = ``fs`` / model rate). ``segments``: trial bounds at this
    rate when trials are joined. Memory: two float64 arrays at the file's rate (16 bytes
    per sample: 1.9 MB for 2 minutes at 1 kHz).

    Parameters
    ----------
    position, scheduling : numpy.ndarray
        The perturbation position and the scheduling variable (rad) at ``fs``.
    fs : float
        The file's rate (Hz).
    segments : tuple, default ``()``
        The joined trials' ``(start, stop)`` bounds at this rate.

    Examples
    --------
    >>> from lpvpc.simulation.simulate import simulate_pair
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
    """Identification data: one record (or several joined) at the model rate.

    Parameters
    ----------
    position : numpy.ndarray
        Perturbation position (rad).
    torque : numpy.ndarray
        Perturbation torque (N m).
    scheduling : numpy.ndarray
        Scheduling variable (rho, rad).
    fs : float
        Sampling rate (Hz).
    extra : dict, optional
        Other channels aligned with them (``time`` (s), ``emg``, ``ut_velocity`` (rad/s) ...).
    source : str, default ""
        Where the data came from.
    meta : dict, optional
        The loading settings (``position_unit``, ``torque_sign``, ``fs_original``,
        ``decimation``) so a model can report them.
    segments : tuple, default ``()``
        The ``(start, stop)`` sample ranges of the trials when several are joined
        (:func:`join_trials`; empty: one trial); identification builds its regressors trial
        by trial (:mod:`lpvpc.io.segments`).
    high_rate : HighRate, optional
        The perturbation position and the scheduling at the file's rate when it was
        decimated (the reflex nonlinearity is identified there).
    origin : RecordSource, optional
        How the record was loaded, so that a model can load it again with its conventions.
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
    origin: "RecordSource | None" = field(default=None, repr=False, compare=False)

    def reload(self, **changes) -> "PerturbationData":
        """The same record loaded again from its files (or Trials) with ``changes`` to its
        conventions (``torque_sign``, ``position_unit``, ``time_unit``, ``channel_skew``,
        ``target_fs``); DataError when it was not loaded by
        :func:`load_identification_data` and so cannot be."""
        if self.origin is None:
            raise DataError([f"these data were not loaded from files or Trials by load_identification_data, so they "
                             f"cannot be loaded again with {', '.join(f'{k}={v!r}' for k, v in changes.items())}: "
                             f"load them that way"], source=self.source or None)
        return self.origin.load(**changes)

    @property
    def conventions(self) -> dict:
        """The conventions these data were loaded with (defaults where the loader did not
        record one): ``position_unit``, ``torque_sign``, ``time_unit``, ``channel_skew`` (s)
        and ``fs`` (Hz)."""
        meta = self.meta or {}
        return {"position_unit": meta.get("position_unit", CONVENTION_DEFAULTS["position_unit"]),
                "torque_sign": float(meta.get("torque_sign", CONVENTION_DEFAULTS["torque_sign"])),
                "time_unit": meta.get("time_unit", CONVENTION_DEFAULTS["time_unit"]),
                "channel_skew": float(meta.get("channel_skew_s", 0.0) or 0.0), "fs": self.fs}

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


def pair_trials(pt: Trial, ut: Trial, *, target_fs=100.0, channel_skew: float = 0.0) -> PerturbationData:
    """Perturbation data from a perturbed (PT) and an unperturbed (UT) trial.

    position = PT position - UT position (rad), torque = PT torque - UT torque (N m),
    scheduling = UT position (rad), all decimated with one anti-alias FIR filter. Extra
    channels: ``time`` (s, from PT), ``ut_velocity`` (rad/s, gradient of the decimated UT
    position), ``emg`` from PT and ``emg_ut`` from UT if present (decimated as given with the
    same filter: rectify/envelope raw EMG first).

    Parameters
    ----------
    pt, ut : lpvpc.io.trial.Trial
        The perturbed and the unperturbed trial, same rate and length.
    target_fs : float or None, default 100.0
        The model rate (Hz); None keeps the trials' rate.
    channel_skew : float, default 0.0
        The torque channels' lag behind the position channels (s), undone at the file's
        rate before decimation (the position and scheduling delayed by it; recorded as
        ``meta["channel_skew_s"]``; docs/guide/data.md).

    Returns
    -------
    PerturbationData
        The record at ``target_fs``.

    Raises
    ------
    lpvpc.errors.DataError
        Problems of either trial, different lengths or rates.
    lpvpc.errors.InsufficientExcitationError
        No perturbation (PT and UT positions the same).
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
    skew = check_channel_skew(channel_skew)
    diff = _aligned(diff, skew)  # at the file's rate: a fraction of a model sample is whole samples here
    diff = to_multiple_rate(diff, target_fs)  # e.g. 1024 Hz: first to 1000 Hz, then decimated by 10
    q = decimation_factor(diff.fs, target_fs, source=source)
    low = decimate_trial(diff, target_fs) if q > 1 else diff
    fs = _output_rate(diff.fs, target_fs)
    _check_perturbation(low.position, source)
    extra = {"time": low.time, "ut_velocity": np.gradient(low.channels["scheduling"]) * fs}
    for k in ("emg", "emg_ut"):
        if k in low.channels:
            extra[k] = low.channels[k]
    meta = {"fs_original": fs_file, "decimation": q, **_resampled(fs_file, diff.fs, target_fs),
            **({"channel_skew_s": skew} if skew else {})}
    high = HighRate(diff.position, diff.channels["scheduling"], meta.get("resampled_to", fs_file)) if q > 1 else None
    return PerturbationData(low.position, low.torque, low.channels["scheduling"], fs, extra, source, meta,
                            high_rate=high)


def load_perturbation_file(path, *, position_unit: str = "rad", torque_sign: float = 1.0,
                           target_fs=100.0, variable=None, channels=None, time_unit: str = "s",
                           channel_skew: float = 0.0) -> PerturbationData:
    """Load perturbation data already computed as PT-UT from one CSV or ``.mat`` file.

    Required columns: ``time`` (s), ``position`` (perturbation, rad), ``torque``
    (perturbation, N m), ``scheduling`` (rho, rad); optional ``emg`` (of the PT trial) and
    ``emg_ut`` (of the UT trial). Units, sign and decimation as in :func:`~lpvpc.io.readers.load_trial` and
    :func:`pair_trials`; ``variable`` and ``channels`` as in :func:`~lpvpc.io.readers.load_trial` (the lab's
    pilot file: ``io`` holds ``posPert1``, ``tqPert1``, and ``sv`` the scheduling position:
    found without options). ``channel_skew`` as in :func:`pair_trials`.

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV or .mat file.
    position_unit, torque_sign, target_fs, variable, channels, time_unit, channel_skew
        As in :func:`load_identification_data`.

    Returns
    -------
    PerturbationData
        The record at ``target_fs``.

    Raises
    ------
    lpvpc.errors.DataError
        An unreadable file, missing columns, or a mistake in units or time base.
    """
    skew = check_channel_skew(channel_skew)
    trial, path = _perturbation_file_trial(path, position_unit, torque_sign, variable, channels, time_unit)
    fs_file = float(trial.fs)
    trial = _aligned(trial, skew)  # at the file's rate, before decimation
    trial = to_multiple_rate(trial, target_fs)  # e.g. 1024 Hz: first to 1000 Hz, then decimated by 10
    q = decimation_factor(trial.fs, target_fs, source=str(path))
    low = decimate_trial(trial, target_fs) if q > 1 else trial
    fs = _output_rate(trial.fs, target_fs)
    _check_perturbation(low.position, str(path))
    extra = {"time": low.time, "ut_velocity": np.gradient(low.channels["scheduling"]) * fs}
    extra.update({c: low.channels[c] for c in PERTURBATION_EMG if c in low.channels})
    meta = {"position_unit": position_unit, "torque_sign": float(torque_sign),
            "fs_original": fs_file, "decimation": q, **_resampled(fs_file, trial.fs, target_fs),
            **({"channel_skew_s": skew} if skew else {})}
    high = HighRate(trial.position, trial.channels["scheduling"], meta.get("resampled_to", fs_file)) if q > 1 else None
    return PerturbationData(low.position, low.torque, low.channels["scheduling"], fs, extra, str(path), meta,
                            high_rate=high)


def _perturbation_file_trial(path, position_unit, torque_sign, variable, channels, time_unit, degrees="warn"):
    """(Trial in SI units at the file's rate with a ``scheduling`` channel, path) of a PT - UT file
    (``degrees``: as in :func:`~lpvpc.io.readers.load_trial`)."""
    _check_settings(position_unit, torque_sign)
    path, variable = _path_and_variable(path, variable)
    table, path = _read_table(path, REQUIRED_CHANNELS + ("scheduling",), PERTURBATION_EMG, variable=variable,
                              channels=channels)
    _refuse_single_trial(table, path)
    trial = _trial_from_table(table, path, _name(path, variable), REQUIRED_CHANNELS + ("scheduling",), PERTURBATION_EMG)
    if degrees == "refuse":
        _refuse_degrees([trial], position_unit)
    return _to_si(trial, position_unit, torque_sign, str(path), time_unit), path


def perturbation_file_trials(path, *, position_unit: str = "rad", torque_sign: float = 1.0, variable=None,
                             channels=None, time_unit: str = "s", degrees: str = "warn") -> tuple[Trial, Trial]:
    """The PT and UT trials behind a PT - UT file (:func:`load_perturbation_file`'s columns), at
    the file's rate, for what needs the two trials (the validation's co-simulation drives an
    actuator with each): UT = the scheduling position, PT = the scheduling plus the perturbation
    position with the perturbation torque. The UT torque is not in such a file: the UT trial's
    torque is zero, so :func:`pair_trials` of the two gives back the file's perturbation data.
    ``degrees`` as in :func:`~lpvpc.io.readers.load_trial`.

    Parameters
    ----------
    path : str or pathlib.Path
        The PT - UT file.
    position_unit, torque_sign, variable, channels, time_unit, degrees
        As in :func:`~lpvpc.io.readers.load_trial`.

    Returns
    -------
    tuple of lpvpc.io.trial.Trial
        ``(pt, ut)`` at the file's rate.

    Examples
    --------
    >>> t = np.arange(2000) / 1000.0
    >>> rng = np.random.default_rng(1)
    >>> pert = 0.03 * np.sign(np.sin(2 * np.pi * 4 * t))
    >>> rows = np.c_[t, pert, 40 * pert + 0.1 * rng.standard_normal(2000), 0.1 * np.sin(t)]
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "pert.csv"
    >>> np.savetxt(path, rows, delimiter=",", header="time,position,torque,scheduling", comments="")
    >>> pt, ut = perturbation_file_trials(path)
    >>> bool(np.allclose(pt.position - ut.position, pert)), float(np.abs(ut.torque).max())
    (True, 0.0)
    """
    trial, path = _perturbation_file_trial(path, position_unit, torque_sign, variable, channels, time_unit, degrees)
    rho = np.asarray(trial.channels["scheduling"], dtype=float)
    emg = {"emg": trial.channels["emg"]} if "emg" in trial.channels else {}
    emg_ut = {"emg": trial.channels["emg_ut"]} if "emg_ut" in trial.channels else {}
    pt = Trial(trial.time, rho + trial.position, np.asarray(trial.torque, dtype=float), emg, f"{trial.name} (PT)")
    ut = Trial(trial.time.copy(), rho.copy(), np.zeros(len(rho)), emg_ut, f"{trial.name} (UT: its scheduling)")
    return pt, ut


def _refuse_single_trial(table, path) -> None:
    """A PT (or UT) trial given where perturbation data (PT - UT with its scheduling) are
    expected: name what is missing and the fix, not only the missing column."""
    if "scheduling" not in table and all(c in table for c in REQUIRED_CHANNELS):
        raise DataError(["no 'scheduling' column: this looks like one trial (time, position, torque), not "
                         "perturbation data (PT - UT with the unperturbed position as 'scheduling'); pass it as "
                         "pt=PT with its unperturbed trial as ut=UT, or with stationary=True if it was recorded "
                         "around one fixed position without a UT trial (a scheduling column named otherwise: "
                         "channels={'scheduling': COLUMN})"], source=str(path))


def stationary_perturbation(pt: Trial, *, target_fs=100.0, channel_skew: float = 0.0) -> PerturbationData:
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

    Parameters
    ----------
    pt : lpvpc.io.trial.Trial
        The perturbed trial.
    target_fs : float or None, default 100.0
        The model rate (Hz); None keeps the trial's rate.
    channel_skew : float, default 0.0
        The torque channel's lag behind position (s), as in :func:`pair_trials`.

    Returns
    -------
    PerturbationData
        The record, its scheduling constant.

    Examples
    --------
    >>> t = np.arange(3000) / 1000.0  # a 3 s trial held at -0.1 rad, 1 kHz
    >>> rng = np.random.default_rng(0)
    >>> pos = -0.1 + 0.02 * np.sign(np.sin(2 * np.pi * 3 * t))
    >>> data = stationary_perturbation(Trial(t, pos, 40 * pos + 0.01 * rng.standard_normal(3000)))
    >>> data.fs, round(data.meta["operating_point"], 3), bool(np.ptp(data.scheduling) == 0.0)
    (100.0, -0.1, True)
    """
    ut = stationary_ut(pt)
    op, tq0 = float(ut.position[0]), float(ut.torque[0])
    out = pair_trials(pt, ut, target_fs=target_fs, channel_skew=channel_skew)
    out.source = f"{pt.name or 'PT'} (stationary at {op:+.4f} rad)"
    out.meta.update(stationary=True, operating_point=op, torque_offset=tq0)
    return out


def stationary_ut(pt: Trial) -> Trial:
    """The UT trial a stationary experiment (one perturbed trial around a fixed operating
    position, no UT recorded) stands for: the PT trial's mean position and mean torque,
    constant (:func:`stationary_perturbation`; the validation's co-simulation drives an
    actuator with it).

    Parameters
    ----------
    pt : lpvpc.io.trial.Trial
        The perturbed trial.

    Returns
    -------
    lpvpc.io.trial.Trial
        The constant UT trial, on the PT trial's time stamps.

    Raises
    ------
    lpvpc.errors.DataError
        A bad trial, or one whose slow mean position moves (not stationary).

    Examples
    --------
    >>> t = np.arange(3000) / 1000.0
    >>> pt = Trial(t, -0.1 + 0.02 * np.sign(np.sin(2 * np.pi * 3 * t)), np.full(3000, 2.0))
    >>> ut = stationary_ut(pt)
    >>> round(float(ut.position[0]), 3), float(np.ptp(ut.position)), float(ut.torque[0])
    (-0.1, 0.0, 2.0)
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
    n = len(pt.time)
    return Trial(np.asarray(pt.time, dtype=float), np.full(n, float(np.mean(pt.position))),
                 np.full(n, float(np.mean(pt.torque))), {}, "constant operating point")


def join_trials(trials) -> PerturbationData:
    """Several trials' perturbation data as one record for a joint identification.

    The arrays are put end to end and ``segments`` marks each trial, so that identification
    builds every regressor trial by trial and nothing (IRF lags, velocities, the reflex
    delay and dynamics, MOESP Hankel blocks) reaches from one trial into the next
    (:mod:`lpvpc.io.segments`). The trials must share the sampling rate (that of their files
    too), the position unit and the torque sign (DataError otherwise); extra channels
    (``time``, ``emg``, ...) are kept when every trial has them.

    Parameters
    ----------
    trials : list of PerturbationData
        The trials, in order.

    Returns
    -------
    PerturbationData
        One record with ``segments`` marking each trial.

    Raises
    ------
    lpvpc.errors.DataError
        No trials, or trials of different rates, position units or torque signs.
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


#: The conventions a record is loaded with and a model carries (its input contract), with
#: the value each takes when not given.
CONVENTION_DEFAULTS = {"position_unit": "rad", "torque_sign": 1.0, "time_unit": "s", "channel_skew": 0.0,
                       "target_fs": 100.0}


class _DefaultRate(float):
    """The loader's default model rate: a float that says it was not given."""

    def __repr__(self):
        return float.__repr__(self)


DEFAULT_RATE = _DefaultRate(CONVENTION_DEFAULTS["target_fs"])


@dataclass(frozen=True)
class RecordSource:
    """How a record was loaded: the files (or Trials) and the settings, so that it can be
    loaded again with other conventions (a model's: its torque sign, units, channel skew
    and rate).

    Parameters
    ----------
    inputs : dict
        The loader's ``pt``, ``ut``, ``data``, ``variable``, ``channels`` and ``stationary``.
    settings : dict
        Every convention of :data:`~lpvpc.io.identification_data.CONVENTION_DEFAULTS`, as used.
    given : frozenset
        The conventions the caller gave explicitly (the others took their defaults).

    Examples
    --------
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=5.0)
    >>> data = load_identification_data(pt=sim.pt, ut=sim.ut, torque_sign=1)
    >>> sorted(data.origin.given), data.reload(target_fs=200).fs
    (['torque_sign'], 200.0)
    """

    inputs: dict
    settings: dict
    given: frozenset
    #: the part of the record these data are (:func:`hold_out`): ("identification" or
    #: "held-out", the held-out stretch), or None for the whole record
    part: tuple | None = None

    def load(self, **changes) -> "PerturbationData":
        """The record loaded again with ``changes`` to its conventions (given explicitly)."""
        unknown = set(changes) - set(CONVENTION_DEFAULTS)
        if unknown:
            raise ValueError(f"not a convention of a record: {', '.join(sorted(unknown))}")
        given = {k: v for k, v in self.settings.items() if k in self.given}
        whole = load_identification_data(**self.inputs, **{**given, **changes})
        if self.part is None:
            return whole
        which, heldout = self.part
        first, later = hold_out(whole, heldout)
        return first if which == "identification" else later


def load_identification_data(pt=None, ut=None, data=None, *, position_unit: str | None = None,
                             torque_sign: float | None = None, target_fs=DEFAULT_RATE,
                             variable=None, channels=None, stationary: bool = False, time_unit: str | None = None,
                             channel_skew=None) -> PerturbationData:
    """Read a record for identification or prediction: the one entry point.

    The mistakes that would give a wrong model are refused (DataError naming the fix):
    angles that look like degrees read as rad, a time column that looks like milliseconds
    read as s, PT and UT swapped (the perturbation in the UT trial). The data remember how
    they were loaded (``data.origin``, :class:`RecordSource`): a model given them loads them
    again with its own conventions where these were not given here
    (:meth:`LPVPCModel.conform <lpvpc.models.model.LPVPCModel.conform>`), and refuses those
    given otherwise.

    Parameters
    ----------
    pt, ut : str, pathlib.Path, lpvpc.io.trial.Trial or list, optional
        The perturbed and the unperturbed trial (CSV or .mat paths, or Trials); lists are
        paired in order and joined by :func:`join_trials` for one joint identification.
        Give either both, or ``data`` alone.
    data : str, pathlib.Path, PerturbationData or list, optional
        A perturbation file (time, position, scheduling, torque), or a PerturbationData,
        returned as is (align it when loading it).
    position_unit : {"rad", "deg"}, optional
        The unit of the position columns (applied to Trials too); default "rad".
    torque_sign : {1, -1}, optional
        The sign that turns the files' torque into lpvpc's (dorsiflexion positive);
        default +1.
    target_fs : float or None, default 100.0
        The model rate (Hz) the record is decimated to; None keeps the file's rate.
    variable, channels : optional
        Which variable and channels of a .mat file (:func:`~lpvpc.io.readers.load_trial`;
        a path ``"file.mat:NAME"`` names its own variable).
    stationary : bool, default False
        ``pt`` alone: a perturbed trial (or a list) around a fixed operating position
        recorded without UT (:func:`stationary_perturbation`).
    time_unit : {"s", "ms"}, optional
        The unit of the time columns; default "s".
    channel_skew : float, optional
        The torque channel's lag behind the position channel (s), a measurement artefact
        undone at the file's rate before decimation (:func:`pair_trials`); to choose it from
        the data, :func:`lpvpc.identification.channel_skew.load_aligned`. Default 0.

    Returns
    -------
    PerturbationData
        Position, scheduling and perturbation torque at ``target_fs`` (SI units), with
        ``meta`` and ``origin`` saying how they were read.

    Raises
    ------
    lpvpc.errors.DataError
        A wrong combination of arguments, an unreadable file, or a mistake in units, time
        base, sign or trial order (one message naming each problem and its fix).

    Examples
    --------
    The virtual subject's files, written at 1 kHz and read at the default 100 Hz:

    >>> import tempfile
    >>> from lpvpc.simulation.simulate import write_dataset
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     files = write_dataset(folder, duration=20.0)
    ...     data = load_identification_data(pt=files["ident_PT"], ut=files["ident_UT"])
    >>> data.fs, len(data.torque), data.meta["position_unit"]
    (100.0, 2000, 'rad')
    """
    settings = {"position_unit": position_unit, "torque_sign": torque_sign, "time_unit": time_unit,
                "channel_skew": channel_skew, "target_fs": target_fs}
    given = frozenset(k for k, v in settings.items() if v is not None and not isinstance(v, _DefaultRate))
    settings = {k: (CONVENTION_DEFAULTS[k] if k not in given and k != "target_fs" else v) for k, v in settings.items()}
    settings["target_fs"] = None if target_fs is None else float(target_fs)
    out = _load(pt, ut, data, variable=variable, channels=channels, stationary=stationary, **settings)
    if not isinstance(data, PerturbationData):
        out.meta.update(position_unit=settings["position_unit"], torque_sign=float(settings["torque_sign"]))
        if settings["time_unit"] != "s":
            out.meta["time_unit"] = settings["time_unit"]
        out.origin = RecordSource({"pt": pt, "ut": ut, "data": data, "variable": variable, "channels": channels,
                                   "stationary": stationary}, settings, given)
    return out


def _load(pt, ut, data, *, position_unit, torque_sign, target_fs, variable, channels, stationary, time_unit,
          channel_skew) -> PerturbationData:
    """:func:`load_identification_data` with every convention given."""

    given = [k for k, v in (("pt", pt), ("ut", ut), ("data", data)) if v is not None]
    allowed = (["pt"],) if stationary else (["pt", "ut"], ["data"])
    if given not in allowed:
        want = "pt alone (a stationary trial has no UT)" if stationary else "either both pt and ut, or data alone"
        raise DataError([f"give {want}; got {', '.join(given) or 'nothing'}"])
    torque_sign = _check_settings(position_unit, torque_sign)
    _check_time_unit(time_unit)
    skew = check_channel_skew(channel_skew)
    kw = dict(position_unit=position_unit, torque_sign=torque_sign, target_fs=target_fs, variable=variable,
              channels=channels, stationary=stationary, time_unit=time_unit)
    if isinstance(data, PerturbationData) and skew:
        raise DataError(["channel_skew aligns the channels at the file's own rate: give the file (or Trials), "
                         "not loaded data"])
    kw["channel_skew"] = skew
    if any(isinstance(v, (list, tuple)) for v in (pt, ut, data)):
        if data is not None:
            return join_trials([_load(None, None, d, **kw) for d in data])
        pts = list(pt) if isinstance(pt, (list, tuple)) else [pt]
        uts = list(ut) if isinstance(ut, (list, tuple)) else [ut] * len(pts) if stationary else [ut]
        if len(pts) != len(uts):
            raise DataError([f"{len(pts)} PT trials but {len(uts)} UT trials: give them in pairs"])
        return join_trials([_load(a, b if not stationary else None, None, **kw) for a, b in zip(pts, uts)])
    if data is not None:
        if isinstance(data, PerturbationData):
            return data
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnitWarning)  # degrees: refused below instead
            out = load_perturbation_file(data, position_unit=position_unit, torque_sign=torque_sign,
                                         target_fs=target_fs, variable=variable, channels=channels,
                                         time_unit=time_unit, channel_skew=skew)
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
        out = stationary_perturbation(trials[0], target_fs=target_fs, channel_skew=skew)
    else:
        out = pair_trials(trials[0], trials[1], target_fs=target_fs, channel_skew=skew)
    _refuse_milliseconds(out, time_unit)
    out.meta.update(position_unit=position_unit, torque_sign=torque_sign)
    if time_unit != "s":
        out.meta["time_unit"] = time_unit
    return out


#: Shortest part (s) hold_out leaves on either side: a few position levels' worth.
MIN_PART_S = 10.0


def hold_out(data: PerturbationData, heldout) -> tuple:
    """Split a record forward in time, as a lab judges a model: identify from the earlier
    part, predict the later one.

    Parameters
    ----------
    data : PerturbationData
        One record (trials joined are split at the same instant).
    heldout : float or tuple
        The held-out stretch: a fraction in (0, 1), the last part of the record; or a time
        range ``(start, stop)`` in s from the record's start (``stop`` None: to the end).
        Identification keeps everything before ``start``.

    Returns
    -------
    tuple of PerturbationData
        ``(identification, held_out)``; each can be read again from the files with other
        conventions (a model's channel skew) and is split the same way.

    Raises
    ------
    lpvpc.errors.DataError
        A fraction or range that leaves either part shorter than :data:`~lpvpc.io.identification_data.MIN_PART_S`.

    Examples
    --------
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0)
    >>> ident, held = hold_out(load_identification_data(pt=sim.pt, ut=sim.ut), 0.3)
    >>> ident.n, held.n, held.meta["part"]["start_s"]
    (4200, 1800, 42.0)
    """
    n = data.n
    if isinstance(heldout, (tuple, list)):
        if len(heldout) != 2:
            raise DataError([f"held-out range {heldout!r}: give (start, stop) in s"], source=data.source or None)
        start_s, stop_s = heldout
        start = int(round(float(start_s) * data.fs))
        stop = n if stop_s is None else int(round(float(stop_s) * data.fs))
        if not 0 < start < stop <= n:
            raise DataError([f"held-out range {start_s}..{stop_s} s does not lie inside the record's "
                             f"0..{n / data.fs:.1f} s after its start"], source=data.source or None)
    else:
        fraction = float(heldout)
        if not 0.0 < fraction < 1.0:
            raise DataError([f"held-out fraction {heldout!r}: give a number between 0 and 1 (e.g. 0.3: the last "
                             f"30 %)"], source=data.source or None)
        start, stop = n - int(round(fraction * n)), n
    short = [f"{name} {m / data.fs:.1f} s" for name, m in (("identification part", start), ("held-out part", stop - start))
             if m / data.fs < MIN_PART_S]
    if short:
        raise DataError([f"holding out {heldout!r} of a {n / data.fs:.1f} s record leaves the {', the '.join(short)} "
                         f"(at least {MIN_PART_S:g} s each)"], source=data.source or None)
    parts = []
    for which, (a, b) in (("identification", (0, start)), ("held-out", (start, stop))):
        part = data.segment(a, b)
        part.meta["part"] = {"which": which, "start_s": a / data.fs, "stop_s": b / data.fs,
                             "record_s": n / data.fs}
        if data.origin is not None:
            part.origin = replace(data.origin, part=(which, heldout))
        parts.append(part)
    return tuple(parts)


def _refuse_milliseconds(data: PerturbationData, time_unit: str) -> None:
    """A time column in ms read as s at target_fs=None (which keeps the rate) gives a model
    at 1 Hz: refuse it as the decimation does."""
    hint = _milliseconds_hint(data.meta.get("fs_original", data.fs)) if time_unit == "s" else ""
    if hint:
        raise DataError([f"sampling rate {data.meta.get('fs_original', data.fs):.6g} Hz: {hint}"],
                        source=data.source or None)


def write_perturbation_csv(data: PerturbationData, path) -> None:
    """Write ``time,position,torque,scheduling[,emg][,emg_ut]`` (s, rad, N m, rad) so
    that :func:`load_perturbation_file` reads it back exactly (17 significant digits).

    Parameters
    ----------
    data : PerturbationData
        The record to write.
    path : str or pathlib.Path
        The CSV file to write.
    """
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
