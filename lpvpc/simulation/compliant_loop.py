"""A compliant exoskeleton loop with an ankle model in it: where the ankle's torque moves the foot.

The set-up controller and prosthesis designers build:

    (I_device + I_ankle) theta'' = Kp (theta_ref - theta) - Kd theta' - torque_ankle(theta, theta')

foot plus a light device (``device_inertia`` 0.01 kg m^2), a PD exoskeleton controller (Kp 40 N m/rad,
Kd 0.5 N m s/rad) tracking a slow multi-level trajectory over -0.35..+0.15 rad with small +-0.02 rad
steps every 100-400 ms (:func:`reference_trajectory`). Torque positive resists dorsiflexion (the
package's convention), so it enters the plant with a minus sign. ``I_ankle`` is the torque source's
declared inertia (the virtual subject's foot, or a closed-loop FMU's ``inertia`` output; 0 for a model
whose torque holds its inertia, like the replay FMU).

The master (:func:`run_loop`) is a fixed-step co-simulation: at each communication point it sets the
source's inputs from the plant state, reads its torque, holds it over the communication step, in
which the plant and the PD controller are integrated on 1 ms sub-steps (semi-implicit Euler).

Torque sources: :class:`VirtualSubject` (lpvpc.simulation.simulate's physics run forward, one 1 ms tick at a
time, with the torque fed back: viscosity, elastic curve and the delayed, rectified, low-passed
reflex; its inertia is the plant's), and :class:`FmuSource` (an FMU through fmpy's FMU2Slave /
FMU3Slave: the closed-loop FMU with inputs angle and angular_velocity, or the whole-joint replay FMU
with input angle).

Units: rad, rad/s, N m, kg m^2, s.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["LoopSetup", "reference_trajectory", "VirtualSubject", "FmuSource", "LoopRun", "run_loop",
           "loop_vaf", "highpass"]

PLANT_STEP = 1e-3  # s: the plant's integration step (the lab's 1 kHz)
DIVERGED = 1.0  # rad: an angle this far from the reference counts as a diverged loop


@dataclass
class LoopSetup:
    """The loop's plant and controller: inertia kg m^2, gains N m/rad and N m s/rad."""

    device_inertia: float = 0.01
    kp: float = 40.0
    kd: float = 0.5


def reference_trajectory(duration: float, seed: int, fs: float = 1000.0) -> np.ndarray:
    """Reference angle (rad) at ``fs``: multilevel levels in -0.35..+0.15 rad held 4-7 s, plus
    +-0.02 rad steps held 100-400 ms (the small steps that show the ankle's dynamics)."""
    from .simulate import multilevel_trajectory, pralds

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 24]))
    return (multilevel_trajectory(duration, fs, rng, lo=-0.35, hi=0.15)
            + pralds(duration, fs, rng, amplitude=0.02, hold=(0.1, 0.4)))


class VirtualSubject:
    """The virtual subject of :mod:`lpvpc.simulation.simulate` as a torque source with feedback, at 1 kHz.

    torque = B theta' + E(theta) + reflex, reflex = LP_2nd(G(theta_d) max(v_d - th(theta_d), 0))
    with theta_d, v_d the angle and velocity ``reflex_delay`` s ago (the simulate module's
    element functions, run one tick at a time); ``inertia`` (the foot's) belongs to the plant.
    """

    max_step = PLANT_STEP  # s: the subject's physics runs at the plant's step only

    def __init__(self, params=None):
        from .simulate import SubjectParams, reflex_lowpass_coefficients

        self.params = params or SubjectParams()
        self.inertia = float(self.params.inertia)
        self.fs = 1.0 / PLANT_STEP
        self._b, self._a = reflex_lowpass_coefficients(self.params.reflex_wn, self.params.reflex_zeta, self.fs)
        self._b, self._a = self._b / self._a[0], self._a / self._a[0]
        self._delay = int(round(self.params.reflex_delay * self.fs))
        self.reset()

    def reset(self):
        self._hist = None
        self._zi = np.zeros(max(len(self._a), len(self._b)) - 1)
        self._pending = None

    def output(self, theta: float, omega: float) -> float:
        p = self.params
        if self._hist is None:  # at rest before the start (simulate's delay_signal: x[0] before it)
            self._hist = deque([(theta, omega)] * (self._delay + 1), maxlen=self._delay + 1)
        self._hist.append((theta, omega))
        theta_d, v_d = self._hist[0]
        z = float(p.reflex_gain(theta_d)) * max(v_d - float(p.reflex_threshold(theta_d)), 0.0)
        # one sample of the direct-form II transposed filter (scipy.signal.lfilter's)
        y = self._b[0] * z + self._zi[0]
        zi = self._zi.copy()
        for i in range(len(zi)):
            zi[i] = (self._zi[i + 1] if i + 1 < len(zi) else 0.0) + self._b[i + 1] * z - self._a[i + 1] * y
        self._pending = zi
        self.reflex = y
        return p.viscosity * omega + float(p.elastic_torque(theta)) + y

    def advance(self, t: float, h: float) -> None:
        self._zi = self._pending


