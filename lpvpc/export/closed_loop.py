"""The closed-loop form of the whole-joint model: joint angle and angular velocity in, ankle
torque out, no look-ahead, inertia declared apart.

The whole-joint model (:mod:`lpvpc.export.whole_joint`) answers L samples late (its intrinsic IRF
is two-sided) and holds the foot's inertia inside its torque. In a loop where the torque
moves the foot both are fatal: a compliant exoskeleton loop diverges within 0.4 s.
This form keeps the whole-joint split (operating angle rho = causal 0.5 Hz low-pass of the
angle, perturbation p = angle - rho) and the identified reflex pathway, and replaces the
intrinsic IRF by a causal impedance of the current inputs:

    torque(t) = T_qs(rho) + K(rho) p + B(rho) omega + c(rho) p^2 [+ sum_l M_l(rho) p(k - l)]
                + reflex(t)                                  (N m, positive resists dorsiflexion)
    inertia     I (kg m^2): NOT in the torque; the plant adds it to its own

with omega the joint's angular velocity (rad/s, an input: a plant holds it as a state). The
reflex is the identified LPV Hammerstein pathway on the perturbation's central-difference
velocity d samples ago (its physiological delay line); between samples it is interpolated
from sample k to k + 1 (both are known at k, since they act on velocities >= d - 1 samples old).

Identification (:func:`fit_closed_loop`): with the identified LPV-PC model's reflex held, least
squares of the trials' total torque minus the quasi-static curve and the reflex on the causal
features (p, omega, p^2 and memory, each times the intrinsic scheduling basis G_i(rho)) and the
angular acceleration (its coefficient is the inertia I, one constant). Offline, omega and the
acceleration come from the angle record by 5-point central differences (the model's stencil);
in a loop the plant supplies omega, and I joins the plant's inertia. A recording whose torque
channel lags its position channel (a measurement artefact: ~1 ms on the lab's pilot trial, 4 of
the form's points there) is lined up for the fit (``position_delay``, :func:`~lpvpc.identification.channel_skew.estimate_channel_skew`);
the model itself answers the plant's angle without delay.

Timing of the exported step and FMU: the model samples every 1/fs s (rho, the delay line,
the reflex state), and runs on a base tick of ~1 ms (:func:`lpvpc.export.exporter.ticks_per_sample`):
every tick's output takes the current angle and angular velocity (direct feedthrough), so a
master may communicate at any multiple of the tick up to (and beyond) the model period.

Units: angle rad, angular velocity rad/s, torque N m, inertia kg m^2, time s.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..models import equations as eq
from ..models.basis import CasadiOps
from ..errors import DataError, ExportError, ModelFileError, non_finite_problem
# the channel skew lives in its own module; its names stay importable from here (earlier API)
from ..identification.channel_skew import ChannelSkew, delay_position, delayed, estimate_channel_skew  # noqa: F401

__all__ = ["ClosedLoopModel", "ClosedLoopPrediction", "fit_closed_loop", "distillation_trial", "closed_loop_step",
           "fit_perturbation_impedance", "predict_perturbation_impedance", "delay_position", "ChannelSkew",
           "estimate_channel_skew",
           "export_closed_loop_fmu", "export_closed_loop_casadi", "OUTPUT_NAMES", "INPUT_NAMES"]

FORMAT = "lpvpc-closed-loop"
FORMAT_VERSION = 1
STENCIL = "central5"  # offline velocity/acceleration of the angle record (module notes)
INPUT_NAMES = ("angle", "angular_velocity")
OUTPUT_NAMES = ("torque", "torque_intrinsic", "torque_reflex", "operating_angle")
_INPUT_INFO = {"angle": ("rad", "joint angle (positive = dorsiflexion)"),
               "angular_velocity": ("rad/s", "joint angular velocity (the plant's state)")}
_OUTPUT_INFO = {
    "torque": ("N.m", "ankle torque without inertia (positive resists dorsiflexion): intrinsic + reflex"),
    "torque_intrinsic": ("N.m", "quasi-static curve + causal impedance (stiffness, viscosity, memory)"),
    "torque_reflex": ("N.m", "reflex pathway torque (delayed velocity, LPV Hammerstein)"),
    "operating_angle": ("rad", "causally low-passed joint angle (the scheduling variable)"),
}
_FEATURES = ("stiffness", "viscosity", "curvature")  # rows of W before the memory rows


@dataclass
class ClosedLoopPrediction:
    """Offline prediction at the model's samples (N m, rad). ``total`` is what the model outputs
    (no inertia); ``inertial`` = inertia x the record's acceleration (5-point differences), so
    ``total + inertial`` is what a torque sensor between foot and actuator records."""

    total: np.ndarray
    intrinsic: np.ndarray
    reflex: np.ndarray
    operating_angle: np.ndarray
    inertial: np.ndarray

    @property
    def measured(self) -> np.ndarray:
        """The torque a sensor records (N m): total + inertial."""
        return self.total + self.inertial


@dataclass
class ClosedLoopModel:
    """Causal whole-joint model, made by :func:`fit_closed_loop`.

    Parameters
    ----------
    whole : lpvpc.export.whole_joint.WholeJointModel
        Its quasi-static curve, low-pass and LPV-PC reflex.
    W : numpy.ndarray
        (3 + memory) x n_i impedance coefficients on the intrinsic scheduling basis: K
        N m/rad, B N m s/rad, curvature N m/rad^2, memory N m/rad.
    inertia : float
        The joint's inertia (kg m^2), for the plant.
    memory : int, default 0
        Past perturbation samples in the impedance.
    fit : dict, optional
        How the fit went (VAF, settings)."""

    whole: object
    W: np.ndarray
    inertia: float
    memory: int = 0
    fit: dict = field(default_factory=dict)

    def __post_init__(self):
        self.W = np.atleast_2d(np.asarray(self.W, dtype=float))
        n_i = self.model.intrinsic_basis.size
        if self.W.shape != (3 + self.memory, n_i):
            raise ValueError(f"impedance coefficients have shape {self.W.shape}, expected {(3 + self.memory, n_i)}")
        if not np.isfinite(self.inertia):
            raise ValueError(f"inertia {self.inertia!r} kg m^2 is not finite")

    @property
    def model(self):
        return self.whole.model

    @property
    def fs(self) -> float:
        return self.whole.fs

    def stiffness(self, rho) -> np.ndarray:
        """K(rho) (N m/rad) of the impedance at operating angles ``rho`` (rad)."""
        return self.model.intrinsic_basis.evaluate(np.asarray(rho, dtype=float)) @ self.W[0]

    def viscosity(self, rho) -> np.ndarray:
        """B(rho) (N m s/rad) at operating angles ``rho`` (rad)."""
        return self.model.intrinsic_basis.evaluate(np.asarray(rho, dtype=float)) @ self.W[1]

    def predict(self, angle, velocity=None, *, warn: bool = False) -> ClosedLoopPrediction:
        """Torque (N m, without inertia) at the samples of an angle record (rad, at ``fs``);
        ``velocity`` (rad/s) defaults to the record's 5-point central differences."""
        angle = _checked(angle, "angle")
        v_est, acc = eq.derivatives(angle, self.fs, STENCIL)
        velocity = v_est if velocity is None else _checked(velocity, "velocity")
        if velocity.shape != angle.shape:
            raise DataError([f"angle and velocity differ in length: {angle.shape} and {velocity.shape}"])
        rho, p = self.whole.split(angle)
        F = _features(p, velocity, self.memory)
        Gi = self.model.intrinsic_basis.evaluate(rho)
        tq_i = eq.impedance_torque(F, Gi, self.W, self.whole.curve_basis.evaluate(rho), self.whole.curve)
        tq_r = self.model.predict(p, rho, warn=warn).reflex
        return ClosedLoopPrediction(total=tq_i + tq_r, intrinsic=tq_i, reflex=tq_r, operating_angle=rho,
                                    inertial=self.inertia * acc)

    # -- persistence ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "memory": int(self.memory),
                "impedance": self.W.tolist(), "inertia": float(self.inertia), "stencil": STENCIL,
                "units": {"angle": "rad", "angular_velocity": "rad/s", "torque": "N m", "inertia": "kg m^2",
                          "impedance rows": "K N m/rad, B N m s/rad, curvature N m/rad^2, memory N m/rad"},
                "fit": self.fit, "whole_joint": self.whole.to_dict()}

    @classmethod
    def from_dict(cls, d: dict, source: str = "closed-loop model") -> "ClosedLoopModel":
        from .whole_joint import WholeJointModel

        if not isinstance(d, dict) or d.get("format") != FORMAT or d.get("format_version") != FORMAT_VERSION:
            raise ModelFileError(f"{source}: not an lpvpc closed-loop model file (format {FORMAT!r} version "
                                 f"{FORMAT_VERSION})")
        try:
            return cls(whole=WholeJointModel.from_dict(d["whole_joint"], source), W=np.array(d["impedance"], float),
                       inertia=float(d["inertia"]), memory=int(d["memory"]), fit=d.get("fit", {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{source}: corrupt closed-loop model file ({type(exc).__name__}: {exc})") from None

    def save(self, path) -> None:
        from ..io.outputs import write_text

        write_text(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path) -> "ClosedLoopModel":
        from ..models.modelfile import read_model_file

        return cls.from_dict(read_model_file(path), str(path))


def _checked(x, name) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or len(x) < 1:
        raise DataError([f"channel {name}: expected a 1-D record of at least one sample, got shape {x.shape}"])
    if problem := non_finite_problem(name, x):
        raise DataError([problem])
    return x


def _features(p, velocity, memory) -> np.ndarray:
    past = [eq.lagged(p, [l])[:, 0] for l in range(1, memory + 1)]  # zero before the record
    return eq.impedance_features(p, velocity, past)


def _at_model_rate(trial, fs):
    """(angle, torque) of a :class:`lpvpc.io.Trial` at ``fs`` (the identification's
    resampling and anti-alias decimation), or an (angle, torque) pair already at ``fs``."""
    from ..io import Trial, decimate_trial, to_multiple_rate

    if isinstance(trial, Trial):
        trial = to_multiple_rate(trial, fs)
        low = trial if abs(trial.fs / fs - 1.0) < 1e-9 else decimate_trial(trial, fs)
        return np.asarray(low.position, float), np.asarray(low.torque, float)
    angle, torque = trial
    return _checked(angle, "angle"), _checked(torque, "torque")


def fit_closed_loop(whole, trials, *, memory: int = 0, position_delay: float = 0.0) -> ClosedLoopModel:
    """Identify the closed-loop form from a whole-joint model and the trials it came from.

    With the reflex held, least squares of the torque minus quasi-static curve and reflex on
    the causal features times G_i(rho) and on the acceleration (coefficient: the inertia).
    The model itself has no delay: it answers a plant's angle at once, as the ankle does.

    Parameters
    ----------
    whole : lpvpc.export.whole_joint.WholeJointModel
        The whole-joint model.
    trials : list
        The PT and UT trials (:class:`lpvpc.io.trial.Trial`, any rate the identification
        accepts, or (angle rad, torque N m) pairs at the model rate), each predicted from
        rest. Without the PT trial, pass ``[distillation_trial(whole, ut)]``.
    memory : int, default 0
        Past perturbation samples in the impedance (0: none; module notes), at most 10.
    position_delay : float, default 0.0
        Each trial's angle is delayed by it (s) before the fit, to undo a torque channel
        recorded that much late (a measurement artefact,
        :func:`~lpvpc.identification.channel_skew.estimate_channel_skew`).

    Returns
    -------
    ClosedLoopModel
        The closed-loop form.

    Raises
    ------
    ValueError
        A ``memory`` outside 0..10.
    """
    from ..models.model import vaf

    model = whole.model
    _check_base_model(model)
    if memory < 0 or memory > 10:
        raise ValueError(f"memory {memory!r} must be 0..10 past samples")
    rows, targets, parts = [], [], []
    for trial in trials:
        angle, torque = _at_model_rate(trial, model.fs)
        if position_delay:
            angle = delayed(angle, model.fs, position_delay)
        vel, acc = eq.derivatives(angle, model.fs, STENCIL)
        rho, p = whole.split(angle)
        known = whole.quasi_static(rho) + model.predict(p, rho, warn=False).reflex
        rows.append(_impedance_rows(model, p, rho, vel, acc, memory))
        targets.append(torque - known)
        parts.append((torque, known))
    W, inertia, fitted = _solve(rows, targets, model, memory)
    fit = {"vaf_with_inertia": vaf(np.concatenate([t for t, _ in parts]), fitted + np.concatenate([k for _, k in parts])),
           "memory": int(memory), "stencil": STENCIL, "samples": int(len(fitted)),
           "position_delay_s": float(position_delay)}
    return ClosedLoopModel(whole=whole, W=W, inertia=inertia, memory=memory, fit=fit)


def _check_base_model(model):
    if getattr(model, "effects", None):
        raise ExportError("the closed-loop form covers the base LPV-PC model; this model has effect terms "
                          f"({', '.join(fe.name for fe in model.effects)}): identify it without --effect")


def _impedance_rows(model, p, rho, vel, acc, memory):
    """Regressor rows: the causal features times G_i(rho) (row-major as W), then the acceleration."""
    Gi = model.intrinsic_basis.evaluate(rho)
    F = _features(p, vel, memory)
    return np.column_stack([(F[:, :, None] * Gi[:, None, :]).reshape(len(p), -1), acc])


def _solve(rows, targets, model, memory, inertia=None):
    """Least squares for W and the inertia (the last column); a given ``inertia`` (kg m^2) is
    held instead of fitted (its term moved to the target)."""
    X, y = np.vstack(rows), np.concatenate(targets)
    if inertia is None:
        theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    else:
        theta = np.r_[np.linalg.lstsq(X[:, :-1], y - inertia * X[:, -1], rcond=None)[0], inertia]
    W = theta[:-1].reshape(3 + memory, model.intrinsic_basis.size)
    return W, float(theta[-1]), X @ theta


def fit_perturbation_impedance(model, position, scheduling, torque, memory: int = 0, inertia=None):
    """The closed-loop form's causal impedance at the level of the identification data (the
    perturbation position p and the recorded scheduling rho, no quasi-static curve): least
    squares of ``torque`` minus the model's reflex on p, p', p^2 (times G_i(rho)) and p''.
    Returns (W, inertia). For data without a whole-joint record (the lab's pilot trial:
    perturbation and scheduling only), to measure what the causal form costs there.
    ``inertia`` (kg m^2): hold it instead of fitting it (past-sample memory with a fitted
    inertia turns into a differentiator with a negative inertia)."""
    _check_base_model(model)
    p, rho = _checked(position, "position"), _checked(scheduling, "scheduling")
    vel, acc = eq.derivatives(p, model.fs, STENCIL)
    target = _checked(torque, "torque") - model.predict(p, rho, warn=False).reflex
    W, inertia, _ = _solve([_impedance_rows(model, p, rho, vel, acc, memory)], [target], model, memory, inertia)
    return W, inertia


def predict_perturbation_impedance(model, W, inertia, position, scheduling):
    """Torque (N m, as recorded: with the inertial term) of :func:`fit_perturbation_impedance`'s
    form: the same equations (:func:`lpvpc.models.equations.impedance_torque`, a zero curve) plus the reflex."""
    p, rho = _checked(position, "position"), _checked(scheduling, "scheduling")
    vel, acc = eq.derivatives(p, model.fs, STENCIL)
    Gi = model.intrinsic_basis.evaluate(rho)
    tq = eq.impedance_torque(_features(p, vel, W.shape[0] - 3), Gi, W, np.zeros((len(p), 1)), np.zeros(1))
    return tq + inertia * acc + model.predict(p, rho, warn=False).reflex


def distillation_trial(whole, ut, *, amplitude: float = 0.04, seed: int = 0):
    """(angle rad, torque N m) at the model rate for a fit without the PT trial: the UT trial's
    angle plus a PRALDS perturbation (+-``amplitude`` rad, 250-350 ms holds, the paper's design)
    as a stiff 25 Hz position servo applies it at 1 kHz, recorded through the anti-alias
    decimation; the torque is the two-sided whole-joint model's (inertia included, as
    recorded). The causal form is then fitted to what the identified model predicts. (A
    perturbation stepped at the model rate instead put the differences' ringing into the
    inertia: 0.004 kg m^2 against the subject's 0.015.)"""
    from ..io import decimate_signal
    from ..simulation.simulate import FS_SIM, pralds, servo

    angle, _ = _at_model_rate(ut, whole.fs)
    q = int(round(FS_SIM / whole.fs))
    if abs(q * whole.fs - FS_SIM) > 1e-9 * FS_SIM:
        raise ValueError(f"the model rate {whole.fs!r} Hz must divide {FS_SIM!r} Hz for the distillation perturbation")
    pert = pralds(len(angle) / whole.fs, FS_SIM, np.random.default_rng(seed), amplitude=amplitude)
    pert = servo(pert, FS_SIM)[0]
    pert = (decimate_signal(pert, q) if q > 1 else pert)[: len(angle)]
    angle = angle + np.pad(pert, (0, len(angle) - len(pert)), mode="edge")
    return angle, whole.predict(angle, warn=False).total


# ---------------------------------------------------------------------------------------
# CasADi step (one base tick) and FMU

def ticks(cl: ClosedLoopModel) -> int:
    """Base ticks per model sample (tick ~1 ms: 10 at 100 Hz)."""
    from .exporter import ticks_per_sample

    return ticks_per_sample(cl.model)


def _history(cl) -> int:
    return max(int(cl.model.delay) + 1, cl.memory + 1)


def _parameter_blocks(cl):
    """[(name, array, unit, description)] of the parametric step's ``params`` (row-major)."""
    m = cl.model
    wj = cl.whole
    rows = list(_FEATURES) + [f"memory lag {l}" for l in range(1, cl.memory + 1)]
    units = ["N.m/rad", "N.m.s/rad", "N.m/rad2"] + ["N.m/rad"] * cl.memory
    return [
        ("W", cl.W, [(f"impedance coefficient ({rows[i]}, scheduling basis function {j})", units[i])
                     for i in range(cl.W.shape[0]) for j in range(cl.W.shape[1])]),
        ("curve", wj.curve.reshape(-1), [(f"quasi-static torque-angle curve coefficient {i} ({wj.curve_basis.family} "
                                          f"basis on [{wj.curve_basis.lo!r}, {wj.curve_basis.hi!r}] rad)", "N.m")
                                         for i in range(wj.curve.size)]),
        ("cutoff", np.array([wj.cutoff]), [("cutoff frequency of the operating-angle low-pass", "Hz")]),
        ("Omega", np.atleast_2d(m.Omega), [(f"reflex nonlinearity coefficient [{i},{j}]", "")
                                           for i in range(m.Omega.shape[0]) for j in range(np.atleast_2d(m.Omega).shape[1])]),
        ("A", np.atleast_2d(m.A), [(f"reflex dynamics A[{i},{j}] (per sample)", "")
                                   for i in range(m.A.shape[0]) for j in range(m.A.shape[0])]),
        ("B", np.asarray(m.B, float).reshape(-1), [(f"reflex dynamics B[{i}]", "") for i in range(m.A.shape[0])]),
        ("C", np.asarray(m.C, float).reshape(-1), [(f"reflex dynamics C[{i}]", "") for i in range(m.A.shape[0])]),
        ("D", np.array([float(m.D)]), [("reflex dynamics feedthrough D", "")]),
    ]


def parameter_table(cl):
    """(names, values, [(description, unit)]) of the FMU parameters, in ``params`` order."""
    names, values, info = [], [], []
    for name, a, inf in _parameter_blocks(cl):
        a = np.asarray(a, float)
        if a.size == 1 and name in ("cutoff", "D"):
            names.append(name)
        elif a.ndim == 1:
            names += [f"{name}[{i}]" for i in range(a.size)]
        else:
            names += [f"{name}[{i},{j}]" for i in range(a.shape[0]) for j in range(a.shape[1])]
        values += list(a.ravel())
        info += inf
    return names, np.array(values, float), info


def closed_loop_step(cl: ClosedLoopModel, parametric: bool = False, name: str = "lpvpc_closed_loop_tick"):
    """One base tick (1 / (fs N) s) of the closed-loop model as a ``casadi.Function``.

    Inputs: ``state`` (zeros at the start), ``angle`` (rad), ``angular_velocity`` (rad/s)
    [, ``params``]. Outputs: ``next_state`` and ``OUTPUT_NAMES`` at the tick's instant,
    from the current inputs. At ticks 0, N, 2N, ... (the model's samples) the outputs equal
    :meth:`ClosedLoopModel.predict` at that sample:

    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> from lpvpc.export.whole_joint import fit_whole_joint
    >>> from lpvpc.export.exporter import trajectory_function
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> cl = fit_closed_loop(fit_whole_joint(identify(pair_trials(sim.pt, sim.ut)), sim.ut), [sim.pt, sim.ut])
    >>> step, N = closed_loop_step(cl), ticks(cl)
    >>> angle = sim.pt.position[:200]
    >>> vel = np.gradient(angle) * cl.fs
    >>> out = trajectory_function(step, N * len(angle))(state=np.zeros(step.size1_in(0)),
    ...     angle=np.repeat(angle, N)[None, :], angular_velocity=np.repeat(vel, N)[None, :])
    >>> torque = np.asarray(out["torque"]).ravel()[::N]
    >>> bool(np.allclose(torque, cl.predict(angle, vel).total, atol=1e-9))
    True
    """
    import casadi as ca

    ops = CasadiOps()
    m, wj = cl.model, cl.whole
    N, H, d, fs = ticks(cl), _history(cl), int(m.delay), cl.fs
    n_r = m.A.shape[0]
    names, values, _ = parameter_table(cl)
    p = ca.SX.sym("params", len(values)) if parametric else None
    blocks, off = {}, 0
    for bname, a, _ in _parameter_blocks(cl):
        a = np.asarray(a, float)
        if p is None:
            blocks[bname] = ca.DM(a)
        else:
            flat = p[off: off + a.size]
            blocks[bname] = ca.reshape(flat, a.shape[1], a.shape[0]).T if a.ndim == 2 else flat
        off += a.size
    A, Bv, Cv, D = blocks["A"], blocks["B"], blocks["C"], blocks["D"][0]

    # state: [phase, samples seen (saturating), rho(k), reflex torque at k and k+1, p(k)..p(k-H+1), x_r(k+1)]
    n_state = 5 + H + n_r
    state = ca.SX.sym("state", n_state)
    angle, omega = ca.SX.sym("angle"), ca.SX.sym("angular_velocity")
    phase, seen, rho_s, tqr_s, tqr_n = state[0], state[1], state[2], state[3], state[4]
    hist, x_r = state[5: 5 + H], state[5 + H:]

    # The model's sample k (taken at phase 0, with the current angle).
    alpha = eq.lowpass_alpha(blocks["cutoff"][0], fs, ops)
    rho = ca.if_else(seen > 0, eq.lowpass_step(rho_s, angle, alpha), angle)
    p_k = angle - rho

    def p_at(i):  # p(k - i), zero before the record
        return p_k if i == 0 else hist[i - 1]

    Gr = m.reflex_rho_basis.evaluate(rho, ops)

    def drive(lag_ahead, lag_behind, available):
        dvel = ca.if_else(available, eq.central_velocity(p_at(lag_ahead), p_at(lag_behind), fs), 0.0)
        return eq.reflex_drive(m.velocity_basis.evaluate(dvel, ops), Gr, blocks["Omega"], ops)

    z_k = drive(d - 1, d + 1, seen >= d)
    x_next, tq_k = eq.reflex_step(A, Bv, Cv.T, D, x_r, z_k)
    if d >= 2:  # z(k+1) acts on p(k-d+2), p(k-d): known now (the scheduling held at rho(k))
        _, tq_k1 = eq.reflex_step(A, Bv, Cv.T, D, x_next, drive(d - 2, d, seen + 1 >= d))
    else:  # the next sample's reflex needs the next angle: hold
        tq_k1 = tq_k
    hist_k = ca.vertcat(p_k, hist[: H - 1]) if H > 1 else p_k

    new_sample = phase < 0.5
    rho_t = ca.if_else(new_sample, rho, rho_s)
    tqr_a = ca.if_else(new_sample, tq_k, tqr_s)
    tqr_b = ca.if_else(new_sample, tq_k1, tqr_n)
    hist_t = ca.if_else(new_sample, hist_k, hist)

    # Outputs at this tick: the impedance of the current angle and velocity, the reflex between samples.
    p_t = angle - rho_t
    F = eq.impedance_features(p_t, omega, [hist_t[l] for l in range(1, cl.memory + 1)], ops)
    Gi = m.intrinsic_basis.evaluate(rho_t, ops)
    tq_i = eq.impedance_torque(F, Gi, blocks["W"], wj.curve_basis.evaluate(rho_t, ops), blocks["curve"], ops)
    tq_r = eq.between_samples(tqr_a, tqr_b, phase / N)

    next_state = ca.vertcat(
        ca.if_else(phase + 1.0 >= N - 0.5, 0.0, phase + 1.0),
        ca.if_else(new_sample, ca.fmin(seen + 1.0, float(d + 2)), seen),
        rho_t, tqr_a, tqr_b, hist_t,
        ca.if_else(new_sample, x_next, x_r),
    )
    inputs, in_names = [state, angle, omega], ["state", *INPUT_NAMES]
    if parametric:
        inputs.append(p)
        in_names.append("params")
    return ca.Function(name, inputs, [next_state, tq_i + tq_r, tq_i, tq_r, rho_t], in_names,
                       ["next_state", *OUTPUT_NAMES])


def export_closed_loop_casadi(cl: ClosedLoopModel, path) -> Path:
    """Save the (non-parametric) tick function with ``Function.save`` and its metadata in
    ``<path>.json`` (:func:`lpvpc.export.exporter.save_casadi`): the tick (1 / (fs N) s: one call per
    tick), the foot's inertia (not in the torque: the plant adds it), units, names and the
    initial state. :func:`lpvpc.export.exporter.load_casadi` reads both and refuses a host step that
    is not the tick."""
    from .exporter import save_casadi

    N = ticks(cl)
    meta = {"kind": "closed-loop", "variant": "causal", "fs": cl.fs, "tick_s": 1.0 / (cl.fs * N),
            "ticks_per_sample": N, "sample_period_s": 1.0 / cl.fs, "latency_samples": 0, "latency_s": 0.0,
            "units": {"state": "the previous call's next_state", "next_state": "(state)",
                      **{n: u for n, (u, _) in _INPUT_INFO.items()},
                      **{n: u.replace("N.m", "N m") for n, (u, _) in _OUTPUT_INFO.items()}},
            "inertia": {"kg_m2": float(cl.inertia), "in_torque": False,
                        "note": "the foot's moment of inertia is NOT in the torque: add it to the plant's"},
            "model_hash": cl.model.model_hash}
    return save_casadi(closed_loop_step(cl), path, meta)


def export_closed_loop_fmu(cl: ClosedLoopModel, path, fmi_version: int = 2, *, reuse_existing: bool = False,
                           fmi_type: str = "cs") -> Path:
    """The closed-loop model as an FMI 2.0 or 3.0 FMU: co-simulation (``fmi_type="cs"``) or Model
    Exchange (``"me"``, a time event per base tick). Inputs ``angle`` (rad), ``angular_velocity``
    (rad/s); outputs ``OUTPUT_NAMES`` from the current inputs (direct feedthrough); constant
    outputs ``inertia`` (kg m^2, for the plant to add to its own), ``sample_period`` (s) and
    ``latency`` (0 s); internal step (base tick) 1 / (fs N) s."""
    from .. import __version__
    from .exporter import build_step_fmu, fmu_parameter_name, step_system_functions
    from .fmu_build import FmuVariable

    step = closed_loop_step(cl, parametric=True)
    deps = step_system_functions(step)[3]
    names, values, info = parameter_table(cl)
    outputs = [FmuVariable(n, "output", _OUTPUT_INFO[n][0], _OUTPUT_INFO[n][1], dependencies=deps[n])
               for n in OUTPUT_NAMES]
    inputs = [FmuVariable(n, "input", *_INPUT_INFO[n], 0.0) for n in INPUT_NAMES]
    parameters = [FmuVariable(fmu_parameter_name(n), "parameter", unit, f"{n}: {text}", float(v))
                  for n, v, (text, unit) in zip(names, values, info)]
    constants = [FmuVariable("inertia", "output", "kg.m2", "the ankle's (foot's) moment of inertia, NOT in "
                             "the torque: add it to the plant's inertia", cl.inertia),
                 FmuVariable("sample_period", "output", "s", "the model's sample period (operating angle, "
                             "reflex delay line)", 1.0 / cl.fs),
                 FmuVariable("latency", "output", "s", "output delay beyond the physiology: none", 0.0)]
    N = ticks(cl)
    lo, hi = cl.model.scheduling_range
    description = (f"Closed-loop ankle model exported by lpvpc {__version__} (LPV-PC model sha256 "
                   f"{cl.model.model_hash}): joint angle and angular velocity in, ankle torque out (positive resists "
                   f"dorsiflexion), no latency: quasi-static torque-angle curve at the operating angle (low-pass "
                   f"{cl.whole.cutoff!r} Hz) + causal position-dependent stiffness and viscosity + reflex (delay "
                   f"{int(cl.model.delay) / cl.fs!r} s). The foot's inertia {cl.inertia:.6g} kg m^2 is NOT in the "
                   f"torque (constant output 'inertia'): the plant adds it to its own. Samples every {1.0 / cl.fs!r} s, "
                   f"outputs every tick of {1.0 / (cl.fs * N)!r} s from the current inputs. Operating angle outside "
                   f"[{lo!r}, {hi!r}] rad: the model is {cl.model.beyond_range}, the curve continues linearly.")
    return build_step_fmu(path, step, model_identifier="lpvpc_closed_loop", fmi_type=fmi_type,
                          prefix="lpvpc-closed-loop-", step_size=1.0 / (cl.fs * N), outputs=outputs, inputs=inputs,
                          parameters=parameters, fmi_version=fmi_version, description=description,
                          version=f"lpvpc {__version__} model {cl.model.model_hash[:12]} closed loop",
                          latency=0.0, reuse_existing=reuse_existing, constants=constants)
