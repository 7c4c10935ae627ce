"""The catalog of physical effects the base LPV-PC model lacks, and the extended model's terms.

Units: position and scheduling rad, velocities rad/s, time s, EMG normalised (1),
torque N m.

An *effect* is a physically named, linear-in-parameters term added to the LPV-PC torque.
Two forms cover the catalog, both written once with :mod:`lpvpc.models.equations` and an ``ops``
backend, so the numpy prediction, the identification regressors and the exported CasADi
step / FMU evaluate the same expressions:

* channel-scheduled IRF (intrinsic pathway): the IRF weights get further scheduling
  functions ``c(k) * G_i(rho(k))`` for each channel c (time, movement direction, EMG):

      tq_e(k) = sum_l  [c(k) G_i(rho(k))] . H_e[l]  pos(k - l)      (eq.intrinsic_torque)

  with its causal counterpart (lags 0..Lc plus velocity and acceleration) for the FMU,
  fitted like the base model's ``H_causal``;
* static features f(k) scheduled by a basis G_e(rho) (friction, tonic torque, rho-weighted
  reflex states):

      tq_e(k) = sum_ij Theta_e[i, j] f_i(k) G_e(rho(k))_j               (eq.scheduled_term)

Signals an effect may need: the extra input channels of :data:`SIGNALS` (they become
extra inputs of the model's ``predict``, of the CasADi step and of the FMU) and derived
signals computed inside the model: the perturbation ``velocity``, the slow-movement
``direction`` memory (:func:`lpvpc.models.equations.direction_memory_step`, two states) and the
reflex pathway's states ``x``, drive ``z`` and a second cascade ``w`` (m states) that
rho-weighted copies of the reflex dynamics need, and ``reflex_shift``: the model's reflex
torque re-run at neighbouring delays (m states per delay step, more position history).

Joint estimation: intrinsic-pathway effects are extra columns of the intrinsic
regressor (appended to Psi_i), so MOESP, the pole refinement, the projection (27)-(28) and
the separable least squares all see them: the extended model is a real refit, not a
residual patch. Reflex-pathway effects need the reflex drive z, known only after the
separable least squares; they are then estimated jointly with the intrinsic part (all
intrinsic coefficients re-solved) with the identified reflex held.

Settings candidates (:data:`SETTINGS`) are not terms: they name an estimator setting that
is probably wrong (reflex delay, IRF length, basis orders) and the variants to try.

Adding an effect to the catalog: write one :class:`Effect` (name, pathway, one-sentence
explanation, the signals it needs and a ``channels`` and/or ``features`` function of a
:class:`Context`) and add it to :data:`CATALOG`. Example (the drift entry)::

    Effect("drift", "intrinsic", "Stiffness changes during the trial ...",
           signals=("trial_time",), channels=lambda c, o: [c.trial_time * (1 / 60.0)])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import equations as eq
from .basis import NUMPY, Basis
from ..errors import DataError

# --------------------------------------------------------------------------- signals

#: Extra input channels an effect may need: name -> (unit, meaning).
SIGNALS = {
    "trial_time": ("s", "time since the start of the trial"),
    "scheduling_velocity": ("rad/s", "velocity of the slow (unperturbed) movement, d rho / dt"),
    "emg": ("1", "EMG envelope of the perturbed trial as recorded (tonic activation AND reflex bursts)"),
    "emg_ut": ("1", "tonic activation of the unperturbed reference trial: its EMG envelope treated as "
                    "the perturbed trial's (background_emg: the bursts of the slow movement's fast "
                    "transitions taken off, low-passed)"),
    "activation": ("1", "background activation of the perturbed trial: its EMG envelope with the reflex "
                        "bursts (explained by lagged stretch velocity) taken off, low-passed "
                        "(background_emg)"),
}
#: Order of the extra inputs in the CasADi step and the FMU.
SIGNAL_ORDER = tuple(SIGNALS)

DRIFT_TIME_SCALE = 60.0  # s: drift channel is time in minutes
FRICTION_SCALES = (0.01, 0.03, 0.1)  # rad/s: velocity scales of the smoothed friction sign
DIRECTION_V_MIN = 0.05  # rad/s: slower movement does not change the remembered direction
DIRECTION_V_WIDTH = 0.01  # rad/s: width of the ramp replacing the jumps of the latch
DIRECTION_TAU = 0.2  # s: time constant with which stiffness follows the direction
#: s: time constants of the stress-relaxation memory when nothing chose them (the diagnosis's
#: candidate, structure="fixed"); identify's cross-validation chooses a record's own
#: (``lpvpc.identification.selection.RELAXATION_VARIANTS``) and the fitted effect stores them
#: (options "relaxation_times_s"), which its prediction, CasADi step and FMU then use.
RELAXATION_TIMES = (0.3, 1.0, 3.0)
QUIET_AFTER_STEP = 0.15  # s: a reflex burst ends this long after the perturbation stops moving
ACTIVATION_CUTOFF = (0.5, 3.0)  # Hz: range of the background activation estimate's low-pass (activation_cutoff)
BURST_MAX_LAG = 0.15  # s: the EMG's reflex-evoked part is explained by the stretch velocity 0..this long ago
BURST_HINGES = (0.0, 0.25, 0.5, 1.0)  #: rad/s: thresholds of the hinge functions of velocity that model the reflex drive
# s: resolution in time of the bursts' slowly varying gain: short enough to follow a reflex gain
# that swings within a trial (docs/design_notes.md, "Background activation from EMG").
BURST_GAIN_S = 15.0
BURST_TONIC_S = 5.0  #: s: resolution in time of the tonic level fitted next to the bursts
MIN_BURST_CORRELATION = 0.2  # reflex_latency: a block's EMG-drive peak correlation below this is noise
#: s: delay changes about the model's delay at which the position-dependent reflex delay
#: entry re-runs the model's reflex (-20..+30 ms: a delay of 20-70 ms around the default 40)
REFLEX_DELAY_STEPS = (-0.02, -0.01, 0.01, 0.02, 0.03)


class Context:
    """Signals available to effect terms at a sample (CasADi) or over a record (numpy
    (N, 1) columns). Attributes: ``rho``, ``position`` and ``velocity`` (perturbation, rad,
    rad/s), the extra
    inputs of :data:`SIGNALS` that were given, ``direction`` (slow-movement memory, -1..1),
    ``relaxation`` (list: the perturbation position's exponential averages over the
    relaxation times, :func:`relaxation_times`, rad),
    ``x`` (list of m reflex states), ``z`` (reflex drive), ``w`` (list of m second-cascade
    states), ``reflex_shift`` ({delay step j in samples: the model's reflex torque with the
    delay d + j minus that with the delay d})."""

    def __init__(self, **signals):
        self.__dict__.update(signals)

    def has(self, name) -> bool:
        return getattr(self, name, None) is not None


# --------------------------------------------------------------------------- catalog


@dataclass(frozen=True)
class Effect:
    """A catalog entry.

    ``channels(ctx, ops)`` returns the channels that schedule an extra intrinsic IRF;
    ``features(ctx, ops, options)`` returns static features scheduled by a rho basis of
    order ``feature_order``. ``signals`` are required inputs, ``optional_signals`` are
    used when the data have them (recorded in the fitted effect's options), ``derived``
    names derived signals ("direction", "reflex").
    """

    name: str
    pathway: str
    explanation: str
    signals: tuple = ()
    optional_signals: tuple = ()
    derived: tuple = ()
    channels: Callable | None = None
    features: Callable | None = None
    feature_order: int = 0
    feature_names: Callable | None = None
    channel_order: int | None = None  # rho basis order of the channel-scheduled IRF (None: the intrinsic one)
    feature_constant: bool = True  # False: the features' rho basis without its constant function
    kind: str = "effect"
    subject: str | None = None  # name of the virtual-subject counterpart in lpvpc.simulation.simulate.EFFECTS (None: same name)
    # An intrinsic term that may also be fitted only in the final joint solve, with the
    # identified reflex held (as the reflex-pathway terms are): slow columns in the subspace
    # step's intrinsic regressor can take the reflex's own slow response from it.
    # Identification fits both ways and keeps the better in-sample fit.
    after_reflex: bool = False
    # A reflex term expanded about the reflex poles: the poles and the nonlinearity are refitted
    # jointly with its weights before the final solve (:func:`_refit_reflex_poles`,
    # :func:`_refit_reflex_drive`), not held at the base fit's (made under LTI dynamics).
    refit_poles: bool = False

    @property
    def uses_reflex(self) -> bool:
        return "reflex" in self.derived


def _background_features(c, ops, options):
    out = [c.activation]
    if options.get("emg_ut"):
        out.append(c.emg_ut)
    return out


def _reflex_dynamics_features(c, ops, options):
    """Reflex states x and cascade states w minus their steady-state values for the drive z
    (kappa = (I - A)^-1 B, w_ss = kappa C kappa z): every combination has zero static gain,
    so these terms change the reflex dynamics, not its gain (the gain's position
    dependence belongs to the reflex nonlinearity and its basis order). The states x give
    the numerator, the cascade w (double poles) the first-order change of the poles."""
    kappa, ck = options["kappa"], options["c_kappa"]
    return ([c.x[i] - kappa[i] * c.z for i in range(len(kappa))]
            + [c.w[i] - (kappa[i] * ck) * c.z for i in range(len(kappa))])


def _reflex_output_features(c):
    """The reflex pathway's output in linear-in-parameters form: its states and drive."""
    return list(c.x) + [c.z]


def _habituation_features(c, ops, options):
    """Reflex states and drive times time (min) and time squared: a reflex gain that changes
    smoothly over the trial (z is slow next to time, so gain x LP(z) = LP(gain x z))."""
    tm = c.trial_time * (1.0 / DRIFT_TIME_SCALE)
    base = _reflex_output_features(c)
    return [f * tm for f in base] + [f * (tm * tm) for f in base]


def _activation_reflex_features(c, ops, options):
    """Reflex states and drive times the background activation."""
    return [f * c.activation for f in _reflex_output_features(c)]


def reflex_delay_steps(delay, fs) -> list:
    """Delay changes (samples, nonzero) of :data:`REFLEX_DELAY_STEPS` at ``fs`` about the
    model's delay ``delay`` (samples), keeping the shifted delay >= 1 sample (causal).

    >>> reflex_delay_steps(4, 100.0)  # 40 ms at 100 Hz: 20-70 ms
    [-2, -1, 1, 2, 3]
    """
    out = []
    for s in REFLEX_DELAY_STEPS:
        j = int(round(s * fs))
        if j != 0 and delay + j >= 1 and j not in out:
            out.append(j)
    return out


def model_reflex_delay_steps(model) -> list:
    """Delay steps (samples) at which a fitted model's effects re-run its reflex (the union of
    their ``steps`` options; empty for a model without such an effect)."""
    return sorted({j for fe in getattr(model, "effects", None) or () if "reflex_delays" in fe.effect.derived
                   for j in fe.options["steps"]})


def _reflex_delay_features(c, ops, options):
    """The model's reflex torque re-run with the delay d + j, minus the torque at d, for the
    steps j of ``options['steps']``: weighted by functions of position, their combination
    is the reflex torque at a position-dependent (fractional: interpolated between the
    integer steps) delay d(rho) = d + sum_j j w_j(rho)."""
    return [c.reflex_shift[j] for j in options["steps"]]


def _amplitude_features(c, ops, options):
    """p |p| and p^3 of the perturbation position p (rad): the elastic torque of a stiffness
    that changes with the size of the displacement (first even and odd correction terms)."""
    p = c.position
    return [p * ops.fmax(p, -p), p * p * p]


#: The effects a model may carry, by name. Each entry names its pathway, the signals its
#: regressor reads (``signals``, ``derived``) and its term (``channels``: an IRF scheduled by
#: those signals; ``features``: static or reflex-state features). Its virtual-subject
#: counterpart is the entry of the same name in :data:`lpvpc.simulation.simulated_effects.EFFECTS`
#: (``subject``).
CATALOG: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "drift", "intrinsic",
            "Joint stiffness changes slowly during the trial (fatigue, habituation, thixotropy): "
            "the intrinsic impulse response drifts with the time since the trial started.",
            signals=("trial_time",),
            channels=lambda c, o: [c.trial_time * (1.0 / DRIFT_TIME_SCALE)],
            # A drift is fitted from the rest of the trial and extrapolated to its ends: the
            # full-order rho basis (6 x the IRF lags) overfits there. Order 2 found it on 5
            # of 5 seeds of the virtual subject (full order 4 of 5), without false alarms.
            channel_order=2,
        ),
        Effect(
            "nonlinear_viscosity", "intrinsic",
            "Part of the joint's damping is friction-like (Coulomb friction of tissue and "
            "joint surfaces): a torque that saturates with the undelayed joint velocity "
            "instead of growing in proportion to it.",
            signals=("scheduling_velocity",),
            features=lambda c, o, opt: [eq.friction_difference(c.velocity, c.scheduling_velocity, s, o)
                                        for s in FRICTION_SCALES],
            feature_order=1,
            feature_names=lambda opt: [f"tanh friction, scale {s:g} rad/s" for s in FRICTION_SCALES],
        ),
        Effect(
            "direction_dependent_stiffness", "intrinsic",
            "Stiffness depends on the direction of the last slow movement (torque-angle "
            "hysteresis, muscle thixotropy): the joint is stiffer after moving one way than "
            "after moving the other way to the same position.",
            signals=("scheduling_velocity",),
            derived=("direction",),
            channels=lambda c, o: [c.direction],
            # On a multilevel trajectory the direction of arrival is partly tied to the level
            # (the extreme levels are always reached from one side); a full-order rho basis
            # then confounds direction with position and extrapolates badly to new
            # trajectories. Order 2 was the best of 1, 2, 3 and 5 on the virtual subject.
            channel_order=2,
        ),
        Effect(
            "stress_relaxation", "intrinsic",
            "Part of the elastic torque relaxes after a displacement (viscoelastic stress relaxation "
            "of muscle, tendon and joint tissue, time constants of 0.3-3 s): the torque depends on "
            "the position's recent history, which the impulse response (tens of ms) cannot hold.",
            derived=("relaxation",),
            features=lambda c, o, opt: list(c.relaxation),
            # Order 1: the relaxing stiffness may change with position like K does, in a line;
            # the lab's stationary trials (one position each) need order 0 only.
            feature_order=1,
            feature_names=lambda opt: [f"position averaged over {t:g} s" for t in relaxation_times(opt)],
            # Joined in the subspace step, the 3-s average took the slow part of the reflex
            # response on a lab stationary trial (z_pf: fit VAF 86.5 -> 86.2 % with it, 87.0
            # with the reflex held); on the virtual subject joining it there predicts better.
            after_reflex=True,
        ),
        Effect(
            "background_activation", "intrinsic",
            "Background muscle activation (the EMG between reflex bursts) adds short-range stiffness and "
            "tonic torque: the activation is a further scheduling variable of the intrinsic "
            "impulse response.",
            signals=("activation",),
            optional_signals=("emg_ut",),
            channels=lambda c, o: [c.activation],
            features=_background_features,
            feature_order=0,
            feature_names=lambda opt: ["tonic torque (activation)"] + (["tonic torque (emg_ut)"] if opt.get("emg_ut") else []),
        ),
        Effect(
            "activation_reflex_gain", "reflex",
            "Background muscle activation (the EMG between reflex bursts) raises the reflex gain "
            "(motoneuron excitability): the reflex torque is scaled by the activation.",
            signals=("activation",),
            derived=("reflex",),
            features=_activation_reflex_features,
            feature_order=0,
            feature_names=lambda opt: [f"reflex state x{i} * activation" for i in range(opt["m"])] + ["reflex drive z * activation"],
        ),
        Effect(
            "reflex_habituation", "reflex",
            "The reflex gain changes during the trial (habituation, fatigue of the reflex loop): the "
            "reflex torque is scaled by a smooth function of the time since the trial started.",
            signals=("trial_time",),
            derived=("reflex",),
            features=_habituation_features,
            feature_order=0,
            feature_names=lambda opt: [f"{n} * t{k}" for k in ("", "^2")
                                       for n in [f"reflex state x{i}" for i in range(opt["m"])] + ["reflex drive z"]],
        ),
        Effect(
            "amplitude_dependent_stiffness", "intrinsic",
            "Stiffness depends on the size of the perturbation (short-range stiffness of muscle and "
            "tissue falls with amplitude): the elastic torque is not linear in the displacement.",
            features=_amplitude_features,
            feature_order=3,
            feature_names=lambda opt: ["p |p|", "p^3"],
        ),
        Effect(
            "position_dependent_reflex_dynamics", "reflex",
            "The reflex loop's linear dynamics (muscle activation and contraction speed) "
            "change with joint position: the reflex states and their second cascade, minus their "
            "steady state, are weighted by functions of position (the static gain is unchanged).",
            derived=("reflex",),
            features=_reflex_dynamics_features,
            # Order 3: the states' weights are a first-order expansion about the model's poles,
            # so a wide change needs more shape in position (docs/design_notes.md, "Diagnosis
            # catalog").
            feature_order=3,
            # Without the constant: only the change WITH position, so that a model whose
            # (position-independent) reflex dynamics are merely off is not taken for this effect.
            feature_constant=False,
            refit_poles=True,
            feature_names=lambda opt: ([f"reflex state x{i} - steady state" for i in range(opt["m"])]
                                       + [f"reflex cascade w{i} - steady state" for i in range(opt["m"])]),
        ),
        Effect(
            "position_dependent_reflex_delay", "reflex",
            "The reflex loop delay changes with joint position (e.g. a longer-latency reflex "
            "component taking over as the muscle is stretched): the reflex torque is the model's "
            "reflex re-run at neighbouring delays, weighted by functions of position (a delay "
            "interpolated between whole samples; gain and dynamics unchanged).",
            derived=("reflex", "reflex_delays"),
            features=_reflex_delay_features,
            feature_order=2,
            # Without the constant, as the dynamics entry: only the change WITH position (a
            # delay that is merely off everywhere is the reflex_delay setting's); with it, the
            # dynamics entry's truth was taken for a delay (docs/design_notes.md, "Diagnosis catalog").
            feature_constant=False,
            feature_names=lambda opt: [f"reflex torque at delay {j:+d} samples - at the model's delay"
                                       for j in opt["steps"]],
        ),
    )
}


