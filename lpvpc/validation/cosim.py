"""Co-simulation master: the lab experiment with the actuator FMU and the model FMU.

Units: time s, angles rad, velocity rad/s, acceleration rad/s^2, torque N m.

The experiment (as in the lab)
------------------------------
Two instances of the actuator FMU run the held-out record's two trials: ``actuator_ut``
follows the UT command (the slow trajectory), ``actuator_pt`` the PT command (trajectory
plus perturbation). The model FMU plays the ankle: it receives the perturbation position
PT - UT and the scheduling variable (the UT position) (the causal variant also the
perturbation velocity and acceleration) and returns the perturbation torque, which loads
the PT actuator. An exact-variant FMU (the two-sided model, outputs L samples late) is
evaluated before the actuators step, its output loads the PT actuator at once (so L steps
late), and the run continues L steps past the record so that its torques can be shifted
back to their time (``latency`` of :func:`run_cosimulation`). Commands come from the record's ``command`` channel; a
record without one is driven by its measured positions passed through the inverse of the
servo loop (a feedforward command under which the servo reproduces the measured
position; see :func:`feedforward_command`), then refined by iterative learning
(``lpvpc.validation.harness.refined_drive``: each pass adds :func:`actuator_inverse` of the
remaining position error and co-simulates again).

Decisions (each a :class:`CosimSettings` field; the defaults are what the report uses)
---------------------------------------------------------------------------------------
Rates
    The actuator steps at its own fixed step (1 ms, from its model description) and
    receives the command at every one of those steps (a 1 kHz record's command is used
    sample by sample; a slower record's command is band-limited interpolated to the
    actuator rate with the same Kaiser FIR the decimator uses). The model FMU steps at the
    model's sample period (10 ms at 100 Hz): the master's communication step. Holding the
    command over a model step instead (``command_rate="hold"``) moves every PRALDS edge by
    up to 9 ms.
Velocity and acceleration fed to the model (``derivatives``)
    ``"central"`` (default): central differences of the perturbation position at the
    model rate, (p(k+1) - p(k-1)) / 2T and (p(k+1) - 2 p(k) + p(k-1)) / T^2, i.e. the mean
    of the actuator's velocity over [t(k-1), t(k+1)] and the triangle-weighted mean of its
    acceleration. This is what the model's velocity and acceleration coefficients were
    identified with (and what an FMU replay of a record uses). p(k+1) is available because
    the master steps the actuators over [t(k), t(k+1)] before it evaluates the model at
    t(k) (position has no direct feedthrough). A causal FMU identified with 5-point
    differences (constant output ``derivative_points`` = 5, the identification default)
    gets them, (8 (p(j+1) - p(j-1)) - (p(j+2) - p(j-2))) / 12T and the matching second
    difference, for sample j = k - 1: it is evaluated one model step late, its torque loads
    the PT actuator one step later than a 3-point model's, and the run continues one step
    past the record so every sample gets its torque. ``"actuator"``: the actuators' own
    instantaneous velocity and acceleration outputs, sampled at t(k): much broader-band
    than the 100 Hz model's central differences (measured: the VAF drops by tens of
    points) and, with a delayed load, unstable when the model's inertia coefficient
    exceeds the footplate inertia (the added-mass instability of partitioned coupling).
Load torque (``load``)
    ``"measured_ut+model"`` (default): the UT actuator is loaded by the record's measured UT
    torque (the ankle's torque during the slow movement, which the model does not predict),
    the PT actuator by the same measured UT torque plus the model's perturbation torque.
    ``"model"``: UT unloaded, PT loaded by the model torque only. ``"none"``: no load.
    With the stiff default servo the load deflects the footplate by load / K_s (0.05 mrad
    per N m); the report measures its effect by repeating the run unloaded.
Algebraic loop (``coupling``)
    With central differences the model torque at t(k) depends on p(k+1), which depends on
    the load over [t(k), t(k+1)], which is that torque: an implicit coupling. ``"delay"``
    breaks it with a one-step delay: the PT actuator sees the model torque of t(k-1) over
    [t(k), t(k+1)] (zero-order hold, 10 ms late). ``"iterate"`` (default) removes the
    delay: the PT actuator's FMU state is saved at t(k), the step is repeated with the new
    torque until it changes by less than ``iterate_tol`` (fixed-point iteration with
    fmi2GetFMUstate/SetFMUstate, first guess extrapolated from the last two steps, secant
    acceleration from the second try on). With ``derivatives="actuator"`` the loop is direct (the
    actuator's acceleration output depends directly on ``load_torque``, the causal model's
    torque directly on its acceleration input), and the same two options apply.

Extra inputs of an extended model (``signals``)
    A model identified with effects (:mod:`lpvpc.models.effects`) has extra FMU inputs
    (``trial_time``, ``scheduling_velocity``, ``emg``, ``emg_ut``). The actuator does not
    produce them: the master feeds the record's (at the model rate, as the offline routes
    use them) at every model step.

Every output of every FMU is checked finite at every communication step; a non-finite
value or an FMU error status raises :class:`lpvpc.errors.FMUError` with the FMU's own log.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from lpvpc.io import decimate_signal
from lpvpc.models.equations import five_point_derivatives
from lpvpc.errors import DataError, FMUError

from .fmu import FMUInfo, FMUInstance

__all__ = ["CosimSettings", "CosimResult", "ActuatorDrive", "run_cosimulation", "connections",
           "to_rate", "band_limit", "feedforward_command", "actuator_inverse", "ACTUATOR_LINEAR_PARAMETERS",
           "calibrate_servo", "ACTUATOR_INPUTS", "ACTUATOR_OUTPUTS",
           "MODEL_INPUTS", "MODEL_OUTPUTS", "model_fmu_variant", "model_fmu_sampled", "model_variant_inputs", "hold_tail"]

ACTUATOR_INPUTS = ("command", "load_torque")
ACTUATOR_OUTPUTS = ("position", "velocity", "acceleration")
MODEL_INPUTS = ("position", "scheduling", "velocity", "acceleration")
MODEL_OUTPUTS = ("torque", "torque_intrinsic", "torque_reflex")


def model_fmu_variant(info: FMUInfo) -> str:
    """"causal" when the model FMU takes velocity and acceleration inputs; "sampled" when it
    runs the causal IRF on positions alone (parameters ``H_causal_*``; latency 1 sample);
    else "exact" (the two-sided model, outputs delayed by its declared latency). lpvpc.export.exporter."""
    if info.variables.get("velocity", (None, None))[1] == "input":
        return "causal"
    return "sampled" if any(n.startswith("H_causal_") for n in info.variables) else "exact"


def model_fmu_sampled(info: FMUInfo) -> bool:
    """True for an FMU in the wrapper's sampled mode (lpvpc.export.exporter's sampled variant): its
    outputs are those of earlier samples, held, read after a step."""
    md = info.model_description
    period = next((float(v.start) for v in getattr(md, "modelVariables", ()) if v.name == "sample_period"), None)
    step = getattr(getattr(md, "defaultExperiment", None), "stepSize", None)
    return period is not None and step is not None and float(step) < period * (1 - 1e-9)


def model_fmu_derivative_points(info: FMUInfo) -> int:
    """Points (3 or 5) of the central differences a causal model FMU's velocity and
    acceleration inputs must be: its constant output ``derivative_points`` (FMUs without
    it: 3).

    >>> from types import SimpleNamespace as NS
    >>> fmu = NS(model_description=NS(modelVariables=[NS(name="derivative_points", start="5")]))
    >>> model_fmu_derivative_points(fmu), model_fmu_derivative_points(NS(model_description=NS(modelVariables=[])))
    (5, 3)
    """
    md = info.model_description
    return int(next((float(v.start) for v in getattr(md, "modelVariables", ()) if v.name == "derivative_points"), 3))


def model_variant_inputs(variant: str) -> tuple:
    """The base inputs of a model FMU variant (an extended model adds its signals)."""
    return MODEL_INPUTS if variant == "causal" else MODEL_INPUTS[:2]

COUPLINGS = ("delay", "iterate")
DERIVATIVES = ("central", "actuator")
LOADS = ("measured_ut+model", "model", "none")
COMMAND_RATES = ("actuator", "hold")


@dataclass
class CosimSettings:
    """How the master couples the FMUs (the module docstring explains each choice).

    Parameters
    ----------
    coupling : {"iterate", "delay"}, default "iterate"
        The algebraic loop between the model's torque and the PT actuator: solved by
        fixed-point iteration within each step, or broken by a one-step delay.
    derivatives : {"central", "actuator"}, default "central"
        The velocity and acceleration fed to the model: central differences of the
        perturbation position at the model rate, or the actuators' own outputs.
    load : {"measured_ut+model", "model", "none"}, default "measured_ut+model"
        The torque loading the actuators.
    command_rate : {"actuator", "hold"}, default "actuator"
        The command at every actuator step (band-limited interpolation of a slower record),
        or held over each model step.
    iterate_tol : float, default 1e-6
        With ``coupling="iterate"``: the torque change (N m) at which the iteration stops.
    max_iterations : int, default 20
        Its iteration limit per step.
    """

    coupling: str = "iterate"
    derivatives: str = "central"
    load: str = "measured_ut+model"
    command_rate: str = "actuator"
    iterate_tol: float = 1e-6  # N m, change of the model torque that ends the iteration
    max_iterations: int = 20

    def check(self):
        for name, allowed in (("coupling", COUPLINGS), ("derivatives", DERIVATIVES), ("load", LOADS),
                              ("command_rate", COMMAND_RATES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        return self


@dataclass
class ActuatorDrive:
    """What drives the two actuator runs, at the actuator rate (1/``step`` Hz).

    ``command_ut``, ``command_pt`` (rad) and ``load_ut`` (N m, measured UT torque) hold
    ``n_model * ratio`` samples; ``source`` says where the commands came from.
    """

    command_ut: np.ndarray
    command_pt: np.ndarray
    load_ut: np.ndarray
    step: float
    ratio: int  # actuator steps per model step
    n_model: int
    source: str


@dataclass
class CosimResult:
    """Everything the master recorded. Model-rate arrays have ``n_model`` samples (time
    k * T); actuator-rate arrays ``n_model * ratio`` (time i * h, outputs at the start of
    each actuator step)."""

    time: np.ndarray  # s, model rate
    torque: np.ndarray  # N m
    torque_intrinsic: np.ndarray
    torque_reflex: np.ndarray
    model_inputs: dict  # name -> array at the model rate (what the model FMU received)
    ut: np.ndarray  # (n, 3) UT actuator position, velocity, acceleration at the actuator rate
    pt: np.ndarray  # (n, 3) PT actuator outputs
    load_pt_model: np.ndarray  # N m, the model torque loading the PT actuator for each sample (over model step k; k + 1 for a 5-point causal FMU)
    iterations: np.ndarray  # fixed-point iterations per model step (1 with coupling="delay")
    settings: CosimSettings
    parameters: dict  # actuator parameters set in both runs
    step_model: float
    step_actuator: float
    elapsed: float  # s of wall time in the stepping loop
    connections: list = field(default_factory=list)
    variant: str = "causal"  # of the model FMU (model_fmu_variant)
    latency: int = 0  # its output delay in model steps, removed from the torques above

    @property
    def real_time_factor(self) -> float:
        return float(self.time[-1] + self.step_model) / self.elapsed if self.elapsed > 0 else float("inf")


# --------------------------------------------------------------------------- signals


def _fir(p: int) -> np.ndarray:
    from lpvpc.io import FIR_ATTENUATION_DB, FIR_TAPS_PER_FACTOR

    return scipy.signal.firwin(FIR_TAPS_PER_FACTOR * p + 1, 1.0 / p,
                               window=("kaiser", scipy.signal.kaiser_beta(FIR_ATTENUATION_DB)))


def to_rate(x, fs_from: float, fs_to: float, what: str = "signal") -> np.ndarray:
    """Resample ``x`` from ``fs_from`` to ``fs_to`` (Hz) when one is an integer multiple of
    the other: the package's anti-aliased decimation down, band-limited (zero-phase
    Kaiser FIR) interpolation up, sample j of the input landing on sample j*p. DataError
    for other ratios."""
    x = np.asarray(x, dtype=float)
    if abs(fs_from - fs_to) <= 1e-9 * fs_to:
        return x.copy()
    if fs_from > fs_to:
        q = fs_from / fs_to
        if abs(q - round(q)) > 1e-6:
            raise DataError(f"{what}: rate {fs_from:g} Hz is not an integer multiple of {fs_to:g} Hz")
        return decimate_signal(x, int(round(q)))
    p = fs_to / fs_from
    if abs(p - round(p)) > 1e-6:
        raise DataError(f"{what}: the actuator rate {fs_to:g} Hz is not an integer multiple of the record's "
                        f"{fs_from:g} Hz")
    p = int(round(p))
    n = len(x)
    ramp = np.linspace(x[0], x[-1], n) if n > 1 else x.copy()
    y = scipy.signal.resample_poly(x - ramp, p, 1, window=_fir(p))  # resample_poly scales by p itself
    ramp_up = np.interp(np.arange(n * p) / p, np.arange(n), ramp)
    return y + ramp_up


def band_limit(x, fs: float, cutoff_fs: float) -> np.ndarray:
    """Zero-phase low-pass of ``x`` (sampled at ``fs`` Hz) to the band of a signal sampled at
    ``cutoff_fs`` Hz: the anti-alias FIR of the package's decimator (Kaiser, 80 dB, cut-off
    at cutoff_fs / 2), applied without decimating. Used on a planned command, which is known
    in advance, so that the actuator moves within the band a model at ``cutoff_fs`` represents."""
    q = fs / cutoff_fs
    if abs(q - round(q)) > 1e-6 or round(q) < 2:
        raise DataError(f"cannot band-limit a {fs:g} Hz signal to the band of {cutoff_fs:g} Hz (needs an integer "
                        "ratio of at least 2)")
    x = np.asarray(x, dtype=float)
    n = len(x)
    ramp = np.linspace(x[0], x[-1], n) if n > 1 else x.copy()
    return ramp + scipy.signal.convolve(x - ramp, _fir(int(round(q))), mode="same", method="fft")


def servo_response(command, step: float, bandwidth: float, damping: float) -> np.ndarray:
    """Position of the 2nd-order servo loop theta'' = wn^2 (r - theta) - 2 zeta wn theta'
    (wn = 2 pi bandwidth) for a command held over each ``step`` (exact zero-order hold),
    starting at rest at command[0]. The actuator FMU's servo without its footplate mode."""
    u = np.asarray(command, dtype=float)
    wn = 2 * np.pi * bandwidth
    A = np.array([[0.0, 1.0], [-wn ** 2, -2 * damping * wn]])
    B = np.array([[0.0], [wn ** 2]])
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), step, method="zoh")
    b, a = scipy.signal.ss2tf(Ad, Bd, np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    return u[0] + scipy.signal.lfilter(b[0], a, u - u[0])


def feedforward_command(position, step: float, bandwidth: float, damping: float) -> np.ndarray:
    """Command under which the servo loop reproduces ``position`` (rad, at 1/``step`` Hz):
    the inverse of the loop, r = theta + (2 zeta / wn) theta' + theta'' / wn^2, with
    derivatives by central differences. Used when a record has no command channel."""
    p = np.asarray(position, dtype=float)
    wn = 2 * np.pi * bandwidth
    v = np.gradient(p, step)
    a = np.gradient(v, step)
    return p + (2 * damping / wn) * v + a / wn ** 2


#: Actuator parameters :func:`actuator_inverse` needs (the actuator FMU's, lpvpc.export.actuator).
ACTUATOR_LINEAR_PARAMETERS = ("servo_bandwidth", "servo_damping", "footplate_inertia", "servo_stiffness",
                              "coupling_damping")


def actuator_inverse(x, step: float, parameters: dict) -> np.ndarray:
    """Command change (rad, at 1/``step`` Hz) under which the actuator's footplate moves by
    ``x`` more: ``x`` divided by the actuator's linear response, the servo loop times the
    footplate mode (lpvpc.export.actuator's equations; the load torque held) times the zero-order
    hold's half-step delay, in the frequency domain over the mirrored record (no wrap-around
    at its ends). ``parameters``: :data:`ACTUATOR_LINEAR_PARAMETERS`. Where
    :func:`feedforward_command` inverts the servo loop alone, this also undoes the footplate's
    lag, which is what remains at 30-50 Hz. Give it band-limited signals: the inverse grows as
    frequency^4.

    >>> p = {"servo_bandwidth": 40.0, "servo_damping": 0.7, "footplate_inertia": 0.02,
    ...      "servo_stiffness": 2.0e4, "coupling_damping": 0.7}
    >>> t = np.arange(2000) * 1e-3  # s
    >>> x = 1e-3 * np.sin(2 * np.pi * 5.0 * t)  # rad, 5 Hz
    >>> d = actuator_inverse(x, 1e-3, p)
    >>> lead = [np.dot(d[200:-200], x[200 + k:len(x) - 200 + k]) for k in range(20)]
    >>> int(np.argmax(lead))  # ms: the command leads the motion by the actuator's lag
    6
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    X = np.fft.rfft(np.r_[x, x[::-1]])
    s = 2j * np.pi * np.fft.rfftfreq(2 * n, step)
    wn = 2 * np.pi * parameters["servo_bandwidth"]
    J, K_s = parameters["footplate_inertia"], parameters["servo_stiffness"]
    B_c = 2 * parameters["coupling_damping"] * np.sqrt(K_s * J)
    servo = wn ** 2 / (s ** 2 + 2 * parameters["servo_damping"] * wn * s + wn ** 2)
    footplate = (B_c * s + K_s) / (J * s ** 2 + B_c * s + K_s)
    return np.fft.irfft(X / (servo * footplate * np.exp(-s * step / 2)), 2 * n)[:n]


def calibrate_servo(command_pert, position_pert, step: float, fs_record: float, start=(40.0, 0.7)) -> dict:
    """Fit the servo loop's bandwidth (Hz) and damping to a record: the perturbation
    command (PT - UT, at the actuator rate 1/``step``) against the measured perturbation
    position (PT - UT, at ``fs_record``), by least squares on the simulated position
    (``servo_response``, brought to the record's rate). Returns the fitted values,
    the VAF of the fit (percent) and the number of evaluations."""
    from scipy.optimize import least_squares

    from lpvpc.models.model import vaf

    fs_a = 1.0 / step
    target = np.asarray(position_pert, dtype=float)
    n = len(target)

    def simulate(theta):
        y = servo_response(command_pert, step, np.exp(theta[0]), theta[1])
        y = to_rate(y, fs_a, fs_record, "servo response")
        return y[:n]

    def residual(theta):
        return simulate(theta) - target

    fit = least_squares(residual, [np.log(start[0]), start[1]], bounds=([np.log(1.0), 0.05], [np.log(500.0), 5.0]),
                        x_scale=[0.3, 0.2], xtol=1e-10, ftol=1e-12)
    return {"servo_bandwidth": float(np.exp(fit.x[0])), "servo_damping": float(fit.x[1]),
            "vaf": vaf(target, simulate(fit.x)), "evaluations": int(fit.nfev)}


# --------------------------------------------------------------------------- master


def connections(settings: CosimSettings, signals=(), variant: str = "causal", latency: int = 0,
                points: int = 3) -> list:
    """The signal connections of the experiment, by variable name, as readable lines
    (``signals``: names of an extended model's extra inputs, fed from the record;
    ``variant``/``latency``: of the model FMU, :func:`model_fmu_variant`; ``points``: of a
    causal FMU's central differences, ``model_fmu_derivative_points``)."""
    load_ut = {"measured_ut+model": "record.UT torque (measured, at the actuator rate)",
               "model": "0", "none": "0"}[settings.load]
    load_pt = {"measured_ut+model": "record.UT torque + model.torque",
               "model": "model.torque", "none": "0"}[settings.load]
    delay = " (torque of the previous model step)" if settings.coupling == "delay" else " (iterated to convergence)"
    if variant == "exact":
        delay = f" (the exact FMU's current output: the torque of {latency} model steps earlier)"
    if settings.load == "none":
        delay = ""
    cmd = "every actuator step" if settings.command_rate == "actuator" else "held over each model step"
    if settings.derivatives == "central" and points == 5:
        vel = "5-point central difference of model.position at the model rate"
        acc = "5-point central second difference of model.position at the model rate"
        if settings.load != "none":  # the model is evaluated one model step late (it needs p(k + 2))
            delay = (" (torque of the model step before the previous one)" if settings.coupling == "delay" else
                     " (the previous model step's torque, iterated to convergence)")
    elif settings.derivatives == "central":
        vel = "central difference of model.position at the model rate"
        acc = "central second difference of model.position at the model rate"
    else:
        vel = "actuator_pt.velocity - actuator_ut.velocity"
        acc = "actuator_pt.acceleration - actuator_ut.acceleration"
    return [
        ("actuator_ut.command", f"record.UT command ({cmd})"),
        ("actuator_pt.command", f"record.PT command ({cmd})"),
        ("actuator_ut.load_torque", load_ut),
        ("actuator_pt.load_torque", load_pt + delay),
        ("model.position", "actuator_pt.position - actuator_ut.position"),
        ("model.scheduling", "actuator_ut.position"),
    ] + ([("model.velocity", vel), ("model.acceleration", acc)] if variant == "causal" else []) + [
        (f"model.{name}", f"record.{name} (at the model rate, every model step)") for name in signals]


def hold_tail(x, n: int):
    """``x`` (along axis 0) followed by ``n`` copies of its last row: a run continued past
    the record with everything held (the record-edge convention of lpvpc.models.equations)."""
    x = np.asarray(x)
    return np.concatenate([x, np.repeat(x[-1:], n, axis=0)]) if n else x


def _check_finite(values, who, names, t):
    for name, v in zip(names, values):
        if not np.isfinite(v):
            raise FMUError(f"{who}: output '{name}' is {v} (not finite) at t = {t:.6g} s although the FMU "
                           "reported OK")


def _next_guess(tried):
    """Next load torque of the fixed-point iteration g = y(g): plain substitution after one
    try, then the secant step to the fixed point of the line through the last two tries
    (y(g) is affine in g when the actuator and the model's dependence on it are linear,
    so this converges in about three evaluations; substitution alone contracts by the
    loop gain per evaluation)."""
    g1, y1 = tried[-1]
    if len(tried) < 2:
        return y1
    g0, y0 = tried[-2]
    if g1 == g0:
        return y1
    slope = (y1 - y0) / (g1 - g0)
    if not np.isfinite(slope) or abs(1.0 - slope) < 1e-12 or abs(slope) >= 1.0:
        return y1
    return g1 + (y1 - g1) / (1.0 - slope)


def run_cosimulation(model_fmu: FMUInfo, actuator_fmu: FMUInfo, drive: ActuatorDrive, *,
                     settings: CosimSettings | None = None, actuator_parameters: dict | None = None,
                     signals: dict | None = None, latency: int = 0) -> CosimResult:
    """Run the experiment (module docstring) over ``drive`` and return what the master saw.

    ``actuator_parameters`` (name -> value) are set in both actuator instances in
    addition to ``initial_position`` (each run starts at rest at its first command).
    ``signals``: an extended model's extra inputs (FMU input name -> array at the model
    rate, at least ``drive.n_model`` samples), set from the record at every model step.
    ``latency``: the output delay in model steps of an exact-variant model FMU
    (:func:`lpvpc.export.exporter.latency_samples`). Its current output (the torque of ``latency``
    steps earlier) loads the PT actuator over the next step (no algebraic loop, no
    derivatives: ``coupling`` and ``derivatives`` do not apply); the run continues
    ``latency`` steps past the record with the last command and load held (the record-edge
    convention of :mod:`lpvpc.models.equations`) and the torques are shifted back to their time.

    Parameters
    ----------
    model_fmu, actuator_fmu : lpvpc.validation.fmu.FMUInfo
        The model FMU and the actuator FMU (:func:`lpvpc.validation.fmu.inspect_fmu`).
    drive : ActuatorDrive
        The actuators' commands for the run.
    settings : CosimSettings, optional
        How the master couples the FMUs; default ``CosimSettings()``.
    actuator_parameters : dict, optional
        Actuator parameter values (name -> value), set in both actuator instances in
        addition to ``initial_position``.
    signals : dict, optional
        An extended model's extra inputs (FMU input name -> array at the model rate, at
        least ``drive.n_model`` samples).
    latency : int, default 0
        The output delay in model steps of an exact-variant model FMU.

    Returns
    -------
    CosimResult
        Everything the master recorded.

    Raises
    ------
    lpvpc.errors.FMUError
        An FMU error status, a non-finite output, a latency the model FMU does not declare,
        or an FMU that cannot iterate (no state saving) with ``coupling="iterate"``.
    lpvpc.errors.DataError
        A drive or signal shorter than the run.
    """
    settings = (settings or CosimSettings()).check()
    params = dict(actuator_parameters or {})
    variant = model_fmu_variant(model_fmu)
    sampled = model_fmu_sampled(model_fmu)
    exact = variant in ("exact", "sampled")  # positions in, outputs of earlier samples: no loop
    if exact != (latency > 0):
        raise FMUError(f"model FMU {model_fmu.path.name}: variant {variant} with latency {latency} samples (an exact "
                       "or sampled FMU has a latency > 0, a causal one none)")
    central = settings.derivatives == "central"
    # 5-point differences of sample j need p(j + 2): with the actuators stepped to t(k + 1),
    # the master evaluates a causal FMU for sample j = k - 1 (one model step late)
    lag = 1 if (variant == "causal" and central and model_fmu_derivative_points(model_fmu) == 5) else 0
    r, h = drive.ratio, drive.step
    H = r * h
    K = drive.n_model
    n_a = K * r
    for name, x in (("command_ut", drive.command_ut), ("command_pt", drive.command_pt), ("load_ut", drive.load_ut)):
        if len(x) < n_a:
            raise DataError(f"actuator drive '{name}' has {len(x)} samples, the run needs {n_a}")
    sig_names = tuple(signals or ())
    S = np.zeros((K, len(sig_names)))
    for j, name in enumerate(sig_names):
        x = np.asarray(signals[name], dtype=float).ravel()
        if len(x) < K:
            raise DataError(f"model input signal '{name}' has {len(x)} samples, the run needs {K}")
        if not np.all(np.isfinite(x[:K])):
            raise DataError(f"model input signal '{name}' has non-finite values")
        S[:, j] = x[:K]
    base_inputs = model_variant_inputs(variant)
    n_in = len(base_inputs) + len(sig_names)
    cmd_u, cmd_p = drive.command_ut[:n_a], drive.command_pt[:n_a]
    if settings.command_rate == "hold":
        idx = (np.arange(n_a) // r) * r
        cmd_u, cmd_p = cmd_u[idx], cmd_p[idx]
    load_u = drive.load_ut[:n_a] if settings.load == "measured_ut+model" else np.zeros(n_a)
    # an exact FMU runs past the end with everything held, so every sample gets its torque
    tail = latency + lag
    cmd_u, cmd_p, load_u = (hold_tail(x, tail * r) for x in (cmd_u, cmd_p, load_u))
    S = hold_tail(S, tail)
    K_run = K + tail
    n_run = K_run * r
    model_loads = settings.load != "none"
    iterate = settings.coupling == "iterate" and model_loads and not exact

    Yu = np.empty((n_run + 1, 3))
    Yp = np.empty((n_run + 1, 3))
    tq = np.empty((K_run, 3))
    ins = np.empty((K_run, n_in))
    load_model = np.zeros(K_run)
    iters = np.ones(K_run, dtype=int)

    instances = []
    try:
        ut = FMUInstance(actuator_fmu, "actuator_ut")
        instances.append(ut)
        pt = FMUInstance(actuator_fmu, "actuator_pt")
        instances.append(pt)
        mod = FMUInstance(model_fmu, "model")
        instances.append(mod)
        ut.initialize(0.0, {**params, "initial_position": float(cmd_u[0])})
        pt.initialize(0.0, {**params, "initial_position": float(cmd_p[0])})
        mod.initialize(0.0)
        a_in = [a.port(ACTUATOR_INPUTS, "input") for a in (ut, pt)]
        a_out = [a.port(ACTUATOR_OUTPUTS, "output") for a in (ut, pt)]
        m_in = mod.port(tuple(base_inputs) + sig_names, "input")
        m_out = mod.port(MODEL_OUTPUTS, "output")
        if iterate and not actuator_fmu.model_description.coSimulation.canGetAndSetFMUstate:
            raise FMUError(f"{actuator_fmu.path.name}: coupling 'iterate' needs fmi{actuator_fmu.fmi_version}"
                           "GetFMUstate/SetFMUstate, which this actuator FMU does not support")

        def run_actuator(inst, port_in, port_out, cmd, base_load, extra, Y, i0):
            for i in range(i0, i0 + r):
                port_in.set((cmd[i], base_load[i] + extra))
                Y[i] = port_out.get()
                inst.do_step(i * h, h)
            Y[i0 + r] = port_out.get()  # outputs at t(k+1) with the last inputs (position has no feedthrough)

        def check_actuators(i0):
            blk_u, blk_p = Yu[i0:i0 + r + 1], Yp[i0:i0 + r + 1]
            if not (np.isfinite(blk_u).all() and np.isfinite(blk_p).all()):
                for who, blk in (("actuator_ut", blk_u), ("actuator_pt", blk_p)):
                    for row in range(r + 1):
                        _check_finite(blk[row], who, ACTUATOR_OUTPUTS, (i0 + row) * h)

        def model_outputs(u, tk):
            m_in.set(u)
            y = m_out.get()
            if not (np.isfinite(y[0]) and np.isfinite(y[1]) and np.isfinite(y[2])):
                _check_finite(y, "model", MODEL_OUTPUTS, tk)
            return y

        Yu[0], Yp[0] = a_out[0].get(), a_out[1].get()  # positions at t(0) (no feedthrough)
        tq_prev = tq_prev2 = 0.0
        p_prev = None
        P = np.empty(K_run + 1)  # perturbation position at the model's sample times
        P[0] = Yp[0, 0] - Yu[0, 0]
        t_start = time.perf_counter()
        for k in range(K_run):
            i0 = k * r
            tk = k * H
            if exact:  # the model first: its output loads the PT actuator over [t(k), t(k+1)]
                u = (Yp[i0, 0] - Yu[i0, 0], Yu[i0, 0], *S[k])
                if sampled:  # processes sample k at the step's start; then holds the torque of k - 1
                    m_in.set(u)
                    mod.do_step(tk, H)
                    y = m_out.get()
                    if not np.isfinite(y).all():
                        _check_finite(y, "model", MODEL_OUTPUTS, tk + H)
                else:
                    y = model_outputs(u, tk)
                guess = y[0] if model_loads else 0.0
                run_actuator(ut, a_in[0], a_out[0], cmd_u, load_u, 0.0, Yu, i0)
                run_actuator(pt, a_in[1], a_out[1], cmd_p, load_u, guess, Yp, i0)
                check_actuators(i0)
                ins[k], tq[k], load_model[k] = u, y, guess
                if not sampled:
                    mod.do_step(tk, H)
                continue
            run_actuator(ut, a_in[0], a_out[0], cmd_u, load_u, 0.0, Yu, i0)
            # first guess of the torque over [t(k), t(k+1)]: the last one (delay), or its
            # linear extrapolation (iterate)
            guess = (2 * tq_prev - tq_prev2 if iterate else tq_prev) if model_loads else 0.0
            state = pt.get_state() if iterate else None
            it = 0
            tried = []
            while True:
                it += 1
                run_actuator(pt, a_in[1], a_out[1], cmd_p, load_u, guess, Yp, i0)
                check_actuators(i0)
                p_k = Yp[i0, 0] - Yu[i0, 0]
                P[k + 1] = Yp[i0 + r, 0] - Yu[i0 + r, 0]
                if lag:  # sample j = k - 1 from p(j - 2) .. p(j + 2); at rest before the record
                    j = k - 1
                    if j < 0:
                        break  # nothing to evaluate yet: the actuators only move to t(1)
                    pj = [P[max(i, 0)] for i in range(j - 2, j + 3)]
                    vel, acc = five_point_derivatives(*pj, 1.0 / H)
                    u = (pj[2], Yu[j * r, 0], vel, acc, *S[j])
                elif central:
                    p_next = P[k + 1]
                    p_before = p_k if p_prev is None else p_prev  # at rest before the record
                    vel = (p_next - p_before) / (2 * H)
                    acc = (p_next - 2 * p_k + p_before) / (H * H)
                    u = (p_k, Yu[i0, 0], vel, acc, *S[k])
                else:
                    vel = Yp[i0, 1] - Yu[i0, 1]
                    acc = Yp[i0, 2] - Yu[i0, 2]
                    u = (p_k, Yu[i0, 0], vel, acc, *S[k])
                y = model_outputs(u, tk - lag * H)
                if not iterate or abs(y[0] - guess) <= settings.iterate_tol or it >= settings.max_iterations:
                    break
                pt.set_state(state)
                pt.time = tk
                tried.append((guess, y[0]))
                guess = _next_guess(tried)
            if state is not None:
                pt.free_state(state)
            p_prev = p_k
            if k < lag:
                continue
            load_model[k - lag] = guess  # the load standing for the torque of sample k - lag
            iters[k - lag] = it
            ins[k - lag] = u
            tq[k] = y  # the torque of sample k - lag (shifted back below)
            mod.do_step(tk - lag * H, H)  # the model's clock is its sample's time
            tq_prev2, tq_prev = tq_prev, y[0]
        elapsed = time.perf_counter() - t_start
    finally:
        for inst in reversed(instances):
            inst.close()
    out = slice(tail, tail + K)  # output k + L is the torque of sample k
    return CosimResult(
        time=np.arange(K) * H, torque=tq[out, 0], torque_intrinsic=tq[out, 1], torque_reflex=tq[out, 2],
        model_inputs={name: ins[:K, j] for j, name in enumerate(tuple(base_inputs) + sig_names)},
        ut=Yu[:n_a], pt=Yp[:n_a], load_pt_model=load_model[:K], iterations=iters[:K], settings=settings,
        parameters=params, step_model=H, step_actuator=h, elapsed=elapsed,
        connections=connections(settings, sig_names, variant, latency, 5 if lag else 3), variant=variant,
        latency=latency)
