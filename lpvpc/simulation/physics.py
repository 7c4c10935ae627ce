"""The physics of the virtual subject, one function per element: the stiff position servo,
the intrinsic mechanics (inertia, viscosity, elastic torque), the stretch reflex
(delayed, rectified, low-passed velocity) and coloured torque noise. SI units, at the
simulation rate.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from ..io.decimation import decimate_signal
from .subject import FS_SIM, SubjectParams


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
    command, then decimated with the anti-alias FIR (:func:`lpvpc.io.decimate_signal`).

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