@dataclass(frozen=True)
class Setting:
    """A settings candidate: an estimator setting that may be wrong, with the variants to
    try (``variants(settings, fs)`` -> list of dicts of changed settings)."""

    name: str
    pathway: str
    explanation: str
    variants: Callable
    kind: str = "setting"
    signals: tuple = ()


def _delay_variants(s, fs):
    d0 = int(round(s["reflex_delay"] * fs))
    lo, hi = max(1, int(round(0.020 * fs)), s["irf_lags"]), int(round(0.080 * fs))
    return [{"reflex_delay": d / fs} for d in range(lo, hi + 1) if d != d0]


def _irf_variants(s, fs):
    d = int(round(s["reflex_delay"] * fs))
    return [{"irf_lags": L} for L in range(s["irf_lags"] + 1, min(s["irf_lags"] + 3, d) + 1)]


#: The estimator's settings the diagnosis may change, by name, each with the variants it tries.
SETTINGS: dict[str, Setting] = {
    c.name: c
    for c in (
        Setting("reflex_delay", "reflex",
                "The reflex loop delay differs from the assumed one: the delayed velocity that "
                "drives the reflex is taken at the wrong time.",
                _delay_variants),
        Setting("irf_length", "intrinsic",
                "The intrinsic impulse response is longer than the IRF lags allow (tissue "
                "viscoelasticity, actuator or sensor dynamics).",
                _irf_variants),
        Setting("intrinsic_basis_order", "intrinsic",
                "Stiffness varies with position more sharply than the intrinsic basis order "
                "can follow.",
                lambda s, fs: [{"intrinsic_order": s["intrinsic_order"] + k} for k in (1, 2)]),
        Setting("reflex_basis_order", "reflex",
                "The reflex nonlinearity (gain, threshold, their position dependence) is "
                "sharper than its basis orders can follow.",
                lambda s, fs: [{"reflex_order": s["reflex_order"] + 2},
                               {"velocity_order": s["velocity_order"] + 2}]),
    )
}


