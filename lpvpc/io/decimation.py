"""Decimation and resampling of signals and trials to the model rate.

Staged anti-alias FIR decimation (flat to 1e-4 up to 0.8 of the new Nyquist rate) for
integer factors; resampling to a multiple of the target rate when the file's rate is not one.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.signal

from .conventions import _milliseconds_hint
from ..errors import DataError
from .trial import RATE_TOLERANCE, Trial


# scipy recommends decimating in stages when the factor exceeds 13.
MAX_STAGE_FACTOR = 13
# Anti-alias FIR per stage: Kaiser window for 80 dB, 30*q+1 taps, cutoff at the new Nyquist rate.
# scipy.signal.decimate's own FIR (Hamming, 20*q+1 taps) has 0.3 % gain error at 5 Hz (q = 10)
# and 53 dB stopband; this one is flat to 1e-4 up to 0.8 of the new Nyquist rate.
FIR_ATTENUATION_DB = 80.0
FIR_TAPS_PER_FACTOR = 30


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

    Parameters
    ----------
    fs : float
        The file's rate (Hz).
    target_fs : float or None
        The model rate (Hz); None: no decimation.
    source : str, optional
        Names the file in the message.

    Returns
    -------
    int
        The decimation factor q = fs / target_fs.

    Raises
    ------
    lpvpc.errors.DataError
        ``fs`` below ``target_fs`` or not an integer multiple of it.
    ValueError
        A ``target_fs`` that is not positive.

    Examples
    --------
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

    Parameters
    ----------
    x : array_like
        The signal.
    q : int
        The decimation factor.

    Returns
    -------
    numpy.ndarray
        The decimated signal, ``ceil(len(x) / q)`` samples.

    Examples
    --------
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

    Parameters
    ----------
    fs : float
        The file's rate (Hz).
    target_fs : float or None
        The model rate (Hz).

    Returns
    -------
    float
        The rate (Hz) to resample to before decimating.

    Examples
    --------
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

    Parameters
    ----------
    trial : lpvpc.io.trial.Trial
        The trial.
    fs_new : float
        The new rate (Hz).

    Returns
    -------
    lpvpc.io.trial.Trial
        The resampled trial.

    Raises
    ------
    lpvpc.errors.DataError
        Fewer than 2 samples after resampling.

    Examples
    --------
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

    Parameters
    ----------
    trial : lpvpc.io.trial.Trial
        The trial.
    target_fs : float or None
        The model rate (Hz).

    Returns
    -------
    lpvpc.io.trial.Trial
        ``trial``, or the resampled trial.

    Examples
    --------
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

    Parameters
    ----------
    trial : lpvpc.io.trial.Trial
        The trial.
    target_fs : float or None
        The model rate (Hz).

    Returns
    -------
    lpvpc.io.trial.Trial
        The decimated trial.

    Raises
    ------
    lpvpc.errors.DataError
        A rate that is not an integer multiple of ``target_fs``.
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
