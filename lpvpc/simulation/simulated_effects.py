"""Effects the base LPV-PC model does not contain, switchable by name in the simulation
(:data:`EFFECTS`). Each changes a trial's state (:class:`TrialState`) before its physics
runs; each has its diagnosis-catalog counterpart of the same name in
:data:`lpvpc.models.effects.CATALOG`, except those marked "outside the diagnosis catalog".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import signal

from .subject import SubjectParams, THETA_DF


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


# Effects outside the diagnosis catalog (no counterpart in lpvpc.models.effects.CATALOG): they test
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


@dataclass(frozen=True)
class CustomEffect:
    """An effect given as an object rather than a name of :data:`EFFECTS`: a parameterised
    form (:mod:`lpvpc.simulation.population` builds them). ``name`` (recorded in ``truth['effects']``),
    ``description`` and ``apply`` (a function of a :class:`TrialState`, as the registry's).

    >>> def stiffer(s):  # K of the whole trial +10 %
    ...     s.stiffness_scale *= 1.1
    ...     return {"scale": 1.1}
    >>> e = CustomEffect("stiffer", "K +10 %", stiffer)
    >>> effect_entry(e)[:2], effect_entry("drift")[0]
    (('stiffer', 'K +10 %'), 'drift')
    """

    name: str
    description: str
    apply: Callable[[TrialState], dict]


def effect_entry(effect) -> tuple:
    """(name, description, apply function) of a registry name or a :class:`CustomEffect`.

    >>> name, description, apply = effect_entry("reflex_habituation")
    >>> name, callable(apply)
    ('reflex_habituation', True)
    """
    if isinstance(effect, CustomEffect):
        return effect.name, effect.description, effect.apply
    return effect, EFFECTS[effect][0], EFFECTS[effect][1]


def _check_effects(effects) -> tuple:
    if isinstance(effects, (str, CustomEffect)):
        effects = (effects,)
    effects = tuple(effects)
    unknown = [e for e in effects if not isinstance(e, CustomEffect) and e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {sorted(EFFECTS)}")
    return effects