def describe(name) -> str:
    """The one-sentence explanation of a catalog effect or settings candidate."""
    entry = CATALOG.get(name) or SETTINGS.get(name)
    if entry is None:
        raise KeyError(name)
    return entry.explanation


def check_effects(effects) -> tuple:
    """Effect names as a tuple; raises ValueError naming unknown ones."""
    if isinstance(effects, str):
        effects = (effects,)
    effects = tuple(effects or ())
    unknown = [e for e in effects if e not in CATALOG]
    if unknown:
        hint = [e for e in unknown if e in SETTINGS]
        extra = (f" ({', '.join(hint)} is an estimator setting, not an effect: change the setting instead)"
                 if hint else "")
        raise ValueError(f"unknown effect(s) {unknown}; known: {sorted(CATALOG)}{extra}")
    if len(set(effects)) != len(effects):
        raise ValueError(f"effect listed twice: {list(effects)}")
    return effects


# --------------------------------------------------------------------------- fitted terms


@dataclass
class FittedEffect:
    """An identified effect term of an extended model.

    ``H``: (n_lags, n_channels * n_i) two-sided IRF coefficients of the channel-scheduled
    IRF (N m/rad per channel unit), ``H_causal``: (Lc + 3, n_channels * n_i) its causal
    form; ``Theta``: (n_features, n_b) static coefficients for ``basis`` (a Basis in rho);
    ``options``: what the term was built with (e.g. whether ``emg_ut`` was used, m).
    """

    name: str
    H: np.ndarray | None = None
    H_causal: np.ndarray | None = None
    Theta: np.ndarray | None = None
    basis: Basis | None = None
    options: dict = field(default_factory=dict)
    channel_basis: Basis | None = None  # rho basis of the channel-scheduled IRF (None: the intrinsic basis)

    @property
    def effect(self) -> Effect:
        return CATALOG[self.name]

    def __repr__(self):
        return f"FittedEffect({self.name!r}, {self.effect.pathway} pathway, signals: {', '.join(self.signals) or 'none'})"

    @property
    def signals(self) -> tuple:
        e = self.effect
        return tuple(e.signals) + tuple(s for s in e.optional_signals if self.options.get(s))

    def to_dict(self) -> dict:
        d = {"name": self.name, "options": self.options}
        for key in ("H", "H_causal", "Theta"):
            a = getattr(self, key)
            if a is not None:
                d[key] = np.asarray(a).tolist()
        if self.basis is not None:
            d["basis"] = self.basis.to_dict()
        if self.channel_basis is not None:
            d["channel_basis"] = self.channel_basis.to_dict()
        return d

    @classmethod
    def from_dict(cls, d) -> "FittedEffect":
        if d["name"] not in CATALOG:
            raise ValueError(f"unknown effect {d['name']!r}")
        arr = {k: (np.array(d[k], dtype=float) if k in d else None) for k in ("H", "H_causal", "Theta")}
        return cls(name=d["name"], basis=Basis.from_dict(d["basis"]) if "basis" in d else None,
                   options=dict(d.get("options", {})),
                   channel_basis=Basis.from_dict(d["channel_basis"]) if "channel_basis" in d else None, **arr)

    def coefficient_blocks(self, variant) -> list:
        """(name, array) of the coefficients the export variant uses."""
        out = []
        H = self.H_causal if variant == "causal" else self.H
        if H is not None:
            out.append((f"{self.name}_{'H_causal' if variant == 'causal' else 'H'}", np.atleast_2d(H)))
        if self.Theta is not None:
            out.append((f"{self.name}_Theta", np.atleast_2d(self.Theta)))
        return out


def model_signals(model) -> tuple:
    """Extra input signals an (extended) model needs, in :data:`SIGNAL_ORDER`."""
    need = {s for fe in getattr(model, "effects", ()) for s in fe.signals}
    return tuple(s for s in SIGNAL_ORDER if s in need)


def model_derived(model) -> set:
    return {d for fe in getattr(model, "effects", ()) for d in fe.effect.derived}


def effect_term(fe: FittedEffect, ctx: Context, position_signals, rho_basis, variant, ops=NUMPY, coef=None):
    """Torque of one fitted effect (N m) from a context; the one definition used by numpy
    prediction and the CasADi step. ``position_signals``: lagged positions (two-sided) or
    causal signals, matching ``variant`` ("exact"/"two_sided" or "causal"); ``rho_basis``:
    the intrinsic basis at rho. ``coef``: {"H": ..., "Theta": ...} replacing the fitted
    values (symbolic parameters of the exported step)."""
    e = fe.effect
    coef = coef or {}
    tq = 0.0
    if e.channels is not None:
        H = coef.get("H", fe.H_causal if variant == "causal" else fe.H)
        G = rho_basis if fe.channel_basis is None else fe.channel_basis.evaluate(ctx.rho, ops)
        sched = ops.hcat([c * G for c in e.channels(ctx, ops)])
        tq = tq + eq.intrinsic_torque(position_signals, sched, H, ops)
    if e.features is not None:
        F = ops.hcat(e.features(ctx, ops, fe.options))
        G = fe.basis.evaluate(ctx.rho, ops)
        tq = tq + eq.scheduled_term(F, G if e.feature_constant else G[:, 1:], coef.get("Theta", fe.Theta), ops)
    return tq


# --------------------------------------------------------------------------- numpy records


def default_signals(scheduling, fs, signals=None) -> dict:
    """Signals with the derivable defaults filled in: ``trial_time`` = k / fs and
    ``scheduling_velocity`` = numpy.gradient(rho) * fs (as :func:`lpvpc.io.pair_trials`)."""
    n = len(scheduling)
    out = {k: np.asarray(v, dtype=float) for k, v in (signals or {}).items() if v is not None}
    out.setdefault("trial_time", np.arange(n) / fs)
    out.setdefault("scheduling_velocity", np.gradient(np.asarray(scheduling, dtype=float)) * fs if n > 1 else np.zeros(n))
    return out


def signals_from_data(data, model=None) -> dict:
    """Extra signals of :class:`lpvpc.io.PerturbationData` under the names of
    :data:`SIGNALS` (trial_time from its time column, starting at 0). The background
    activation (``activation``, and ``emg_ut`` from the unperturbed trial's EMG) is
    :func:`background_emg` of the EMG: its reflex-evoked part explained by ``model``'s reflex
    drive when a model is given (``_emg_reflex_drives``), else by the measured velocity;
    estimates stored in the data (:func:`with_model_activation`) are used as they are."""
    extra = getattr(data, "extra", {}) or {}
    out = {}
    if "time" in extra:
        t = np.asarray(extra["time"], dtype=float)
        out["trial_time"] = t - t[0]
    if "ut_velocity" in extra:
        out["scheduling_velocity"] = np.asarray(extra["ut_velocity"], dtype=float)
    for k in ("emg", "emg_ut"):
        if k in extra:
            out[k] = np.asarray(extra[k], dtype=float)
    drives = _emg_reflex_drives(model, data) if model is not None and not _has_backgrounds(extra) else None
    if "emg" in out:
        out["activation"] = (np.asarray(extra["emg_background"], dtype=float) if "emg_background" in extra else
                             background_emg(out["emg"], data.position, data.fs, scheduling=data.scheduling,
                                            drive=None if drives is None else drives[0]))
    if "emg_ut" in out:  # the second, independent estimate of tonic activation: the same treatment
        out["emg_ut"] = (np.asarray(extra["emg_ut_background"], dtype=float) if "emg_ut_background" in extra else
                         background_emg(out["emg_ut"], np.zeros(len(out["emg_ut"])), data.fs,
                                        scheduling=data.scheduling, drive=None if drives is None else drives[1]))
    return default_signals(data.scheduling, data.fs, out)


def _has_backgrounds(extra) -> bool:
    return "emg_background" in extra or "emg_ut_background" in extra


def _emg_reflex_drives(model, data):
    """The model's own reflex drive for each trial's EMG (:func:`background_emg`'s ``drive``):
    the nonlinearity's output (delayed, before the reflex dynamics, as the EMG is recorded)
    on the perturbation's velocity (PT) and on the slow movement's (UT: all it has). Not on
    the PT's whole joint velocity: the nonlinearity is identified on perturbation
    velocities, and extrapolated to the slow movement's it put slow-velocity content into
    the PT estimate (a reflex gain modulated by the slow velocity, outside the catalog, was
    then named activation_reflex_gain, +0.74 pp); the price is that the few bursts the slow
    movement fires in the PT stay in its estimate. None when the model has no reflex pathway."""
    if model is None or getattr(model, "Omega", None) is None:
        return None
    p, rho = (np.asarray(x, dtype=float) for x in (data.position, data.scheduling))
    return (np.asarray(model.reflex_drive(p, rho), dtype=float),
            np.asarray(model.reflex_drive(rho, rho), dtype=float))


