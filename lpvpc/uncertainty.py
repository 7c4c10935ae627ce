"""Confidence intervals for the identified model's physical quantities.

Method: heteroscedasticity-and-autocorrelation-consistent (HAC) sandwich covariance of the
final least squares of the identification, propagated to the derived quantities.

The final fit (eqs. 27-29) is, with the reflex dynamics A, C given, the separable
least-squares problem ``y = Psi_i theta_i + sum_j c_j (Psi_r,j omega) + e`` with
``c = [B; d]``. Its Jacobian at the solution is ``J = [Psi_i, sum_j c_j Psi_r,j, [Psi_r,j
omega]_j]``; the scale of (omega, c) is fixed by ``|omega| = 1``, so omega moves only in
the tangent space of that sphere. The residuals of these records are correlated (coloured
sensor noise, the reflex's slow dynamics, what the model misses), so the middle of the
sandwich ``(J'J)^-1 S (J'J)^-1`` is the long-run covariance of ``J_k e_k``, estimated by
overlapping batch means over blocks of ``BLOCK_LENGTH`` seconds (the Bartlett-kernel
Newey-West estimator in O(N p^2), one matrix product). The perturbation's 250-350 ms holds
are the longest correlation in the regressors; 0.5 s covers them.

Derived quantities:

- K(rho), viscosity B(rho) and inertia I(rho) are linear in theta_i (sums and moments of
  the IRF weights), so their standard errors are exact propagations of the covariance.
  On the virtual subject the statistical part alone is conservative (against the same
  trials identified without noise the K intervals cover 99 %), but the estimator has
  structural bias (the IRF one lag short, a polynomial basis following an exponential K,
  reflex torque the model misses leaking into K): HAC alone covers 89 %. So the
  intervals are bias-aware (:func:`bias_aware_critical_value`) with
  :func:`structural_bias_bound`: the sum of the shifts of the quantity when the IRF is
  one lag shorter on each side and when the scheduling basis is one order higher (each
  refitted to the same intrinsic torque) bounds the bias;
- reflex gain and threshold come from a half-wave-rectifier fit to the nonlinearity
  (:meth:`lpvpc.model.LPVPCModel.reflex_gain_threshold`), not a smooth function of the
  parameters: their intervals are percentiles over parameter draws from the Gaussian
  with that covariance (a fixed seed, so intervals are reproducible);
- VAF: moving-block bootstrap of the record (blocks of ``BLOCK_LENGTH``).

The reflex poles (denominator of the companion form that pole refinement returns) join
the parameters as extra Jacobian columns. Not included: the reflex nonlinearity's
structural error (the rectifier of 1 kHz velocity seen at 100 Hz biases the reflex gain by
-1 % in plantarflexion to +19 % in dorsiflexion on the virtual subject, so gain and
threshold intervals under-cover). Measured coverage: ``benchmarks/results/uncertainty.txt``.

Stored in the model file as ``"uncertainty"`` (absent in older files; the interval methods
then raise :class:`~lpvpc.errors.ModelFileError`)::

    method, block_length_s, n_samples, dof
    truncation    {"lags": [-(L-1)..L-1], "H": the one-lag-shorter IRF (N m/rad)}
    richer_basis  {"basis": scheduling basis one order higher, "H": that IRF (N m/rad)}
    parameters    {"theta_i": n, "omega": n_v * n_r, "bd": m + 1, "den": m or 0}: order of
                  the covariance (den: reflex denominator coefficients, when refined)
    covariance    p x p (units of the parameters: theta_i N m/rad, omega 1, bd N m, den 1)
    vaf           {"estimate": %, "lower": %, "upper": %, "level": 0.95}
"""

from __future__ import annotations

import numpy as np

BLOCK_LENGTH = 0.5  # s, batch length of the HAC estimate and block of the VAF bootstrap
N_DRAWS = 400  # parameter draws for the reflex gain/threshold intervals
N_BOOT = 1000  # moving-block bootstrap replicates of the VAF
METHOD = "HAC sandwich (overlapping batch means, 0.5 s) of the final least squares incl. reflex poles"


def z_value(level: float) -> float:
    """Two-sided standard-normal quantile for a confidence ``level`` in (0, 1).

    >>> round(z_value(0.95), 4)
    1.96
    """
    from scipy.stats import norm

    if not 0 < level < 1:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    return float(norm.ppf(0.5 + level / 2))


