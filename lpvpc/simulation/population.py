"""A population of virtual subjects: one seed gives one reproducible subject, its parameters
drawn from published ranges and its effects in one of several forms.

The project's own virtual subject (:class:`lpvpc.simulation.subject.SubjectParams` at its defaults,
one form per effect in :data:`lpvpc.simulation.simulated_effects.EFFECTS`) is one point; a method
calibrated on it may miss on another. :func:`draw_subject` draws a whole subject
(:class:`PopulationSubject`): intrinsic mechanics and the shape of K(theta) (one of
:data:`STIFFNESS_FORMS`), reflex gain, threshold (near-zero thresholds included), delay and
dynamics, torque noise level and colour, EMG form, unit and noise floor, the perturbation
design, and optionally one effect of :data:`POPULATION_EFFECTS` in one of its forms.
:func:`simulate_subject` simulates its PT/UT pair with the same physics as
:func:`lpvpc.simulation.simulate.simulate_pair` (it calls it), :func:`write_subject` writes its data set
as :func:`lpvpc.simulation.simulate.write_dataset` does (``lpvpc simulate --population-seed N`` calls it).

Every range (:data:`RANGES`, :data:`EFFECT_RANGES`) and where it comes from is listed in
docs/guide/population.md. Seeds for developing methods (:data:`DEVELOPMENT_SEEDS`) and for
the recorded results (:data:`RECORD_SEEDS`) are disjoint.

>>> s = draw_subject(3, effect="reflex_habituation", form="exponential")
>>> s == draw_subject(3, effect="reflex_habituation", form="exponential"), s.effect, s.form
(True, 'reflex_habituation', 'exponential')
>>> PopulationSubject.from_dict(json.loads(json.dumps(s.to_dict()))) == s  # JSON round trip
True
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from functools import partial
from pathlib import Path

import numpy as np
from scipy import signal

from .emg import EMG_FORMS
from .simulated_effects import CustomEffect, TrialState
from .subject import THETA_DF, THETA_PF, SubjectParams
from .trajectories import PERTURBATIONS

#: Seeds to develop and calibrate methods on.
DEVELOPMENT_SEEDS = range(0, 100_000)
#: Seeds for recorded results only, drawn after the methods are settled (disjoint from
#: :data:`DEVELOPMENT_SEEDS`).
RECORD_SEEDS = range(1_000_000, 1_100_000)

#: Shapes of the elastic stiffness K(theta): "exponential" (a constant plus one exponential
#: rising toward dorsiflexion), "two_exponentials" (a constant plus two exponentials: a
#: minimum between neutral and plantarflexion) and "polynomial" (a cubic about its minimum).
STIFFNESS_FORMS = ("exponential", "two_exponentials", "polynomial")

#: Effect name (that of its diagnosis-catalog entry, :data:`lpvpc.models.effects.CATALOG`) ->
#: its forms.
POPULATION_EFFECTS = {
    "reflex_habituation": ("linear", "exponential", "step"),
    "background_activation": ("intrinsic", "reflex", "both"),
    "nonlinear_viscosity": ("coulomb", "stribeck"),
    "position_dependent_reflex_delay": ("linear", "exponential", "step"),
    "position_dependent_reflex_dynamics": ("linear", "exponential", "step"),
}

#: Drawn subject parameters: name -> (low, high, unit, how drawn). Uniform unless "log"
#: (log-uniform). Their sources: docs/guide/population.md.
RANGES = {
    "inertia": (0.01, 0.03, "kg m^2", "uniform"),
    "viscosity": (0.5, 1.0, "N m s/rad", "uniform"),
    "k_min": (15.0, 40.0, "N m/rad", "uniform"),  # K's low part (constant, or the polynomial's minimum)
    "k_df_end": (100.0, 200.0, "N m/rad", "uniform"),  # K at +0.2 rad (dorsiflexion end)
    "k_df_rate": (5.0, 15.0, "1/rad", "uniform"),  # growth rate of the dorsiflexion exponential
    "k_pf": (5.0, 30.0, "N m/rad", "uniform"),  # plantarflexion exponential (two_exponentials) / rise at -0.4 (polynomial)
    "k_pf_rate": (8.0, 18.0, "1/rad", "uniform"),
    "k_min_position": (-0.3, -0.1, "rad", "uniform"),  # the polynomial's minimum
    "elastic_rest": (-0.3, -0.1, "rad", "uniform"),
    "reflex_delay": (0.030, 0.060, "s", "uniform"),
    "reflex_wn": (12.0, 20.0, "rad/s", "uniform"),
    "reflex_zeta": (0.55, 0.75, "1", "uniform"),
    "reflex_gain_pf": (1.0, 4.0, "N m s/rad", "uniform"),
    "reflex_gain_ratio": (1.2, 5.0, "1", "uniform"),  # gain at +0.2 over gain at -0.4
    "reflex_threshold_df": (0.02, 0.4, "rad/s", "log"),
    "reflex_threshold_rise": (0.05, 0.6, "rad/s", "uniform"),  # threshold at -0.4 minus at +0.2
    "snr_db": (12.0, 20.0, "dB", "uniform"),
    "noise_cutoff": (10.0, 40.0, "Hz", "uniform"),
    "perturbation_amplitude": (0.03, 0.05, "rad", "uniform"),
    "emg_tonic": (0.03, 0.15, "1", "uniform"),
    "emg_reflex_torque": (8.0, 25.0, "N m", "uniform"),
    "emg_volts": (100e-6, 500e-6, "V", "uniform"),
    "emg_noise": (0.005, 0.05, "1", "log"),
    "emg_cutoff": (10.0, 40.0, "Hz", "uniform"),
    "emg_offset": (0.0, 0.1, "1", "uniform"),  # "envelope" form only (0 otherwise)
}

#: Drawn effect parameters, per effect: name -> (low, high, unit, how drawn).
EFFECT_RANGES = {
    "reflex_habituation": {
        "end_fraction": (0.2, 0.8, "1", "uniform"),  # linear: gain fraction left after 120 s
        "time_constant": (10.0, 120.0, "s", "log"),  # exponential
        "floor": (0.0, 0.8, "1", "uniform"),  # exponential: fraction it tends to
        "step_time": (20.0, 80.0, "s", "uniform"),  # step
        "step_level": (0.2, 0.7, "1", "uniform"),  # step: fraction after it
    },
    "background_activation": {
        "stiffness_gain": (0.5, 1.5, "1", "uniform"),  # K of perturbations and B scaled by 1 + this a
        "reflex_gain": (0.5, 1.5, "1", "uniform"),  # reflex gain scaled by 1 + this a
        "tonic_torque": (0.0, 2.0, "N m", "uniform"),  # active torque at a = 1
        "burst_cutoff": (0.1, 0.25, "Hz", "uniform"),  # bursts: 4-10 s
        "drift_start": (0.0, 0.6, "1", "uniform"),  # drift: a at t = 0 ...
        "drift_end": (0.0, 0.6, "1", "uniform"),  # ... and at the end of the trial
    },
    "nonlinear_viscosity": {
        "coulomb_torque": (0.15, 0.6, "N m", "uniform"),
        "velocity_scale": (0.005, 0.03, "rad/s", "uniform"),  # smoothing of sign(v)
        "breakaway_ratio": (1.5, 3.0, "1", "uniform"),  # stribeck: static / Coulomb friction
        "stribeck_velocity": (0.02, 0.1, "rad/s", "uniform"),
    },
    "position_dependent_reflex_delay": {
        "delay_increase": (0.015, 0.040, "s", "uniform"),  # delay at +0.2 rad minus at -0.4 rad
        "step_position": (-0.25, 0.05, "rad", "uniform"),
    },
    "position_dependent_reflex_dynamics": {
        "wn_ratio": (1.7, 3.0, "1", "uniform"),  # wn at +0.2 rad over wn at -0.4 rad
        "step_position": (-0.25, 0.05, "rad", "uniform"),
    },
}

#: The recorded-value choices drawn with equal probability.
CHOICES = {
    "stiffness_form": STIFFNESS_FORMS,
    "design": tuple(PERTURBATIONS),  # pralds, lab_pulses, prbs
    "emg_form": EMG_FORMS,
    "emg_unit": ("V", "mV"),
    "noise_order": (1, 2),
    "activation_time_course": ("bursts", "drift"),
    "activation_shared": (False, True),
}

_SALT = 0x504F50  # the population's own stream: seed N's subject does not reuse simulate_pair's streams


@dataclass(frozen=True)
class PopulationSubject:
    """One drawn virtual subject: what :func:`simulate_subject` needs, JSON-serialisable.

    ``params``: the physics (:class:`lpvpc.simulation.subject.SubjectParams`); ``stiffness_form``
    (:data:`STIFFNESS_FORMS`); ``effect`` (a key of :data:`POPULATION_EFFECTS` or None),
    its ``form`` and ``effect_params``; ``design`` (perturbation, :data:`lpvpc.simulation.trajectories.PERTURBATIONS`)
    and ``perturbation_amplitude`` (rad); ``snr_db`` (dB of the perturbation torque);
    ``emg_unit``; ``draws``: every value drawn from :data:`RANGES` / :data:`EFFECT_RANGES`
    by its name (effect parameters as "effect.name"); ``seed`` also seeds the simulation's
    random streams (trajectory, perturbation, noise).

    >>> s = draw_subject(2)
    >>> 0.01 <= s.params.inertia <= 0.03, s.effect, s.draws["inertia"] == s.params.inertia
    (True, None, True)
    """

    seed: int
    params: SubjectParams
    stiffness_form: str
    design: str
    perturbation_amplitude: float
    snr_db: float
    emg_unit: str
    effect: str | None = None
    form: str | None = None
    effect_params: dict = field(default_factory=dict)
    draws: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain JSON-serialisable dictionary (tuples as lists)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["params"] = self.params.to_dict()
        return json.loads(json.dumps(d))

    @classmethod
    def from_dict(cls, d: dict) -> "PopulationSubject":
        """The subject of :meth:`to_dict`'s dictionary."""
        d = dict(d)
        p = dict(d.pop("params"))
        for k, v in p.items():  # JSON lists back to the tuples SubjectParams holds
            if isinstance(v, list):
                p[k] = tuple(v)
        return cls(params=SubjectParams(**p), **d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    def effects(self) -> tuple:
        """The effect as :func:`lpvpc.simulation.simulate.simulate_pair` takes it (empty when none)."""
        if self.effect is None:
            return ()
        apply = partial(_APPLY[self.effect], form=self.form, p=dict(self.effect_params))
        desc = f"{self.effect} ({self.form} form) of a population subject: {self.effect_params}"
        return (CustomEffect(self.effect, desc, apply),)


# ---------------------------------------------------------------------------------------
# Drawing
# ---------------------------------------------------------------------------------------


def _draw(rng, table, name, draws, prefix=""):
    lo, hi, _, how = table[name]
    v = float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) if how == "log" else float(rng.uniform(lo, hi))
    draws[prefix + name] = v
    return v


