"""Reflex pathway: LPV Hammerstein regressors and the separable least squares (eqs. 12-29)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal

from ..errors import IdentificationError

# A rank-1 fit whose relative error is within this of the unstructured fit's is accepted
# without trying further starts (the poor attractor seen in practice is ~0.5 worse).
NEAR_UNSTRUCTURED = 0.02
# Starts of the alternating LS taken from the direction search when no singular pair led close.
DIRECTION_STARTS = 3
# Percentile (each end) of the high-rate delayed velocities outside the velocity basis's range.
VELOCITY_RANGE_PERCENTILE = 0.5


def reflex_input_regressor(velocity_basis, rho_basis):
    """U_r (eq. 17): row k is DV(k) kron G_r(k), column ``i * n_r + j`` (Omega[i, j]).

    >>> DV, G = np.array([[1.0, 2.0]]), np.array([[1.0, 10.0]])
    >>> reflex_input_regressor(DV, G)  # columns i * n_r + j
    array([[ 1., 10.,  2., 20.]])
    """
    n = velocity_basis.shape[0]
    return (velocity_basis[:, :, None] * rho_basis[:, None, :]).reshape(n, -1)


@dataclass
class HighRateInput:
    """The reflex nonlinearity's inputs evaluated at the file's rate and decimated.

    ``U_r`` (N, n_v * n_r) model-rate regressor (eq. 17): every column of the high-rate
    U_r (velocity basis of the delayed high-rate velocity times the rho basis) decimated
    with the package's anti-alias filter; ``dvel`` the high-rate delayed velocity (rad/s),
    ``rho`` the high-rate scheduling (rad), ``delay`` the reflex delay in high-rate samples,
    ``fs`` that rate (Hz), ``velocity_basis`` fitted to the high-rate velocities.

    >>> from lpvpc.models.basis import basis_from_data
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=20.0)  # 1 kHz trials
    >>> data = pair_trials(sim.pt, sim.ut)  # 100 Hz, the 1 kHz signals kept
    >>> rho_basis = basis_from_data(data.scheduling, "chebyshev", 2)
    >>> hi = high_rate_input(data.high_rate, 10, 0.040, rho_basis, "hinge", 8)
    >>> hi.U_r.shape, hi.delay, len(hi.dvel)  # model-rate rows; 40 samples of 1 ms
    ((2000, 27), 40, 20000)
    >>> Omega = np.linalg.lstsq(hi.U_r, np.ones(2000), rcond=None)[0].reshape(9, 3)
    >>> z = high_rate_drive(data.high_rate, 10, hi.delay, hi.velocity_basis, rho_basis, Omega)
    >>> bool(np.allclose(z, hi.U_r @ Omega.ravel()))  # the same decimated nonlinearity
    True
    """

    U_r: np.ndarray
    dvel: np.ndarray
    rho: np.ndarray
    delay: int
    fs: float
    velocity_basis: object


def high_rate_input(high, q, reflex_delay, rho_basis, velocity_family, velocity_order) -> HighRateInput:
    """:class:`HighRateInput` from :class:`lpvpc.io.HighRate` signals decimated by ``q``.

    The rectifier of the delayed velocity is nonlinear, so it must act on the velocity the
    lab records (1 kHz: the 20 ms reflex-evoking pulses resolved) and only its output may
    be low-passed to the model rate: decimation is linear, so the decimated columns of U_r
    times Omega equal the decimated rectifier output (eq. 17), and the reflex's linear
    dynamics (bandwidth ~3 Hz) are identified at the model rate as before. Built trial by
    trial (``high.segments``), one column at a time (memory: a few high-rate vectors).
    """
    src = HighRateReflexInput(high, q, reflex_delay, velocity_family, velocity_order)
    return HighRateInput(src(rho_basis), src.dvel, high.scheduling, src.delay, float(high.fs), src.velocity_basis)


class HighRateReflexInput:
    """The high-rate path's model-rate U_r as a function of the scheduling basis: the
    delayed high-rate velocity and its basis are evaluated once, and each call decimates
    the products with ``rho_basis.evaluate(high.scheduling)`` (structure selection calls it
    again with the bases an end fold's model would hold: lpvpc.identification.selection).

    >>> from lpvpc.models.basis import basis_from_data
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=10.0)  # 1 kHz trials
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> src = HighRateReflexInput(data.high_rate, 10, 0.040, "chebyshev", 4)
    >>> rho_basis = basis_from_data(data.scheduling, "chebyshev", 2)
    >>> src(rho_basis).shape, src.n_velocity  # model-rate rows; 5 velocity functions x 3
    ((1000, 15), 5)
    """

    def __init__(self, high, q, reflex_delay, velocity_family, velocity_order):
        from . import equations as eq
        from .basis import Basis
        from ..io.segments import Segments

        fs_h = float(high.fs)
        self.delay = int(round(reflex_delay * fs_h))
        if self.delay < 1:
            raise IdentificationError(f"reflex delay {reflex_delay} s is less than one sample at {fs_h:g} Hz")
        self.q, self.scheduling = int(q), high.scheduling
        self.seg = Segments(high.segments, high.n)
        self.dvel = self.seg.map(eq.delayed_velocity, high.position, fs=fs_h, delay=self.delay)
        # The basis spans the central 99 % of the velocities: at 1 kHz the rare extremes of the
        # servo's step transients (-10..+6 rad/s against +-2.6 for the central 99 % on the virtual
        # subject) would otherwise set the range and leave the rectifier's kink region (0.2-0.8
        # rad/s) between a few coarse knots; beyond the range the basis continues linearly.
        lo, hi = np.percentile(self.dvel, [VELOCITY_RANGE_PERCENTILE, 100.0 - VELOCITY_RANGE_PERCENTILE])
        self.velocity_basis = Basis(velocity_family, int(velocity_order), float(lo), float(max(hi, lo + 1e-9)),
                                    "linear")
        self.V = self.velocity_basis.evaluate(self.dvel)
        self.n_velocity = self.V.shape[1]

    def __call__(self, rho_basis) -> np.ndarray:
        G = rho_basis.evaluate(self.scheduling)
        cols = [self.seg.map(lambda x: sparse_decimated(x, self.q), self.V[:, i] * G[:, j])
                for i in range(self.V.shape[1]) for j in range(G.shape[1])]
        return np.column_stack(cols)


def sparse_decimated(x, q: int) -> np.ndarray:
    """``decimate_signal(x, q)`` computed on windows around the stretches where ``x`` is not
    zero (an end fold's change of basis values is zero but on one level's visits): the same
    values, since the decimation is a finite FIR with zero padding and ``x`` is zero at both
    ends (no end-point line to remove), at a fraction of the cost. Mostly non-zero, or
    non-zero near an end: the whole signal.

    >>> from lpvpc.io import decimate_signal
    >>> x = np.zeros(20000)
    >>> x[3000:4500], x[12000:12500] = np.linspace(0.0, 1.0, 1500), 0.3  # two stretches
    >>> bool(np.allclose(sparse_decimated(x, 10), decimate_signal(x, 10), rtol=0.0, atol=1e-12))
    True
    """
    from ..io import decimate_signal
    from ..io.decimation import FIR_TAPS_PER_FACTOR

    x = np.asarray(x, dtype=float)
    n = len(x)
    nz = np.flatnonzero(x)
    margin = 2 * (FIR_TAPS_PER_FACTOR + 2) * q  # beyond every stage's filter reach (in input samples)
    if nz.size == 0:
        return np.zeros(-(-n // q))
    if nz[0] < margin or nz[-1] >= n - margin or nz.size > n // 3:
        return decimate_signal(x, q)
    cut = np.flatnonzero(np.diff(nz) > 2 * margin)  # stretches whose windows do not meet
    out = np.zeros(-(-n // q))
    for a, b in zip(np.r_[nz[0], nz[cut + 1]], np.r_[nz[cut], nz[-1]] + 1):
        a0 = (a - margin) // q * q  # a multiple of q: the window's samples k*q are the record's
        y = decimate_signal(x[a0 : b + margin], q)
        out[a0 // q : a0 // q + len(y)] = y
    return out


def high_rate_drive(high, q, delay, velocity_basis, rho_basis, Omega):
    """Model-rate reflex drive z (eq. 13) of a record with high-rate signals: the
    nonlinearity evaluated at the high rate (delay in high-rate samples), then decimated
    by ``q`` trial by trial (the path :func:`high_rate_input` identifies)."""
    from . import equations as eq
    from ..io import decimate_signal
    from ..io.segments import Segments

    seg = Segments(high.segments, high.n)
    dvel = seg.map(eq.delayed_velocity, high.position, fs=high.fs, delay=delay)
    z = eq.reflex_drive(velocity_basis.evaluate(dvel), rho_basis.evaluate(high.scheduling), Omega)
    return seg.map(lambda x: decimate_signal(x, q), z)


def reflex_regressor(U_r, A, C, segments=None):
    """Psi_r (eq. 25) computed by filtering, not by explicit sums.

    Block i < m holds U_r filtered by C (zI - A)^-1 e_i (the response of the output to
    state i's input); the last block is U_r itself (the D term). theta_r = [B; d] kron Omega
    (eq. 26) so Psi_r @ theta_r is the reflex torque. With ``segments`` (trials joined end
    to end, :mod:`lpvpc.io.segments`) the filters start from rest in each trial.

    >>> rng = np.random.default_rng(0)
    >>> dvel = rng.standard_normal(3000)  # delayed velocity, rad/s
    >>> DV = np.column_stack([np.ones(3000), dvel, np.maximum(dvel, 0.0)])  # velocity basis
    >>> G = np.column_stack([np.ones(3000), np.linspace(-1.0, 1.0, 3000)])  # scheduling basis
    >>> U_r = reflex_input_regressor(DV, G)
    >>> A, C = np.array([[1.6, 1.0], [-0.63, 0.0]]), np.array([[1.0, 0.0]])  # poles 0.9, 0.7
    >>> blocks = reflex_regressor(U_r, A, C)
    >>> len(blocks), blocks[-1] is U_r  # one block per state, then the feedthrough
    (3, True)
    >>> omega = np.array([0.0, 0.0, 0.0, 0.0, 2.0, 1.0])  # a rectifier whose gain grows with rho
    >>> z = U_r @ omega  # the nonlinearity's output
    >>> x = np.zeros(2)
    >>> y = np.empty(3000)
    >>> for k in range(3000):  # x(k+1) = A x(k) + B z(k), y = C x + D z with B = (1, 0), D = 0
    ...     y[k] = x[0]
    ...     x = A @ x + np.array([1.0, 0.0]) * z[k]
    >>> bool(np.allclose(np.hstack(blocks) @ np.kron([1.0, 0.0, 0.0], omega), y))
    True
    """
    m = A.shape[0]
    blocks = []
    for i in range(m):
        e_i = np.zeros((m, 1))
        e_i[i] = 1.0
        num, den = scipy.signal.ss2tf(A, e_i, C, np.zeros((1, 1)))
        filt = lambda u, num=num, den=den: scipy.signal.lfilter(num[0], den, u, axis=0)  # noqa: E731
        blocks.append(filt(U_r) if segments is None else segments.map(filt, U_r))
    blocks.append(U_r)
    return blocks



def reflex_response_regressor(U_r, A, C, b, d, segments=None):
    """sum_i b_i Psi_r,i + d U_r (the blocks of :func:`reflex_regressor` weighted by [B; D]):
    U_r filtered by the whole reflex dynamics C (zI - A)^-1 B + D in one filter instead of m.

    >>> rng = np.random.default_rng(0)
    >>> U = rng.standard_normal((500, 3))
    >>> A, C = np.array([[1.6, 1.0], [-0.63, 0.0]]), np.array([[1.0, 0.0]])
    >>> b, d = np.array([0.5, -0.2]), 0.1
    >>> blocks = reflex_regressor(U, A, C)
    >>> bool(np.allclose(reflex_response_regressor(U, A, C, b, d), sum(c * k for c, k in zip([*b, d], blocks))))
    True
    """
    num, den = scipy.signal.ss2tf(A, np.asarray(b, dtype=float).reshape(-1, 1), C, np.array([[float(d)]]))
    filt = lambda u: scipy.signal.lfilter(num[0], den, u, axis=0)  # noqa: E731
    return filt(U_r) if segments is None else segments.map(filt, U_r)

@dataclass
class HammersteinFit:
    """The result of :func:`fit_hammerstein`: the reflex dynamics' input vector and
    feedthrough, and the unit-norm nonlinearity coefficients (their product is what the data
    determine; the torque scale sits in ``b`` and ``d``).

    See :func:`fit_hammerstein`, which returns one:

    >>> fit = HammersteinFit(b=np.array([0.5, 0.2]), d=0.0, omega=np.array([0.6, 0.8]), iterations=3,
    ...                      converged=True, relative_error=1e-3)
    >>> float(np.linalg.norm(fit.omega))
    1.0
    """

    b: np.ndarray  # (m,) input vector B of the reflex dynamics
    d: float  # feedthrough D
    omega: np.ndarray  # (n_v * n_r,) nonlinearity coefficients, unit norm
    iterations: int
    converged: bool
    relative_error: float  # ||tq_r - fit||^2 / ||tq_r||^2


def fit_hammerstein(blocks, tq_r, orientation, tol=1e-6, abs_tol=1e-12, max_iter=100) -> HammersteinFit:
    """Separable (alternating) least squares for [B; d] and Omega.

    Starts from rank-1 SVD terms of the unstructured least-squares solution, then alternates
    between the two linear sub-problems. Omega is normalised to unit norm with its sign
    chosen so that ``orientation @ omega > 0`` (a physically meaningful sign: the
    nonlinearity's output grows with stretch velocity). Stops when the normalised error
    changes by less than ``tol`` relative or ``abs_tol`` absolute (on noise-free data
    the relative test alone never triggers).

    A rectifier of velocity (rad/s) through first-order dynamics (pole 0.8), B = 0.5, D = 0.1:

    >>> v = np.random.default_rng(1).standard_normal(2000)
    >>> U_r = reflex_input_regressor(np.column_stack([v, np.maximum(v, 0.0)]), np.ones((2000, 1)))
    >>> blocks = reflex_regressor(U_r, np.array([[0.8]]), np.array([[1.0]]))
    >>> omega = np.array([0.0, 3.0])
    >>> tq = np.hstack(blocks) @ np.kron([0.5, 0.1], omega)
    >>> fit = fit_hammerstein(blocks, tq, orientation=omega)
    >>> fit.converged, bool(fit.relative_error < 1e-12)
    (True, True)
    >>> bool(np.allclose(fit.omega, omega / np.linalg.norm(omega)))  # unit norm, sign by orientation
    True
    >>> bool(np.allclose(np.r_[fit.b, fit.d], np.array([0.5, 0.1]) * np.linalg.norm(omega)))
    True
    """
    m1 = len(blocks)
    n_w = blocks[0].shape[1]
    energy = float(tq_r @ tq_r)
    if energy <= 0:
        raise IdentificationError("reflex torque estimate is identically zero")
    Psi = np.hstack(blocks)
    theta, *_ = np.linalg.lstsq(Psi, tq_r, rcond=None)
    U, S, Vt = np.linalg.svd(theta.reshape(m1, n_w), full_matrices=False)
    # The alternating LS has several attractors, and the dominant singular pair of the
    # unstructured solution does not always lead to the best one (on the virtual subject
    # it once ended at 75 % relative error where the second pair reached 26 %). Start from
    # the singular pairs in turn until a fit comes close to the unstructured optimum.
    resid = tq_r - Psi @ theta
    unstructured = float(resid @ resid) / energy
    best = None
    for k in range(len(S)):
        if S[k] <= 1e-12 * S[0]:
            break
        fit = _alternate(blocks, tq_r, U[:, k] * S[k], Vt[k], orientation, energy, tol, abs_tol, max_iter)
        if best is None or fit.relative_error < best.relative_error:
            best = fit
        if best.relative_error <= unstructured + NEAR_UNSTRUCTURED:
            return best
    # No singular pair led close (seen with well-fitting orders 2 and 3 stuck at twice the
    # error of order 1): search the direction of [B; d], a point on a small sphere whose
    # best Omega is one least-squares solve, and alternate from the best directions found.
    for bd, omega in _best_directions(blocks, tq_r, DIRECTION_STARTS):
        fit = _alternate(blocks, tq_r, bd, omega, orientation, energy, tol, abs_tol, max_iter)
        if fit.relative_error < best.relative_error:
            best = fit
    return best


def refit_jointly(blocks, Psi_i, y, hf, orientation, tol=1e-9, max_iter=50):
    """The intrinsic parameters and the Hammerstein reflex fitted together (separable least
    squares on [Psi_i, rank-1 reflex]), started from the projection's Hammerstein fit ``hf``.
    Returns (theta_i, :class:`HammersteinFit`) with ``relative_error`` that of y.

    Why: the projection (eqs. 27-28) takes the intrinsic parameters from y with the whole
    unstructured reflex space removed: (m+1) x n_v x n_r columns, not the rank-1 reflex the
    model has. With a slow reflex mode (a pole near the time-constant cap: its filter
    integrates the velocity columns into position-like ones) or a richer velocity basis
    (the 1 kHz hinge one) that space overlaps the elastic torque, and K(theta) takes the
    difference (docs/design_notes.md, "Joint intrinsic-reflex refit"). Joint least squares holds
    the reflex to the rank-1 form the selection's cross-validation scores
    (lpvpc.identification.selection): each half-step is linear
    (Omega with [B; d] held, then [B; d]), the intrinsic columns in both. Used where the
    nonlinearity acts on the high-rate velocity (identify); at the model rate it predicted
    left-out levels worse, so the projection's estimate stays there.

    >>> v = np.random.default_rng(2).standard_normal(3000)
    >>> U_r = reflex_input_regressor(np.column_stack([v, np.maximum(v, 0.0)]), np.ones((3000, 1)))
    >>> blocks = reflex_regressor(U_r, np.array([[0.8]]), np.array([[1.0]]))
    >>> Psi_i = np.column_stack([np.cumsum(v) / 30.0, v])  # two intrinsic columns
    >>> y = Psi_i @ [2.0, 0.3] + np.hstack(blocks) @ np.kron([0.5, 0.1], [0.0, 3.0])
    >>> start = HammersteinFit(b=np.array([0.4]), d=0.0, omega=np.array([0.6, 0.8]), iterations=0,
    ...                        converged=False, relative_error=1.0)
    >>> theta_i, fit = refit_jointly(blocks, Psi_i, y, start, orientation=np.array([0.0, 1.0]))
    >>> np.round(theta_i, 6).tolist(), bool(fit.relative_error < 1e-12)
    ([2.0, 0.3], True)
    """
    n_i = Psi_i.shape[1]
    energy = float(y @ y)
    bd, omega = _normalise(np.append(hf.b, hf.d), hf.omega, orientation)
    err_prev, converged, theta_i = np.inf, False, None
    for it in range(1, max_iter + 1):
        X = np.hstack([Psi_i, sum(c * blk for c, blk in zip(bd, blocks))])
        sol = np.linalg.lstsq(X, y, rcond=None)[0]
        bd, omega = _normalise(bd, sol[n_i:], orientation)
        X = np.hstack([Psi_i, np.column_stack([blk @ omega for blk in blocks])])
        sol = np.linalg.lstsq(X, y, rcond=None)[0]
        theta_i, bd = sol[:n_i], sol[n_i:]
        resid = y - X @ sol
        err = float(resid @ resid) / energy
        if abs(err_prev - err) <= max(tol * err, 1e-15):
            converged = True
            break
        err_prev = err
    return theta_i, HammersteinFit(b=bd[:-1], d=float(bd[-1]), omega=omega, iterations=hf.iterations + it,
                                   converged=converged, relative_error=err)


def _best_directions(blocks, tq_r, n_starts, n_per_dim=150):
    """The ``n_starts`` unit vectors [B; d] (of a fixed quasi-random set) whose
    least-squares Omega leaves the smallest residual (the profile of the separable
    problem), each with that Omega."""
    dim = len(blocks)
    directions = np.random.default_rng(0).standard_normal((n_per_dim * dim, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    fits = []
    for bd in directions:
        X = sum(c * blk for c, blk in zip(bd, blocks))
        omega, *_ = np.linalg.lstsq(X, tq_r, rcond=None)
        r = tq_r - X @ omega
        fits.append((float(r @ r), bd, omega))
    fits.sort(key=lambda f: f[0])
    return [(bd, omega) for _, bd, omega in fits[:n_starts]]


def _alternate(blocks, tq_r, bd, omega, orientation, energy, tol, abs_tol, max_iter) -> HammersteinFit:
    bd, omega = _normalise(bd, omega, orientation)
    err_prev = np.inf
    converged = False
    for it in range(1, max_iter + 1):
        X_bd = np.column_stack([blk @ omega for blk in blocks])
        bd, *_ = np.linalg.lstsq(X_bd, tq_r, rcond=None)
        X_om = sum(c * blk for c, blk in zip(bd, blocks))
        omega, *_ = np.linalg.lstsq(X_om, tq_r, rcond=None)
        bd, omega = _normalise(bd, omega, orientation)
        resid = tq_r - sum(c * (blk @ omega) for c, blk in zip(bd, blocks))
        err = float(resid @ resid) / energy
        if abs(err_prev - err) <= max(tol * err, abs_tol):
            converged = True
            break
        err_prev = err
    return HammersteinFit(b=bd[:-1], d=float(bd[-1]), omega=omega, iterations=it, converged=converged, relative_error=err)


def _normalise(bd, omega, orientation):
    norm = np.linalg.norm(omega)
    if norm == 0:
        raise IdentificationError("reflex nonlinearity collapsed to zero")
    sign = 1.0 if float(orientation @ omega) >= 0 else -1.0
    return bd * norm * sign, omega * sign / norm


def rectifier_fit(v, curves):
    """Least-squares half-wave rectifier G * max(v - th, 0) + c for each row of ``curves``
    (N m) over velocities ``v`` (rad/s, ascending); th searched over v[:-5].
    Returns (G in N m s/rad, th in rad/s), one per row.

    >>> v = np.linspace(0, 2, 201)
    >>> g, th = rectifier_fit(v, 3.0 * np.maximum(v - 0.5, 0)[None, :] + 1.0)
    >>> float(g[0]), float(th[0])
    (3.0, 0.5)
    """
    v = np.asarray(v, dtype=float)
    F = np.atleast_2d(np.asarray(curves, dtype=float))
    ths = v[:-5]
    A = np.maximum(v[None, :] - ths[:, None], 0.0)
    A -= A.mean(axis=1, keepdims=True)  # the intercept c, profiled out
    Fc = F - F.mean(axis=1, keepdims=True)
    aa = np.einsum("tv,tv->t", A, A)
    af = A @ Fc.T  # (n_th, n_curves)
    sse = np.einsum("cv,cv->c", Fc, Fc)[None, :] - af**2 / aa[:, None]
    k = np.argmin(sse, axis=0)
    cols = np.arange(F.shape[0])
    return af[k, cols] / aa[k], ths[k]
