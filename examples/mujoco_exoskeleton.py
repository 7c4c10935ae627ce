"""An exoskeleton on a MuJoCo foot hinge, with the identified ankle in the loop.

MuJoCo simulates the foot and the exoskeleton's footplate as one body on a hinge joint (the
ankle). A PD exoskeleton controller drives the hinge to follow a slow multi-level angle
trajectory with small steps (20 s at 1 kHz), adding the ankle's rest torque at the reference
angle as a feed-forward. The ankle pushes back with the torque of the identified closed-loop
ankle model (lpvpc.export.closed_loop), stepped once per 1 ms tick:

    (I_device + I_ankle) theta'' = Kp (theta_ref - theta) - Kd theta' + T_qs(theta_ref)
                                   - torque(theta, theta')

The ankle torque comes either from the model's CasADi tick function or from its FMU, run by
fmpy's FMU2Slave. Both give the same torque; the FMU is what a tool that cannot call Python
would use.

Run:
    python examples/mujoco_exoskeleton.py
        (identifies a model from the virtual subject's simulated trials first, about 20 s)
    python examples/mujoco_exoskeleton.py --model cl.json --fmu ankle.fmu
        (your own model, made by `lpvpc whole-joint model.json --ut UT.csv -o cl.json
        --fmu ankle.fmu --closed-loop`)

Needs MuJoCo: pip install 'lpvpc[mujoco]' (or pip install mujoco).
Units: rad, rad/s, N m, kg m^2, kg, m, s. Positive angle is dorsiflexion; positive model torque
resists dorsiflexion.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

# ---------------------------------------------------------------------------------------------
# Settings: the exoskeleton, the foot, the run

DEVICE_INERTIA = 0.01  # kg m^2: the exoskeleton's footplate about the ankle axis
KPS = (40.0, 150.0)  # N m/rad: the PD controller's stiffness (a compliant and a stiff setting)
KD = 0.5  # N m s/rad: the PD controller's damping
DURATION = 20.0  # s
TIMESTEP = 1e-3  # s: MuJoCo's step, equal to the model's tick (see "Step sizes" below)
SKIP = 1.0  # s: the start-up left out of the tracking error (the loop settles from rest)

# Only used with gravity on: where the foot's weight acts. The model declares the foot's
# inertia about the ankle, not its mass; these are typical adult values.
FOOT_MASS = 1.0  # kg
FOOT_COM = 0.05  # m: the foot's centre of mass in front of the ankle axis
GRAVITY = 9.81  # m/s^2

# ---------------------------------------------------------------------------------------------
# The ankle model: the closed-loop form (angle and velocity in, torque out, no latency,
# the foot's inertia declared apart)


def closed_loop_model(path=None, seed: int = 0, duration: float = 60.0):
    """The closed-loop ankle model: loaded from ``path`` (a file written by ``lpvpc whole-joint
    ... --closed-loop``), or identified from the virtual subject's simulated PT/UT trials."""
    from lpvpc.export.closed_loop import ClosedLoopModel, distillation_trial, fit_closed_loop

    if path is not None:
        return ClosedLoopModel.load(path)

    import warnings

    from lpvpc.export.whole_joint import fit_whole_joint
    from lpvpc.identification.identify import identify
    from lpvpc.io import pair_trials
    from lpvpc.simulation.simulate import simulate_pair

    sim = simulate_pair("multilevel", seed=seed, duration=duration, fs_out=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short trials: the identification warns about its margins
        whole = fit_whole_joint(identify(pair_trials(sim.pt, sim.ut)), sim.ut)
    return fit_closed_loop(whole, [distillation_trial(whole, sim.ut)])


def model_tick(cl) -> float:
    """The model's tick (s): its sample period divided into whole ticks of about 1 ms."""
    from lpvpc.export.exporter import ticks_per_sample

    return 1.0 / (cl.fs * ticks_per_sample(cl.model))


# ---------------------------------------------------------------------------------------------
# The foot on a hinge (MJCF)
#
# The hinge's axis is -y, so that a positive joint angle lifts the toes (x forward, z up):
# dorsiflexion, the model's sign. The moving part is two bodies welded together:
# - "device", the exoskeleton's footplate: its inertia at the axis (its own weight is the
#   exoskeleton's business and is left out);
# - "foot": the model's declared inertia about the ankle, as a mass FOOT_MASS at FOOT_COM in
#   front of the axis plus its own inertia about its centre of mass (parallel axis theorem).
# The hinge's total inertia is then DEVICE_INERTIA + cl.inertia: the identified torque holds no
# inertia, the plant carries it. No joint damping, no armature, no contacts: the model's torque
# is all of the ankle.
#
# Gravity and the foot's weight. The quasi-static torque in the model is fitted to the UT trial's
# torque as the lab recorded it. If the torque sensor carried the foot's weight (a foot resting in
# the footplate, the sensor zeroed without it), the weight's moment is inside the model's
# torque, and MuJoCo must not apply it a second time: gravity="in-model" keeps gravity on for
# the rest of a larger scene and cancels it on the foot (MuJoCo's gravcomp="1"). If the lab
# removed the weight from the record, the model holds none: gravity="not-in-model" lets MuJoCo's
# gravity pull on the foot. The data cannot tell which: the lab's set-up does. The virtual
# subject has no gravity, so its model holds no weight: gravity="off" (the default) and
# "in-model" give the same run.

GRAVITY_MODES = ("off", "in-model", "not-in-model")


def foot_mjcf(foot_inertia: float, *, timestep: float = TIMESTEP, gravity: str = "off",
              device_inertia: float = DEVICE_INERTIA, foot_mass: float = FOOT_MASS,
              foot_com: float = FOOT_COM) -> str:
    """The MJCF of the foot hinge with the exoskeleton's motor (``exo``) on it."""
    if gravity not in GRAVITY_MODES:
        raise ValueError(f"gravity {gravity!r}: expected one of {', '.join(GRAVITY_MODES)}")
    own = foot_inertia - foot_mass * foot_com**2  # kg m^2: the foot about its centre of mass
    if not own > 0:
        raise ValueError(f"the foot's inertia {foot_inertia!r} kg m^2 about the ankle is less than its mass "
                         f"{foot_mass!r} kg at {foot_com!r} m gives ({foot_mass * foot_com**2!r} kg m^2)")
    g = 0.0 if gravity == "off" else GRAVITY
    gravcomp = 1 if gravity == "in-model" else 0
    return f"""
<mujoco model="ankle_exoskeleton">
  <option timestep="{timestep!r}" integrator="Euler" gravity="0 0 {-g!r}"/>
  <worldbody>
    <body name="device">
      <joint name="ankle" type="hinge" axis="0 -1 0"/>
      <inertial pos="0 0 0" mass="0.5" diaginertia="{device_inertia!r} {device_inertia!r} {device_inertia!r}"/>
      <body name="foot" gravcomp="{gravcomp}">
        <inertial pos="{foot_com!r} 0 0" mass="{foot_mass!r}" diaginertia="{own!r} {own!r} {own!r}"/>
        <geom type="capsule" fromto="-0.05 0 -0.04 0.18 0 -0.04" size="0.03" contype="0" conaffinity="0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="exo" joint="ankle" gear="1"/>
  </actuator>
</mujoco>
"""


# ---------------------------------------------------------------------------------------------
# Step sizes: MuJoCo's timestep against the model's tick
#
# The model counts its own time in ticks (1 ms at a 100 Hz model): every call of the CasADi
# tick function is one tick, whatever the caller's clock says. Called once per MuJoCo step of
# 0.5 ms, its time would run twice as fast as MuJoCo's, silently (the FMU refuses such a
# step). So the loop below fits the two clocks together, or refuses:
# - a MuJoCo step of m whole ticks (2 ms: m = 2): the tick runs m times per step with the
#   inputs held, as the FMU's doStep does for a communication step of m ticks;
# - a tick of m whole MuJoCo steps (0.5 ms: m = 2): the tick runs every m-th step and its
#   torque is held in between, as an FMU master holds an output between communication points;
# - anything else (0.7 ms) is refused.
# Whole within 1e-9 relative: a timestep written in decimal (0.001) is not exactly 1/1000.


def clock_ratio(timestep: float, tick: float) -> tuple[int, int]:
    """(ticks per MuJoCo step, MuJoCo steps per tick): one of them is 1."""
    for ratio, flip in ((timestep / tick, False), (tick / timestep, True)):
        m = int(round(ratio))
        if m >= 1 and abs(ratio - m) <= 1e-9 * m:
            return (1, m) if flip else (m, 1)
    raise ValueError(f"MuJoCo's timestep {timestep!r} s is neither a whole number of the model's ticks "
                     f"({tick!r} s) nor a whole fraction of one")


# ---------------------------------------------------------------------------------------------
# The ankle torque from the CasADi tick
#
# The tick function takes (state, angle, angular_velocity) and returns the next state and the
# torque of this tick, from the current inputs (no delay). Initialisation: the state starts at
# zeros, which means "at rest at the first angle it is given": the operating angle starts
# there, the perturbation and the reflex at zero. So the first call must get the plant's own
# starting angle (not 0 rad and then a jump to it).


class CasadiAnkle:
    """The closed-loop model's CasADi tick as a torque source."""

    name = "casadi"

    def __init__(self, cl):
        from lpvpc.export.closed_loop import closed_loop_step

        self.tick_function = closed_loop_step(cl)
        self.inertia = cl.inertia  # kg m^2: add to the plant's
        self.tick = model_tick(cl)
        self.state = np.zeros(self.tick_function.size1_in(0))
        self._next = None

    def torque(self, angle: float, velocity: float) -> float:
        """The ankle torque (N m) at this tick."""
        self._inputs = (angle, velocity)
        self._next, torque = self.tick_function(self.state, angle, velocity)[:2]
        return float(torque)

    def advance(self, n_ticks: int) -> None:
        """Move the model on by ``n_ticks`` ticks, the inputs held."""
        self.state = self._next
        for _ in range(n_ticks - 1):
            self.state = self.tick_function(self.state, *self._inputs)[0]

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------------------------------
# ... or from the FMU (FMI 2 co-simulation, through fmpy)
#
# The FMU declares its tick as the DefaultExperiment step size and the foot's inertia as the
# constant output "inertia". Initialisation: the plant's starting angle is set during
# initialisation mode, so that the FMU starts at rest there, as the CasADi tick does.
# Communication points are counted in whole ticks and multiplied out (k x tick), so that they
# stay on the FMU's grid over long runs; a time built by adding steps drifts off it.


class FmuAnkle:
    """The closed-loop FMU as a torque source."""

    name = "fmu"

    def __init__(self, path, start_angle: float):
        import fmpy
        from fmpy.fmi2 import FMU2Slave

        md = fmpy.read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.tick = float(md.defaultExperiment.stepSize)
        self._unzipped = fmpy.extract(str(path))
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self._unzipped,
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="ankle")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.setReal([self.vr["angle"], self.vr["angular_velocity"]], [start_angle, 0.0])
        self.fmu.exitInitializationMode()
        self.inertia = self.fmu.getReal([self.vr["inertia"]])[0]  # kg m^2: add to the plant's
        self.ticks_done = 0  # the FMU's time in whole ticks: t = ticks_done x tick, never a running sum

    def torque(self, angle: float, velocity: float) -> float:
        self.fmu.setReal([self.vr["angle"], self.vr["angular_velocity"]], [angle, velocity])
        return self.fmu.getReal([self.vr["torque"]])[0]

    def advance(self, n_ticks: int) -> None:
        self.fmu.doStep(self.ticks_done * self.tick, n_ticks * self.tick)
        self.ticks_done += n_ticks

    def close(self) -> None:
        import shutil

        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self._unzipped, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# The loop: read the hinge, ask the ankle, set the exoskeleton's and the ankle's torques, step