def _choice(rng, name, draws, given=None):
    options = CHOICES[name]
    if given is not None:
        if given not in options:
            raise ValueError(f"unknown {name} {given!r}; use one of {list(options)}")
        rng.integers(len(options))  # the stream advances the same whether given or drawn
        draws[name] = given
        return given
    v = options[int(rng.integers(len(options)))]
    draws[name] = v.item() if hasattr(v, "item") else v
    return draws[name]


def _stiffness(rng, form, draws, retry) -> dict:
    """SubjectParams fields of the elastic curve of ``form``; every range draw is made for
    every form (one stream whatever the form)."""
    d = {k: _draw(rng, RANGES, k, draws) for k in
         ("k_min", "k_df_end", "k_df_rate", "k_pf", "k_pf_rate", "k_min_position")}
    if form == "exponential":
        return {"stiffness_family": "standard", "k_base": d["k_min"], "k_df": d["k_df_end"] - d["k_min"],
                "k_df_rate": d["k_df_rate"], "k_pf": 0.0}
    if form == "two_exponentials":
        return {"stiffness_family": "standard", "k_base": d["k_min"], "k_df": d["k_df_end"] - d["k_min"],
                "k_df_rate": d["k_df_rate"], "k_pf": d["k_pf"], "k_pf_rate": d["k_pf_rate"]}
    # polynomial: K = k_min + a u^2 + b u^3, u = theta - theta_m, through K(+0.2) and K(-0.4) = k_min + k_pf;
    # a cubic that would fall below k_min / 2 within 0.1 rad beyond the range is redrawn (its
    # minimum's position and rise) from a stream of its own, so the draws after it do not move
    P = np.polynomial.polynomial
    wide = np.linspace(THETA_PF - 0.1, THETA_DF + 0.1, 161)
    for _ in range(1000):
        tm = d["k_min_position"]
        d1, d2 = THETA_DF - tm, THETA_PF - tm
        a, b = np.linalg.solve([[d1 ** 2, d1 ** 3], [d2 ** 2, d2 ** 3]], [d["k_df_end"] - d["k_min"], d["k_pf"]])
        coef = P.polyadd(P.polyadd([d["k_min"]], P.polypow([-tm, 1.0], 2) * a), P.polypow([-tm, 1.0], 3) * b)
        if P.polyval(wide, coef).min() >= 0.5 * d["k_min"]:
            break
        d["k_pf"], d["k_min_position"] = (_draw(retry, RANGES, k, draws) for k in ("k_pf", "k_min_position"))
    else:  # pragma: no cover (the ranges make this practically impossible)
        raise RuntimeError("no positive polynomial stiffness found")
    return {"stiffness_family": "polynomial", "k_poly": tuple(float(c) for c in coef)}


