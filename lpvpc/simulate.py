"""The virtual subject: a physics-based ankle on a stiff position servo.

Simulates the two trials the LPV-PC method needs (Sobhani Tehrani, Jalaleddini, Kearney,
EMBC 2014): an unperturbed trial (UT) that follows a slow position trajectory and a
perturbed trial (PT) on the same trajectory with a PRALDS perturbation added. Everything
runs at ``fs_sim`` = 1 kHz and is optionally decimated to the output rate.

Units are SI everywhere: time s, angle rad (positive = dorsiflexion), angular velocity
rad/s, acceleration rad/s^2, torque N m (positive = the torque that resists
dorsiflexion, i.e. the same sign as ``K * angle``), stiffness N m/rad, viscosity
N m s/rad, inertia kg m^2.

The chain, one function per physical element::

    trajectory (multilevel_trajectory | novel_trajectory)  --+
    pralds (PT only) ----------------------------------------+--> command
    command --> servo --> theta, velocity, acceleration        (stiff: torque does not
                                                                 deflect the servo)
    intrinsic_torque = I*acc + B*vel + E(theta)
    reflex_torque    = LP_2nd( G(theta) * max(vel(t - delay) - th(theta), 0) )
    torque           = intrinsic + reflex + coloured_noise

    emg              = envelope(tonic + activation + reflex drive / emg_reflex_torque) + noise

Both trials record an EMG envelope (V): tonic activation in both, reflex-evoked bursts
(~40 ms after each velocity pulse, with the reflex's gain and threshold) in the perturbed
one, measurement noise. Effects the base LPV-PC model does not contain are switchable by
name through the :data:`EFFECTS` registry; each has its diagnosis-catalog counterpart of
the same name in :data:`lpvpc.effects.CATALOG`, except those marked "outside the diagnosis
catalog" (they test what the diagnosis says of effects it has no entry for).

Public API: :class:`SubjectParams`, :class:`SimulatedPair`, :func:`simulate_pair`,
:func:`write_dataset`, :data:`EFFECTS`, and the element functions
:func:`multilevel_trajectory`, :func:`novel_trajectory`, :func:`pralds`, :func:`lab_pulses`, :func:`prbs`, :func:`servo`,
:func:`intrinsic_torque`, :func:`reflex_torque`, :func:`coloured_noise`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy import signal

from lpvpc.data import Trial, decimate_signal, write_trial_csv
from lpvpc.model import vaf

FS_SIM = 1000.0  # Hz: the rate of the continuous-time physics (and of the lab's A/D)

# The identification range of the paper's multilevel trajectory.
THETA_PF = -0.4  # rad, most plantarflexed level
THETA_DF = 0.2  # rad, most dorsiflexed level

_EXP_MAX = 700.0  # keeps np.exp finite for absurd angles (no overflow warnings)


def _exp(x):
    return np.exp(np.clip(x, -_EXP_MAX, _EXP_MAX))


# ---------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------


@dataclass
class SubjectParams:
    """Physical parameters of the virtual ankle, the actuator and the torque sensor.

    Elastic stiffness (exponential-type, smooth, not a polynomial)::

        K(theta) = k_base + k_df * exp(k_df_rate * (theta - theta_df))
                          + k_pf * exp(-k_pf_rate * (theta - theta_pf))

    rises steeply toward dorsiflexion (~150 N m/rad at +0.2 rad), has its minimum
    (~33 N m/rad) near -0.26 rad, between neutral and full plantarflexion, and rises again
    somewhat toward -0.4 rad (~40 N m/rad): passive tissue stretch of the plantarflexors
    (dorsiflexion) and of the anterior structures (plantarflexion).
    ``elastic_torque`` is its exact integral, zero at ``elastic_rest``.

    Reflex nonlinearity: half-wave rectifier of delayed velocity with gain ``G(theta)``
    (exponential from ``reflex_gain_pf`` at theta_pf to ``reflex_gain_df`` at theta_df)
    and threshold ``th(theta)`` (linear from ``reflex_threshold_pf`` to
    ``reflex_threshold_df``, floored at ``reflex_threshold_min``).
    """

    # intrinsic mechanics
    inertia: float = 0.015  # kg m^2, foot + pedal moment of inertia
    viscosity: float = 0.7  # N m s/rad, intrinsic viscosity B
    k_base: float = 25.0  # N m/rad, constant part of K(theta)
    k_df: float = 125.0  # N m/rad, dorsiflexion exponential's value at theta_df
    k_df_rate: float = 7.0  # 1/rad, its growth rate toward dorsiflexion
    k_pf: float = 15.0  # N m/rad, plantarflexion exponential's value at theta_pf
    k_pf_rate: float = 12.0  # 1/rad, its growth rate toward plantarflexion
    theta_df: float = THETA_DF  # rad, reference angle of the dorsiflexion end
    theta_pf: float = THETA_PF  # rad, reference angle of the plantarflexion end
    elastic_rest: float = -0.2  # rad, angle where the elastic torque is zero (passive rest)
    # reflex pathway
    reflex_delay: float = 0.040  # s, stretch-reflex loop delay
    reflex_gain_pf: float = 2.0  # N m s/rad, rectifier slope at theta_pf
    reflex_gain_df: float = 8.0  # N m s/rad, rectifier slope at theta_df
    reflex_threshold_pf: float = 0.7  # rad/s, velocity threshold at theta_pf
    reflex_threshold_df: float = 0.25  # rad/s, velocity threshold at theta_df
    reflex_threshold_min: float = 0.05  # rad/s, floor when extrapolating far into DF
    reflex_wn: float = 16.0  # rad/s, natural frequency of the reflex low-pass (activation dynamics)
    reflex_zeta: float = 0.65  # 1, damping of the reflex low-pass (unit DC gain)
    # actuator: a stiff hydraulic position servo
    servo_wn: float = 2 * math.pi * 25.0  # rad/s (25 Hz): closed-loop natural frequency
    servo_zeta: float = 0.7  # 1, closed-loop damping
    # EMG (a rectified, smoothed envelope of the plantarflexors' surface EMG, as the lab records it)
    emg_tonic: float = 0.08  # 1, tonic (background) activation present in both trials
    emg_reflex_torque: float = 15.0  # N m of reflex drive per unit of reflex-evoked activation
    emg_volts: float = 300e-6  # V of envelope at full activation (1.0)
    emg_noise: float = 0.015  # 1, RMS of the envelope's measurement noise (activation units)
    emg_cutoff: float = 30.0  # Hz, envelope low-pass (rectify, then 2nd-order Butterworth)
    emg_band: tuple = (20.0, 450.0)  # Hz, band of the raw surface EMG (the noise carrier the drive modulates)
    # background activation a(t) of the activation effects (its own slow dynamics, not the reflex's)
    activation_cutoff: float = 0.05  # Hz, how fast a(t) varies (2nd-order low-pass of the noise behind it)
    activation_shared: bool = False  # True: the same a(t) in PT and UT (a real pair is recorded at two times)
    activation_stiffness_gain: float = 1.0  # background_activation: perturbation K, B scaled by 1 + this * a
    activation_reflex_gain: float = 1.0  # background_activation: reflex gain scaled by 1 + this * a
    # torque sensor / background noise
    noise_cutoff: float = 20.0  # Hz, cut-off of the 2nd-order Butterworth that colours the noise
    noise_order: int = 2  # order of that filter

    # -- intrinsic --------------------------------------------------------------------
    def K(self, theta):
        """Elastic stiffness dE/dtheta (N m/rad) at joint angle ``theta`` (rad)."""
        theta = np.asarray(theta, dtype=float)
        return (
            self.k_base
            + self.k_df * _exp(self.k_df_rate * (theta - self.theta_df))
            + self.k_pf * _exp(-self.k_pf_rate * (theta - self.theta_pf))
        )

    def incremental_stiffness(self, theta, amplitude: float = 0.04):
        """Stiffness (N m/rad) a linear model sees at ``theta`` (rad) under perturbations
        uniform in +-``amplitude`` rad (the PRALDS levels): the least-squares slope of
        E(theta + s) - E(theta) on s, 3/(2 a^3) int_{-a}^{a} s (E(theta + s) - E(theta)) ds.

        The elastic curve is nonlinear within a perturbation (its dorsiflexion exponential
        changes by e^{+-0.28} over +-0.04 rad), so this is what any linear identification
        estimates; it exceeds the tangent K(theta) by 0.3-0.6 % at 0.04 rad. Exactly: each
        exponential term c e^{r u} becomes c e^{r u} phi(r a), phi(x) = 3 (x cosh x - sinh x) / x^3
        = 1 + x^2/10 + ... (and ``amplitude`` -> 0 gives K).
        """
        theta = np.asarray(theta, dtype=float)

        def phi(x):
            return 1.0 + x * x / 10.0 if x < 1e-3 else 3.0 * (x * np.cosh(x) - np.sinh(x)) / x**3

        return (
            self.k_base
            + self.k_df * _exp(self.k_df_rate * (theta - self.theta_df)) * phi(self.k_df_rate * amplitude)
            + self.k_pf * _exp(-self.k_pf_rate * (theta - self.theta_pf)) * phi(self.k_pf_rate * amplitude)
        )

    def _E_unshifted(self, theta):
        theta = np.asarray(theta, dtype=float)
        return (
            self.k_base * theta
            + self.k_df / self.k_df_rate * _exp(self.k_df_rate * (theta - self.theta_df))
            - self.k_pf / self.k_pf_rate * _exp(-self.k_pf_rate * (theta - self.theta_pf))
        )

    def elastic_torque(self, theta):
        """Elastic torque E(theta) (N m): the exact integral of K, zero at ``elastic_rest``."""
        return self._E_unshifted(theta) - self._E_unshifted(self.elastic_rest)

    # -- reflex -----------------------------------------------------------------------
    def _s(self, theta):
        # 0 at theta_pf, 1 at theta_df (extrapolates linearly outside)
        return (np.asarray(theta, dtype=float) - self.theta_pf) / (self.theta_df - self.theta_pf)

    def reflex_gain(self, theta):
        """Reflex rectifier slope G(theta) (N m s/rad): rises exponentially toward DF."""
        ratio = self.reflex_gain_df / self.reflex_gain_pf
        return self.reflex_gain_pf * _exp(np.log(ratio) * self._s(theta))

    def reflex_threshold(self, theta):
        """Reflex velocity threshold th(theta) (rad/s): falls linearly toward DF."""
        s = self._s(theta)
        th = self.reflex_threshold_pf + (self.reflex_threshold_df - self.reflex_threshold_pf) * s
        return np.maximum(th, self.reflex_threshold_min)

    def to_dict(self) -> dict:
        """Plain-float dictionary of all fields (JSON-serialisable)."""
        return {k: (float(v) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    def curves(self, theta=None) -> dict:
        """K, elastic torque, reflex gain and threshold sampled on a theta grid (lists)."""
        if theta is None:
            theta = np.round(np.arange(-0.45, 0.2501, 0.01), 10)
        theta = np.asarray(theta, dtype=float)
        return {
            "theta": theta.tolist(),
            "K": self.K(theta).tolist(),
            "elastic_torque": self.elastic_torque(theta).tolist(),
            "reflex_gain": self.reflex_gain(theta).tolist(),
            "reflex_threshold": self.reflex_threshold(theta).tolist(),
        }


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


#: Perturbation designs of :func:`simulate_pair` (``perturbation=``): name -> generator.
PERTURBATIONS = {"pralds": pralds, "lab_pulses": lab_pulses, "prbs": prbs}


# ---------------------------------------------------------------------------------------
# Element 3: the actuator
# ---------------------------------------------------------------------------------------


def servo(command, fs: float, params: SubjectParams | None = None):
    """Position servo: joint angle, velocity and acceleration for a command (rad).

    A stiff hydraulic position servo, modelled as the closed-loop 2nd-order system
    ``theta'' = wn^2 (command - theta) - 2 zeta wn theta'`` (wn = ``params.servo_wn``,
    zeta = ``params.servo_zeta``). It is stiff: the ankle torque does NOT deflect it
    (no torque input), so the position is the same whatever the subject does -- the
    assumption the PT-UT subtraction relies on.

    The command is held constant between samples (the controller's DAC), so the
    zero-order-hold discretisation is exact. Velocity is the second state and the
    acceleration the state-space output equation, so all three are exact at the sample
    instants (no finite differences). The servo starts at rest at ``command[0]``.

    Returns ``(theta, velocity, acceleration)`` in rad, rad/s, rad/s^2.
    """
    p = params or SubjectParams()
    u = np.asarray(command, dtype=float)
    wn, z = p.servo_wn, p.servo_zeta
    A = np.array([[0.0, 1.0], [-wn ** 2, -2 * z * wn]])
    B = np.array([[0.0], [wn ** 2]])
    Ad, Bd, *_ = signal.cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), 1.0 / fs, method="zoh")
    du = u - u[0]  # deviation from the initial rest position: zero initial state
    bp, ap = signal.ss2tf(Ad, Bd, np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    bv, av = signal.ss2tf(Ad, Bd, np.array([[0.0, 1.0]]), np.zeros((1, 1)))
    dtheta = signal.lfilter(bp[0], ap, du)
    vel = signal.lfilter(bv[0], av, du)
    acc = wn ** 2 * (du - dtheta) - 2 * z * wn * vel
    return u[0] + dtheta, vel, acc


SENSOR_OVERSAMPLING = 10  # physics rate / fs of the recorded inertial torque (see below)


def recorded_acceleration(command, fs: float, params: SubjectParams | None = None,
                          oversample: int = SENSOR_OVERSAMPLING) -> np.ndarray:
    """The servo's angular acceleration (rad/s^2) as a torque sensor behind an anti-alias
    filter records it at ``fs``: the servo run at ``oversample`` x ``fs`` on the same held
    command, then decimated with the anti-alias FIR (:func:`lpvpc.data.decimate_signal`).

    The held command makes the acceleration jump at every command sample; sampled at those
    instants (``servo``'s exact values, the jump's right limit) the jumps put the inertial
    torque half a sample early. A linear IRF fitted to such data reads that as viscosity:
    +0.19 N m s/rad on this subject (IRF first moment 0.89 instead of B = 0.70 at 100 Hz);
    from the anti-aliased acceleration it gets 0.70.

    >>> cmd = np.r_[np.zeros(50), np.full(150, 0.01)]  # rad: one step of the held command
    >>> jump, recorded = servo(cmd, FS_SIM)[2][50], recorded_acceleration(cmd, FS_SIM)[50]  # rad/s^2
    >>> bool(jump > 240), bool(recorded < 0.7 * jump)  # the jump wn^2 * 0.01 rad, and what is recorded
    (True, True)
    """
    if oversample <= 1:
        return servo(command, fs, params)[2]
    _, _, acc = servo(np.repeat(np.asarray(command, dtype=float), oversample), fs * oversample, params)
    return decimate_signal(acc, oversample)


# ---------------------------------------------------------------------------------------
# Element 4: intrinsic mechanics
# ---------------------------------------------------------------------------------------


def intrinsic_torque(theta, vel, acc, params: SubjectParams | None = None, *,
                     stiffness_scale=1.0, viscosity_scale=1.0, extra=0.0):
    """Intrinsic torque (N m) = I*acc + B*vel + E(theta).

    Inertia of foot and pedal, viscosity and the nonlinear elastic curve of passive
    tissue (slope K(theta)). ``stiffness_scale`` multiplies E (hence K),
    ``viscosity_scale`` multiplies B and ``extra`` is added (N m): hooks for effects.

    At the elastic rest angle, the torque is inertia times acceleration plus viscosity times velocity:

    >>> p = SubjectParams()
    >>> tq = intrinsic_torque(np.array([p.elastic_rest]), np.array([0.1]), np.array([2.0]), p)
    >>> bool(np.isclose(tq[0], p.inertia * 2.0 + p.viscosity * 0.1))  # N m
    True
    """
    p = params or SubjectParams()
    return (p.inertia * np.asarray(acc) + p.viscosity * viscosity_scale * np.asarray(vel)
            + stiffness_scale * p.elastic_torque(theta) + extra)


# ---------------------------------------------------------------------------------------
# Element 5: stretch reflex
# ---------------------------------------------------------------------------------------


def delay_signal(x, delay: float, fs: float) -> np.ndarray:
    """``x(t - delay)``: exact sample shift when ``delay*fs`` is an integer, linear
    interpolation otherwise; the signal is taken as ``x[0]`` before it starts.

    >>> delay_signal(np.array([1.0, 2.0, 3.0, 4.0]), 0.002, 1000.0)  # 2 ms at 1 kHz: 2 samples
    array([1., 1., 1., 2.])
    >>> delay_signal(np.array([0.0, 2.0, 4.0]), 0.0005, 1000.0)  # half a sample: interpolated
    array([0., 1., 3.])
    """
    x = np.asarray(x, dtype=float)
    d = delay * fs
    n0 = int(np.floor(d + 1e-9))
    frac = d - n0 if d - n0 > 1e-9 else 0.0

    def shift(k):
        if k <= 0:
            return x.copy()
        k = min(k, len(x))
        return np.concatenate([np.full(k, x[0]), x[:len(x) - k]])

    out = shift(n0)
    if frac:
        out = (1 - frac) * out + frac * shift(n0 + 1)
    return out


def reflex_lowpass_coefficients(wn: float, zeta: float, fs: float):
    """Discrete (b, a) of the unit-DC-gain reflex low-pass wn^2/(s^2 + 2 zeta wn s + wn^2),
    first-order-hold discretised (the rectifier output is continuous, not a staircase).

    >>> b, a = reflex_lowpass_coefficients(16.0, 0.65, 1000.0)  # rad/s, 1, Hz
    >>> round(float(np.sum(b) / np.sum(a)), 12)  # unit DC gain
    1.0
    """
    num, den, _ = signal.cont2discrete(([wn ** 2], [1.0, 2 * zeta * wn, wn ** 2]), 1.0 / fs,
                                       method="foh")
    return np.ravel(num), np.ravel(den)


def _tv_lowpass(z, wn, zeta: float, fs: float) -> np.ndarray:
    """Reflex low-pass with a time-varying natural frequency ``wn[k]`` (rad/s).

    y'' = wn(t)^2 (z - y) - 2 zeta wn(t) y', integrated with the trapezoidal rule (A-stable;
    for constant wn it is the bilinear transform). A plain loop: ~0.1 s per 100k samples.
    """
    h = 1.0 / fs
    w = np.asarray(wn, dtype=float)
    w2 = w ** 2
    det = 1.0 + h * zeta * w + 0.25 * h * h * w2
    zz = np.asarray(z, dtype=float)
    out = np.empty(len(zz))
    y = yd = 0.0
    out[0] = 0.0
    w2l, wl, detl, zl = w2.tolist(), w.tolist(), det.tolist(), zz.tolist()
    hh = 0.5 * h
    for k in range(len(zl) - 1):
        # right-hand side (I + h/2 A_k) x_k + h/2 (b_k z_k + b_{k+1} z_{k+1})
        r0 = y + hh * yd
        r1 = yd + hh * (-w2l[k] * y - 2 * zeta * wl[k] * yd
                        + w2l[k] * zl[k] + w2l[k + 1] * zl[k + 1])
        # solve (I - h/2 A_{k+1}) x_{k+1} = r in closed form
        a11 = 1.0 + h * zeta * wl[k + 1]
        y, yd = (a11 * r0 + hh * r1) / detl[k + 1], (-hh * w2l[k + 1] * r0 + r1) / detl[k + 1]
        out[k + 1] = y
    return out


def reflex_torque(theta, vel, fs: float, params: SubjectParams | None = None, *,
                  gain_scale=1.0, wn=None, delay=None):
    """Stretch-reflex torque (N m) of a joint moving with ``vel`` (rad/s) at ``theta`` (rad).

    Velocity delayed by ``reflex_delay`` (the stretch-reflex loop), half-wave rectified
    with position-dependent threshold and gain, z = G(theta_d) * max(v(t - d) - th(theta_d), 0)
    with theta_d = theta(t - d): the spindle afferent encodes the muscle's length and
    velocity at the same moment and the loop delays both (with the current angle instead,
    each stretch's gain would be read at the level it ends on, +8 % in gain on average).
    The reflex responds to the TOTAL joint velocity, so fast trajectory transitions fire it
    too. Then the unit-DC-gain 2nd-order low-pass
    (``reflex_wn``, ``reflex_zeta``: muscle activation/contraction dynamics). ``gain_scale``
    multiplies G; ``wn`` (array, rad/s) replaces the constant natural frequency with a
    time-varying one and ``delay`` (array, s) the constant delay with a time-varying one
    (effects the LPV-PC model does not contain).

    Returns ``(torque, z)``.
    """
    p = params or SubjectParams()
    if delay is None:
        dvel, dtheta = delay_signal(vel, p.reflex_delay, fs), delay_signal(theta, p.reflex_delay, fs)
    else:  # vel(t - delay(t)), linear interpolation, vel[0] before the start
        t = np.arange(len(vel)) / fs
        t_d = t - np.asarray(delay, dtype=float)
        dvel, dtheta = np.interp(t_d, t, np.asarray(vel, dtype=float)), np.interp(t_d, t, np.asarray(theta, dtype=float))
    z = gain_scale * p.reflex_gain(dtheta) * np.maximum(dvel - p.reflex_threshold(dtheta), 0.0)
    if wn is None:
        b, a = reflex_lowpass_coefficients(p.reflex_wn, p.reflex_zeta, fs)
        tq = signal.lfilter(b, a, z)
    else:
        tq = _tv_lowpass(z, np.broadcast_to(np.asarray(wn, dtype=float), z.shape), p.reflex_zeta, fs)
    return tq, z


# ---------------------------------------------------------------------------------------
# Element 6: torque noise
# ---------------------------------------------------------------------------------------


def coloured_noise(n: int, fs: float, rng: np.random.Generator,
                   params: SubjectParams | None = None) -> np.ndarray:
    """Unit-variance-input white noise through a Butterworth low-pass (``noise_cutoff`` Hz,
    ``noise_order``): the sensor/background torque noise (before scaling to the SNR).

    >>> from scipy.signal import welch
    >>> e = coloured_noise(20000, 1000.0, np.random.default_rng(0))
    >>> f, P = welch(e, 1000.0, nperseg=1024)
    >>> bool(P[f < 10].mean() > 100 * P[f > 100].mean())  # coloured below the 20 Hz cut-off
    True
    """
    p = params or SubjectParams()
    b, a = signal.butter(p.noise_order, p.noise_cutoff, fs=fs)
    return signal.lfilter(b, a, rng.standard_normal(n))


# ---------------------------------------------------------------------------------------
# Effects the base LPV-PC model does not contain
# ---------------------------------------------------------------------------------------


@dataclass
class TrialState:
    """What an effect may read and modify for one trial (arrays at the simulation rate).

    Read: ``t`` (s), ``theta`` (rad), ``vel`` (rad/s), ``acc`` (rad/s^2), ``command``
    (rad), ``slow_velocity`` (rad/s) and ``slow_theta`` (rad): velocity and angle of the
    unperturbed trial (the slow operating point, the same for PT and UT), ``perturbed``
    (True for PT), ``fs`` (Hz), ``params``, ``rng`` (this trial's own random stream).
    Modify: ``stiffness_scale`` (multiplies E and K), ``viscosity_scale`` (multiplies B), ``reflex_gain_scale`` (multiplies G),
    ``extra_torque`` (N m, added to the intrinsic torque), ``reflex_wn`` (None or array
    rad/s: time-varying reflex natural frequency), ``reflex_delay`` (None or array s:
    time-varying reflex delay), ``activation`` (1: background activation added to the
    tonic level; it shows in the trial's EMG), ``channels`` (extra recorded channels).

    >>> n = 3
    >>> s = TrialState(t=np.arange(n) / 1000.0, theta=np.zeros(n), vel=np.zeros(n), acc=np.zeros(n),
    ...                command=np.zeros(n), slow_velocity=np.zeros(n), slow_theta=np.zeros(n), perturbed=True,
    ...                fs=1000.0, params=SubjectParams(), rng=np.random.default_rng(0))
    >>> s.stiffness_scale, s.extra_torque  # nothing modified: unit scales, no extra torque (N m)
    (array([1., 1., 1.]), array([0., 0., 0.]))
    """

    t: np.ndarray
    theta: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    command: np.ndarray
    slow_velocity: np.ndarray
    slow_theta: np.ndarray
    perturbed: bool
    fs: float
    params: SubjectParams
    rng: np.random.Generator
    stiffness_scale: np.ndarray = None
    viscosity_scale: np.ndarray = None
    reflex_gain_scale: np.ndarray = None
    extra_torque: np.ndarray = None
    reflex_wn: np.ndarray | None = None
    reflex_delay: np.ndarray | None = None
    activation: np.ndarray = None
    channels: dict = field(default_factory=dict)
    ut_activation: np.ndarray | None = None  # the UT's slow activation draws (PT only; activation_shared)

    def __post_init__(self):
        n = len(self.t)
        for name in ("stiffness_scale", "viscosity_scale", "reflex_gain_scale"):
            if getattr(self, name) is None:
                setattr(self, name, np.ones(n))
        if self.extra_torque is None:
            self.extra_torque = np.zeros(n)
        if self.activation is None:
            self.activation = np.zeros(n)


def _effect_drift(s: TrialState) -> dict:
    """Intrinsic fatigue / thixotropy: stiffness decays linearly in time, -30 % over
    120 s (floored at 10 % of the initial value). The reflex is untouched (its own
    time-varying gain is ``reflex_habituation``)."""
    rate = 0.30 / 120.0  # 1/s
    scale = np.maximum(1.0 - rate * s.t, 0.1)
    s.stiffness_scale *= scale
    return {"rate_per_s": rate, "floor": 0.1, "applies_to": ["K"]}


def _effect_reflex_habituation(s: TrialState) -> dict:
    """Reflex habituation: the reflex gain falls exponentially toward 30 % of its initial
    value with a 40-s time constant (-67 % after 2 min); intrinsic stiffness untouched."""
    final, tau = 0.3, 40.0  # 1, s
    s.reflex_gain_scale *= final + (1.0 - final) * np.exp(-s.t / tau)
    return {"final_fraction": final, "time_constant_s": tau, "applies_to": ["reflex_gain"]}


def _effect_nonlinear_viscosity(s: TrialState) -> dict:
    """Coulomb-like friction on the undelayed velocity, F_c * tanh(v / v_c): a smoothed
    sign term the linear viscosity B cannot represent."""
    fc, vc = 0.4, 0.02  # N m, rad/s
    s.extra_torque += fc * np.tanh(s.vel / vc)
    return {"coulomb_torque": fc, "velocity_scale": vc}


def _effect_direction_dependent_stiffness(s: TrialState) -> dict:
    """History-dependent stiffness: K is 25 % higher after the slow trajectory has moved
    toward dorsiflexion than after it has moved toward plantarflexion (the hysteresis of
    passive joint torque-angle loops; muscle thixotropy). The direction is that of the
    last slow movement faster than 0.05 rad/s, latched through holds, and the stiffness
    follows it with a 0.2 s time constant (no torque jumps). It acts the same in PT and
    UT (it reads the unperturbed trajectory's velocity)."""
    gain, v_min, tau = 0.25, 0.05, 0.2  # 1, rad/s, s
    v = s.slow_velocity
    moving = np.abs(v) > v_min
    last = np.maximum.accumulate(np.where(moving, np.arange(len(v)), 0))
    toward_df = (moving[last] & (v[last] > 0)).astype(float)  # 0 before any movement
    alpha = 1.0 - math.exp(-1.0 / (tau * s.fs))
    smooth = signal.lfilter([alpha], [1.0, alpha - 1.0], toward_df)
    s.stiffness_scale *= 1.0 + gain * smooth
    return {"increase_after_moving_toward_df": gain, "velocity_threshold": v_min, "time_constant": tau}


def _slow_activation(s: TrialState, cutoff=None) -> np.ndarray:
    """A slowly varying background activation a(t) in [0, 1], mostly low (~0.1) with bursts
    toward 0.9: unit-variance noise low-passed at ``cutoff`` Hz (default
    ``params.activation_cutoff``), a = (1 + tanh(x - 1)) / 2. Each trial has its own
    (activation is not reproducible between trials) unless ``params.activation_shared``:
    then the perturbed trial reuses the unperturbed trial's a(t)."""
    if s.params.activation_shared and s.ut_activation is not None:
        return s.ut_activation.copy()
    cutoff = s.params.activation_cutoff if cutoff is None else cutoff
    b, a = signal.butter(2, cutoff, fs=s.fs)
    lead = int(max(20.0, 1.0 / cutoff) * s.fs)  # discard the filter's start-up so a(t) is stationary from t = 0
    x = signal.lfilter(b, a, s.rng.standard_normal(len(s.t) + lead))[lead:]
    x /= max(np.std(x), 1e-12)
    return 0.5 * (1.0 + np.tanh(x - 1.0))


def _effect_background_activation(s: TrialState) -> dict:
    """Slowly varying background activation a(t) (see :func:`_slow_activation`), own per
    trial; it adds to the tonic level in the trial's EMG.

    Physiology: active fibres add short-range stiffness proportional to activation, acting
    on fast length changes about the slowly moving operating point (cross-bridges
    re-attach during slow movement, so the slow trajectory is not resisted). Hence the
    elastic torque of perturbations is scaled by (1 + a): a(t) * [E(theta) - E(theta_slow)]
    is added, i.e. K_eff = (1 + a) K for the perturbation. Viscosity is scaled by (1 + a)
    too, a tonic active (plantarflexing, resists dorsiflexion: positive) torque
    ``tonic * a`` is added, and the motoneuron pool's excitability raises the reflex gain
    by (1 + a) as well (activation raises intrinsic stiffness and reflex gain alike).
    PT - UT keeps a slow residual ``tonic * (a_PT - a_UT)``."""
    tonic = 2.0  # N m at full activation
    pr = s.params
    cutoff, ks, kr = pr.activation_cutoff, pr.activation_stiffness_gain, pr.activation_reflex_gain
    act = _slow_activation(s)
    s.extra_torque += ks * act * (pr.elastic_torque(s.theta) - pr.elastic_torque(s.slow_theta)) + tonic * act
    s.viscosity_scale *= 1.0 + ks * act
    s.reflex_gain_scale *= 1.0 + kr * act
    s.activation += act
    return {"cutoff_hz": cutoff, "tonic_torque": tonic,
            "mapping": "a = 0.5*(1+tanh(x-1)), x unit-variance noise low-passed at cutoff_hz",
            "perturbation_stiffness_scale": f"1 + {ks:g} a", "viscosity_scale": f"1 + {ks:g} a",
            "reflex_gain_scale": f"1 + {kr:g} a", "independent_per_trial": not pr.activation_shared}


def _effect_activation_reflex_gain(s: TrialState) -> dict:
    """Background activation (as in ``background_activation``, in the EMG) that raises only
    the reflex gain, by (1 + 1.5 a): motoneuron excitability without a measurable change of
    intrinsic stiffness (e.g. a weak contraction of a muscle whose fibres add little
    short-range stiffness at the joint)."""
    gain = 1.5
    act = _slow_activation(s)
    s.reflex_gain_scale *= 1.0 + gain * act
    s.activation += act
    return {"reflex_gain_scale": f"1 + {gain} a", "independent_per_trial": not s.params.activation_shared}


def _effect_amplitude_dependent_stiffness(s: TrialState) -> dict:
    """Short-range stiffness that falls with the perturbation's amplitude: the elastic
    torque of the displacement p = theta - theta_slow is scaled by 1 - |p| / 0.12 rad
    (-33 % at the PRALDS's 0.04 rad), a known property of joint tissue. Only the
    perturbed trial has p != 0."""
    p0 = 0.12  # rad
    pr = s.params
    p = s.theta - s.slow_theta
    s.extra_torque -= np.minimum(np.abs(p) / p0, 0.9) * (pr.elastic_torque(s.theta) - pr.elastic_torque(s.slow_theta))
    return {"stiffness_scale": "1 - |p| / 0.12 rad", "p0": p0}


def _effect_stress_relaxation(s: TrialState) -> dict:
    """Viscoelastic stress relaxation: after a displacement p = theta - theta_slow, 40 % of
    its elastic torque relaxes with a 0.6 s time constant, i.e. the exponential average of
    that torque over 0.6 s is taken off, 0.4 * LP(E(theta) - E(theta_slow)). K stays the
    short-range (instantaneous) stiffness; held 3 s, a displacement keeps 60 % of it. The
    catalog's averages (0.3, 1 and 3 s) bracket 0.6 s, so the model's term approximates it.
    Only the perturbed trial has p != 0."""
    fraction, tau = 0.4, 0.6  # 1, s
    pr = s.params
    alpha = 1.0 - math.exp(-1.0 / (tau * s.fs))
    elastic = pr.elastic_torque(s.theta) - pr.elastic_torque(s.slow_theta)
    s.extra_torque -= fraction * signal.lfilter([alpha], [1.0, alpha - 1.0], elastic)
    return {"relaxing_fraction": fraction, "time_constant_s": tau}


def _effect_position_dependent_reflex_delay(s: TrialState) -> dict:
    """The reflex delay grows toward dorsiflexion: 30 ms up to -0.2 rad, then linearly to
    80 ms at +0.2 rad. Why this shape: the short-latency (group Ia, ~30 ms) stretch reflex
    dominates the torque of a short muscle; stretched, the medium-latency (group II,
    60-80 ms) component takes over. The range is at the wide end of that, so that it is
    visible: with the reflex's slow activation dynamics, a 25-55 ms range cost a model
    without it only ~0.1 pp of held-out VAF; this one 0.3-0.5 pp. The LPV-PC model has one
    delay; its diagnosis-catalog counterpart re-runs the model's reflex at neighbouring
    delays, weighted by position."""
    d_short, d_long, theta_0 = 0.030, 0.080, -0.2  # s, s, rad
    slope = (d_long - d_short) / (THETA_DF - theta_0)  # s/rad
    s.reflex_delay = d_short + slope * np.maximum(s.theta - theta_0, 0.0)
    return {"delay_formula": "0.03 s + 0.125 s/rad * max(theta + 0.2, 0)", "delay_at_-0.2": d_short,
            "delay_at_+0.2": d_long}


def _effect_position_dependent_reflex_dynamics(s: TrialState) -> dict:
    """Reflex low-pass natural frequency varies with position (faster toward DF):
    wn(theta) = reflex_wn * 1.7**((theta + 0.1) / 0.3), ~9.4 rad/s at -0.4, 27 rad/s at +0.2.
    The LPV-PC model assumes LTI reflex dynamics. (With 1.5 it cost a model without it
    0.15 VAF points, the diagnosis's minimum gain, once the model held the elastic
    curvature: a test of detection needs an effect above that.)"""
    ratio = 1.7
    s.reflex_wn = s.params.reflex_wn * ratio ** ((s.theta + 0.1) / 0.3)
    return {"wn_formula": "reflex_wn * 1.7**((theta + 0.1)/0.3)",
            "wn_at_-0.4": float(s.params.reflex_wn / ratio),
            "wn_at_+0.2": float(s.params.reflex_wn * ratio)}


# Effects outside the diagnosis catalog (no counterpart in lpvpc.effects.CATALOG): they test
# whether the diagnosis's signal-dependence probes point to the right signal and pathway.


def _effect_oscillating_reflex_gain(s: TrialState) -> dict:
    """Reflex gain that oscillates with trial time, 1 + 0.4 sin(2 pi t / 35 s): a slow
    periodic swing of attention / motoneuron excitability. Not habituation: it returns to
    where it started every 35 s, so a trend in t and t^2 cannot follow it. Outside the
    diagnosis catalog."""
    depth, period = 0.4, 35.0  # 1, s
    s.reflex_gain_scale *= 1.0 + depth * np.sin(2.0 * np.pi * s.t / period)
    return {"reflex_gain_scale": f"1 + {depth} sin(2 pi t / {period} s)", "outside_catalog": True}


def _effect_stiffness_by_slow_speed(s: TrialState) -> dict:
    """Short-range stiffness that falls while the joint moves slowly (thixotropy: the slow
    movement detaches cross-bridges; they re-form in holds): the elastic torque of the
    perturbation about the slow operating point is scaled by 1 - 0.4 tanh(|v_slow| / 0.05
    rad/s), whichever the direction of the movement (unlike ``direction_dependent_stiffness``,
    nothing is latched). Outside the diagnosis catalog."""
    depth, v0 = 0.4, 0.05  # 1, rad/s
    pr = s.params
    drop = depth * np.tanh(np.abs(s.slow_velocity) / v0)
    s.extra_torque -= drop * (pr.elastic_torque(s.theta) - pr.elastic_torque(s.slow_theta))
    return {"perturbation_stiffness_scale": f"1 - {depth} tanh(|v_slow| / {v0} rad/s)", "outside_catalog": True}


#: name -> (description, apply function). An apply function takes a :class:`TrialState`,
#: modifies its modulation fields in place and returns a JSON-serialisable dict of its
#: parameters (recorded in ``truth['effects']``). To add an effect: write such a function
#: and add one line here.
EFFECTS: dict[str, tuple[str, Callable[[TrialState], dict]]] = {
    "drift": ("stiffness decays linearly, -30 % over 2 min (intrinsic fatigue)", _effect_drift),
    "reflex_habituation": ("reflex gain decays exponentially to 30 % (time constant 40 s)",
                           _effect_reflex_habituation),
    "nonlinear_viscosity": ("Coulomb-like friction 0.4*tanh(v/0.02) N m on undelayed velocity",
                            _effect_nonlinear_viscosity),
    "direction_dependent_stiffness": ("K +25 % after the slow trajectory moved toward "
                                      "dorsiflexion (torque-angle hysteresis)",
                                      _effect_direction_dependent_stiffness),
    "background_activation": ("slow background activation a(t) (in the EMG), own per trial: K of "
                              "perturbations, B and reflex gain scaled by 1+a, tonic torque 2a N m",
                              _effect_background_activation),
    "activation_reflex_gain": ("slow background activation a(t) (in the EMG) scaling the reflex gain "
                               "only, by 1+1.5a", _effect_activation_reflex_gain),
    "amplitude_dependent_stiffness": ("perturbation stiffness falls with amplitude, 1-|p|/0.12 rad",
                                      _effect_amplitude_dependent_stiffness),
    "stress_relaxation": ("40 % of the perturbation's elastic torque relaxes with a 0.6 s time constant",
                          _effect_stress_relaxation),
    "position_dependent_reflex_dynamics": ("reflex low-pass wn varies with position (9.4-27 rad/s)",
                                           _effect_position_dependent_reflex_dynamics),
    "position_dependent_reflex_delay": ("reflex delay grows toward dorsiflexion, 30 ms up to -0.2 rad, "
                                        "80 ms at +0.2 rad", _effect_position_dependent_reflex_delay),
    # outside the diagnosis catalog
    "oscillating_reflex_gain": ("reflex gain oscillates with trial time, 1+0.4 sin(2 pi t/35 s) "
                                "(outside the diagnosis catalog)", _effect_oscillating_reflex_gain),
    "stiffness_by_slow_speed": ("perturbation stiffness falls while the joint moves slowly, "
                                "1-0.4 tanh(|v_slow|/0.05) (outside the diagnosis catalog)",
                                _effect_stiffness_by_slow_speed),
}


def _check_effects(effects) -> tuple:
    if isinstance(effects, str):
        effects = (effects,)
    effects = tuple(effects)
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {sorted(EFFECTS)}")
    return effects


# ---------------------------------------------------------------------------------------
# The pair
# ---------------------------------------------------------------------------------------


@dataclass
class SimulatedPair:
    """A simulated PT/UT pair at the output rate.

    ``pt``, ``ut``: noisy trials (channels 'command' and 'emg', the EMG envelope
    in ``emg_unit``); ``pt_clean``, ``ut_clean``: the same with noise-free torque;
    ``truth``: JSON-serialisable parameters, curves and measured quantities;
    ``components``: noise-free torques (N m) 'pt_intrinsic', 'pt_reflex',
    'ut_intrinsic', 'ut_reflex'; ``activation``: each trial's true background activation
    (1; tonic level plus any slow activation, the EMG's drive without the reflex bursts),
    {'PT': ..., 'UT': ...} at the output rate.

    >>> pair = simulate_pair("multilevel", seed=0, duration=10.0, fs_out=100.0)
    >>> pair.pt.fs, len(pair.pt.time), sorted(pair.pt.channels)  # Hz, samples, recorded channels
    (100.0, 1000, ['command', 'emg'])
    >>> bool(np.allclose(pair.pt_clean.position, pair.pt.position))  # noise is in the torque only
    True
    """

    pt: Trial
    ut: Trial
    pt_clean: Trial
    ut_clean: Trial
    truth: dict
    components: dict
    activation: dict = field(default_factory=dict)


def stationary_trajectory(duration: float, fs: float, rng: np.random.Generator, *,
                          position: float = -0.1) -> np.ndarray:
    """One operating position held for the whole trial (rad; a stationary experiment).

    >>> stationary_trajectory(0.005, 1000.0, np.random.default_rng(0))
    array([-0.1, -0.1, -0.1, -0.1, -0.1])
    """
    return np.full(_n_samples(duration, fs), float(position))


_TRAJECTORIES = {"multilevel": (0, multilevel_trajectory), "novel": (1, novel_trajectory),
                 "stationary": (2, stationary_trajectory)}


def _simulate_trial(command, slow, perturbed, fs, params, effects, rng):
    """Physics of one trial at the simulation rate: returns kinematics, torques, channels.
    ``slow`` is the unperturbed trial's result (None when simulating the UT itself)."""
    theta, vel, _ = servo(command, fs, params)
    acc = recorded_acceleration(command, fs, params)  # band-limited, as recorded (not the jumps' samples)
    t = np.arange(len(command)) / fs
    st = TrialState(t=t, theta=theta, vel=vel, acc=acc, command=command,
                    slow_velocity=vel if slow is None else slow["vel"],
                    slow_theta=theta if slow is None else slow["theta"],
                    perturbed=perturbed, fs=fs, params=params, rng=rng,
                    ut_activation=None if slow is None else slow["slow_activation"])
    info = {name: EFFECTS[name][1](st) for name in effects}
    tq_i = intrinsic_torque(theta, vel, acc, params, stiffness_scale=st.stiffness_scale,
                            viscosity_scale=st.viscosity_scale, extra=st.extra_torque)
    tq_r, z = reflex_torque(theta, vel, fs, params, gain_scale=st.reflex_gain_scale, wn=st.reflex_wn,
                            delay=st.reflex_delay)
    return {"theta": theta, "vel": vel, "intrinsic": tq_i, "reflex": tq_r, "reflex_drive": z,
            "activation": params.emg_tonic + st.activation, "slow_activation": st.activation,
            "channels": st.channels, "effects": info}


#: EMG units of :func:`simulate_pair` and the factor from volts.
EMG_UNITS = {"V": 1.0, "mV": 1e3, "uV": 1e6}


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


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def simulate_pair(trajectory: str = "multilevel", *, seed: int = 0, duration: float = 120.0,
                  fs_out: float = 1000.0, snr_db: float = 18.0,
                  perturbation_amplitude: float = 0.04, params: SubjectParams | None = None,
                  effects=(), emg_unit: str = "V", perturbation: str = "pralds") -> SimulatedPair:
    """Simulate a perturbed (PT) and an unperturbed (UT) trial on the same trajectory.

    ``trajectory``: "multilevel" (identification), "novel" (held-out shapes that also
    leave the identified range briefly) or "stationary" (one position, -0.1 rad). ``seed`` selects all random streams (trajectory,
    PRALDS, noise, effects); the novel trajectory uses a different stream than the
    multilevel one for the same seed. ``duration`` s; ``fs_out`` Hz must divide 1000
    (1000: no decimation; 100: ``scipy.signal.decimate(q=10, ftype='fir', zero_phase=True)``).
    ``snr_db``: SNR of the PERTURBATION torque, 10 log10(var(PT-UT clean) / var(PT-UT
    noise)), exact at the output rate (``inf`` or ``None``: no noise).
    ``perturbation_amplitude`` rad: PRALDS levels uniform in +-amplitude. ``perturbation``:
    "pralds" (:func:`pralds`), "lab_pulses" (:func:`lab_pulses`, the lab pilot trial's
    design: every step large) or "prbs" (:func:`prbs`: +-amplitude switching every
    50-150 ms, no quiet windows). ``effects``:
    names from :data:`EFFECTS`. Position has no sensor noise (an optical encoder's
    quantisation is negligible next to the torque noise). Both trials carry channel
    'emg' (:func:`emg_envelope`: tonic activation in both, reflex-evoked bursts, noise)
    in ``emg_unit`` ("V", "mV" or "uV").
    """
    if emg_unit not in EMG_UNITS:
        raise ValueError(f"unknown EMG unit {emg_unit!r}; use one of {sorted(EMG_UNITS)}")
    if trajectory not in _TRAJECTORIES:
        raise ValueError(f"unknown trajectory {trajectory!r}; use one of {sorted(_TRAJECTORIES)}")
    if perturbation not in PERTURBATIONS:
        raise ValueError(f"unknown perturbation {perturbation!r}; use one of {sorted(PERTURBATIONS)}")
    effects = _check_effects(effects)
    params = params or SubjectParams()
    fs = FS_SIM
    q = fs / fs_out
    if fs_out <= 0 or abs(q - round(q)) > 1e-9:
        raise ValueError(f"fs_out={fs_out} Hz must divide the simulation rate {fs} Hz")
    q = int(round(q))
    if duration * fs_out < 100:
        raise ValueError(f"duration {duration} s is too short (need >= 100 output samples)")

    code, make_traj = _TRAJECTORIES[trajectory]
    ss = np.random.SeedSequence([int(seed), code])
    r_traj, r_pert, r_npt, r_nut, r_ept, r_eut = (np.random.default_rng(s) for s in ss.spawn(6))
    r_mpt, r_mut = (np.random.default_rng(s) for s in ss.spawn(2))  # EMG noise (after the others: same streams)

    traj = make_traj(duration, fs, r_traj)
    pert = PERTURBATIONS[perturbation](duration, fs, r_pert, amplitude=perturbation_amplitude)
    cmd = {"UT": traj, "PT": traj + pert}
    ut = _simulate_trial(cmd["UT"], None, False, fs, params, effects, r_eut)
    pt = _simulate_trial(cmd["PT"], ut, True, fs, params, effects, r_ept)
    for sim, r in ((ut, r_mut), (pt, r_mpt)):
        sim["channels"]["emg"] = EMG_UNITS[emg_unit] * emg_envelope(sim["activation"], sim["reflex_drive"], fs, r, params)

    def out(x):  # to the output rate
        return decimate_signal(x, q)

    n = len(traj)
    t_out = (np.arange(n) / fs)[::q]
    comp = {"pt_intrinsic": out(pt["intrinsic"]), "pt_reflex": out(pt["reflex"]),
            "ut_intrinsic": out(ut["intrinsic"]), "ut_reflex": out(ut["reflex"])}
    clean = {"PT": comp["pt_intrinsic"] + comp["pt_reflex"],
             "UT": comp["ut_intrinsic"] + comp["ut_reflex"]}
    pos = {"PT": out(pt["theta"]), "UT": out(ut["theta"])}

    # Noise: independent coloured noise in each trial, one common scale chosen so the
    # perturbation torque (PT - UT) has exactly the requested SNR at the output rate
    # (decimation is linear, so scaling after decimating is the same as before).
    noise_pt = out(coloured_noise(n, fs, r_npt, params))
    noise_ut = out(coloured_noise(n, fs, r_nut, params))
    d_clean = clean["PT"] - clean["UT"]
    if snr_db is None or np.isinf(snr_db):
        scale = 0.0
    else:
        scale = float(np.sqrt(np.var(d_clean) / (np.var(noise_pt - noise_ut) * 10 ** (snr_db / 10))))
    noisy = {"PT": clean["PT"] + scale * noise_pt, "UT": clean["UT"] + scale * noise_ut}
    d_noisy = noisy["PT"] - noisy["UT"]

    def trial(key, torque, sim):
        ch = {"command": out(cmd[key])}
        ch.update({k: out(v) for k, v in sim["channels"].items()})
        ch["emg"] = np.maximum(ch["emg"], 0.0)  # an envelope: the decimation filter's ringing clipped
        return Trial(time=t_out.copy(), position=pos[key].copy(), torque=torque, channels=ch,
                     name=f"{trajectory}_{key}")

    eff_truth = [{"name": e, "description": EFFECTS[e][0], "parameters": pt["effects"][e]}
                 for e in effects]
    d_vel = out(pt["vel"] - ut["vel"])
    d_int = comp["pt_intrinsic"] - comp["ut_intrinsic"]
    d_ref = comp["pt_reflex"] - comp["ut_reflex"]
    truth = {
        "trajectory": trajectory,
        "seed": int(seed),
        "duration": float(duration),
        "fs_sim": fs,
        "fs_out": float(fs_out),
        "snr_db": None if snr_db is None else float(snr_db),
        "perturbation_amplitude": float(perturbation_amplitude),
        "perturbation": perturbation,
        "params": params.to_dict(),
        "curves": params.curves(),
        "reflex_delay": params.reflex_delay,
        "reflex_wn": params.reflex_wn,
        "reflex_zeta": params.reflex_zeta,
        "effects": eff_truth,
        "noise_scale": scale,
        "position_noise": 0.0,
        "units": {"time": "s", "position": "rad", "torque": "N m", "command": "rad", "emg": emg_unit},
        "emg_unit": emg_unit,
        # measured on this record at the output rate; RMS values are about zero
        "measured": {
            "snr_db": float(10 * np.log10(np.var(d_clean) / np.var(d_noisy - d_clean)))
            if scale > 0 else float("inf"),
            "vaf_ceiling": vaf(d_noisy, d_clean),
            "perturbation_torque_rms": _rms(d_clean - d_clean.mean()),
            "perturbation_intrinsic_rms": _rms(d_int - d_int.mean()),
            "perturbation_reflex_rms": _rms(d_ref),
            "ut_reflex_rms": _rms(comp["ut_reflex"]),
            "pt_reflex_rms": _rms(comp["pt_reflex"]),
            "ut_to_perturbation_reflex_rms_ratio": _rms(comp["ut_reflex"]) / max(_rms(d_ref), 1e-12),
            "ut_reflex_active_fraction": float(np.mean(np.abs(comp["ut_reflex"]) > 0.01)),
            "noise_rms": _rms(d_noisy - d_clean),
            "peak_perturbation_velocity": float(np.max(np.abs(d_vel))),
            "peak_ut_velocity": float(np.max(np.abs(out(ut["vel"])))),
            "scheduling_range": [float(pos["UT"].min()), float(pos["UT"].max())],
            "pt_position_range": [float(pos["PT"].min()), float(pos["PT"].max())],
        },
    }
    if truth["measured"]["snr_db"] == float("inf"):
        truth["measured"]["snr_db"] = None  # JSON has no infinity
    pair = SimulatedPair(
        pt=trial("PT", noisy["PT"], pt), ut=trial("UT", noisy["UT"], ut),
        pt_clean=trial("PT", clean["PT"], pt), ut_clean=trial("UT", clean["UT"], ut),
        truth=truth, components=comp, activation={"PT": out(pt["activation"]), "UT": out(ut["activation"])})
    return pair


def _save_truth_npz(path, pair: SimulatedPair):
    from .outputs import atomic_path

    c = pair.components
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: savez adds no suffix
        np.savez_compressed(
            fh, time=pair.pt.time,
            pt_position=pair.pt.position, ut_position=pair.ut.position,
            pt_torque_clean=pair.pt_clean.torque, ut_torque_clean=pair.ut_clean.torque,
            perturbation_intrinsic=c["pt_intrinsic"] - c["ut_intrinsic"],
            perturbation_reflex=c["pt_reflex"] - c["ut_reflex"],
            **c)


def write_dataset(out_dir, *, seed: int = 0, fs_out: float = 1000.0, snr_db: float = 18.0,
                  effects=(), duration: float = 120.0, params: SubjectParams | None = None,
                  perturbation: str = "pralds") -> dict:
    """Write an identification pair and a novel (held-out) pair with their truth.

    Files in ``out_dir``: ident_PT.csv, ident_UT.csv, novel_PT.csv, novel_UT.csv
    (header ``time,position,torque[,emg],command``; s, rad, N m, rad), truth.json
    (parameters, curves, per-pair truth) and truth_ident.npz / truth_novel.npz (time,
    positions, clean PT/UT torques, the four components and the perturbation intrinsic
    and reflex torques, all at the output rate). ``perturbation`` as in
    :func:`simulate_pair`. Returns {stem: Path}.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    params = params or SubjectParams()
    paths, truth = {}, {"params": params.to_dict(), "curves": params.curves(),
                        "units": {"time": "s", "position": "rad", "torque": "N m",
                                  "command": "rad", "emg": "V"}}
    for key, kind in (("ident", "multilevel"), ("novel", "novel")):
        pair = simulate_pair(kind, seed=seed, duration=duration, fs_out=fs_out, snr_db=snr_db,
                             params=params, effects=effects, perturbation=perturbation)
        for which, tr in (("PT", pair.pt), ("UT", pair.ut)):
            p = out_dir / f"{key}_{which}.csv"
            write_trial_csv(tr, p)
            paths[f"{key}_{which}"] = p
        p = out_dir / f"truth_{key}.npz"
        _save_truth_npz(p, pair)
        paths[f"truth_{key}"] = p
        truth[key] = pair.truth
    p = out_dir / "truth.json"
    from .outputs import write_text

    write_text(p, json.dumps(truth, indent=1))
    paths["truth"] = p
    return paths