class FmuSource:
    """An ankle FMU through fmpy's co-simulation slave (FMI 2 or 3), extracted and instantiated
    once; ``inputs``: the FMU's input names it gets, from ("angle", "angular_velocity")."""

    def __init__(self, fmu_path):
        import fmpy

        self.md = fmpy.read_model_description(str(fmu_path))
        self.unzipdir = fmpy.extract(str(fmu_path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        cls = fmpy.fmi3.FMU3Slave if self.md.fmiVersion.startswith("3") else fmpy.fmi2.FMU2Slave
        self.fmu = cls(guid=self.md.guid, unzipDirectory=self.unzipdir,
                       modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="ankle")
        self.fmi3 = self.md.fmiVersion.startswith("3")
        self.fmu.instantiate()
        self.inertia = 0.0
        self._started = False

    def _get(self, names):
        g = self.fmu.getFloat64 if self.fmi3 else self.fmu.getReal
        return g([self.vr[n] for n in names])

    def reset(self):
        if self._started:
            self.fmu.reset()
        if self.fmi3:
            self.fmu.enterInitializationMode(startTime=0.0)
        else:
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self._started = True
        self.inertia = float(self._get(["inertia"])[0]) if "inertia" in self.vr else 0.0

    def output(self, theta: float, omega: float) -> float:
        values = {"angle": theta, "angular_velocity": omega}
        s = self.fmu.setFloat64 if self.fmi3 else self.fmu.setReal
        s([self.vr[n] for n in self.inputs], [values[n] for n in self.inputs])
        return float(self._get(["torque"])[0])

    def advance(self, t: float, h: float) -> None:
        self.fmu.doStep(t, h)

    def close(self):
        import shutil

        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            shutil.rmtree(self.unzipdir, ignore_errors=True)


@dataclass
class LoopRun:
    """One run's records at the plant step (1 ms): time s, reference/angle rad, velocity rad/s,
    ankle and exoskeleton torque N m; ``diverged_at`` s (None: stable to the end)."""

    time: np.ndarray
    reference: np.ndarray
    angle: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    exo_torque: np.ndarray
    diverged_at: float | None

    @property
    def stable(self) -> bool:
        return self.diverged_at is None

    @property
    def deviation(self) -> np.ndarray:
        """Angle minus reference (rad)."""
        return self.angle - self.reference


def run_loop(source, reference, setup: LoopSetup = LoopSetup(), comm_step: float = PLANT_STEP,
             assist=None) -> LoopRun:
    """Run the compliant loop (module notes) with ``source`` as the ankle, ``reference`` (rad) at
    1 kHz, communicating every ``comm_step`` s (a multiple of 1 ms). Starts at rest at the
    reference's first angle. Stops when the angle leaves the reference by ``DIVERGED`` rad,
    turns non-finite, or the source fails (the time is ``diverged_at``). ``assist``: a
    feed-forward exoskeleton torque (N m, one value per 1 ms, positive toward dorsiflexion)
    added to the PD controller's (with ``kp = kd = 0``: the profile alone)."""
    reference = np.asarray(reference, dtype=float)
    assist = np.zeros(len(reference)) if assist is None else np.asarray(assist, dtype=float)
    if assist.shape != reference.shape:
        raise ValueError(f"assist has {assist.shape} samples, the reference {reference.shape}")
    from fmpy.fmi1 import FMICallException  # what an FMU's error status raises

    sub = int(round(comm_step / PLANT_STEP))
    if sub < 1 or abs(sub * PLANT_STEP - comm_step) > 1e-12:
        raise ValueError(f"communication step {comm_step!r} s must be a positive multiple of {PLANT_STEP} s")
    if comm_step > getattr(source, "max_step", np.inf) + 1e-12:
        raise ValueError(f"{type(source).__name__} takes communication steps up to {source.max_step} s")
    source.reset()
    inertia = setup.device_inertia + source.inertia
    n = len(reference)
    angle, vel, tq, exo = (np.full(n, np.nan) for _ in range(4))
    theta, omega = float(reference[0]), 0.0
    diverged = None
    k = 0
    while k < n:
        try:
            torque = source.output(theta, omega)
        except FMICallException:  # an FMU error status (a non-finite value): the loop has failed here
            diverged = k * PLANT_STEP
            break
        for j in range(k, min(k + sub, n)):
            u = setup.kp * (reference[j] - theta) - setup.kd * omega + assist[j]
            angle[j], vel[j], tq[j], exo[j] = theta, omega, torque, u
            omega += PLANT_STEP * (u - torque) / inertia
            theta += PLANT_STEP * omega
        if not (np.isfinite(theta) and abs(theta - reference[min(k + sub, n) - 1]) < DIVERGED):
            diverged = min(k + sub, n) * PLANT_STEP
            break
        try:
            source.advance(k * PLANT_STEP, sub * PLANT_STEP)
        except FMICallException:
            diverged = (k + sub) * PLANT_STEP
            break
        k += sub
    return LoopRun(time=np.arange(n) * PLANT_STEP, reference=reference, angle=angle, velocity=vel, torque=tq,
                   exo_torque=exo, diverged_at=diverged)


def highpass(x, cutoff: float = 0.5, fs: float = 1000.0) -> np.ndarray:
    """Zero-phase 2nd-order Butterworth high-pass (``cutoff`` Hz) of a record."""
    from scipy import signal

    sos = signal.butter(2, cutoff, "highpass", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float))


def loop_vaf(truth: LoopRun, model: LoopRun, skip: float = 1.0) -> dict:
    """VAF (%) of a model's loop against the subject's: angle deviation and torque, whole and
    above 0.5 Hz (both high-passed), after ``skip`` s of start-up. -inf for a diverged run."""
    from ..models.model import vaf

    if not model.stable:
        return {k: float("-inf") for k in ("deviation", "torque", "deviation_hp", "torque_hp")}
    a = int(round(skip / PLANT_STEP))
    out = {}
    for name, get in (("deviation", lambda r: r.deviation), ("torque", lambda r: r.torque)):
        x, y = get(truth), get(model)
        out[name] = vaf(x[a:], y[a:])
        out[name + "_hp"] = vaf(highpass(x)[a:], highpass(y)[a:])
    return out
