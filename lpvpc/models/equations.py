"""The LPV parallel-cascade model equations, written once.

These functions are the single definition of the model. The numpy prediction
(:mod:`lpvpc.models.model`), the identification regressors (:mod:`lpvpc.models.intrinsic`,
:mod:`lpvpc.models.reflex`) and the CasADi step exported to CasADi and FMUs
(:mod:`lpvpc.export.exporter`) all call them, with numpy arrays (one row per sample) or CasADi
rows (one sample).

Notation (seed paper, eqs. 3-20), at sample k, sampling period T = 1/fs:

    intrinsic:  tq_i(k) = sum_l  h_l(rho(k)) * pos(k - l),   h_l(rho) = G_i(rho) . H[l]
                          + (G_i(rho(k)) . c) * pos(k)^2          (elastic curvature, not in the paper)
    velocity:   vel(k)  = (pos(k+1) - pos(k-1)) / (2T)            (central difference)
    reflex in:  z(k)    = sum_ij Omega[i, j] g_i(dvel(k)) G_r(rho(k))_j,  dvel(k) = vel(k - delay)
    reflex:     x(k+1)  = A x(k) + B z(k),   tq_r(k) = C x(k) + D z(k)
    total:      tq(k)   = tq_i(k) + tq_r(k)

Record edges: positions before the start of a record are zero (a perturbation starts
from rest, as the forward-running CasADi step and FMU do); positions after its end are
held at the last value (a record may end mid-perturbation: the joint does not jump back
to zero, and a zero there would put a spurious step into the two-sided IRF and the
central differences of the last samples).
"""

from __future__ import annotations

import numpy as np

from .basis import NUMPY


def intrinsic_torque(lagged_position, rho_basis, H, ops=NUMPY):
    """Intrinsic torque (N m).

    lagged_position: (N, n_lags), column l holds pos(k - lags[l]) in rad.
    rho_basis: (N, n_i) intrinsic scheduling basis G_i(rho(k)).
    H: (n_lags, n_i) IRF coefficients, row l for lag lags[l] (N m/rad).

    A stiffness of 50 N m/rad on lag 0, scheduled by a constant basis, is a spring:

    >>> pos = np.array([0.0, 0.01, 0.02])  # rad
    >>> float(intrinsic_torque(lagged(pos, [0, 1]), np.ones((3, 1)), np.array([[50.0], [0.0]]))[2])
    1.0
    """
    weights = ops.mtimes(rho_basis, H.T)  # h_l(rho(k)) for every lag, (N, n_lags)
    return ops.row_sum(weights * lagged_position)


def elastic_curvature_torque(position, rho_basis, curvature, ops=NUMPY):
    """Second-order elastic torque within a perturbation (N m): (G_i(rho) . c) pos^2.

    The elastic torque of a perturbation p about rho is E(rho + p) - E(rho) = K(rho) p +
    0.5 K'(rho) p^2 + ...; the IRF, linear in p, holds the first term, this the second
    (``curvature`` c: (n_i,) coefficients in N m/rad^2, G_i(rho) . c = 0.5 K'(rho)). Without it the
    reflex nonlinearity of stretch velocity takes up part of p^2 (a stretch step raises
    both) and its gain comes out ~10 % high on the virtual subject
    (benchmarks/results/reflex_1k_bias.txt).

    position: (N,) pos(k) in rad; rho_basis: (N, n_i) G_i(rho(k)).

    >>> float(elastic_curvature_torque(np.array([0.02]), np.ones((1, 1)), np.array([500.0]))[0])  # N m
    0.2
    """
    return ops.mtimes(rho_basis, curvature) * position * position


def central_velocity(pos_ahead, pos_behind, fs):
    """Velocity (rad/s) at k from pos(k+1) and pos(k-1).

    >>> round(central_velocity(0.03, 0.01, fs=100.0), 12)  # rad/s: 0.02 rad over 2 samples of 10 ms
    1.0
    """
    return (pos_ahead - pos_behind) * (0.5 * fs)