def with_model_activation(data, model):
    """``data`` with its background-activation estimates computed once with ``model``'s reflex
    drive (extra ``emg_background``, ``emg_ut_background``; :func:`signals_from_data` then
    uses them), so every fit and evaluation of the data sees the same estimate (the
    estimator's refits read the data's signals without the model). Unchanged without EMG,
    without a reflex pathway, or when the estimates are there already.

    Why the model's drive: the lagged hinges of measured velocity (~400 columns) also fit part
    of the slow activation itself, the model's drive (16 lags) does not (docs/design_notes.md,
    "Background activation from EMG").

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)  # both trials' EMG in data.extra
    >>> stored = with_model_activation(data, identify(data))
    >>> sorted(set(stored.extra) - set(data.extra))
    ['emg_background', 'emg_ut_background']
    >>> bool(np.all(signals_from_data(stored)["activation"] == stored.extra["emg_background"]))
    True
    """
    import dataclasses

    extra = getattr(data, "extra", None) or {}
    if ("emg" not in extra and "emg_ut" not in extra) or _has_backgrounds(extra):
        return data
    drives = _emg_reflex_drives(model, data)
    if drives is None:
        return data
    sig = signals_from_data(data, model)
    new = dict(extra)
    if "emg" in extra:
        new["emg_background"] = sig["activation"]
    if "emg_ut" in extra:
        new["emg_ut_background"] = sig["emg_ut"]
    return dataclasses.replace(data, extra=new)


def reads_activation(effects) -> bool:
    """Whether any of the catalog effects ``effects`` reads a background-activation estimate.

    >>> reads_activation(("background_activation",)), reads_activation(("stress_relaxation",))
    (True, False)
    """
    wanted = {"activation", "emg_ut"}
    return any(wanted & (set(CATALOG[n].signals) | set(CATALOG[n].optional_signals)) for n in effects if n in CATALOG)


def quiet_mask(position, fs, after=QUIET_AFTER_STEP) -> np.ndarray:
    """True where no perturbation movement happened in the last ``after`` s: samples whose
    EMG holds no reflex-evoked burst (the burst comes ~40 ms after a velocity pulse and
    lasts as long as the pulse, plus the envelope's smoothing). Moving: |velocity| above
    10 % of its 99th percentile (at least 0.02 rad/s)."""
    v = np.abs(eq.velocity(np.asarray(position, dtype=float), fs))
    moving = v > max(0.1 * np.percentile(v, 99), 0.02) if len(v) else v > 0
    k = max(1, int(round(after * fs)))
    # samples since the last moving one
    idx = np.arange(len(v))
    last = np.maximum.accumulate(np.where(moving, idx, -10 * k))
    return idx - last > k


def _slow_time_basis(n, fs, resolution):
    """(n, K) cosine basis in time, 1, cos(pi k t / T) for k < T / ``resolution``: any
    function of trial time that changes over ``resolution`` s or more."""
    t = np.arange(n) / fs
    T = max(n / fs, 1e-9)
    k = np.arange(max(1, int(round(T / resolution))) + 1)
    return np.cos(np.pi * np.outer(t, k) / T)


def _gain_time_basis(n, fs, resolution):
    """(n, K + 2) Legendre polynomials of trial time, degrees 0..K + 1 for K = T / ``resolution``:
    a gain that changes over ``resolution`` s or more, including an exponential decay from
    the record's start. The cosines of ``_slow_time_basis`` have zero slope at both ends and
    leave a habituating reflex's early bursts in the tonic estimate (docs/design_notes.md,
    "Background activation from EMG")."""
    T = max(n / fs, 1e-9)
    k = max(1, int(round(T / resolution))) + 1
    return np.polynomial.legendre.legvander(2.0 * np.arange(n) / max(n - 1, 1) - 1.0, k)


def fast_drive(drive, fs, window_s=1.0) -> np.ndarray:
    """The reflex drive's bursts: ``drive`` less its ``window_s`` moving average, rectified.

    A burst lasts tens of ms; what the drive does over seconds the EMG cannot tell from
    tonic activation, so only its fast part explains bursts and its slow part is left to
    the tonic estimate. On the slow movement of a held-out record the model's drive can be
    mostly slow, and fitted whole it takes the unperturbed trial's activation
    (docs/design_notes.md, "Background activation from EMG").

    >>> slow = np.linspace(0.0, 1.0, 300)  # a ramp over 3 s at 100 Hz: no burst
    >>> burst = slow.copy(); burst[150:153] += 2.0  # a 30-ms burst on it
    >>> float(fast_drive(slow, 100.0)[100:200].max()) < 0.01, float(fast_drive(burst, 100.0)[151]) > 1.9
    (True, True)
    """
    drive = np.asarray(drive, dtype=float)
    w = max(1, int(round(window_s * fs)))
    if len(drive) <= w:
        return drive
    return np.maximum(drive - np.convolve(drive, np.ones(w) / w, mode="same"), 0.0)


def reflex_evoked_emg(emg, position, fs, *, scheduling=None, max_lag=BURST_MAX_LAG,
                      gain_s=BURST_GAIN_S, drive=None) -> np.ndarray:
    """The reflex-evoked part of a perturbed trial's EMG envelope (same unit as ``emg``).

    The reflex drive is a half-wave rectified velocity of the stretch (at 100 Hz its
    threshold is not sharp), so the bursts are explained by lagged copies of hinges
    max(+-v - c, 0), c in :data:`BURST_HINGES` (v: the joint velocity, rad/s, of ``position`` plus
    ``scheduling`` when given: the slow movement's transitions fire the reflex too;
    either sign is the stretch, whatever the convention), lags 0..``max_lag`` s, the stretching side scaled
    by a quadratic in the scheduling position (the reflex gain's position dependence).
    Their gain may change slowly (habituation, activation): a second least-squares fit
    scales the burst by a function of trial time resolved to ``gain_s`` s (identified by
    the bursts' fast part: their local mean rises with the tonic level whenever
    activation raises both), next to a tonic level resolved to :data:`BURST_TONIC_S` s. Returns gain(t) * burst(t); zero where nothing
    explains the EMG. Costs two least-squares fits (~400 and ~30 columns).

    >>> fs = 100.0
    >>> rng = np.random.default_rng(0)
    >>> p = np.repeat(rng.uniform(-0.04, 0.04, 400), 30)  # PRALDS-like, rad
    >>> v = np.maximum(np.gradient(p) * fs, 0.0)
    >>> burst = 0.02 * np.r_[np.zeros(4), v[:-4]]  # 40 ms after each stretch
    >>> tonic = 0.1 + 0.05 * np.sin(np.arange(p.size) / fs / 10)
    >>> got = reflex_evoked_emg(tonic + burst, p, fs)
    >>> bool(np.sqrt(np.mean((got - burst) ** 2)) < 0.05 * np.sqrt(np.mean(burst ** 2)))
    True
    """
    emg = np.asarray(emg, dtype=float)
    n = len(emg)
    if drive is not None and not np.any(drive):  # no reflex drive: nothing evoked
        return np.zeros(n)
    step = max(1, int(round(0.01 * fs)))  # one lag per 10 ms: ~16 lags at any rate

    def per_lag(x):  # each lag stands for the mean of its 10 ms
        return np.convolve(x, np.ones(step) / step, mode="full")[:n] if step > 1 else x

    lags = list(range(0, int(round(max_lag * fs)) + 1, step))
    T = _slow_time_basis(n, fs, BURST_TONIC_S)  # the tonic level
    Tg = _gain_time_basis(n, fs, gain_s)  # the bursts' gain
    if drive is not None:  # the model's own reflex drive: delayed, rectified, position-gained already
        hinges, R = [per_lag(fast_drive(drive, fs))], np.ones((n, 1))
    else:
        # the reflex sees the joint's whole velocity: the slow movement's fast transitions fire it too
        joint = np.asarray(position, dtype=float) + (0.0 if scheduling is None else np.asarray(scheduling, dtype=float))
        v = per_lag(eq.velocity(joint, fs))
        if scheduling is None:
            R = np.ones((n, 1))
        else:
            rho = np.asarray(scheduling, dtype=float)
            lo, hi = float(np.min(rho)), float(np.max(rho))
            r = (2 * rho - lo - hi) / (hi - lo) if hi > lo else np.zeros(n)
            R = np.column_stack([np.ones(n), r, r * r])
        # hinges max(+-v - c, 0): a rectifier with a threshold anywhere in BURST_HINGES is their sum
        hinges = [np.maximum(sign * v - c, 0.0) for sign in (1.0, -1.0) for c in BURST_HINGES]

    def drive_columns(a, b):  # rows a..b-1 of the lagged, position-scaled hinges
        cols = [eq.lagged_rows(h, lags, a, b)[:, :, None] * R[a:b, None, :] for h in hinges]
        return np.concatenate(cols, axis=1).reshape(b - a, -1)

    # normal equations in chunks of rows: ~400 columns stay small at 1 kHz too
    nt = T.shape[1]
    G, g = 0.0, 0.0
    chunk = 20000
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        X = np.hstack([T[a:b], drive_columns(a, b)])
        G, g = G + X.T @ X, g + X.T @ emg[a:b]
    G = G + 1e-9 * np.trace(G) / len(G) * np.eye(len(G))  # unexcited hinges: keep the solve defined
    beta = np.linalg.solve(G, g)
    burst = np.concatenate([drive_columns(a, min(n, a + chunk)) @ beta[nt:] for a in range(0, n, chunk)])
    if not np.any(burst):
        return np.zeros(n)
    # gain changing slowly over the trial: emg ~ tonic(t) + gain(t) * burst, the gain told
    # by the bursts' fast part only (their local mean rises with the tonic level whenever
    # activation raises both: it would take the tonic change for a gain change)
    w = max(1, int(round(1.0 * fs)))
    fast = burst - np.convolve(burst, np.ones(w) / w, mode="same")
    X2 = np.hstack([T, Tg * fast[:, None]])
    beta2 = np.linalg.lstsq(X2, emg, rcond=None)[0]
    return (Tg @ beta2[nt:]) * burst