def long_run_covariance(U, block: int) -> np.ndarray:
    """HAC estimate of Cov(sum_k U_k) for rows U_k (N x p), by overlapping batch means
    over ``block`` rows (equivalent to Newey-West with a Bartlett kernel of that width).

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal((20000, 1))
    >>> round(float(long_run_covariance(u, 20)[0, 0]) / 20000, 1)  # white noise: N var
    1.0
    """
    n = U.shape[0]
    block = int(min(max(block, 1), n))
    c = np.vstack([np.zeros((1, U.shape[1])), np.cumsum(U, axis=0)])
    W = c[block:] - c[:-block]  # (n - block + 1) moving sums
    return (W.T @ W) * (n / ((n - block + 1) * block))


def _reflex_output(z, bd, den, segments=None):
    """Reflex torque of the companion-form dynamics with denominator ``den`` driven by z
    (from rest in each trial of ``segments``)."""
    import scipy.signal

    from .subspace import companion_form

    A, C = companion_form(den)
    num, a = scipy.signal.ss2tf(A, bd[:-1, None], C, np.array([[bd[-1]]]))
    if segments is None:
        return scipy.signal.lfilter(num[0], a, z)
    return segments.map(lambda x: scipy.signal.lfilter(num[0], a, x), z)


def fit_uncertainty(model, Psi_i, blocks, y, bd, omega, theta_i, U_r=None, A=None, truncated=None,
                    segments=None, richer=None) -> dict:
    """The ``uncertainty`` entry of the model file for the fit ``y ~ Psi_i theta_i +
    sum_j bd_j blocks_j omega`` (see the module docstring). Arrays in SI units.

    With ``U_r`` and a companion-form ``A`` (the refined poles' form) the denominator
    coefficients of the reflex dynamics join the parameters (Jacobian columns by central
    differences, one filter each), so pole uncertainty reaches K and the reflex gain.
    ``truncated`` = (lags, Psi) of a one-lag-shorter IRF: refitted to the same intrinsic
    torque for the truncation term of the intrinsic intervals; ``richer`` = (basis, Psi) of
    the IRF with the scheduling basis one order higher, refitted likewise for the basis
    term (module docstring).

    :func:`lpvpc.identify.identify` calls it; the model (and its file) keeps the result:

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> sorted(model.uncertainty)[:4], model.uncertainty["n_samples"]
    (['block_length_s', 'covariance', 'dof', 'method'], 3000)
    """
    from .subspace import companion_form

    N = len(y)
    X_om = sum(c * blk for c, blk in zip(bd, blocks))
    X_bd = np.column_stack([blk @ omega for blk in blocks])
    fitted = Psi_i @ theta_i + X_om @ omega
    e = y - fitted
    # omega moves in the tangent space of |omega| = 1: an orthonormal basis T of omega's complement
    T = np.linalg.svd(omega[:, None], full_matrices=True)[0][:, 1:]
    cols = [Psi_i, X_om @ T, X_bd]
    den = None
    if U_r is not None and A is not None and np.allclose(companion_form(-A[:, 0])[0], A):
        den = -A[:, 0]
        z = U_r @ omega
        for k in range(len(den)):
            h = 1e-6 * max(1.0, abs(den[k]))
            dp, dm = den.copy(), den.copy()
            dp[k] += h
            dm[k] -= h
            cols.append(((_reflex_output(z, bd, dp, segments) - _reflex_output(z, bd, dm, segments)) / (2 * h))[:, None])
    J = np.hstack(cols)
    p = J.shape[1]
    block = max(1, int(round(BLOCK_LENGTH * model.fs)))
    R = np.linalg.qr(J, mode="r")
    Rinv = np.linalg.inv(R)
    S = long_run_covariance(J * e[:, None], block)
    cov_z = Rinv @ (Rinv.T @ S @ Rinv) @ Rinv.T * (N / max(N - p, 1))  # small-sample dof correction
    n_i, n_w, n_bd, n_den = Psi_i.shape[1], len(omega), len(bd), 0 if den is None else len(den)
    G = np.zeros((n_i + n_w + n_bd + n_den, p))
    G[:n_i, :n_i] = np.eye(n_i)
    G[n_i:n_i + n_w, n_i:n_i + n_w - 1] = T
    G[n_i + n_w:, n_i + n_w - 1:] = np.eye(n_bd + n_den)
    cov = G @ cov_z @ G.T
    cov = 0.5 * (cov + cov.T)
    out = {
        "method": METHOD,
        "block_length_s": block / model.fs,
        "n_samples": int(N),
        "dof": int(N - p),
        "parameters": {"theta_i": int(n_i), "omega": int(n_w), "bd": int(n_bd), "den": int(n_den)},
        "covariance": cov.tolist(),
        "vaf": vaf_interval(y, fitted, block),
    }
    y_i = y - X_om @ omega  # the intrinsic torque of the fit
    if truncated is not None:
        lags_t, Psi_t = truncated
        theta_t = np.linalg.lstsq(Psi_t, y_i, rcond=None)[0]
        out["truncation"] = {"lags": [int(x) for x in lags_t], "H": theta_t.reshape(len(lags_t), -1).tolist()}
    if richer is not None:
        basis_b, Psi_b = richer
        theta_b = np.linalg.lstsq(Psi_b, y_i, rcond=None)[0]
        out["richer_basis"] = {"basis": basis_b.to_dict(), "H": theta_b.reshape(len(model.lags), -1).tolist()}
    return out