def run(physics, ankle, reference, kp: float, kd: float = KD, feedforward=None) -> dict:
    """One run: ``reference`` (rad), one value per MuJoCo step; ``physics`` the MuJoCo model
    (its timestep fitted to the ankle's tick, :func:`clock_ratio`); ``feedforward`` (N m, one
    value per step, or None) added to the PD torque. Starts at rest at the reference's first
    angle. Returns the records (one per step) and the wall time (s)."""
    import mujoco

    data = mujoco.MjData(physics)
    ticks_per_step, steps_per_tick = clock_ratio(physics.opt.timestep, ankle.tick)
    exo = physics.actuator("exo").id
    n = len(reference)
    feedforward = np.zeros(n) if feedforward is None else np.asarray(feedforward, dtype=float)
    angle, velocity, torque, exo_torque = (np.full(n, np.nan) for _ in range(4))
    data.qpos[0], data.qvel[0] = reference[0], 0.0  # at rest at the start; the ankle is told below
    start = time.perf_counter()
    for k in range(n):
        theta, omega = float(data.qpos[0]), float(data.qvel[0])
        if not (np.isfinite(theta) and abs(theta) < 2.0):  # rad: the foot has left any ankle's range
            break
        if k % steps_per_tick == 0:  # a tick starts: the ankle's torque from the current state
            tau_ankle = ankle.torque(theta, omega)
        data.ctrl[exo] = kp * (reference[k] - theta) - kd * omega + feedforward[k]
        data.qfrc_applied[0] = -tau_ankle  # the model's torque resists dorsiflexion
        angle[k], velocity[k], torque[k], exo_torque[k] = theta, omega, tau_ankle, data.ctrl[exo]
        mujoco.mj_step(physics, data)
        if (k + 1) % steps_per_tick == 0:
            ankle.advance(ticks_per_step)
    wall = time.perf_counter() - start
    return {"time": np.arange(n) * physics.opt.timestep, "reference": np.asarray(reference), "angle": angle,
            "velocity": velocity, "torque": torque, "exo_torque": exo_torque, "wall": wall}