def central_acceleration(pos_ahead, pos_here, pos_behind, fs):
    """Acceleration (rad/s^2) at k from pos(k+1), pos(k) and pos(k-1) (central second difference).

    >>> round(central_acceleration(0.04, 0.01, 0.0, fs=100.0), 6)  # pos = 0.5 a t^2 with a = 200 rad/s^2
    200.0
    """
    return (pos_ahead - 2.0 * pos_here + pos_behind) * fs**2


def reflex_drive(velocity_basis, rho_basis, Omega, ops=NUMPY):
    """Output z of the reflex static nonlinearity f(dvel, rho).

    velocity_basis: (N, n_v) basis of the delayed velocity; rho_basis: (N, n_r);
    Omega: (n_v, n_r) coefficients (eqs. 12-13).

    A half-wave rectifier of velocity with gain 2 N m s/rad (a hinge basis), independent of rho:

    >>> from lpvpc.models.basis import Basis
    >>> v = np.array([-1.0, 0.5, 1.0])  # rad/s
    >>> g = Basis("hinge", 2, -1.0, 1.0).evaluate(v)  # 1, s, max(s, 0)
    >>> reflex_drive(g, np.ones((3, 1)), np.array([[0.0], [0.0], [2.0]]))
    array([0., 1., 2.])
    """
    return ops.row_sum(ops.mtimes(velocity_basis, Omega) * rho_basis)


def reflex_step(A, B, C, D, x, z):
    """One step of the reflex linear dynamics (eq. 15): returns (x_next, tq_r).

    >>> A, B, C, D = np.array([[0.5]]), np.array([1.0]), np.array([[1.0]]), 0.0
    >>> x, tq = reflex_step(A, B, C, D, np.zeros(1), 1.0)  # an impulse of the drive
    >>> x, tq = reflex_step(A, B, C, D, x, 0.0)
    >>> float(tq[0]), float(reflex_step(A, B, C, D, x, 0.0)[1][0])  # decays by A each sample
    (1.0, 0.5)
    """
    return A @ x + B * z, C @ x + D * z


def static_gain(A, B, C, D) -> float:
    """Steady-state (DC) gain C (I - A)^-1 B + D of the discrete reflex dynamics of
    :func:`reflex_step` (numpy): the steady reflex torque per unit of constant drive.

    >>> import numpy as np
    >>> static_gain(np.array([[0.5]]), np.array([1.0]), np.array([1.0]), 0.0)  # 1 / (1 - 0.5)
    2.0
    """
    A = np.asarray(A, dtype=float)
    return float(np.asarray(C, dtype=float).ravel() @ np.linalg.solve(np.eye(len(A)) - A, np.asarray(B, dtype=float).ravel())
                 + float(D))


def lagged(signal, lags):
    """(N, len(lags)) array whose column l is signal(k - lags[l]): zero before the record,
    the last value after it (see the module notes on record edges).

    >>> lagged([1.0, 2.0, 3.0], [-1, 0, 1])  # ahead: last value held; behind: zero before
    array([[2., 1., 0.],
           [3., 2., 1.],
           [3., 3., 2.]])
    """
    signal = np.asarray(signal, dtype=float)
    n = len(signal)
    out = np.zeros((n, len(lags)))
    for col, lag in enumerate(lags):
        if lag >= 0:
            out[lag:, col] = signal[: n - lag] if lag < n else []
        else:
            ahead = min(-lag, n)
            out[: n - ahead, col] = signal[ahead:]
            out[n - ahead:, col] = signal[-1] if n else 0.0
    return out


def kron_rows(a, b):
    """Row-wise Kronecker product: row k is ``a[k]`` kron ``b[k]`` (the LPV regressor of
    lagged signals ``a`` whose weights vary with the scheduling basis values ``b``).

    >>> kron_rows(np.array([[1.0, 2.0]]), np.array([[1.0, 10.0]]))
    array([[ 1., 10.,  2., 20.]])
    """
    return (a[:, :, None] * b[:, None, :]).reshape(len(a), -1)


def _padded(position):
    """The record with one sample of edge padding: zero before, the last value after."""
    p = np.asarray(position, dtype=float)
    return np.concatenate([[0.0], p, p[-1:]])