def vaf_interval(y, fitted, block: int, level: float = 0.95, n_boot: int = N_BOOT) -> dict:
    """VAF (%) of ``fitted`` with a moving-block bootstrap percentile interval (blocks of
    ``block`` samples resampled with replacement, fixed seed).

    >>> rng = np.random.default_rng(1)
    >>> y = rng.standard_normal(5000); f = y + 0.3 * rng.standard_normal(5000)
    >>> v = vaf_interval(y, f, 25)
    >>> v["lower"] < v["estimate"] < v["upper"]
    True
    """
    y = np.asarray(y, dtype=float)
    e = y - np.asarray(fitted, dtype=float)
    n = len(y)
    k = int(np.ceil(n / block))
    cs = [np.concatenate([[0.0], np.cumsum(s)]) for s in (e, e * e, y, y * y)]
    rng = np.random.default_rng(20141)
    starts = rng.integers(0, n - block + 1, size=(n_boot, k))
    sums = [(c[starts + block] - c[starts]).sum(axis=1) for c in cs]
    m = k * block
    var_e = sums[1] / m - (sums[0] / m) ** 2
    var_y = sums[3] / m - (sums[2] / m) ** 2
    boot = 100.0 * (1.0 - var_e / var_y)
    est = float(100.0 * (1.0 - np.var(e) / np.var(y)))
    lo, hi = np.percentile(boot, [50 * (1 - level), 50 * (1 + level)])
    return {"estimate": est, "lower": float(lo), "upper": float(hi), "level": level}


# ----------------------------------------------------------------- derived quantities


def _gradients_intrinsic(model, rho, weights):
    """Gradient of sum_l weights_l h_l(rho) with respect to theta_i, (len(rho), n_theta_i)."""
    G = model.intrinsic_basis.evaluate(np.atleast_1d(np.asarray(rho, dtype=float)))
    w = np.asarray(weights, dtype=float)
    return (w[None, :, None] * G[:, None, :]).reshape(len(G), -1)


def lag_moment_weights(model, quantity: str, lags=None) -> np.ndarray:
    """Weights over the IRF lags (default the model's) turning the weights h_l into K
    (N m/rad), viscosity (N m s/rad) or inertia (kg m^2): Taylor moments of
    ``sum_l h_l p(k - l)``.

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> lag_moment_weights(model, "stiffness")  # K = sum of the IRF weights
    array([1., 1., 1., 1., 1., 1., 1., 1., 1.])
    >>> bool(np.allclose(model.irf_weights(0.0) @ lag_moment_weights(model, "viscosity"), model.viscosity(0.0)))
    True
    """
    lags = np.asarray(model.lags if lags is None else lags, dtype=float)
    dt = 1.0 / model.fs
    if quantity == "stiffness":
        return np.ones_like(lags)
    if quantity == "viscosity":
        return -lags * dt
    if quantity == "inertia":
        return 0.5 * (lags * dt) ** 2
    raise ValueError(f"unknown intrinsic quantity {quantity!r}")


def _stored(model):
    from .errors import ModelFileError

    u = getattr(model, "uncertainty", None)
    if not u:
        raise ModelFileError("this model carries no uncertainty (identified by an older lpvpc, or an extended "
                             "model): re-identify it to get intervals")
    return u


def _cov_blocks(model):
    u = _stored(model)
    cov = np.asarray(u["covariance"], dtype=float)
    n_i, n_w = u["parameters"]["theta_i"], u["parameters"]["omega"]
    return cov, n_i, n_w