def draw_subject(seed: int, effect: str | None = None, form: str | None = None, *,
                 stiffness: str | None = None, design: str | None = None) -> PopulationSubject:
    """The virtual subject of ``seed`` (an int >= 0).

    ``effect``: None (a clean subject) or a key of :data:`POPULATION_EFFECTS`; ``form``: one of
    that effect's forms (None: drawn). ``stiffness`` (:data:`STIFFNESS_FORMS`) and ``design``
    (a perturbation name) fix those choices instead of drawing them. The subject's own
    parameters come from one stream and the effect's from another, so the same seed gives
    the same subject with or without an effect, and whatever is fixed.

    >>> s = draw_subject(8, stiffness="polynomial")
    >>> s.stiffness_form, s.params.stiffness_family
    ('polynomial', 'polynomial')
    >>> draw_subject(8).params == draw_subject(8, "reflex_habituation").params  # the effect draws on its own stream
    True
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"population seed must be an integer >= 0, got {seed!r}")
    if effect is not None and effect not in POPULATION_EFFECTS:
        raise ValueError(f"unknown population effect {effect!r}; use one of {list(POPULATION_EFFECTS)}")
    if form is not None:
        if effect is None:
            raise ValueError(f"form {form!r} given without an effect")
        if form not in POPULATION_EFFECTS[effect]:
            raise ValueError(f"unknown form {form!r} of {effect}; use one of {list(POPULATION_EFFECTS[effect])}")
    r_subject, r_effect, r_retry = (np.random.default_rng(s) for s in
                                    np.random.SeedSequence([int(seed), _SALT]).spawn(3))
    draws: dict = {}
    r = r_subject
    kform = _choice(r, "stiffness_form", draws, stiffness)
    elastic = _stiffness(r, kform, draws, r_retry)
    th_df = _draw(r, RANGES, "reflex_threshold_df", draws)
    th_pf = th_df + _draw(r, RANGES, "reflex_threshold_rise", draws)
    g_pf = _draw(r, RANGES, "reflex_gain_pf", draws)
    g_df = g_pf * _draw(r, RANGES, "reflex_gain_ratio", draws)
    emg_form = _choice(r, "emg_form", draws)
    offset = _draw(r, RANGES, "emg_offset", draws)
    params = SubjectParams(
        inertia=_draw(r, RANGES, "inertia", draws), viscosity=_draw(r, RANGES, "viscosity", draws),
        elastic_rest=_draw(r, RANGES, "elastic_rest", draws),
        reflex_delay=_draw(r, RANGES, "reflex_delay", draws), reflex_wn=_draw(r, RANGES, "reflex_wn", draws),
        reflex_zeta=_draw(r, RANGES, "reflex_zeta", draws),
        reflex_gain_pf=g_pf, reflex_gain_df=g_df, reflex_threshold_pf=th_pf, reflex_threshold_df=th_df,
        reflex_threshold_min=0.5 * th_df,
        noise_cutoff=_draw(r, RANGES, "noise_cutoff", draws), noise_order=int(_choice(r, "noise_order", draws)),
        emg_tonic=_draw(r, RANGES, "emg_tonic", draws), emg_reflex_torque=_draw(r, RANGES, "emg_reflex_torque", draws),
        emg_volts=_draw(r, RANGES, "emg_volts", draws), emg_noise=_draw(r, RANGES, "emg_noise", draws),
        emg_cutoff=_draw(r, RANGES, "emg_cutoff", draws), emg_form=emg_form,
        emg_offset=offset if emg_form == "envelope" else 0.0, **elastic)
    if emg_form != "envelope":
        draws["emg_offset"] = 0.0
    des = _choice(r, "design", draws, design)
    amp = _draw(r, RANGES, "perturbation_amplitude", draws)
    snr = _draw(r, RANGES, "snr_db", draws)
    unit = _choice(r, "emg_unit", draws)
    eff_params: dict = {}
    if effect is not None:
        forms = POPULATION_EFFECTS[effect]
        drawn_form = forms[int(r_effect.integers(len(forms)))]
        form = form or drawn_form
        table = EFFECT_RANGES[effect]
        eff_params = {k: _draw(r_effect, table, k, draws, prefix=effect + ".") for k in table}
        if effect == "background_activation":
            eff_params["time_course"] = _choice(r_effect, "activation_time_course", draws)
            eff_params["shared"] = bool(_choice(r_effect, "activation_shared", draws))
        if effect == "reflex_habituation":
            eff_params["seconds_reference"] = 120.0  # s: the linear form's end_fraction is reached here
    return PopulationSubject(seed=int(seed), params=params, stiffness_form=kform, design=des,
                             perturbation_amplitude=amp, snr_db=snr, emg_unit=unit, effect=effect, form=form,
                             effect_params=eff_params, draws=draws)


# ---------------------------------------------------------------------------------------
# The effects' forms (each modifies a TrialState, as lpvpc.simulation.simulated_effects' do)
# ---------------------------------------------------------------------------------------


def _s(theta):
    """0 at -0.4 rad, 1 at +0.2 rad, constant beyond."""
    return np.clip((np.asarray(theta, dtype=float) - THETA_PF) / (THETA_DF - THETA_PF), 0.0, 1.0)


def _position_profile(form, theta, p):
    """A position profile from 0 (at -0.4 rad) to 1 (at +0.2 rad): linear, exponential
    (convex: e^{3 s} rescaled) or a step at ``p['step_position']``, smoothed over 0.02 rad."""
    s = _s(theta)
    if form == "linear":
        return s
    if form == "exponential":
        return np.expm1(3.0 * s) / math.expm1(3.0)
    return 0.5 * (1.0 + np.tanh((np.asarray(theta, dtype=float) - p["step_position"]) / 0.01))


def _habituation(st: TrialState, form, p) -> dict:
    t = st.t
    if form == "linear":
        rate = (1.0 - p["end_fraction"]) / p["seconds_reference"]
        scale = np.maximum(1.0 - rate * t, 0.05)
        what = f"1 - {rate:.4g} t, floored at 0.05"
    elif form == "exponential":
        scale = p["floor"] + (1.0 - p["floor"]) * np.exp(-t / p["time_constant"])
        what = f"{p['floor']:.3g} + {1 - p['floor']:.3g} exp(-t / {p['time_constant']:.3g} s)"
    else:
        scale = np.where(t < p["step_time"], 1.0, p["step_level"])
        what = f"1 before {p['step_time']:.3g} s, {p['step_level']:.3g} after"
    st.reflex_gain_scale *= scale
    return {"form": form, "reflex_gain_scale": what, **p}


def _activation_signal(st: TrialState, p) -> np.ndarray:
    if p["shared"] and st.ut_activation is not None:
        return st.ut_activation.copy()
    if p["time_course"] == "drift":  # each trial its own start and end unless shared
        a0, a1 = (p["drift_start"], p["drift_end"]) if st.ut_activation is None or p["shared"] else \
            tuple(st.rng.uniform(*EFFECT_RANGES["background_activation"]["drift_start"][:2], size=2))
        return a0 + (a1 - a0) * st.t / max(st.t[-1], 1e-12)
    cutoff = p["burst_cutoff"]
    b, a = signal.butter(2, cutoff, fs=st.fs)
    lead = int(max(20.0, 1.0 / cutoff) * st.fs)
    x = signal.lfilter(b, a, st.rng.standard_normal(len(st.t) + lead))[lead:]
    x /= max(np.std(x), 1e-12)
    return 0.5 * (1.0 + np.tanh(x - 1.0))


def _activation(st: TrialState, form, p) -> dict:
    pr = st.params
    act = _activation_signal(st, p)
    ks = p["stiffness_gain"] if form in ("intrinsic", "both") else 0.0
    kr = p["reflex_gain"] if form in ("reflex", "both") else 0.0
    st.extra_torque += ks * act * (pr.elastic_torque(st.theta) - pr.elastic_torque(st.slow_theta)) + p["tonic_torque"] * act
    st.viscosity_scale *= 1.0 + ks * act
    st.reflex_gain_scale *= 1.0 + kr * act
    st.activation += act
    return {"form": form, "perturbation_stiffness_scale": f"1 + {ks:.3g} a", "viscosity_scale": f"1 + {ks:.3g} a",
            "reflex_gain_scale": f"1 + {kr:.3g} a", **p}


def _friction(st: TrialState, form, p) -> dict:
    v, fc, vc = st.vel, p["coulomb_torque"], p["velocity_scale"]
    if form == "coulomb":
        st.extra_torque += fc * np.tanh(v / vc)
        what = f"{fc:.3g} tanh(v / {vc:.3g})"
    else:
        fs_ = fc * p["breakaway_ratio"]
        st.extra_torque += np.tanh(v / vc) * (fc + (fs_ - fc) * np.exp(-(v / p["stribeck_velocity"]) ** 2))
        what = f"tanh(v / {vc:.3g}) ({fc:.3g} + {fs_ - fc:.3g} exp(-(v / {p['stribeck_velocity']:.3g})^2))"
    return {"form": form, "friction_torque": what, **p}


def _reflex_delay(st: TrialState, form, p) -> dict:
    d0 = st.params.reflex_delay
    st.reflex_delay = d0 + p["delay_increase"] * _position_profile(form, st.theta, p)
    return {"form": form, "delay_at_-0.4": d0, "delay_at_+0.2": d0 + p["delay_increase"], **p}


def _reflex_dynamics(st: TrialState, form, p) -> dict:
    wn, ratio = st.params.reflex_wn, p["wn_ratio"]
    lo, hi = wn / math.sqrt(ratio), wn * math.sqrt(ratio)
    if form == "exponential":  # geometric in position: wn = lo * ratio^s
        st.reflex_wn = lo * ratio ** _s(st.theta)
    else:
        st.reflex_wn = lo + (hi - lo) * _position_profile(form, st.theta, p)
    return {"form": form, "wn_at_-0.4": lo, "wn_at_+0.2": hi, **p}


_APPLY = {
    "reflex_habituation": _habituation,
    "background_activation": _activation,
    "nonlinear_viscosity": _friction,
    "position_dependent_reflex_delay": _reflex_delay,
    "position_dependent_reflex_dynamics": _reflex_dynamics,
}


# ---------------------------------------------------------------------------------------
# Simulating
# ---------------------------------------------------------------------------------------


def simulate_subject(subject: PopulationSubject, trajectory: str = "multilevel", *, duration: float = 120.0,
                     fs_out: float = 1000.0, snr_db: float | None = None, clean: bool = False,
                     position_noise: float = 0.0):
    """The subject's PT/UT pair (:class:`lpvpc.simulation.simulate.SimulatedPair`): exactly
    :func:`lpvpc.simulation.simulate.simulate_pair` with the subject's parameters, effect, design,
    perturbation amplitude, SNR (``snr_db`` overrides it; ``clean=True``: the effect left
    out, the same subject otherwise) and EMG unit, seeded by the subject's seed;
    ``position_noise``: the position sensor's noise floor (RMS, rad), none by default.
    ``trajectory``: "multilevel" (identification) or "novel" (held out).

    >>> s = draw_subject(4, effect="nonlinear_viscosity", form="coulomb")
    >>> pair = simulate_subject(s, duration=10.0, fs_out=100.0)
    >>> pair.truth["perturbation"] == s.design, pair.truth["effects"][0]["name"]
    (True, 'nonlinear_viscosity')
    """
    from .simulate import simulate_pair

    return simulate_pair(trajectory, seed=subject.seed, duration=duration, fs_out=fs_out,
                         snr_db=subject.snr_db if snr_db is None else snr_db,
                         perturbation_amplitude=subject.perturbation_amplitude, params=subject.params,
                         effects=() if clean else subject.effects(), emg_unit=subject.emg_unit,
                         perturbation=subject.design, position_noise=position_noise)


def write_subject(subject: PopulationSubject, out_dir, *, fs_out: float = 1000.0, duration: float = 120.0) -> dict:
    """Write the subject's identification and novel pairs as :func:`lpvpc.simulation.simulate.write_dataset`
    does (the same files), its description under "population_subject" in truth.json.
    Returns {stem: Path}.

    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     paths = write_subject(draw_subject(4), tmp, fs_out=100.0, duration=10.0)
    ...     saved = json.loads(paths["truth"].read_text())["population_subject"]
    >>> PopulationSubject.from_dict(saved) == draw_subject(4)
    True
    """
    from .simulate import write_dataset

    return write_dataset(Path(out_dir), seed=subject.seed, fs_out=fs_out, snr_db=subject.snr_db,
                         effects=subject.effects(), duration=duration, params=subject.params,
                         perturbation=subject.design, emg_unit=subject.emg_unit,
                         perturbation_amplitude=subject.perturbation_amplitude,
                         extra_truth={"population_subject": subject.to_dict()})
