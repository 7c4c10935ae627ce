"""Trials, loaders, checks, decimation and PT-UT pairing.

Units: time in s, position in rad, torque in N m (SI everywhere).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

OPTIONAL_CHANNELS = ("emg", "command", "scheduling")


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


def write_trial_csv(trial: Trial, path) -> None:
    """Write a trial as CSV with header ``time,position,torque[,emg,command,scheduling]``."""
    names = ["time", "position", "torque"] + [c for c in OPTIONAL_CHANNELS if c in trial.channels]
    cols = [trial.time, trial.position, trial.torque] + [trial.channels[c] for c in names[3:]]
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.10g")