def intrinsic_interval(model, quantity: str, rho, level: float = 0.95):
    """(estimate, lower, upper) arrays of an intrinsic quantity at positions ``rho`` (rad).

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> est, lower, upper = intrinsic_interval(model, "stiffness", np.array([-0.1, 0.1]))  # N m/rad
    >>> bool(np.allclose(est, model.elastic_stiffness([-0.1, 0.1]))), bool(np.all((lower < est) & (est < upper)))
    (True, True)
    """
    cov, n_i, _ = _cov_blocks(model)
    w = lag_moment_weights(model, quantity)
    g = _gradients_intrinsic(model, rho, w)
    n_base = g.shape[1]  # theta_i beyond the base IRF belongs to effects (not stored here)
    est = g @ model.H.ravel()
    var = np.einsum("ij,jk,ik->i", g, cov[:n_base, :n_base], g)
    se = np.sqrt(var)
    bias = structural_bias_bound(model, quantity, rho, est)
    half = bias_aware_critical_value(bias / np.maximum(se, 1e-300), level) * se
    return est, est - half, est + half


def structural_bias_bound(model, quantity: str, rho, est) -> np.ndarray:
    """Bound on the structural bias of an intrinsic quantity at ``rho`` (its units): the sum
    of the absolute shifts of the quantity under the stored neighbouring specifications of
    the intrinsic pathway (the IRF one lag shorter, the scheduling basis one order higher;
    each refitted to the same intrinsic torque). Biases from separate parts of the
    specification add, so the sum (not the root sum of squares) bounds them. Zeros when
    the file stores none (then the intervals are the plain HAC ones).

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> rho = np.array([-0.1, 0.1])  # rad
    >>> K = model.elastic_stiffness(rho)  # N m/rad
    >>> bound = structural_bias_bound(model, "stiffness", rho, K)  # N m/rad
    >>> bool(np.all((bound > 0) & (bound < 0.5 * K)))  # 30 s of data: a few to 15 %
    True
    """
    from .basis import Basis

    u = _stored(model)
    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    bias = np.zeros(len(rho))
    trunc = u.get("truncation")
    if trunc:
        g = _gradients_intrinsic(model, rho, lag_moment_weights(model, quantity, trunc["lags"]))
        bias += np.abs(g @ np.asarray(trunc["H"], dtype=float).ravel() - est)
    richer = u.get("richer_basis")
    if richer:
        G = Basis.from_dict(richer["basis"]).evaluate(rho)
        H = np.asarray(richer["H"], dtype=float)
        bias += np.abs((G @ H.T) @ lag_moment_weights(model, quantity) - est)
    return bias


def bias_aware_critical_value(t, level: float = 0.95):
    """c with P(|N(t, 1)| <= c) = level, elementwise for t >= 0 (bias |b| <= t standard
    errors): the interval estimate +- c se covers at ``level`` whatever the bias within
    that bound (Armstrong and Kolesar, Econometrica 2020). c = z at t = 0, about t + z for
    large t.

    >>> round(float(bias_aware_critical_value(0.0)), 3), round(float(bias_aware_critical_value(1.0)), 3)
    (1.96, 2.646)
    """
    from scipy.stats import norm

    t = np.abs(np.asarray(t, dtype=float))
    lo, hi = np.full_like(t, z_value(level)), t + z_value(level) + 1.0
    for _ in range(60):  # bisection: coverage(c) increases with c
        mid = 0.5 * (lo + hi)
        low = norm.cdf(mid - t) - norm.cdf(-mid - t) < level
        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
    return 0.5 * (lo + hi)


