"""The virtual subject's EMG envelope (V): tonic and slow activation plus reflex-evoked
bursts, band-limited measurement noise, in the units of :data:`EMG_UNITS`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from .subject import SubjectParams


#: EMG units of :func:`~lpvpc.simulation.simulate.simulate_pair` and the factor from volts.
EMG_UNITS = {"V": 1.0, "mV": 1e3, "uV": 1e6}

#: How the envelope is made (``SubjectParams.emg_form``): "modulated_noise" (band-limited noise
#: whose amplitude follows the drive, rectified and smoothed, as a lab's hardware does) or
#: "envelope" (the drive itself low-passed, plus ``emg_offset`` and low-passed measurement
#: noise: a system that exports an already-smoothed envelope with an offset).
EMG_FORMS = ("modulated_noise", "envelope")


def emg_envelope(activation, reflex_drive, fs: float, rng: np.random.Generator,
                 params: SubjectParams | None = None) -> np.ndarray:
    """The recorded EMG envelope (V) of one trial, made as a muscle's surface EMG is.

    Neural drive = background activation (tonic level plus any slow activation, each trial
    its own) + reflex-evoked drive: the reflex drive z (N m; the delayed, rectified,
    position-gained velocity BEFORE the muscle's activation dynamics, so the bursts come
    ~40 ms after each velocity pulse, as short as the pulse) divided by
    ``emg_reflex_torque``. Raw EMG: band-limited noise (``emg_band`` Hz, unit RMS) whose
    amplitude follows the drive, plus electrode / amplifier noise (same band,
    ``emg_noise`` RMS). The lab's envelope: full-wave rectified, 2nd-order Butterworth
    low-pass at ``emg_cutoff`` Hz, scaled by sqrt(pi / 2) so a drive of 1 reads 1, times
    ``emg_volts``. A perturbed trial's EMG therefore correlates with the reflex torque; an
    unperturbed trial's shows the tonic part (and small bursts when the slow movement is
    fast enough to fire the reflex). The band must lie below fs / 2 (fs >= 1 kHz).

    Reflex drive (N m) raises the envelope (V) above its tonic level:

    >>> rng = np.random.default_rng(0)
    >>> drive = np.r_[np.zeros(500), np.full(500, 15.0)]
    >>> e = emg_envelope(np.full(1000, 0.08), drive, 1000.0, rng)
    >>> bool(e[600:].mean() > 5 * e[100:500].mean())
    True
    """
    p = params or SubjectParams()
    drive = np.asarray(activation, dtype=float) + np.asarray(reflex_drive, dtype=float) / p.emg_reflex_torque
    n = len(drive)
    if p.emg_form not in EMG_FORMS:
        raise ValueError(f"unknown EMG form {p.emg_form!r}; use one of {list(EMG_FORMS)}")
    if p.emg_form == "envelope":
        return p.emg_volts * _smooth_envelope(drive, fs, rng, p)
    lo, hi = p.emg_band
    hi = min(hi, 0.45 * fs)
    bb, ab = signal.butter(2, (lo, hi), btype="bandpass", fs=fs)

    def band_noise():  # unit-RMS band-limited noise, its filter's start-up discarded
        lead = int(fs)  # 1 s
        x = signal.lfilter(bb, ab, rng.standard_normal(n + lead))[lead:]
        return x / max(_rms(x), 1e-300)

    raw = np.maximum(drive, 0.0) * band_noise() + p.emg_noise * band_noise()
    b, a = signal.butter(2, p.emg_cutoff, fs=fs)
    rect = math.sqrt(math.pi / 2.0) * np.abs(raw)
    env = rect[:200].mean() + signal.lfilter(b, a, rect - rect[:200].mean())
    return p.emg_volts * np.maximum(env, 0.0)


def _smooth_envelope(drive, fs, rng, p) -> np.ndarray:
    """The "envelope" form (activation units): the non-negative drive and white measurement
    noise (``emg_noise`` RMS after the filter) through the envelope low-pass
    (``emg_cutoff`` Hz, 2nd-order Butterworth, from rest at the drive's first value), plus
    ``emg_offset``; floored at 0 like a rectified signal."""
    b, a = signal.butter(2, p.emg_cutoff, fs=fs)
    d = np.maximum(drive, 0.0)
    smooth = d[0] + signal.lfilter(b, a, d - d[0])
    lead = int(fs)  # 1 s of filter start-up discarded
    noise = signal.lfilter(b, a, rng.standard_normal(len(d) + lead))[lead:]
    noise *= p.emg_noise / max(_rms(noise), 1e-300)
    return np.maximum(smooth + noise + p.emg_offset, 0.0)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))