def velocity(position, fs):
    """Central-difference velocity (rad/s) of a whole record (record edges: module notes).

    >>> t = np.arange(5) / 100.0  # s
    >>> velocity(0.5 * t, fs=100.0)[1:-1]  # a ramp of 0.5 rad/s
    array([0.5, 0.5, 0.5])
    """
    p = _padded(position)
    return central_velocity(p[2:], p[:-2], fs)


def acceleration(position, fs):
    """Central second-difference acceleration (rad/s^2) of a whole record.

    >>> t = np.arange(6) / 100.0
    >>> acceleration(0.5 * 3.0 * t**2, fs=100.0)[1:-1].round(9)  # 3 rad/s^2
    array([3., 3., 3., 3.])
    """
    p = _padded(position)
    return central_acceleration(p[2:], p[1:-1], p[:-2], fs)


#: Velocity and acceleration estimates of the causal form: "central3" (3-point central
#: differences, models saved before format key intrinsic.derivatives) or "central5" (5-point,
#: fourth-order: less attenuation of fast velocities; docs/design_notes.md, "Causal-form
#: derivative stencils").
DERIVATIVE_STENCILS = ("central3", "central5")


def derivatives(position, fs, stencil="central3"):
    """(velocity rad/s, acceleration rad/s^2) of a whole record by the named stencil
    (:data:`DERIVATIVE_STENCILS`; record edges: module notes).

    The five-point stencil is exact for a cubic where the three-point one is not:

    >>> t = np.arange(12) / 100.0
    >>> v3, _ = derivatives(t**3, 100.0, "central3")
    >>> v5, _ = derivatives(t**3, 100.0, "central5")
    >>> bool(abs(v5[6] - 3 * t[6]**2) < 1e-12 < abs(v3[6] - 3 * t[6]**2))
    True
    """
    if stencil == "central3":
        return velocity(position, fs), acceleration(position, fs)
    if stencil != "central5":
        raise ValueError(f"unknown derivative stencil {stencil!r}; choose one of {DERIVATIVE_STENCILS}")
    p = np.asarray(position, dtype=float)
    q = np.concatenate([[0.0, 0.0], p, [p[-1], p[-1]]]) if len(p) else np.zeros(4)
    return five_point_derivatives(*(q[i:i + len(p)] for i in range(5)), fs)


def five_point_derivatives(m2, m1, c, p1, p2, fs):
    """(velocity rad/s, acceleration rad/s^2) at k from pos(k-2), pos(k-1), pos(k), pos(k+1),
    pos(k+2): fourth-order central differences (arrays, floats or CasADi symbols).

    >>> h = 0.01
    >>> vel, acc = five_point_derivatives(*(np.sin(k * h) for k in (-2, -1, 0, 1, 2)), fs=1 / h)
    >>> round(float(vel), 9), round(float(acc), 9)  # d/dt sin = 1, d2/dt2 sin = 0 at t = 0
    (1.0, 0.0)
    """
    vel = (8.0 * (p1 - m1) - (p2 - m2)) * (fs / 12.0)
    acc = (16.0 * (p1 + m1) - (p2 + m2) - 30.0 * c) * (fs**2 / 12.0)
    return vel, acc


def causal_signals(position, fs, lags, vel=None, acc=None, stencil="central3"):
    """Signals of the causal intrinsic IRF: pos(k - l) for l in ``lags`` (all >= 0), then
    the velocity and acceleration at k.

    A causal IRF cannot see the onset of an inertial torque (it needs pos(k+1)); in
    closed loop the actuator supplies the current velocity and acceleration instead.
    Offline they are estimated from the record by ``stencil`` unless given.

    >>> pos = np.array([0.0, 0.01, 0.02, 0.03])  # rad, a 1 rad/s ramp at 100 Hz
    >>> causal_signals(pos, 100.0, [0, 1])[1:3].round(9) + 0.0  # pos(k), pos(k-1), vel, acc
    array([[0.01, 0.  , 1.  , 0.  ],
           [0.02, 0.01, 1.  , 0.  ]])
    """
    if vel is None or acc is None:
        v_est, a_est = derivatives(position, fs, stencil)
        vel = v_est if vel is None else vel
        acc = a_est if acc is None else acc
    vel, acc = np.asarray(vel, dtype=float), np.asarray(acc, dtype=float)
    return np.column_stack([lagged(position, lags), vel, acc])


