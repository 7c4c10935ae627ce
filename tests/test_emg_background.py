"""The background-activation estimate under a reflex whose gain changes over the trial."""

import numpy as np
import pytest

from lpvpc.models.effects import background_emg
from lpvpc.simulation.trajectories import lab_pulses


@pytest.mark.parametrize("seed", [0, 1])
def test_habituating_bursts_stay_out_of_the_background_estimate(seed):
    """A reflex habituating as the virtual subject's does (gain 1 -> 0.33, 40-s time
    constant) under the lab's pulses, tonic activation constant: the bursts' gain must be
    followed from the record's start, or the early bursts stay in the estimate and it
    falls with trial time as the reflex does (then activation explains habituation). With
    cosines in time for the gain the first 10 s read 0.0021-0.0024 too high (10 % of the
    bursts' mean), with Legendre polynomials 0.0002 or less."""
    fs, tonic = 100.0, 0.1
    rng = np.random.default_rng(seed)
    p = lab_pulses(120.0, fs, rng)  # rad
    t = np.arange(p.size) / fs
    gain = 0.3 + 0.7 * np.exp(-t / 40.0)
    stretch = np.maximum(np.gradient(p) * fs, 0.0)
    burst = 0.5 * gain * np.r_[np.zeros(4), stretch[:-4]]  # 40 ms after each stretch
    emg = tonic + burst + 0.005 * rng.standard_normal(p.size)
    est = background_emg(emg, p, fs)
    early = est[: int(10 * fs)].mean() - tonic
    assert abs(early) < 0.03 * burst[: int(10 * fs)].mean(), early  # 9-10 % with cosines
    assert abs(np.corrcoef(est - tonic, gain)[0, 1]) < 0.12


@pytest.mark.parametrize("seed", [0, 1])
def test_a_reflex_gain_swinging_over_35_s_stays_mostly_out_of_the_background_estimate(seed):
    """Reflex gain 1 + 0.4 sin(2 pi t / 35 s), tonic activation constant: the bursts' gain
    must follow a swing, not only a trend, or their remainder stays in the estimate, which
    then follows the reflex gain (activation_reflex_gain named for it). Bursts' gain resolved
    to 60 s (a cubic over 2 minutes): correlation with the gain 0.93, error 27 % of the
    bursts' mean; at 15 s (lpvpc.models.effects.BURST_GAIN_S): 0.56-0.61 and 16 %."""
    fs, tonic = 100.0, 0.1
    rng = np.random.default_rng(seed)
    p = lab_pulses(120.0, fs, rng)  # rad
    t = np.arange(p.size) / fs
    gain = 1.0 + 0.4 * np.sin(2.0 * np.pi * t / 35.0)
    stretch = np.maximum(np.gradient(p) * fs, 0.0)
    burst = 0.5 * gain * np.r_[np.zeros(4), stretch[:-4]]  # 40 ms after each stretch
    emg = tonic + burst + 0.005 * rng.standard_normal(p.size)
    est = background_emg(emg, p, fs)
    assert np.corrcoef(est - tonic, gain)[0, 1] < 0.75
    assert np.sqrt(np.mean((est - tonic) ** 2)) < 0.2 * burst.mean()
