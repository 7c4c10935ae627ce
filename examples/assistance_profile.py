"""Design an exoskeleton assistance torque profile through the identified closed-loop ankle model
(casadi.Opti + IPOPT), then check it on the virtual subject in closed loop.

The plant is the foot plus a light device (0.01 kg m^2 + the model's declared foot inertia). The
exoskeleton applies a torque profile u(t), feed-forward only, held for 10 ms at a time. The ankle
pushes back with the model's torque (positive resists dorsiflexion):

    (I_device + I_ankle) theta'' = u(t) - torque(theta, theta')

The optimiser finds u so that the angle follows a target movement: a 0.2 rad dorsiflexion and
back, minimum-jerk, from a held -0.15 rad. The ankle model is the closed-loop form's CasADi tick
function (lpvpc.export.closed_loop.closed_loop_step, 1 ms per call). Its state and the plant's state are
decision variables (multiple shooting, so the problem stays sparse). The profile is then applied,
unchanged and without feedback, to the virtual subject (lpvpc.simulation.compliant_loop: the subject's physics
with its torque fed back) and the angle it produces is compared with the target.

Run: python examples/assistance_profile.py  (identifies a model from simulated trials first)
Units: rad, rad/s, N m, kg m^2, s.
"""

from __future__ import annotations

import numpy as np

DEVICE_INERTIA = 0.01  # kg m^2
TICK = 1e-3  # s: the model's base tick and the plant's step
HOLD = 10  # ticks per assistance value (10 ms)


def target_trajectory(duration: float = 1.0, start: float = -0.15, amplitude: float = 0.2) -> np.ndarray:
    """Target angle (rad) every 1 ms: held, a minimum-jerk move up by ``amplitude`` in 0.25 s,
    held, and back in 0.25 s."""
    t = np.arange(int(round(duration / TICK))) * TICK

    def min_jerk(t0, T):
        s = np.clip((t - t0) / T, 0.0, 1.0)
        return 10 * s**3 - 15 * s**4 + 6 * s**5

    return start + amplitude * (min_jerk(0.1, 0.25) - min_jerk(0.55, 0.25))


def design_profile(cl, target: np.ndarray, smoothness: float = 1e-6):
    """Assistance torque (N m, one value per 1 ms, held for 10 ms) that makes the closed-loop model
    ``cl`` follow ``target`` (rad); returns (profile, the model's predicted angle)."""
    import casadi as ca

    from lpvpc.export.closed_loop import closed_loop_step
    from lpvpc.export.exporter import trajectory_function

    step = closed_loop_step(cl)
    n, nx = len(target), step.size1_in(0)
    inertia = DEVICE_INERTIA + cl.inertia
    opti = ca.Opti()
    theta, omega = opti.variable(n + 1), opti.variable(n + 1)
    X = opti.variable(nx, n + 1)  # the model's state at every tick
    u = opti.variable(n // HOLD)
    opti.subject_to([theta[0] == target[0], omega[0] == 0.0, X[:, 0] == 0.0])
    for k in range(n):
        x_next, torque = step(X[:, k], theta[k], omega[k])[:2]
        acc = (u[k // HOLD] - torque) / inertia
        opti.subject_to([X[:, k + 1] == x_next,
                         omega[k + 1] == omega[k] + TICK * acc,  # the plant's semi-implicit Euler step
                         theta[k + 1] == theta[k] + TICK * omega[k + 1]])
    opti.minimize(ca.sumsqr(theta[1:] - target) + smoothness * ca.sumsqr(ca.diff(u)))
    # warm start: the inverse dynamics of the target through the model (its states along the target,
    # u = inertia x acceleration + the model's torque, averaged over each hold). The model state's
    # tick counters then start exactly on their known values.
    vel = np.gradient(target, TICK)
    run = trajectory_function(step, n)(state=np.zeros(nx), angle=target[None, :], angular_velocity=vel[None, :])
    states = np.column_stack([np.zeros(nx), np.asarray(run["next_state"])])
    u0 = inertia * np.gradient(vel, TICK) + np.asarray(run["torque"]).ravel()
    opti.set_initial(theta, np.r_[target, target[-1]])
    opti.set_initial(omega, np.r_[vel, vel[-1]])
    opti.set_initial(X, states)
    opti.set_initial(u, u0[: n // HOLD * HOLD].reshape(-1, HOLD).mean(axis=1))
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "max_iter": 100, "tol": 1e-6})
    sol = opti.solve()
    profile = np.repeat(np.asarray(sol.value(u)).ravel(), HOLD)
    return profile, np.asarray(sol.value(theta)).ravel()[:n]


def check_on_subject(profile: np.ndarray, target: np.ndarray):
    """The profile applied to the virtual subject in the loop (no feedback controller): the angle."""
    from lpvpc.simulation.compliant_loop import LoopSetup, VirtualSubject, run_loop

    run = run_loop(VirtualSubject(), target, LoopSetup(device_inertia=DEVICE_INERTIA, kp=0.0, kd=0.0),
                   assist=profile)
    return run


def main(seed: int = 0, duration: float = 60.0) -> dict:
    """Identify (simulated PT/UT trials), fit the closed-loop form, design, check; returns the figures."""
    import warnings

    from lpvpc.export.closed_loop import distillation_trial, fit_closed_loop
    from lpvpc.io import pair_trials
    from lpvpc.identification.identify import identify
    from lpvpc.models.model import vaf
    from lpvpc.simulation.simulate import simulate_pair
    from lpvpc.export.whole_joint import fit_whole_joint

    sim = simulate_pair("multilevel", seed=seed, duration=duration, fs_out=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wj = fit_whole_joint(identify(pair_trials(sim.pt, sim.ut)), sim.ut)
    cl = fit_closed_loop(wj, [distillation_trial(wj, sim.ut)])
    target = target_trajectory()
    profile, predicted = design_profile(cl, target)
    run = check_on_subject(profile, target)
    move = np.ptp(target)
    out = {"stable": run.stable, "model_rms_error": float(np.sqrt(np.mean((predicted - target) ** 2))),
           "subject_rms_error": float(np.sqrt(np.mean((run.angle - target) ** 2))), "movement": float(move),
           "subject_vaf": vaf(target, run.angle), "peak_assist": float(np.max(np.abs(profile)))}
    # without the ankle in the design (inertia only), the same target on the subject
    naive = np.gradient(np.gradient(target, TICK), TICK) * (DEVICE_INERTIA + cl.inertia)
    out["naive_rms_error"] = float(np.sqrt(np.mean((check_on_subject(naive, target).angle - target) ** 2)))
    return out


if __name__ == "__main__":
    for k, v in main().items():
        print(f"{k}: {v}")
