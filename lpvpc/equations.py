"""The LPV parallel-cascade model equations, written once.

These functions are the single definition of the model. The numpy prediction
(:mod:`lpvpc.model`), the identification regressors (:mod:`lpvpc.intrinsic`,
:mod:`lpvpc.reflex`) and the CasADi step exported to CasADi and FMUs
(:mod:`lpvpc.export`) all call them, with numpy arrays (one row per sample) or CasADi
rows (one sample).

Notation (seed paper, eqs. 3-20), at sample k, sampling period T = 1/fs:

    intrinsic:  tq_i(k) = sum_l  h_l(rho(k)) * pos(k - l),   h_l(rho) = G_i(rho) . H[l]
    velocity:   vel(k)  = (pos(k+1) - pos(k-1)) / (2T)            (central difference)
    reflex in:  z(k)    = sum_ij Omega[i, j] g_i(dvel(k)) G_r(rho(k))_j,  dvel(k) = vel(k - delay)
    reflex:     x(k+1)  = A x(k) + B z(k),   tq_r(k) = C x(k) + D z(k)
    total:      tq(k)   = tq_i(k) + tq_r(k)

Positions before the start of a record are taken as zero (they are perturbations).
"""

from __future__ import annotations

import numpy as np

from .basis import NUMPY


def intrinsic_torque(lagged_position, rho_basis, H, ops=NUMPY):
    """Intrinsic torque (N m).

    lagged_position: (N, n_lags), column l holds pos(k - lags[l]) in rad.
    rho_basis: (N, n_i) intrinsic scheduling basis G_i(rho(k)).
    H: (n_lags, n_i) IRF coefficients, row l for lag lags[l] (N m/rad).
    """
    weights = ops.mtimes(rho_basis, H.T)  # h_l(rho(k)) for every lag, (N, n_lags)
    return ops.row_sum(weights * lagged_position)


def central_velocity(pos_ahead, pos_behind, fs):
    """Velocity (rad/s) at k from pos(k+1) and pos(k-1)."""
    return (pos_ahead - pos_behind) * (0.5 * fs)


def reflex_drive(velocity_basis, rho_basis, Omega, ops=NUMPY):
    """Output z of the reflex static nonlinearity f(dvel, rho).

    velocity_basis: (N, n_v) basis of the delayed velocity; rho_basis: (N, n_r);
    Omega: (n_v, n_r) coefficients (eqs. 12-13).
    """
    return ops.row_sum(ops.mtimes(velocity_basis, Omega) * rho_basis)


def reflex_step(A, B, C, D, x, z):
    """One step of the reflex linear dynamics (eq. 15): returns (x_next, tq_r)."""
    return A @ x + B * z, C @ x + D * z


def lagged(signal, lags):
    """(N, len(lags)) array whose column l is signal(k - lags[l]), zero outside the record."""
    signal = np.asarray(signal, dtype=float)
    n = len(signal)
    out = np.zeros((n, len(lags)))
    for col, lag in enumerate(lags):
        if lag >= 0:
            out[lag:, col] = signal[: n - lag] if lag < n else []
        else:
            out[: n + lag, col] = signal[-lag:]
    return out


def velocity(position, fs):
    """Central-difference velocity (rad/s) of a whole record (zero outside the record)."""
    p = np.concatenate([[0.0], np.asarray(position, dtype=float), [0.0]])
    return central_velocity(p[2:], p[:-2], fs)


def acceleration(position, fs):
    """Central second-difference acceleration (rad/s^2) of a whole record."""
    p = np.concatenate([[0.0], np.asarray(position, dtype=float), [0.0]])
    return (p[2:] - 2.0 * p[1:-1] + p[:-2]) * fs**2


def causal_signals(position, fs, lags, vel=None, acc=None):
    """Signals of the causal intrinsic IRF: pos(k - l) for l in ``lags`` (all >= 0), then
    the velocity and acceleration at k.

    A causal IRF cannot see the onset of an inertial torque (it needs pos(k+1)); in
    closed loop the actuator supplies the current velocity and acceleration instead.
    Offline they are central differences of the record unless given.
    """
    vel = velocity(position, fs) if vel is None else np.asarray(vel, dtype=float)
    acc = acceleration(position, fs) if acc is None else np.asarray(acc, dtype=float)
    return np.column_stack([lagged(position, lags), vel, acc])


def delayed_velocity(position, fs, delay):
    """dvel(k) = vel(k - delay) for a whole record, delay in samples (>= 1 keeps it causal)."""
    return lagged(velocity(position, fs), [delay])[:, 0]