def activation_cutoff(x, fs, *, limits=ACTIVATION_CUTOFF, ratio=10.0) -> float:
    """Low-pass cut-off (Hz) for a background activation estimate ``x`` (an EMG envelope
    with its reflex bursts taken off): 1.5 x the highest frequency below 5 Hz whose power
    stands ``ratio`` times above the envelope's noise floor (the median power at 3-10
    Hz), within ``limits``. A slow activation gets a low cut-off (less noise), one that
    changes within seconds a higher one (a fixed 1 Hz took a third of a 0.5-Hz
    activation's variance away: 17 % error against 11 % at 2 Hz).

    >>> fs = 100.0
    >>> t = np.arange(12000) / fs
    >>> noise = 0.01 * np.random.default_rng(0).standard_normal(t.size)
    >>> activation_cutoff(1 + noise, fs)  # nothing above the floor: the lowest cut-off
    0.5
    >>> c = activation_cutoff(1 + 0.3 * np.sin(2 * np.pi * 1.2 * t) + noise, fs)  # Hz
    >>> bool(1.5 * 1.2 <= c < 1.5 * 1.4)
    True
    """
    import scipy.signal

    x = np.asarray(x, dtype=float)
    if fs <= 20.0 or len(x) < 20 * fs:  # too short or too slow a record to tell: the middle of the range
        return float(np.clip(1.0, *limits))
    f, P = scipy.signal.welch(x - x.mean(), fs, nperseg=int(20 * fs))
    floor = np.median(P[(f >= 3.0) & (f <= 10.0)])
    above = f[(f <= 5.0) & (P > ratio * floor)]
    return float(np.clip(1.5 * above.max() if above.size else 0.0, *limits))


def background_emg(emg, position, fs, *, cutoff=None, scheduling=None, drive=None) -> np.ndarray:
    """Background activation from the perturbed trial's EMG envelope (same unit as ``emg``).

    Leak-free under any perturbation design: the reflex-evoked part is taken off
    (:func:`reflex_evoked_emg`: the bursts explained by lagged stretch velocity with a
    slowly varying gain) and what is left is low-passed (zero-phase, ``cutoff`` Hz;
    None: :func:`activation_cutoff`). Every sample is used, not only the quiet windows
    before perturbation steps (:func:`quiet_mask`): on the virtual subject the quiet
    windows alone gave a noisier estimate (10 % against 7 % error, PRALDS) and a PRBS
    has almost none. The diagnosis still checks whether the model's reflex drive
    explains the estimate before using it."""
    import scipy.signal

    emg = np.asarray(emg, dtype=float)
    n = len(emg)
    if n <= 30:
        return emg.copy()
    x = emg - reflex_evoked_emg(emg, position, fs, scheduling=scheduling, drive=drive)
    cutoff = activation_cutoff(x, fs) if cutoff is None else cutoff
    if cutoff < fs / 2:
        b, a = scipy.signal.butter(2, cutoff, fs=fs)
        x = scipy.signal.filtfilt(b, a, x, padlen=min(n - 1, 3 * int(fs / cutoff)))
    return x