#: Lagged-position cells (samples x signals) built at once by a whole-record prediction:
#: longer records are predicted in blocks, so memory grows with the record, not with
#: record x lags (2**22 cells: 32 MiB per array).
BLOCK_CELLS = 2**22


def blocks(n: int, width: int) -> list:
    """(start, stop) sample ranges covering 0..n, each at most BLOCK_CELLS / width samples.

    >>> blocks(10, 3)
    [(0, 10)]
    >>> len(blocks(2 * BLOCK_CELLS, 1))  # 2**23 samples of one signal: two blocks
    2
    """
    rows = max(1024, BLOCK_CELLS // max(int(width), 1))
    return [(a, min(a + rows, n)) for a in range(0, n, rows)] or [(0, 0)]


def lagged_rows(signal, lags, start: int, stop: int):
    """Rows start..stop-1 of ``lagged(signal, lags)``, built from the samples they need.

    >>> x = np.arange(10.0)
    >>> bool(np.array_equal(lagged_rows(x, [-2, 0, 3], 4, 7), lagged(x, [-2, 0, 3])[4:7]))
    True
    """
    signal = np.asarray(signal, dtype=float)
    back, ahead = max(max(lags), 0), max(-min(lags), 0)
    lo, hi = max(0, start - back), min(len(signal), stop + ahead)
    # Before the record: zeros (lo == 0); after it: the last value (hi == len). Elsewhere the
    # window holds every sample the rows reach, so the rows equal the whole record's.
    return lagged(signal[lo:hi], lags)[start - lo: stop - lo]


def position_signals(position, fs, lags, start: int, stop: int, *, causal: bool, vel=None, acc=None):
    """Rows start..stop-1 of the intrinsic IRF's signals: ``lagged(position, lags)`` or, causal,
    ``causal_signals(position, fs, lags, vel, acc)`` (``vel``, ``acc``: whole-record arrays or None).

    >>> pos = np.linspace(0.0, 0.09, 10)  # rad
    >>> position_signals(pos, 100.0, [0, 1], 2, 4, causal=True).round(9) + 0.0  # lags, then vel, acc
    array([[0.02, 0.01, 1.  , 0.  ],
           [0.03, 0.02, 1.  , 0.  ]])
    """
    rows = lagged_rows(position, lags, start, stop)
    if not causal:
        return rows
    vel = velocity(position, fs) if vel is None else np.asarray(vel, dtype=float)
    acc = acceleration(position, fs) if acc is None else np.asarray(acc, dtype=float)
    return np.column_stack([rows, vel[start:stop], acc[start:stop]])


def delayed_velocity(position, fs, delay):
    """dvel(k) = vel(k - delay) for a whole record, delay in samples (>= 1 keeps it causal).

    >>> pos = np.array([0.0, 0.0, 0.01, 0.02, 0.02, 0.02])  # rad
    >>> delayed_velocity(pos, 100.0, 2)  # rad/s, 2 samples late
    array([0. , 0. , 0. , 0.5, 1. , 0.5])
    """
    return lagged(velocity(position, fs), [delay])[:, 0]


# ---------------------------------------------------------------------------------------
# Extension terms of the extended model (lpvpc.models.effects). Same conventions: numpy arrays
# (one row per sample) or CasADi rows (one sample), through an ``ops`` backend.


class ScalarOps:
    """The ops backend for plain Python floats (per-sample recurrences run in numpy).

    >>> SCALAR.fmin(2.0, 3.0), SCALAR.fmax(2.0, 3.0), SCALAR.exp(0.0)
    (2.0, 3.0, 1.0)
    """

    name = "scalar"

    @staticmethod
    def fmin(a, b):
        return a if a < b else b

    @staticmethod
    def fmax(a, b):
        return a if a > b else b

    @staticmethod
    def exp(a):
        import math

        return math.exp(a)


SCALAR = ScalarOps()


def scheduled_term(features, scheduling_functions, coefficients, ops=NUMPY):
    """Torque (N m) sum_ij coefficients[i, j] * features[:, i] * scheduling_functions[:, j].

    features: (N, n_f); scheduling_functions: (N, n_s) (basis functions of rho, possibly
    times further channels); coefficients: (n_f, n_s). The intrinsic IRF (with lagged
    positions as features) and the reflex nonlinearity are instances of this form.

    A stiffness K(rho) = 40 + 100 rho N m/rad acting on the position (rad):

    >>> pos, rho = np.array([0.01, 0.01]), np.array([0.0, 0.2])
    >>> scheduled_term(pos[:, None], np.column_stack([np.ones(2), rho]), np.array([[40.0, 100.0]]))
    array([0.4, 0.6])
    """
    return ops.row_sum(ops.mtimes(features, coefficients) * scheduling_functions)


def smooth_sign(x, scale, ops=NUMPY):
    """tanh(x / scale), written with exp (argument clipped to +-30: no overflow).

    >>> smooth_sign(np.array([-1.0, 0.0, 1e6]), 0.1).round(6)  # no overflow for huge arguments
    array([-1.,  0.,  1.])
    """
    u = ops.fmin(ops.fmax(x * (1.0 / scale), -30.0), 30.0)
    return 2.0 / (1.0 + ops.exp(-2.0 * u)) - 1.0


def friction_difference(velocity, slow_velocity, scale, ops=NUMPY):
    """tanh((v_slow + v) / scale) - tanh(v_slow / scale): the change a perturbation velocity
    v (rad/s) makes to a smoothed Coulomb friction acting on the total joint velocity.

    At rest a perturbation velocity of 0.5 rad/s takes a 0.05 rad/s-smoothed friction sign
    almost to 1; during a fast slow-movement (1 rad/s) it changes little.

    >>> friction_difference(np.array([0.5, 0.5]), np.array([0.0, 1.0]), 0.05).round(4)
    array([1., 0.])
    """
    return smooth_sign(slow_velocity + velocity, scale, ops) - smooth_sign(slow_velocity, scale, ops)


def direction_memory_step(latched, smoothed, slow_velocity, v_min, v_width, alpha, ops=SCALAR):
    """One sample of the slow-movement direction memory; returns (latched, smoothed) at k.

    ``latched`` jumps to sign(v) while |v| > v_min (rad/s; a ramp of width v_width
    rad/s instead of a jump) and holds its value through holds; ``smoothed`` follows it
    with the first-order factor alpha = 1 - exp(-T / tau). +1 after moving toward
    dorsiflexion (positive rho), -1 after moving toward plantarflexion, 0 before any movement.

    >>> latched, smoothed = direction_memory_step(0.0, 0.0, 0.2, v_min=0.05, v_width=0.01, alpha=1.0)
    >>> latched, smoothed  # moving toward dorsiflexion at 0.2 rad/s
    (1.0, 1.0)
    >>> direction_memory_step(latched, smoothed, 0.0, 0.05, 0.01, 1.0)  # a hold keeps it
    (1.0, 1.0)
    """
    speed = ops.fmax(slow_velocity, -slow_velocity)
    moving = ops.fmin(ops.fmax((speed - v_min) * (1.0 / v_width), 0.0), 1.0)
    sign = ops.fmin(ops.fmax(slow_velocity * (1.0 / v_width), -1.0), 1.0)
    latched = latched + moving * (sign - latched)
    smoothed = smoothed + alpha * (latched - smoothed)
    return latched, smoothed


def direction_memory(slow_velocity, v_min, v_width, alpha):
    """:func:`direction_memory_step` over a whole record (state zero before it): (N,) array.

    >>> v = np.r_[np.full(3, -0.2), np.zeros(3)]  # rad/s: toward plantarflexion, then hold
    >>> direction_memory(v, 0.05, 0.01, 1.0)
    array([-1., -1., -1., -1., -1., -1.])
    """
    latched = smoothed = 0.0
    out = np.empty(len(slow_velocity))
    for k, v in enumerate(np.asarray(slow_velocity, dtype=float).tolist()):
        latched, smoothed = direction_memory_step(latched, smoothed, v, v_min, v_width, alpha, SCALAR)
        out[k] = smoothed
    return out


def relaxation_step(lowpass, position, alpha):
    """One sample of the stress-relaxation memory: the exponential average of the
    perturbation position (rad), lowpass(k) = lowpass(k-1) + alpha (p(k) - lowpass(k-1)),
    alpha = 1 - exp(-T / tau). Returns lowpass(k), which is both the feature at k and the
    next state (state zero before the record, as the numpy record's).

    >>> relaxation_step(0.0, 0.02, 0.5)  # a 20 mrad step, half-way in one sample
    0.01
    """
    return lowpass + alpha * (position - lowpass)


def relaxation_memory(position, alpha):
    """:func:`relaxation_step` over a whole record (state zero before it): (N,) array.

    >>> relaxation_memory(np.full(4, 0.02), 0.5)  # rad: the average catches up with a held step
    array([0.01   , 0.015  , 0.0175 , 0.01875])
    """
    import scipy.signal  # (here: the CLI's start does not need scipy.signal)

    return scipy.signal.lfilter([alpha], [1.0, alpha - 1.0], np.asarray(position, dtype=float))


def state_trajectory(A, B, u):
    """States x(k) of x(k+1) = A x(k) + B u(k), x(0) = 0, for a whole record: (N, m).

    The recurrence of :func:`reflex_step`, run by linear filtering (one filter per state).

    Equals the per-sample recurrence of :func:`reflex_step`:

    >>> A, B = np.array([[0.9, 0.1], [-0.2, 0.8]]), np.array([0.0, 1.0])
    >>> u = np.sin(np.arange(20) / 3.0)
    >>> X = state_trajectory(A, B, u)
    >>> x = np.zeros(2)
    >>> for k in range(19):
    ...     x, _ = reflex_step(A, B, np.eye(2), 0.0, x, u[k])
    >>> bool(np.allclose(X[19], x))
    True
    """
    import scipy.signal

    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(-1, 1)
    m = A.shape[0]
    out = np.empty((len(u), m))
    for i in range(m):
        e_i = np.zeros((1, m))
        e_i[0, i] = 1.0
        num, den = scipy.signal.ss2tf(A, B, e_i, np.zeros((1, 1)))
        out[:, i] = scipy.signal.lfilter(num[0], den, u)
    return out


# ---------------------------------------------------------------------------------------
# Whole-joint model (lpvpc.export.whole_joint): the operating angle is a causal low-pass of the
# joint angle; the quasi-static torque-angle curve acts on it; the LPV-PC model on the rest.


def lowpass_alpha(cutoff, fs, ops=NUMPY):
    """Factor alpha = 1 - exp(-2 pi cutoff / fs) of the first-order low-pass (cutoff Hz, fs Hz).

    >>> round(float(lowpass_alpha(1.0, 100.0)), 4)  # 1 Hz at 100 Hz: about 2 pi / 100
    0.0609
    """
    return 1.0 - ops.exp(-2.0 * np.pi * cutoff / fs)


def lowpass_step(previous, angle, alpha):
    """One sample of the causal first-order low-pass: y(k) = y(k-1) + alpha (x(k) - y(k-1)).

    >>> lowpass_step(0.0, 0.1, 0.5)  # rad: half way toward the new angle
    0.05
    """
    return previous + alpha * (angle - previous)


def lowpass(angle, alpha):
    """:func:`lowpass_step` over a whole record (rad), at rest at the first sample: y(0) = x(0).

    The same recurrence, run as a linear filter on x - x(0).

    >>> y = lowpass(np.r_[0.0, np.full(999, 0.1)], lowpass_alpha(1.0, 100.0))  # a 0.1 rad step
    >>> bool(abs(y[16] - 0.1 * (1 - np.exp(-1))) < 0.002), round(float(y[-1]), 6)  # tau = 1/(2 pi) s
    (True, 0.1)
    """
    import scipy.signal

    x = np.asarray(angle, dtype=float)
    if not len(x):
        return x.copy()
    return scipy.signal.lfilter([alpha], [1.0, alpha - 1.0], x - x[0]) + x[0]


def quasi_static_torque(angle_basis, coefficients, ops=NUMPY):
    """Quasi-static joint torque (N m) sum_i c_i g_i(angle): angle_basis (N, n) basis values,
    coefficients (n,) in N m.

    >>> from lpvpc.models.basis import Basis
    >>> angle = np.array([-0.4, 0.2])  # rad
    >>> quasi_static_torque(Basis("chebyshev", 1, -0.4, 0.2).evaluate(angle), np.array([1.0, 3.0]))
    array([-2.,  4.])
    """
    return ops.mtimes(angle_basis, coefficients)


# ---------------------------------------------------------------------------------------
# Closed-loop form of the whole-joint model (lpvpc.export.closed_loop): a causal impedance of the
# current joint angle and angular velocity (no look-ahead, no inertia), plus the reflex
# pathway with its delay line. Written for numpy arrays (one row per sample) and CasADi rows.


def impedance_features(perturbation, velocity, past_perturbations=(), ops=NUMPY):
    """Features of the causal impedance at one instant: p (rad), omega (rad/s), p^2 (rad^2),
    then the perturbation's past samples p(k-1), ..., p(k-M) (rad; the short memory).

    ``perturbation`` p = angle - operating angle; ``velocity`` the joint's angular velocity.

    >>> impedance_features(np.array([0.01, 0.02]), np.array([0.5, 0.0]))
    array([[1.e-02, 5.e-01, 1.e-04],
           [2.e-02, 0.e+00, 4.e-04]])
    """
    return ops.hcat([perturbation, velocity, perturbation * perturbation, *past_perturbations])


def impedance_torque(features, rho_basis, coefficients, curve_basis, curve, ops=NUMPY):
    """Causal intrinsic torque (N m): the quasi-static torque-angle curve at the operating angle
    plus the position-dependent impedance of the perturbation,

        T_qs(rho) + sum_ij W[i, j] features_i G_i(rho)_j

    (W row 0: stiffness K(rho) in N m/rad, row 1: viscosity B(rho) in N m s/rad, row 2: elastic
    curvature in N m/rad^2, then the memory weights). No inertia: the plant carries it.

    A 40 N m/rad spring with 1 N m s/rad viscosity on a flat curve:

    >>> f = impedance_features(np.array([0.01]), np.array([0.2]))
    >>> impedance_torque(f, np.ones((1, 1)), np.array([[40.0], [1.0], [0.0]]), np.ones((1, 1)), np.zeros(1))
    array([0.6])
    """
    return quasi_static_torque(curve_basis, curve, ops) + scheduled_term(features, rho_basis, coefficients, ops)


def between_samples(at_sample, at_next_sample, fraction):
    """Linear interpolation from a sampled pathway's value at sample k to its value at k + 1
    (``fraction`` of the sample period elapsed, 0..1): the reflex torque between samples,
    without the half-sample lag of a held value.

    >>> between_samples(1.0, 2.0, 0.25)
    1.25
    """
    return at_sample + fraction * (at_next_sample - at_sample)


def companion_form(den):
    """(A, C) in observable canonical form for the monic denominator z^m + den[0] z^(m-1) + ...

    >>> A, C = companion_form(np.poly([0.9, 0.7])[1:])
    >>> np.sort(np.linalg.eigvals(A)), C
    (array([0.7, 0.9]), array([[1., 0.]]))
    """
    m = len(den)
    A = np.zeros((m, m))
    A[:, 0] = -np.asarray(den, dtype=float)
    A[:-1, 1:] = np.eye(m - 1)
    C = np.zeros((1, m))
    C[0, 0] = 1.0
    return A, C


#: Poles of at least this radius count as unstable in the pole refinement.
STABLE_POLE_RADIUS = 0.999
