"""The lab's conventions and the mistakes caught on the way in.

Loaders convert the lab's units and sign (``position_unit``, ``torque_sign``, ``time_unit``)
to SI here; everything after them is SI. The same place catches what a wrong convention
looks like before a model is written: angles in degrees read as rad, a time column in ms
read as s, and PT and UT given the wrong way round.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..errors import DataError, UnitWarning
from .trial import ANGLE_CHANNELS, Trial


# A time column read in s whose rate is below MS_MAX_RATE Hz, but at least MS_MIN_RATE Hz
# once read in ms, was written in milliseconds (1 kHz in ms reads as 1 Hz): refused with the fix.
MS_MAX_RATE = 50.0
MS_MIN_RATE = 50.0
# PT and UT given the wrong way round: the perturbation is then in the "UT" trial. The power
# of each position about its SWAP_WINDOW-s moving average (what is faster than the slow
# movement) tells: correct pairs give a UT/PT ratio far below 1, swapped ones far above
# (docs/design_notes.md, "PT and UT swapped"). Refused above SWAP_RATIO.
SWAP_WINDOW = 0.1
SWAP_RATIO = 2.0


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