def reflex_latency(emg, drive, scheduling, fs, *, block_s=2.0, max_latency=0.15, mask=None) -> dict | None:
    """Latency (s) of the EMG's reflex-evoked bursts and how it changes with position.

    ``drive``: the reflex's input without delay (e.g. the model's nonlinearity on the
    undelayed velocity). In each ``block_s`` block the demeaned EMG is cross-correlated
    with the demeaned drive at lags 0..``max_latency``; the peak (parabola through its
    neighbours) is that block's latency. The latencies are regressed on the blocks' mean
    scheduling value (ordinary least squares; blocks are nearly independent). The EMG is
    recorded before the muscle's activation and contraction dynamics, so its latency
    moves with the reflex delay but not with the reflex's dynamics. Blocks without drive
    or with samples left out (``mask`` False) are skipped, and so are blocks whose peak is at
    either end of the lags or correlates less than MIN_BURST_CORRELATION (the reflex
    hardly fires there: the peak is noise). Returns None with fewer than 5
    blocks, else {"slope" (s/rad), "p_value" (two-sided, slope = 0), "latency_lo",
    "latency_hi" (s, fitted at the 5th and 95th percentile of the blocks' positions),
    "position_lo", "position_hi" (rad), "blocks"}.

    >>> fs, rng = 100.0, np.random.default_rng(0)
    >>> rho = np.repeat(np.linspace(-0.3, 0.1, 20), 400)  # rad, slow position levels
    >>> drive = (rng.random(rho.size) < 0.05).astype(float)  # reflex input pulses
    >>> lag = np.round((0.03 + 0.125 * (rho + 0.3)) * fs).astype(int)  # 30 ms -> 80 ms
    >>> emg = drive[np.clip(np.arange(rho.size) - lag, 0, None)] + 0.01 * rng.standard_normal(rho.size)
    >>> r = reflex_latency(emg, drive, rho, fs)
    >>> round(1000 * r["latency_lo"]), round(1000 * r["latency_hi"]), r["p_value"] < 0.05
    (33, 77, True)
    """
    import scipy.stats

    emg, drive, rho = (np.asarray(x, dtype=float) for x in (emg, drive, scheduling))
    b, L = int(round(block_s * fs)), int(round(max_latency * fs))
    lat, pos = [], []
    for i in range(len(emg) // b):
        sl = slice(i * b, (i + 1) * b)
        if mask is not None and not np.all(mask[sl]):
            continue
        e, z = emg[sl] - emg[sl].mean(), drive[sl] - drive[sl].mean()
        if z @ z <= 0 or b <= L + 2:
            continue
        c = np.array([e[k:] @ z[:b - k] for k in range(L + 1)])
        k = int(np.argmax(c))
        curv = c[k - 1] - 2 * c[k] + c[k + 1] if 0 < k < L else 0.0
        if curv >= 0 or c[k] < MIN_BURST_CORRELATION * np.sqrt((e @ e) * (z @ z)):
            continue  # no burst peak inside the lags (a block where the reflex hardly fires)
        dk = 0.5 * (c[k - 1] - c[k + 1]) / curv
        lat.append((k + dk) / fs)
        pos.append(rho[sl].mean())
    if len(lat) < 5 or np.ptp(pos) <= 0:
        return None
    fit = scipy.stats.linregress(pos, lat)
    lo, hi = np.percentile(pos, [5, 95])
    p = float(fit.pvalue) if np.isfinite(fit.pvalue) else (0.0 if fit.slope != 0 else 1.0)
    return {"slope": float(fit.slope), "p_value": p, "latency_lo": float(fit.intercept + fit.slope * lo),
            "latency_hi": float(fit.intercept + fit.slope * hi), "position_lo": float(lo), "position_hi": float(hi),
            "blocks": len(lat)}


def check_signals(signals: dict, needed, n: int, source="data"):
    problems = []
    for name in needed:
        if name not in signals:
            problems.append(f"channel '{name}' ({SIGNALS[name][1]}, {SIGNALS[name][0]}) is missing: the model's effects need it")
            continue
        x = np.asarray(signals[name])
        if x.shape != (n,):
            problems.append(f"channel '{name}': expected {n} samples, got shape {x.shape}")
        elif not np.all(np.isfinite(x)):
            bad = ~np.isfinite(x)
            problems.append(f"channel {name}: {int(bad.sum())} non-finite values, first at index {int(np.argmax(bad))}")
    if problems:
        raise DataError(problems, source=source)


def shifted_reflex_torques(model, position, scheduling, steps) -> dict:
    """{j: the model's reflex torque (N m) with its delay d + j samples, minus that with d}
    over a record: the same nonlinearity (at rho(k)) and linear dynamics, the velocity
    taken j samples later (j > 0) or earlier."""
    p, rho = np.asarray(position, dtype=float), np.asarray(scheduling, dtype=float)
    C = np.asarray(model.C, dtype=float)

    def torque(d):
        z = model.reflex_drive(p, rho, delay=d)
        return eq.state_trajectory(model.A, model.B, z) @ C + float(model.D) * z

    t0 = torque(int(model.delay))
    return {j: torque(int(model.delay) + j) - t0 for j in steps}


def relaxation_times(options=None) -> tuple:
    """Time constants (s) of a stress-relaxation term: those its options store (a fitted
    effect's, chosen per record), else :data:`RELAXATION_TIMES` (files from before the choice).

    >>> relaxation_times({"relaxation_times_s": [0.6]}), relaxation_times()
    ((0.6,), (0.3, 1.0, 3.0))
    """
    times = (options or {}).get("relaxation_times_s")
    return tuple(float(t) for t in times) if times else RELAXATION_TIMES


def model_relaxation_times(model) -> tuple:
    """The relaxation times of a model's stress_relaxation term (:func:`relaxation_times`).

    >>> import types
    >>> fe = FittedEffect("stress_relaxation", options={"relaxation_times_s": [0.45]})
    >>> model_relaxation_times(types.SimpleNamespace(effects=[fe]))  # s: chosen for its record
    (0.45,)
    """
    fe = next((f for f in getattr(model, "effects", None) or () if "relaxation" in f.effect.derived), None)
    return relaxation_times(fe.options if fe is not None else None)


def record_context(position, scheduling, fs, signals, *, velocity=None, derived=(), reflex=None,
                   reflex_shift=None, relaxation=RELAXATION_TIMES) -> Context:
    """numpy Context for a record: (N, 1) columns. ``reflex`` = (A, B, C, z) when the
    reflex-derived signals are needed, ``reflex_shift`` ({j: array}, from
    :func:`shifted_reflex_torques`) when the shifted-delay ones are; ``relaxation``: the
    averaging times (s) of the relaxation memory."""
    col = lambda a: np.asarray(a, dtype=float).reshape(-1, 1)  # noqa: E731
    vel = eq.velocity(position, fs) if velocity is None else velocity
    ctx = {"rho": col(scheduling), "velocity": col(vel), "position": col(position)}
    for k, v in signals.items():
        ctx[k] = col(v)
    if "direction" in derived:
        ctx["direction"] = col(eq.direction_memory(signals["scheduling_velocity"], DIRECTION_V_MIN,
                                                   DIRECTION_V_WIDTH, direction_alpha(fs)))
    if "relaxation" in derived:
        ctx["relaxation"] = [col(eq.relaxation_memory(position, smoothing_alpha(tau, fs))) for tau in relaxation]
    if "reflex" in derived:
        A, B, C, z = reflex
        X = eq.state_trajectory(A, B, z)
        W = eq.state_trajectory(A, B, X @ np.asarray(C, dtype=float))
        ctx["x"] = [X[:, [i]] for i in range(X.shape[1])]
        ctx["z"] = col(z)
        ctx["w"] = [W[:, [i]] for i in range(W.shape[1])]
    if reflex_shift is not None:
        ctx["reflex_shift"] = {j: col(v) for j, v in reflex_shift.items()}
    return Context(**ctx)


def smoothing_alpha(tau, fs) -> float:
    """Factor of a first-order exponential average with time constant ``tau`` (s) at ``fs``
    (Hz): the direction memory's and the stress-relaxation averages'.

    >>> round(smoothing_alpha(1.0, 100.0), 5)  # 1 s at 100 Hz: 1 % of the gap per sample
    0.00995
    """
    return 1.0 - math.exp(-1.0 / (tau * fs))


def direction_alpha(fs) -> float:
    return smoothing_alpha(DIRECTION_TAU, fs)


def predict_effects(model, position, scheduling, signals=None, *, causal=False, velocity=None,
                    acceleration=None, z=None) -> dict:
    """Torques (N m) of the model's effect terms over a record: {name: (pathway, torque)}."""
    if not model.effects:
        return {}
    n = len(position)
    sig = default_signals(scheduling, model.fs, signals)
    check_signals(sig, model_signals(model), n)
    derived = model_derived(model)
    reflex = None
    if "reflex" in derived:
        if z is None:
            z = model.reflex_drive(position, scheduling)
        reflex = (model.A, model.B, model.C, z)
    shift = None
    if "reflex_delays" in derived:
        shift = shifted_reflex_torques(model, position, scheduling, model_reflex_delay_steps(model))
    if causal:  # the causal form's inputs as replayed into the FMU: the model's stencil unless given
        v_est, a_est = eq.derivatives(position, model.fs, model.causal_derivatives)
        velocity = v_est if velocity is None else velocity
        acceleration = a_est if acceleration is None else acceleration
    ctx = record_context(position, scheduling, model.fs, sig, velocity=velocity, derived=derived, reflex=reflex,
                         reflex_shift=shift, relaxation=model_relaxation_times(model))
    lags = model.causal_lags if causal else model.lags
    Gi = model.intrinsic_basis.evaluate(scheduling)
    out = {fe.name: (fe.effect.pathway, np.zeros(n)) for fe in model.effects}
    for a, b in eq.blocks(n, len(lags) + 2):  # bounded memory for any record length
        S = eq.position_signals(position, model.fs, lags, a, b, causal=causal, vel=velocity, acc=acceleration)
        rows = Context(**{k: ([u[a:b] for u in v] if isinstance(v, list) else
                              {j: u[a:b] for j, u in v.items()} if isinstance(v, dict) else v[a:b])
                          for k, v in vars(ctx).items()})
        for fe in model.effects:
            tq = effect_term(fe, rows, S, Gi[a:b], "causal" if causal else "two_sided")
            out[fe.name][1][a:b] = np.asarray(tq, dtype=float).reshape(-1)
    return out


# --------------------------------------------------------------------------- regressors


def effect_columns(effect: Effect, options: dict, ctx: Context, position, lags, Gi_val, basis: Basis | None):
    """Regressor columns of one effect over a record: (irf_columns or None, static or None).

    IRF columns are ordered ``l * n_s + j`` (H.ravel()), static ones ``i * n_b + j``
    (Theta.ravel()), so the coefficients reshape directly."""
    irf = static = None
    if effect.channels is not None:
        sched = np.column_stack([c * Gi_val for c in effect.channels(ctx, NUMPY)])
        irf = eq.kron_rows(eq.lagged(position, lags), sched)
    if effect.features is not None:
        F = np.column_stack(effect.features(ctx, NUMPY, options))
        G = basis.evaluate(ctx.rho[:, 0])
        static = eq.kron_rows(F, G if effect.feature_constant else G[:, 1:])
    return irf, static


def effect_options(effect: Effect, signals: dict, model_like=None, relaxation=RELAXATION_TIMES) -> dict:
    opts = {s: True for s in effect.optional_signals if s in signals}
    if "relaxation" in effect.derived:  # saved with the model: its Theta rows are per time constant
        opts["relaxation_times_s"] = [float(t) for t in relaxation]
    if effect.uses_reflex and model_like is not None:
        A = np.atleast_2d(np.asarray(model_like.A, dtype=float))
        kappa = np.linalg.solve(np.eye(A.shape[0]) - A, np.asarray(model_like.B, dtype=float))
        opts.update(m=int(A.shape[0]), kappa=[float(k) for k in kappa],
                    c_kappa=float(np.asarray(model_like.C, dtype=float) @ kappa))
        if "reflex_delays" in effect.derived:
            opts["steps"] = reflex_delay_steps(int(model_like.delay), float(model_like.fs))
    return opts


def channel_basis(effect: Effect, rho_basis: Basis) -> Basis | None:
    """The rho basis of an effect's channel-scheduled IRF: None (the intrinsic basis
    itself) unless the effect asks for a lower order."""
    if effect.channels is None or effect.channel_order is None or effect.channel_order >= rho_basis.order:
        return None
    return Basis(family=rho_basis.family, order=effect.channel_order, lo=rho_basis.lo, hi=rho_basis.hi)


def effect_basis(effect: Effect, rho_basis: Basis, order: int | None = None) -> Basis | None:
    """The rho basis of an effect's static features (same family and range as the
    intrinsic basis, the effect's own order unless ``order`` is given; order 0 with an
    order-0 intrinsic basis: a stationary trial, one operating position, cannot determine
    their position dependence)."""
    if effect.features is None:
        return None
    family = rho_basis.family
    order = 0 if rho_basis.order == 0 else (effect.feature_order if order is None else int(order))
    return Basis(family=family, order=order, lo=rho_basis.lo, hi=rho_basis.hi)


def causal_irf(position, fs, causal_lags, sched_values, two_sided_torque, stencil="central3"):
    """Causal IRF coefficients (Lc + 3, n_s) fitted to a two-sided IRF torque (as the
    base model's H_causal; ``stencil`` of the velocity and acceleration as the model's)."""
    S_c = eq.causal_signals(position, fs, causal_lags, stencil=stencil)
    Psi_c = eq.kron_rows(S_c, sched_values)
    return np.linalg.lstsq(Psi_c, two_sided_torque, rcond=None)[0].reshape(S_c.shape[1], sched_values.shape[1])


class EffectDesign:
    """Regressor columns of a list of effects on one record, and the bookkeeping that turns
    estimated coefficients into :class:`FittedEffect` terms.

    ``lags`` and ``intrinsic_basis`` are the model's; ``signals`` the extra channels
    (:func:`signals_from_data`); ``relaxation``: (averaging times in s, position-weight
    order or None for the catalog's) of a stress-relaxation term. Intrinsic-pathway columns
    are built at once (``columns``, ``blocks``); reflex-pathway ones need an identified model
    (:meth:`reflex_columns`). ``late``: effects marked ``after_reflex`` go to the final
    joint solve (``late_columns``) instead of the intrinsic columns.
    """

    def __init__(self, effects, position, scheduling, fs, lags, intrinsic_basis: Basis, signals: dict,
                 *, source="data", late=False, relaxation=(RELAXATION_TIMES, None)):
        self.names = check_effects(effects)
        self.position = np.asarray(position, dtype=float)
        self.scheduling = np.asarray(scheduling, dtype=float)
        self.fs = float(fs)
        self.lags = list(lags)
        self.intrinsic_basis = intrinsic_basis
        self.signals = default_signals(self.scheduling, self.fs, signals)
        self.effects = [CATALOG[n] for n in self.names]
        needed = sorted({s for e in self.effects for s in e.signals})
        check_signals(self.signals, needed, len(self.position), source)
        self.Gi_val = intrinsic_basis.evaluate(self.scheduling)
        self.intrinsic_effects = [e for e in self.effects if not e.uses_reflex and not (late and e.after_reflex)]
        self.late_effects = [e for e in self.effects if not e.uses_reflex and late and e.after_reflex]
        self.reflex_effects = [e for e in self.effects if e.uses_reflex]
        derived = {d for e in self.intrinsic_effects + self.late_effects for d in e.derived}
        times, order = relaxation  # the stress-relaxation term's averaging times (s) and position-weight order
        self._ctx = record_context(self.position, self.scheduling, self.fs, self.signals, derived=derived,
                                   relaxation=times)
        self.options = {e.name: effect_options(e, self.signals, relaxation=times)
                        for e in self.intrinsic_effects + self.late_effects}
        self.bases = {e.name: effect_basis(e, intrinsic_basis, order if "relaxation" in e.derived else None)
                      for e in self.effects}
        self.channel_bases = {e.name: channel_basis(e, intrinsic_basis) for e in self.effects}
        self.channel_values = {n: (self.Gi_val if b is None else b.evaluate(self.scheduling))
                               for n, b in self.channel_bases.items()}
        # (effect name, "irf"|"static", n columns): the subspace step's intrinsic columns, and
        # the late ones (after_reflex) of the final joint solve
        self.columns, self.blocks = self._intrinsic_columns(self.intrinsic_effects)
        self.late_columns, self.late_blocks = self._intrinsic_columns(self.late_effects)

    def _intrinsic_columns(self, effects):
        blocks, cols = [], []
        for e in effects:
            irf, static = effect_columns(e, self.options[e.name], self._ctx, self.position, self.lags,
                                         self.channel_values[e.name], self.bases[e.name])
            for kind, c in (("irf", irf), ("static", static)):
                if c is not None:
                    blocks.append((e.name, kind, c.shape[1]))
                    cols.append(c)
        return (np.hstack(cols) if cols else np.zeros((len(self.position), 0))), blocks

    def reflex_columns(self, model, z=None):
        """Columns of the reflex-pathway effects given an identified (base) model (and its
        drive ``z`` over the record, when already computed)."""
        if not self.reflex_effects:
            return np.zeros((len(self.position), 0)), []
        if z is None:
            z = model.reflex_drive(self.position, self.scheduling)
        for e in self.reflex_effects:
            self.options[e.name] = effect_options(e, self.signals, model)
        steps = sorted({j for e in self.reflex_effects for j in self.options[e.name].get("steps", ())})
        shift = shifted_reflex_torques(model, self.position, self.scheduling, steps) if steps else None
        ctx = record_context(self.position, self.scheduling, self.fs, self.signals, derived=("reflex",),
                             reflex=(model.A, model.B, model.C, z), reflex_shift=shift)
        cols, blocks = [], []
        for e in self.reflex_effects:
            _, static = effect_columns(e, self.options[e.name], ctx, self.position, self.lags, self.Gi_val,
                                       self.bases[e.name])
            cols.append(static)
            blocks.append((e.name, "static", static.shape[1]))
        return np.hstack(cols), blocks

    def fitted(self, theta, blocks, causal_lags, stencil="central3") -> list:
        """FittedEffect terms from the coefficients of ``blocks`` (in column order)."""
        out, offset = {}, 0
        for name, kind, width in blocks:
            coef = np.asarray(theta[offset: offset + width], dtype=float)
            offset += width
            e = CATALOG[name]
            fe = out.setdefault(name, FittedEffect(name=name, basis=self.bases[name], options=dict(self.options[name]),
                                                   channel_basis=self.channel_bases[name]))
            if kind == "irf":
                H = coef.reshape(len(self.lags), -1)
                fe.H = H
                sched = np.column_stack([c * self.channel_values[name] for c in e.channels(self._ctx, NUMPY)])
                two_sided = eq.intrinsic_torque(eq.lagged(self.position, self.lags), sched, H)
                fe.H_causal = causal_irf(self.position, self.fs, causal_lags, sched, two_sided, stencil)
            else:
                fe.Theta = coef.reshape(-1, self.bases[name].size - (0 if e.feature_constant else 1))
        return [out[n] for n in self.names if n in out]


#: Bounds (c, 1/c) of the base reflex's rescaling in an extended fit with reflex effects.
MIN_REFLEX_RESCALE = 0.05
# For effects marked refit_poles: refit the reflex poles, the nonlinearity (False: hold the
# base fit's; bench_reflex_dynamics_range compares). One round of each: a second hardly
# changes the held-out VAF (docs/design_notes.md, "Extended fits").
REFIT_POLES = True
REFIT_DRIVE = True


def _reflex_solve_rss(design: EffectDesign, model, fixed, y):
    """Residual sum of squares of the final joint solve of :func:`finish_extended_fit` (the
    intrinsic columns ``fixed``, the reflex effects' columns and the model's reflex torque)
    and the reflex torque's coefficient."""
    X_r, _ = design.reflex_columns(model)
    tq_r = model.predict(design.position, design.scheduling, warn=False).reflex
    X = np.hstack([fixed, X_r, tq_r[:, None]])
    scale = np.sqrt(np.mean(X**2, axis=0))
    scale[scale == 0] = 1.0
    theta = np.linalg.lstsq(X / scale, y, rcond=None)[0]
    r = y - (X / scale) @ theta
    return float(r @ r), float(theta[-1] / scale[-1])


def _refit_reflex_drive(design: EffectDesign, model, fixed, y, max_iter=20, tol=1e-5) -> dict:
    """Refit the reflex nonlinearity (Omega) jointly with the reflex effects' weights, by
    alternating least squares: the reflex torque is linear in the drive z = U_r Omega for
    given dynamics and effect weights, and linear in the weights for given z. The base fit's
    Omega was fitted under LTI dynamics; held, it keeps that bias."""
    import copy

    from ..linalg import orthonormal_range

    U = model.reflex_input(design.position, design.scheduling)
    Q0 = orthonormal_range(fixed)
    y_perp = y - Q0 @ (Q0.T @ y)
    perp = lambda X: X - Q0 @ (Q0.T @ X)  # noqa: E731
    C, D = np.asarray(model.C, dtype=float), float(model.D)
    shape = np.shape(model.Omega)
    omega = np.asarray(model.Omega, dtype=float).ravel()
    unit = copy.copy(model)
    # the reflex effects' columns and the base reflex torque are linear in the drive: those of
    # each column of U, once (n_U x (features + 1) columns)
    F = []
    for k in range(U.shape[1]):
        unit.Omega = np.eye(1, U.shape[1], k).reshape(shape)  # (the delay entry re-runs the drive itself)
        X_k, _ = design.reflex_columns(unit, U[:, k])
        F.append(perp(np.column_stack([X_k, eq.state_trajectory(model.A, model.B, U[:, k]) @ C + D * U[:, k]])))
    F = np.stack(F, axis=2)  # (N, features + 1, n_U)
    rss_prev, history = np.inf, []
    for _ in range(max_iter):
        X = F @ omega  # (N, features + 1)
        theta = np.linalg.lstsq(X, y_perp, rcond=None)[0]
        r = y_perp - X @ theta
        rss = float(r @ r)
        history.append(rss)
        if rss_prev - rss < tol * rss:
            break
        rss_prev = rss
        T = np.einsum("nfk,f->nk", F, theta)  # the reflex torque of each column of U, these weights
        new = np.linalg.lstsq(T, y_perp, rcond=None)[0]
        omega = new * (np.linalg.norm(omega) / max(np.linalg.norm(new), 1e-300))
    model.Omega = omega.reshape(shape)
    return {"rss": history}


def _refit_reflex_poles(design: EffectDesign, model, fixed, y, max_radius=None) -> dict:
    """Refit the reflex poles jointly with the weights of the reflex effects (variable
    projection: for each denominator the least squares of ``y`` on ``fixed`` (the intrinsic
    columns), the reflex effects' columns and the base reflex torque; Nelder-Mead over the
    denominator's m coefficients). The base fit's poles are the best LTI dynamics; an
    expansion about them (position_dependent_reflex_dynamics) needs poles whose neighbourhood
    the dynamics over the whole range stay in. The numerator is kept; A, B, C are set on
    ``model`` in observable canonical form. Returns {"den0", "den", "rss0", "rss"}."""
    import copy

    import scipy.optimize
    import scipy.signal

    from ..linalg import orthonormal_range
    from .equations import STABLE_POLE_RADIUS, companion_form

    max_radius = STABLE_POLE_RADIUS if max_radius is None else max_radius
    num, den = scipy.signal.ss2tf(np.atleast_2d(np.asarray(model.A, dtype=float)), np.asarray(model.B, dtype=float).reshape(-1, 1),
                                  np.asarray(model.C, dtype=float).reshape(1, -1), np.zeros((1, 1)))
    b, den0 = num[0][1:], den[1:]  # observable canonical form: B holds the numerator's coefficients
    Q0 = orthonormal_range(fixed)
    y_perp = y - Q0 @ (Q0.T @ y)
    z = model.reflex_drive(design.position, design.scheduling)
    trial = copy.copy(model)

    def canonical(a):  # (A, C) as the model stores them
        A, C = companion_form(a)
        return A, C.ravel()

    def rss(a):
        if np.max(np.abs(np.roots(np.r_[1.0, a]))) >= max_radius:
            return np.inf
        trial.A, trial.C = canonical(a)
        trial.B = b
        X_r, _ = design.reflex_columns(trial, z)
        tq_r = eq.state_trajectory(trial.A, b, z) @ trial.C + float(model.D) * z
        X = np.column_stack([X_r, tq_r])
        X = X - Q0 @ (Q0.T @ X)
        X /= np.maximum(np.sqrt(np.einsum("ij,ij->j", X, X)), 1e-300)
        R = np.linalg.qr(np.column_stack([X, y_perp]), mode="r")  # the residual norm is R's last entry
        return float(R[-1, -1] ** 2)

    rss0 = rss(den0)
    res = scipy.optimize.minimize(rss, den0, method="Nelder-Mead",
                                  options={"xatol": 1e-6, "fatol": 1e-7 * rss0, "maxfev": 400})
    out = {"den0": den0.tolist(), "den": den0.tolist(), "rss0": rss0, "rss": rss0}
    if res.fun < rss0:
        model.A, model.C = canonical(res.x)
        model.B = b
        out.update(den=res.x.tolist(), rss=float(res.fun))
    return out


def finish_extended_fit(design: EffectDesign, model, theta_effects, Psi_i_base, y, Psi_irf=None):
    """Complete an extended fit: attach the intrinsic-pathway effects estimated with the
    base model (``theta_effects``, the effect part of the projection's solution), then,
    if there are reflex-pathway or late (``after_reflex``) effects, re-solve the intrinsic
    part and every effect jointly with the identified reflex held. Updates ``model``
    (H, H_causal, curvature, effects) in place. ``Psi_i_base``: the base model's intrinsic
    columns (with the elastic curvature tied in, if the model has it), ``Psi_irf`` the IRF's
    alone (default: the same). Sets ``design.extension`` = (columns, coefficients) of the
    effects as the final fit has them (the intervals' full regression: lpvpc.models.uncertainty)."""
    effects = design.fitted(theta_effects, design.blocks, model.causal_lags, model.causal_derivatives)
    design.extension = (design.columns, np.asarray(theta_effects, dtype=float))
    if design.reflex_effects or design.late_effects:
        model.effects = []
        if (REFIT_POLES or REFIT_DRIVE) and any(e.refit_poles for e in design.reflex_effects):
            fixed = np.hstack([Psi_i_base, design.columns, design.late_columns])
            tau = (model.settings or {}).get("max_reflex_time_constant")  # identify's bound on the poles
            radius = math.exp(-1.0 / (tau * model.fs)) if tau else 0.999
            held = {k: getattr(model, k) for k in ("A", "B", "C", "Omega")}
            rss_held, _ = _reflex_solve_rss(design, model, fixed, y)
            # poles and nonlinearity, else the nonlinearity alone: with many reflex effects the
            # pole search can reach a slow mode (the 1-s bound) that takes the trial's slow
            # torque, the base reflex's scale going to 0.002 (tests/test_effects.py's record
            # with every effect: its fit rose 94.8 -> 96.1 %, held-out physiology lost)
            for poles in (REFIT_POLES, False):
                if poles:
                    _refit_reflex_poles(design, model, fixed, y, max_radius=radius)
                if REFIT_DRIVE and model.high_rate is None:
                    _refit_reflex_drive(design, model, fixed, y)
                rss, c = _reflex_solve_rss(design, model, fixed, y)
                # kept only when the final solve below fits better with it and a base reflex is left
                if rss < rss_held and MIN_REFLEX_RESCALE < c < 1.0 / MIN_REFLEX_RESCALE:
                    break
                for k, v in held.items():
                    setattr(model, k, v)
                if not poles:
                    break
        X_r, blocks_r = design.reflex_columns(model)
        X_r, blocks_r = np.hstack([design.late_columns, X_r]), design.late_blocks + blocks_r
        tq_r = model.predict(design.position, design.scheduling, warn=False).reflex
        # The base reflex's scale joins the solve: a reflex effect modulates the gain about
        # a base level (e.g. activation scales it by 1 + b a, a >= 0), whereas the base fit
        # absorbed the trial's mean gain; held at that level, the effect could only add to
        # it (docs/design_notes.md, "Extended fits").
        X = np.hstack([Psi_i_base, design.columns, X_r, tq_r[:, None]])
        scale = np.sqrt(np.mean(X**2, axis=0))
        scale[scale == 0] = 1.0
        theta = np.linalg.lstsq(X / scale, y, rcond=None)[0] / scale
        c = float(theta[-1])
        if not MIN_REFLEX_RESCALE < c < 1.0 / MIN_REFLEX_RESCALE:  # degenerate: keep the base reflex
            theta = np.linalg.lstsq(X[:, :-1] / scale[:-1], y - tq_r, rcond=None)[0] / scale[:-1]
            c = 1.0
        theta = theta[:X_r.shape[1] + Psi_i_base.shape[1] + design.columns.shape[1]]
        # z (and with it every reflex state and effect feature) is linear in Omega: scale it,
        # and the reflex effects' coefficients by the inverse, so predictions are unchanged
        model.Omega = model.Omega * c
        theta[Psi_i_base.shape[1] + design.columns.shape[1] + design.late_columns.shape[1]:] /= c
        n_b = Psi_i_base.shape[1]
        model.H = theta[:n_b].reshape(model.H.shape)
        if model.curvature is not None:
            from .intrinsic import curvature_from_irf

            model.curvature = curvature_from_irf(model.H, model.intrinsic_basis)
        model.H_causal = causal_irf(design.position, design.fs, model.causal_lags, design.Gi_val,
                                    (Psi_i_base if Psi_irf is None else Psi_irf) @ theta[:n_b], model.causal_derivatives)
        n_e = design.columns.shape[1]
        n_late = design.late_columns.shape[1]  # the reflex effects' columns scale with Omega (above)
        design.extension = (np.hstack([design.columns, X_r[:, :n_late], c * X_r[:, n_late:]]), theta[n_b:])
        effects = design.fitted(np.concatenate([theta[n_b: n_b + n_e], theta[n_b + n_e:]]),
                                design.blocks + blocks_r, model.causal_lags, model.causal_derivatives)
    model.effects = effects
    # RMS of the extra inputs in the files' own unit (EMG): predict warns when a record's is
    # far off (EMG in mV for a model identified in V; LPVPCModel.predict)
    model.provenance["signal_levels"] = {s: float(np.sqrt(np.mean(np.square(design.signals[s]))))
                                         for s in model_signals(model) if SIGNALS[s][0] == "1" and s in design.signals}
    if "effects" in model.settings:  # JSON form (a list), so that save/load round-trips exactly
        model.settings["effects"] = list(model.settings["effects"])
    return model


# --------------------------------------------------------------------------- stress relaxation's two stiffnesses

#: Labels of the two elastic stiffnesses of a model with stress relaxation (summary, model file, report).
SHORT_RANGE_LABEL = "short-range stiffness (before relaxation)"
RELAXED_LABEL = "relaxed stiffness (steady state, displacement held)"


def relaxation_stiffnesses(model, rho):
    """(short-range, relaxed) elastic stiffness (N m/rad) at positions ``rho`` (rad) of a
    model with the stress_relaxation effect. Short-range: K(rho), the IRF's static gain,
    the torque per radian right after a displacement. Relaxed: after a displacement held
    long past the relaxation times, every averaged position equals the displacement, so the
    effect adds sum_i Theta_i . G_e(rho) to K (negative when the torque relaxes).

    >>> import types
    >>> from lpvpc.models.basis import Basis
    >>> b = Basis("chebyshev", 0, -0.1, 0.1)
    >>> fe = FittedEffect("stress_relaxation", Theta=np.array([[-5.0], [-3.0], [-2.0]]), basis=b)
    >>> model = types.SimpleNamespace(effects=[fe], elastic_stiffness=lambda r: np.full(len(r), 50.0))
    >>> relaxation_stiffnesses(model, np.array([0.0]))  # N m/rad: 10 of 50 relax
    (array([50.]), array([40.]))
    """
    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    K = np.asarray(model.elastic_stiffness(rho), dtype=float)
    fe = next((f for f in model.effects or () if f.name == "stress_relaxation"), None)
    if fe is None:
        raise ValueError("the model has no stress_relaxation effect")
    G = fe.basis.evaluate(rho)
    if not fe.effect.feature_constant:
        G = G[:, 1:]
    return K, K + (G @ np.asarray(fe.Theta, dtype=float).T).sum(axis=1)


def relaxation_stiffness_entry(model, n: int = 5) -> dict:
    """The model file's ``fit.stiffness`` entry: both stiffnesses, labelled, with units, at
    ``n`` positions across the identified range (one on a stationary trial).

    >>> import types
    >>> from lpvpc.models.basis import Basis
    >>> fe = FittedEffect("stress_relaxation", Theta=np.array([[-5.0], [-3.0], [-2.0]]),
    ...                   basis=Basis("chebyshev", 0, -0.1, -0.1 + 1e-9))
    >>> model = types.SimpleNamespace(effects=[fe], scheduling_range=(-0.1, -0.1),
    ...                               elastic_stiffness=lambda r: np.full(len(r), 50.0))
    >>> e = relaxation_stiffness_entry(model)
    >>> e["relaxed"]["label"], e["relaxed"]["unit"], e["relaxed"]["values"], e["relaxed"]["determined"]
    ('relaxed stiffness (steady state, displacement held)', 'N m/rad', [40.0], [True])
    """
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, n) if hi - lo > 1e-6 else np.array([lo])
    short, relaxed = relaxation_stiffnesses(model, rho)
    # Stress relaxation lowers the torque of a held displacement: a relaxed stiffness outside
    # (0, short-range] is the averages' steady state extrapolated beyond what the record's
    # holds show (lab stationary trials, whose perturbation holds last well under the 3-s
    # average: -20 and 183 N m/rad next to 154 and 156 short-range)
    plausible = [bool(0.0 < r <= k) for r, k in zip(relaxed, short)]
    return {"scheduling": [float(x) for x in rho], "scheduling_unit": "rad",
            "short_range": {"label": SHORT_RANGE_LABEL, "unit": "N m/rad", "values": [float(x) for x in short]},
            "relaxed": {"label": RELAXED_LABEL, "unit": "N m/rad", "values": [float(x) for x in relaxed],
                        "determined": plausible}}
