"""Position trajectories and perturbation designs of the virtual subject (command signals at
``fs``, rad): the paper's multilevel trajectory, a novel one, a stationary position, and the
perturbations PRALDS, lab pulses and PRBS (:data:`PERTURBATIONS`).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from .subject import THETA_DF, THETA_PF


# ---------------------------------------------------------------------------------------
# Element 1: position trajectories (command signals at fs)
# ---------------------------------------------------------------------------------------


def _n_samples(duration: float, fs: float) -> int:
    return int(round(duration * fs))


def _butter_from_rest(x, cutoff, fs, order=2):
    """Causal Butterworth low-pass of ``x``, starting at rest at ``x[0]``."""
    b, a = signal.butter(order, cutoff, fs=fs)
    return x[0] + signal.lfilter(b, a, x - x[0])


def multilevel_trajectory(duration: float, fs: float, rng: np.random.Generator, *,
                          n_levels: int = 10, lo: float = THETA_PF, hi: float = THETA_DF,
                          hold=(4.0, 7.0), cutoff: float = 2.5) -> np.ndarray:
    """The paper's identification trajectory (rad) at ``fs`` (Hz).

    Levels drawn at random from ``n_levels`` evenly spaced in [lo, hi] rad (every level
    once per round of ``n_levels`` holds, consecutive levels different), held for durations uniform in ``hold`` s; the step sequence is
    smoothed by a causal 2nd-order Butterworth low-pass at ``cutoff`` Hz, from rest at the
    first level (as the paper does, to avoid sharp transitions). The Butterworth step
    response overshoots ~4 % of each step, so the trajectory can exceed [lo, hi] by up to
    ~0.026 rad after a full-range step.

    >>> x = multilevel_trajectory(60.0, 100.0, np.random.default_rng(0))
    >>> len(x), bool(THETA_PF - 0.03 < x.min() and x.max() < THETA_DF + 0.03)  # rad, with overshoot
    (6000, True)
    """
    n = _n_samples(duration, fs)
    levels = np.linspace(lo, hi, n_levels)
    steps = np.empty(n)
    order = _level_sequence(rng, n_levels)
    i = 0
    while i < n:
        m = int(round(rng.uniform(*hold) * fs))
        steps[i:i + m] = levels[next(order)]
        i += m
    return _butter_from_rest(steps, cutoff, fs)


def _level_sequence(rng: np.random.Generator, n_levels: int):
    """Level indices in random order, each level once per round (a protocol covers the
    whole range: with independent draws a 2-minute trial missed the two most dorsiflexed
    levels on 1 of 20 seeds), consecutive levels different."""
    last = -1
    while True:
        perm = rng.permutation(n_levels)
        if perm[0] == last:
            perm[[0, -1]] = perm[[-1, 0]]
        yield from (int(k) for k in perm)
        last = int(perm[-1])


def _fold(x, lo, hi):
    """Reflect ``x`` into [lo, hi] (a random walk bouncing off the range limits)."""
    w = hi - lo
    r = np.mod(x - lo, 2 * w)
    return lo + w - np.abs(r - w)


def _ramp_to(x0, x1, speed, fs):
    m = max(1, int(round(abs(x1 - x0) / speed * fs)))
    return x0 + (x1 - x0) * np.arange(1, m + 1) / m


def _seg_ramps(x0, rng, fs, lo, hi):
    """2-3 ramps (0.05-0.3 rad/s) between random targets, with short holds."""
    out, x = [], x0
    for _ in range(int(rng.integers(2, 4))):
        target = x
        while abs(target - x) < 0.1:
            target = rng.uniform(lo, hi)
        out.append(_ramp_to(x, target, rng.uniform(0.05, 0.3), fs))
        out.append(np.full(int(rng.uniform(0.5, 2.0) * fs), target))
        x = target
    return np.concatenate(out)


def _seg_sine(x0, rng, fs, lo, hi):
    """Sinusoid 0.1-0.5 Hz through x0, amplitude limited so peak velocity <= 0.6 rad/s."""
    f = rng.uniform(0.1, 0.5)
    amp = min(rng.uniform(0.08, 0.25), 0.6 / (2 * np.pi * f), 0.5 * (hi - lo))
    c = rng.uniform(max(lo + amp, x0 - amp), min(hi - amp, x0 + amp))
    phi = np.arcsin(np.clip((x0 - c) / amp, -1.0, 1.0))
    if rng.random() < 0.5:  # start moving down instead of up
        phi = np.pi - phi
    n_cyc = max(1, int(round(rng.uniform(6.0, 15.0) * f)))
    tau = np.arange(1, int(round(n_cyc / f * fs)) + 1) / fs
    return c + amp * np.sin(2 * np.pi * f * tau + phi)


def _seg_walk(x0, rng, fs, lo, hi):
    """Slow random walk: velocity = white noise low-passed at 0.3 Hz (RMS 0.1 rad/s),
    integrated and reflected at the range limits."""
    m = int(rng.uniform(8.0, 15.0) * fs)
    b, a = signal.butter(2, 0.3, fs=fs)
    v = signal.lfilter(b, a, rng.standard_normal(m))
    v *= 0.1 / max(np.sqrt(np.mean(v ** 2)), 1e-12)
    return _fold(x0 + np.cumsum(v) / fs, lo, hi)


def _seg_excursion(x0, target, rng, fs, lo, hi):
    """Brief excursion beyond the identification range: ramp out, hold 0.3-0.6 s, ramp back."""
    speed = rng.uniform(0.15, 0.3)
    back = rng.uniform(lo + 0.1, hi - 0.1)
    return np.concatenate([
        _ramp_to(x0, target, speed, fs),
        np.full(int(rng.uniform(0.3, 0.6) * fs), target),
        _ramp_to(target, back, speed, fs),
    ])


def novel_trajectory(duration: float, fs: float, rng: np.random.Generator, *,
                     lo: float = THETA_PF, hi: float = THETA_DF, overshoot: float = 0.035,
                     cutoff: float = 2.5) -> np.ndarray:
    """A held-out trajectory (rad) with shapes the multilevel trajectory never has.

    Concatenated segments (each type once per round, in random order) of ramps
    (0.05-0.3 rad/s), sines (0.1-0.5 Hz, peak velocity <= 0.6 rad/s) and slow random walks
    within [lo, hi], plus two brief excursions (one to ``lo - overshoot``, one to
    ``hi + overshoot``, each held 0.3-0.6 s) placed as the 2nd and 4th segments, because
    held-out records in real labs always leave the identified range a little. The
    default overshoot 0.035 rad exceeds the largest Butterworth overshoot of the
    multilevel trajectory (0.026 rad), so the novel record always visits angles the
    identification record did not. Smoothed like the multilevel trajectory (2nd-order
    Butterworth, ``cutoff`` Hz, causal, from rest). Needs ~40 s to contain both excursions.

    >>> x = novel_trajectory(60.0, 100.0, np.random.default_rng(1))
    >>> bool(x.min() < THETA_PF - 0.026 and x.max() > THETA_DF + 0.026)  # leaves the identified range
    True
    """
    n = _n_samples(duration, fs)
    gens = [_seg_ramps, _seg_sine, _seg_walk]
    excursions = [lo - overshoot, hi + overshoot]
    rng.shuffle(excursions)
    x = rng.uniform(lo + 0.1, hi - 0.1)
    parts, total, order = [np.array([x])], 1, []
    while total < n:
        if not order:
            order = list(rng.permutation(len(gens)))
        if len(parts) in (2, 4) and excursions:
            seg = _seg_excursion(x, excursions.pop(), rng, fs, lo, hi)
        else:
            seg = gens[order.pop()](x, rng, fs, lo, hi)
        parts.append(seg)
        total += len(seg)
        x = float(seg[-1])
    traj = np.concatenate(parts)[:n]
    return _butter_from_rest(traj, cutoff, fs)


# ---------------------------------------------------------------------------------------
# Element 2: PRALDS perturbation
# ---------------------------------------------------------------------------------------


def pralds(duration: float, fs: float, rng: np.random.Generator, *, amplitude: float = 0.04,
           hold=(0.25, 0.35)) -> np.ndarray:
    """Pseudo-random arbitrary-level distributed signal (rad) at ``fs`` (Hz).

    Piecewise constant; levels uniform in [-amplitude, +amplitude] rad, hold durations
    uniform in ``hold`` s (250-350 ms: wide-band yet slow enough not to suppress reflexes).

    >>> p = pralds(10.0, 1000.0, np.random.default_rng(0))
    >>> bool(np.abs(p).max() <= 0.04)  # rad
    True
    >>> holds = np.diff(np.flatnonzero(np.diff(p))) / 1000.0  # s between level changes
    >>> bool(holds.min() >= 0.25 - 1e-9 and holds.max() <= 0.35 + 1e-9)
    True
    """
    return _held_levels(duration, fs, rng, hold, lambda k: rng.uniform(-amplitude, amplitude))


def _held_levels(duration, fs, rng, hold, level) -> np.ndarray:
    """Piecewise-constant signal at ``fs`` (Hz): holds of uniform(*hold) s, hold k at
    ``level(k)`` (drawn after its duration: the random streams of :func:`pralds` as before)."""
    n = _n_samples(duration, fs)
    out = np.empty(n)
    i, k = 0, 0
    while i < n:
        m = max(1, int(round(rng.uniform(*hold) * fs)))
        out[i:i + m] = level(k)
        i, k = i + m, k + 1
    return out


def lab_pulses(duration: float, fs: float, rng: np.random.Generator, *, amplitude: float = 0.04,
               hold=(0.25, 0.35), smallest: float = 0.5) -> np.ndarray:
    """The perturbation of the lab's pilot trial (rad) at ``fs`` (Hz): holds of
    ``hold`` s that alternate between 0 and a pulse level +-A, A uniform in
    [``smallest``, 1] x ``amplitude``, sign random.

    Measured on ``pilot_ident.csv`` (1 kHz, 248 velocity pulses): holds 257-344 ms (5-95 %),
    every other hold at 0 and the others at -42..+41 mrad, steps 22-42 mrad (5-95 %). Unlike
    :func:`pralds` (levels uniform in +-amplitude: steps of every size) every step is
    large: peak stretch velocities fall in a narrow band (pilot 2.3-5.2 rad/s), well above
    a reflex threshold of a few tenths of a rad/s.

    >>> p = lab_pulses(10.0, 1000.0, np.random.default_rng(0))
    >>> levels = p[np.r_[0, np.flatnonzero(np.diff(p)) + 1]]  # the level of each hold
    >>> bool(np.all(levels[::2] == 0.0) and np.all(np.abs(levels[1::2]) >= 0.02))
    True
    """
    return _held_levels(duration, fs, rng, hold, lambda k: 0.0 if k % 2 == 0 else
                        rng.choice((-1.0, 1.0)) * rng.uniform(smallest, 1.0) * amplitude)


def prbs(duration: float, fs: float, rng: np.random.Generator, *, amplitude: float = 0.04,
         hold=(0.05, 0.15)) -> np.ndarray:
    """Pseudo-random binary sequence (rad) at ``fs`` (Hz): the level switches between
    +amplitude and -amplitude after holds uniform in ``hold`` s (50-150 ms). No quiet
    windows: a reflex burst (~40 ms after a stretch, lasting as long as the servo's step)
    often runs into the next switch, so the EMG between bursts is rarely free of them.

    >>> p = prbs(10.0, 1000.0, np.random.default_rng(0))
    >>> sorted(set(np.round(p, 6).tolist()))  # rad
    [-0.04, 0.04]
    >>> holds = np.diff(np.flatnonzero(np.diff(p))) / 1000.0  # s between switches
    >>> bool(holds.min() >= 0.05 - 1e-9 and holds.max() <= 0.15 + 1e-9)
    True
    """
    first = rng.choice((-1.0, 1.0))
    return _held_levels(duration, fs, rng, hold, lambda k: amplitude * first * (-1.0) ** k)


#: Perturbation designs of :func:`~lpvpc.simulation.simulate.simulate_pair` (``perturbation=``): name -> generator.
PERTURBATIONS = {"pralds": pralds, "lab_pulses": lab_pulses, "prbs": prbs}


def stationary_trajectory(duration: float, fs: float, rng: np.random.Generator, *,
                          position: float = -0.1) -> np.ndarray:
    """One operating position held for the whole trial (rad; a stationary experiment).

    >>> stationary_trajectory(0.005, 1000.0, np.random.default_rng(0))
    array([-0.1, -0.1, -0.1, -0.1, -0.1])
    """
    return np.full(_n_samples(duration, fs), float(position))


_TRAJECTORIES = {"multilevel": (0, multilevel_trajectory), "novel": (1, novel_trajectory),
                 "stationary": (2, stationary_trajectory)}