def parameter_draws(model, n_draws: int = N_DRAWS, seed: int = 0):
    """Draws from the stored Gaussian: Omega (n_draws, n_v, n_r) and the reflex DC gain
    C (I - A)^-1 B + D (n_draws,) (with pole draws when the file holds their covariance).

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> omega, dc_gain = parameter_draws(model, n_draws=50)
    >>> omega.shape == (50, *model.Omega.shape), dc_gain.shape
    (True, (50,))
    """
    cov, n_i, n_w = _cov_blocks(model)
    n_den = _stored(model)["parameters"].get("den", 0)
    c = cov[n_i:, n_i:]
    Omega = model.nonlinearity()[1]  # the identified one (high-rate when the model has it)
    mean = np.concatenate([Omega.ravel(), model.B, [model.D], -model.A[:, 0] if n_den else []])
    # the tangent-space covariance is singular along omega: draw with an eigen-factor
    vals, vecs = np.linalg.eigh(c)
    factor = vecs * np.sqrt(np.clip(vals, 0.0, None))
    rng = np.random.default_rng(seed)
    x = mean + rng.standard_normal((n_draws, len(mean))) @ factor.T
    om = x[:, :n_w]
    om = om / np.linalg.norm(om, axis=1, keepdims=True)  # back onto the sphere
    m = model.state_order
    B, D = x[:, n_w:n_w + m], x[:, n_w + m]
    if n_den:  # DC gain of the companion form: sum(numerator) / sum([1, den])
        from .subspace import companion_form

        dc = np.empty(n_draws)
        for i, den in enumerate(x[:, n_w + m + 1:]):
            A, C = companion_form(den)
            dc[i] = float((C @ np.linalg.solve(np.eye(m) - A, B[i]))[0]) + D[i]
    else:
        dc = model.C @ np.linalg.solve(np.eye(m) - model.A, B.T) + D
    return om.reshape(n_draws, *Omega.shape), dc


def reflex_interval(model, rho, level: float = 0.95, n_draws: int = N_DRAWS):
    """Intervals of reflex gain (N m s/rad) and threshold (rad/s) at ``rho``: the estimate
    minus/plus the distances from the parameter draws' median to their percentiles;
    ((gain_lo, gain_hi), (threshold_lo, threshold_hi)), arrays of len(rho).

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> (g_lo, g_hi), (th_lo, th_hi) = reflex_interval(model, np.array([0.0]), n_draws=100)
    >>> gain, threshold = model.reflex_gain_threshold([0.0])  # N m s/rad, rad/s
    >>> bool(g_lo[0] < gain[0] < g_hi[0]) and bool(th_lo[0] < threshold[0] < th_hi[0])
    True
    """
    from .model import rectifier_fit

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    v, _ = model.rectifier_velocity_grid()
    curves = _nonlinearity_draws(model, v, rho, n_draws)  # (draws, rho, v)
    gain, th = rectifier_fit(v, curves.reshape(-1, len(v)))
    gain, th = gain.reshape(n_draws, len(rho)), th.reshape(n_draws, len(rho))
    return tuple(_spread_around(est, draws, level) for draws, est in zip((gain, th), model.reflex_gain_threshold(rho)))


def _nonlinearity_draws(model, velocity, rho, n_draws):
    """The scaled reflex nonlinearity (N m) of each parameter draw: (draws, rho, velocity)."""
    Om, dc = parameter_draws(model, n_draws)
    Vb = model.nonlinearity()[0].evaluate(np.atleast_1d(velocity))
    Rb = model.reflex_rho_basis.evaluate(np.atleast_1d(rho))
    return dc[:, None, None] * np.einsum("rj,dij,vi->drv", Rb, Om, Vb)


def _spread_around(estimate, draws, level):
    """(lower, upper): the estimate minus/plus the distances from the draws' median to their
    percentiles (axis 0). The reflex quantities are nonlinear in the parameters (static gain
    of the dynamics times the nonlinearity; the rectifier fit): the draws' median can sit
    away from the estimate (a 1 kHz model's 27 hinge coefficients, put back on the unit
    sphere, shrink toward zero), so the interval keeps their spread around the estimate."""
    lo, mid, hi = np.percentile(draws, [50 * (1 - level), 50, 50 * (1 + level)], axis=0)
    return estimate - (mid - lo), estimate + (hi - mid)


def nonlinearity_band(model, velocity, rho, level: float = 0.95, n_draws: int = N_DRAWS):
    """Pointwise band (lower, upper) of the scaled reflex nonlinearity (N m), shape
    (len(rho), len(velocity)) each (for figure bands): the estimate minus/plus the distances
    from the parameter draws' median to their percentiles, as :func:`reflex_interval`.

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> v = np.linspace(0.0, 1.0, 5)  # rad/s
    >>> lower, upper = nonlinearity_band(model, v, np.array([0.0]), n_draws=100)  # N m
    >>> f = model.reflex_nonlinearity(v, [0.0])
    >>> lower.shape, bool(np.all((lower <= f) & (f <= upper)))
    ((1, 5), True)
    """
    est = np.asarray(model.reflex_nonlinearity(np.atleast_1d(velocity), np.atleast_1d(rho)), dtype=float)
    return _spread_around(est, _nonlinearity_draws(model, velocity, rho, n_draws), level)