def summary(r: dict, timestep: float) -> dict:
    """Stability and tracking of a run (rad, N m) after the start-up, and its real-time factor."""
    after = int(round(SKIP / timestep))
    err = (r["angle"] - r["reference"])[after:]
    finite = bool(np.all(np.isfinite(r["angle"])) and np.all(np.isfinite(r["torque"])))
    duration = len(r["angle"]) * timestep
    return {"stable": finite and float(np.max(np.abs(err))) < 0.2, "finite": finite,
            "rms_error": float(np.sqrt(np.mean(err**2))), "max_error": float(np.max(np.abs(err))),
            "max_angle": float(np.max(np.abs(r["angle"]))), "realtime_factor": duration / r["wall"]}


# ---------------------------------------------------------------------------------------------
# Everything together


def main(model=None, fmu=None, *, kps=KPS, duration: float = DURATION, timestep: float = TIMESTEP,
         gravity: str = "off", compensate: bool = True, sources=("casadi", "fmu"), seed: int = 0,
         keep_runs: bool = False) -> dict:
    """Run the loop for each gain in ``kps`` and each torque source; returns
    ``{(kp, source): summary}`` (with ``"run"``: the records, when ``keep_runs``).

    ``model``: a closed-loop model or its file (None: identify one from the virtual subject);
    ``fmu``: its FMU (None: exported to a temporary folder when ``sources`` has "fmu");
    ``compensate``: the exoskeleton adds the model's quasi-static torque at the reference
    angle to its PD torque (without it, the PD alone holds the foot off the reference by the
    ankle's rest torque over Kp plus the ankle's stiffness)."""
    import tempfile
    import warnings
    from pathlib import Path

    import mujoco

    from lpvpc.export.closed_loop import ClosedLoopModel, export_closed_loop_fmu
    from lpvpc.simulation.compliant_loop import reference_trajectory

    cl = model if isinstance(model, ClosedLoopModel) else closed_loop_model(model)
    physics = mujoco.MjModel.from_xml_string(foot_mjcf(cl.inertia, timestep=timestep, gravity=gravity))
    clock_ratio(physics.opt.timestep, model_tick(cl))  # refuse a timestep the model cannot follow
    n = int(round(duration / timestep))
    reference = reference_trajectory(n * timestep, seed, fs=1.0 / timestep)[:n]  # rad
    # The model knows the ankle over the angles it was identified on; beyond them its
    # quasi-static curve continues as a straight line, which may be far from the ankle.
    lo, hi = cl.model.scheduling_range  # rad
    if reference.min() < lo or reference.max() > hi:
        warnings.warn(f"the reference ({reference.min():.3f}..{reference.max():.3f} rad) leaves the model's "
                      f"identified range [{lo:.3f}, {hi:.3f}] rad", stacklevel=2)
    # The exoskeleton's feed-forward: the ankle's rest torque at the reference angle (the model's
    # quasi-static torque-angle curve), so that the PD corrects only what moves.
    feedforward = cl.whole.quasi_static(reference) if compensate else None  # N m
    results = {}
    with tempfile.TemporaryDirectory(prefix="mujoco-ankle-") as tmp:
        if "fmu" in sources and fmu is None:
            fmu = export_closed_loop_fmu(cl, Path(tmp) / "ankle.fmu")
        for kp in kps:
            for source in sources:
                ankle = CasadiAnkle(cl) if source == "casadi" else FmuAnkle(fmu, reference[0])
                try:
                    r = run(physics, ankle, reference, kp, feedforward=feedforward)
                finally:
                    ankle.close()
                results[(kp, source)] = summary(r, timestep) | ({"run": r} if keep_runs else {})
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="closed-loop model file (lpvpc whole-joint ... --closed-loop)")
    parser.add_argument("--fmu", help="its FMU (default: exported from the model)")
    parser.add_argument("--duration", type=float, default=DURATION, help="s")
    parser.add_argument("--timestep", type=float, default=TIMESTEP, help="MuJoCo's step, s")
    parser.add_argument("--gravity", choices=GRAVITY_MODES, default="off")
    parser.add_argument("--no-compensation", action="store_true", help="the PD alone, no feed-forward")
    args = parser.parse_args()
    out = main(args.model, args.fmu, duration=args.duration, timestep=args.timestep, gravity=args.gravity,
               compensate=not args.no_compensation)
    for (kp, source), s in out.items():
        print(f"Kp {kp:5.0f} N m/rad, {source:6s}: stable {s['stable']}, tracking error RMS "
              f"{1e3 * s['rms_error']:.2f} mrad (max {1e3 * s['max_error']:.2f}), "
              f"{s['realtime_factor']:.1f}x real time")
