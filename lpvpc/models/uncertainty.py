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
  one lag shorter on each side (not for viscosity) and when the scheduling basis is one order higher
  (each refitted to the same intrinsic torque) bounds the bias; and, when the model stores
  it (:func:`lpvpc.identification.structural_uncertainty.add_structural_uncertainty`), plus the spread
  over the intrinsic structures cross-validation cannot tell apart, which holds on
  stiffness curves the basis cannot represent
  (``benchmarks/results/coverage_families.txt``);
- reflex gain and threshold, and the gain's slope along the joint angle: a parametric
  bootstrap of the rectifier fit to the scaled nonlinearity through this covariance, in
  :mod:`lpvpc.models.reflex_uncertainty`;
- VAF: moving-block bootstrap of the record (blocks of ``BLOCK_LENGTH``).

The reflex poles (denominator of the companion form that pole refinement returns) join
the parameters as extra Jacobian columns. A quantity whose interval spans most of its
plausible range is reported "not determined by these data" (:data:`NOT_DETERMINED`,
``Interval.determined``). Measured coverage: ``benchmarks/results/uncertainty.txt``.

Stored in the model file as ``"uncertainty"`` (absent in older files; the interval methods
then raise :class:`~lpvpc.errors.ModelFileError`)::

    method, block_length_s, n_samples, dof
    truncation    {"lags": [-(L-1)..L-1], "H": the one-lag-shorter IRF (N m/rad)}
    richer_basis  {"basis": scheduling basis one order higher, "H": that IRF (N m/rad)}
    curvature_reflex {"omega": n_v * n_r, "bd": m + 1}: the reflex refitted with free elastic
                  curvature columns in the intrinsic pathway (:func:`~lpvpc.models.reflex_uncertainty.reflex_bias_bound`)
    parameters    {"theta_i": n, "extension": n_e, "omega": n_v * n_r, "bd": m + 1, "den": m or 0}:
                  order of the covariance (extension: an extended model's effect coefficients,
                  fitted with the base ones, absent for a base model; den: reflex denominator
                  coefficients, when refined)
    covariance    p x p (units of the parameters: theta_i N m/rad, omega 1, bd N m, den 1)
    vaf           {"estimate": %, "lower": %, "upper": %, "level": 0.95}
    reflex_determined {"rho": 9 positions over the identified range (rad), "gain": [bool],
                  "threshold": [bool], "level", "rule"}: where the reflex gain and threshold
                  are determined by the data (:func:`~lpvpc.models.reflex_uncertainty.reflex_determination`); derived from
                  the rest, written on save and recomputed (not read) on load
    structural    (optional) the IRF shifts of the structures cross-validation cannot tell
                  apart (:mod:`lpvpc.identification.structural_uncertainty`); when present the K, viscosity
                  and inertia intervals include them (:func:`intrinsic_interval`)
"""

from __future__ import annotations

import numpy as np


BLOCK_LENGTH = 0.5  # s, batch length of the HAC estimate and block of the VAF bootstrap
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
    S = np.zeros((U.shape[1], U.shape[1]))
    c_a = np.zeros(U.shape[1])  # sum of the rows before a
    for a in range(0, n - block + 1, 8192):  # the (n - block + 1) moving sums, a block of rows at a time
        b = min(a + 8192, n - block + 1)
        c = np.zeros((b - a + block, U.shape[1]))
        c[0] = c_a
        c[1:] = c_a + np.cumsum(U[a : b + block - 1], axis=0)  # c[i] = sum of rows < a + i
        W = c[block:] - c[: b - a]
        S += W.T @ W
        c_a = c[b - a]
    return S * (n / ((n - block + 1) * block))


def _reflex_output(z, bd, den, segments=None):
    """Reflex torque of the companion-form dynamics with denominator ``den`` driven by z
    (from rest in each trial of ``segments``)."""
    import scipy.signal

    from .equations import companion_form

    A, C = companion_form(den)
    num, a = scipy.signal.ss2tf(A, bd[:-1, None], C, np.array([[bd[-1]]]))
    if segments is None:
        return scipy.signal.lfilter(num[0], a, z)
    return segments.map(lambda x: scipy.signal.lfilter(num[0], a, x), z)


def fit_uncertainty(model, Psi_i, blocks, y, bd, omega, theta_i, U_r=None, A=None, truncated=None,
                    segments=None, richer=None, free_curvature=None, curvature_torque=None, n_base=None) -> dict:
    """The ``uncertainty`` entry of the model file for the fit ``y ~ Psi_i theta_i +
    sum_j bd_j blocks_j omega`` (see the module docstring). Arrays in SI units.

    With ``U_r`` and a companion-form ``A`` (the refined poles' form) the denominator
    coefficients of the reflex dynamics join the parameters (Jacobian columns by central
    differences, one filter each), so pole uncertainty reaches K and the reflex gain.
    ``truncated`` = (lags, Psi) of a one-lag-shorter IRF: refitted to the same intrinsic
    torque for the truncation term of the intrinsic intervals; ``richer`` = (basis, Psi) of
    the IRF with the scheduling basis one order higher, refitted likewise for the basis
    term (both refits after the model's elastic curvature torque ``curvature_torque`` is
    removed); ``free_curvature`` = columns p^2 G_i(theta) of the elastic torque's
    second-order term with free coefficients (the model's are tied to its K'(theta), or
    absent): the final separable least squares refitted with them for the reflex bias
    bound (:func:`~lpvpc.models.reflex_uncertainty.reflex_bias_bound`).

    An extended model (lpvpc.models.effects): ``Psi_i`` holds the base IRF's ``n_base`` columns
    followed by the effects' columns, fitted together with them (``theta_i`` likewise); the
    covariance is of that whole regression, so the base parameters' block is their marginal
    covariance with the effects free, and the neighbouring specifications are refitted to
    the intrinsic torque with the effects' torque removed. Default ``n_base``: every column
    is the base IRF's.

    :func:`lpvpc.identification.identify.identify` calls it; the model (and its file) keeps the result:

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> sorted(model.uncertainty)[:4], model.uncertainty["n_samples"]
    (['block_length_s', 'covariance', 'curvature_reflex', 'dof'], 3000)
    """
    from .equations import companion_form

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
    from ..linalg import tall_lstsq, triangular_factor

    R = triangular_factor(J)  # (row signs aside, np.linalg.qr's R without its N x p copy)
    diag = np.abs(np.diag(R))
    if not diag.size or diag.min() <= 1e-10 * diag.max():
        # e.g. a reflex pathway that came out zero (B = D = 0): its nonlinearity's direction
        # is then unidentified, and an inverse would be noise, not an interval
        raise np.linalg.LinAlgError(
            f"the final fit's parameters are not all identified ({int(np.sum(diag > 1e-10 * diag.max()))} of "
            f"{p} directions; a reflex pathway that came out zero leaves its nonlinearity undetermined)")
    Rinv = np.linalg.inv(R)
    if n_base is not None and Psi_i.shape[1] > n_base:
        _check_extension_inflation(R, Rinv, int(n_base), Psi_i.shape[1])
    J *= e[:, None]  # in place: J is not needed after R (an N x p copy less)
    S = long_run_covariance(J, block)
    del J
    cov_z = Rinv @ (Rinv.T @ S @ Rinv) @ Rinv.T * (N / max(N - p, 1))  # small-sample dof correction
    n_i, n_w, n_bd, n_den = Psi_i.shape[1], len(omega), len(bd), 0 if den is None else len(den)
    n_b = n_i if n_base is None else int(n_base)  # the base IRF's columns; the rest: the effects'
    extension = {"extension": int(n_i - n_b)} if n_i > n_b else {}
    G = np.zeros((n_i + n_w + n_bd + n_den, p))
    G[:n_i, :n_i] = np.eye(n_i)
    G[n_i:n_i + n_w, n_i:n_i + n_w - 1] = T
    G[n_i + n_w:, n_i + n_w - 1:] = np.eye(n_bd + n_den)
    cov = G @ cov_z @ G.T
    cov = 0.5 * (cov + cov.T)
    from .modelfile import MAX_ABS_VALUE

    if n_i > n_b and np.abs(cov[n_b:n_i]).max() > MAX_ABS_VALUE:
        # effect coefficients in tiny units (EMG in V): their block would not fit the model file.
        # Dropped, the rest is unchanged (the marginal covariance of the base and reflex parameters)
        keep = np.r_[0:n_b, n_i:len(cov)]
        cov, extension = cov[np.ix_(keep, keep)], {}
    if np.abs(cov).max() > MAX_ABS_VALUE:
        raise np.linalg.LinAlgError(f"the final fit's parameters are not determined (covariance entries up to "
                                    f"{np.abs(cov).max():.3g}, above the model file's {MAX_ABS_VALUE:g})")
    out = {
        "method": METHOD,
        "block_length_s": block / model.fs,
        "n_samples": int(N),
        "dof": int(N - p),
        "parameters": {"theta_i": int(n_b), **extension, "omega": int(n_w), "bd": int(n_bd), "den": int(n_den)},
        "covariance": cov.tolist(),
        "vaf": vaf_interval(y, fitted, block),
    }
    y_i = y - X_om @ omega  # the IRF's torque of the fit
    if n_i > n_b:  # without the effects' torque, which the refitted neighbours cannot hold
        y_i = y_i - Psi_i[:, n_b:] @ theta_i[n_b:]
    if curvature_torque is not None:
        y_i = y_i - curvature_torque
    if truncated is not None:
        lags_t, Psi_t = truncated
        theta_t = tall_lstsq(Psi_t, y_i)
        out["truncation"] = {"lags": [int(x) for x in lags_t], "H": theta_t.reshape(len(lags_t), -1).tolist()}
    if richer is not None:
        basis_b, Psi_b = richer
        theta_b = tall_lstsq(Psi_b, y_i)
        out["richer_basis"] = {"basis": basis_b.to_dict(), "H": theta_b.reshape(len(model.lags), -1).tolist()}
    if free_curvature is not None:
        from ..errors import InsufficientExcitationError

        try:
            out["curvature_reflex"] = _reflex_refit(blocks, [Psi_i, free_curvature], y, omega)
        except InsufficientExcitationError:  # the columns are already in Psi_i, or p^2 is unexcited
            pass
    return out


#: Largest factor by which an extended model's effects, fitted with the base columns, may grow
#: the base IRF parameters' standard errors (square root of the variance inflation; the
#: Gram matrix of the final fit). Stress relaxation: 1.13-1.2 on the virtual subject; every
#: catalog effect at once on a 60-s record (tests/test_effects.py): up to 21, where the HAC
#: covariance reached 1e10 and K's interval +-1e5 N m/rad.
MAX_EXTENSION_INFLATION = 5.0


def _check_extension_inflation(R, Rinv, n_base, n_i):
    """Raise LinAlgError when the effects' columns (n_base..n_i of the triangular factor R
    of the final fit's Jacobian) leave the base IRF parameters undetermined: their standard
    errors with the effects free exceed those with the effects held by more than
    :data:`MAX_EXTENSION_INFLATION` (the same parameters, so no scaling matters)."""
    keep = np.r_[0:n_base, n_i:R.shape[1]]
    R_k = np.linalg.qr(R[:, keep], mode="r")  # the Gram matrix without the effects' columns
    held = np.sum(np.linalg.inv(R_k)[:n_base] ** 2, axis=1)
    free = np.sum(Rinv[:n_base] ** 2, axis=1)
    worst = float(np.sqrt(np.max(free / held)))
    if not worst <= MAX_EXTENSION_INFLATION:
        raise np.linalg.LinAlgError(
            f"the effects' columns leave the base pathway undetermined: fitted with them, its parameters' "
            f"standard errors grow up to {worst:.3g}x (more than MAX_EXTENSION_INFLATION = "
            f"{MAX_EXTENSION_INFLATION:g}); fewer effects, or a longer or better-excited record, give intervals")


def _reflex_refit(blocks, Psi, y, omega) -> dict:
    """The final separable least squares of the identification (reflex dynamics A, C
    fixed; intrinsic part after projecting out the reflex regressors, then the Hammerstein
    fit) with intrinsic columns ``Psi`` (an array, or a list of arrays side by side):
    {"Omega": ..., "bd": [B; D]} (the nonlinearity's
    sign as ``omega``'s)."""
    from ..linalg import project_out_and_solve, triangular_factor
    from .reflex import fit_hammerstein

    k_r = sum(blk.shape[1] for blk in blocks)
    R = triangular_factor(list(blocks) + (list(Psi) if isinstance(Psi, list) else [Psi]) + [y])  # no N-row copy
    blocks_c, Psi_c, y_c = np.hsplit(R[:, :k_r], len(blocks)), R[:, k_r:-1], R[:, -1]
    theta = project_out_and_solve(R[:, :k_r], Psi_c, y_c)
    hf = fit_hammerstein(blocks_c, y_c - Psi_c @ theta, omega)
    return {"omega": hf.omega.tolist(), "bd": np.append(hf.b, hf.d).tolist()}


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

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
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
    from ..errors import ModelFileError

    u = getattr(model, "uncertainty", None)
    if not u:
        raise ModelFileError("this model carries no uncertainty (identified by an older lpvpc, whose extended "
                             "models had none, or a fit whose parameters were not all identified: see the "
                             "warning identify gave): re-identify it to get intervals")
    return u


def _cov_blocks(model):
    """(covariance, index where the reflex parameters start, number of omega entries): an
    extended model's effect coefficients sit between the base IRF's and the reflex's."""
    u = _stored(model)
    cov = np.asarray(u["covariance"], dtype=float)
    par = u["parameters"]
    return cov, par["theta_i"] + par.get("extension", 0), par["omega"]


def intrinsic_interval(model, quantity: str, rho, level: float = 0.95):
    """(estimate, lower, upper) arrays of an intrinsic quantity at positions ``rho`` (rad).

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> est, lower, upper = intrinsic_interval(model, "stiffness", np.array([-0.1, 0.1]))  # N m/rad
    >>> bool(np.allclose(est, model.elastic_stiffness([-0.1, 0.1]))), bool(np.all((lower < est) & (est < upper)))
    (True, True)
    """
    est, se, bias = intrinsic_interval_parts(model, quantity, rho)
    # The two bounds see different parts of the bias (the neighbours: a short IRF's and a
    # richer basis's shift of this fit; the structures: what the CV cannot decide), so they
    # add. The larger of the two alone under-covered the piecewise K on 100 Hz files (88 %,
    # 1 of 20 seeds fully covered; benchmarks/results/coverage_families.txt)
    half = bias_aware_critical_value((bias["specification"] + bias["structures"] + bias["reflex_leak"])
                                     / np.maximum(se, 1e-300), level) * se
    return est, est - half, est + half


def intrinsic_interval_parts(model, quantity: str, rho):
    """(estimate, standard error, {"specification": ..., "structures": ..., "reflex_leak": ...})
    of an intrinsic quantity at ``rho``: the HAC standard error of the noise, and the three
    structural bias bounds that :func:`intrinsic_interval` adds: :func:`structural_bias_bound`
    (the IRF one lag shorter, the basis one order higher), :func:`structural_shift` (the
    structures cross-validation cannot tell apart) and :func:`reflex_leak_shift` (the reflex
    dynamics left free); the last two zeros unless stored. All in the quantity's units.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> est, se, bias = intrinsic_interval_parts(model, "stiffness", np.array([-0.1, 0.1]))  # N m/rad
    >>> bool(np.all(se > 0)), bool(np.all(bias["specification"] > 0)), bias["structures"].tolist()  # none stored
    (True, True, [0.0, 0.0])
    """
    cov, n_i, _ = _cov_blocks(model)
    w = lag_moment_weights(model, quantity)
    g = _gradients_intrinsic(model, rho, w)
    n_base = g.shape[1]  # the base IRF's block: with effects, their marginal covariance (effects free)
    est = g @ model.H.ravel()
    se = np.sqrt(np.einsum("ij,jk,ik->i", g, cov[:n_base, :n_base], g))
    return est, se, {"specification": structural_bias_bound(model, quantity, rho, est),
                     "structures": structural_shift(model, quantity, rho),
                     "reflex_leak": reflex_leak_shift(model, quantity, rho)}


def relaxed_stiffness_interval(model, rho, level: float = 0.95):
    """(estimate, lower, upper) arrays (N m/rad) of the relaxed stiffness at ``rho`` (rad) of
    a model whose one effect is stress relaxation (:func:`lpvpc.models.effects.relaxation_stiffnesses`):
    K(rho) plus the relaxation's steady-state term, linear in the base IRF's and the effect's
    coefficients, so its noise standard error comes from their joint covariance
    (``parameters.extension``); the structural bias bounds are K's (the relaxed stiffness
    shares K's impulse response). ValueError for another model.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=1, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut), effects=("stress_relaxation",))
    >>> est, lower, upper = relaxed_stiffness_interval(model, [0.0])  # N m/rad
    >>> bool(lower[0] < est[0] < upper[0])
    True
    """
    from .effects import relaxation_stiffnesses

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    u = _stored(model)
    effects = list(getattr(model, "effects", None) or ())
    n_e = u["parameters"].get("extension", 0)
    if [fe.name for fe in effects] != ["stress_relaxation"] or np.size(effects[0].Theta) != n_e:
        raise ValueError("a relaxed-stiffness interval needs a model whose one effect is stress_relaxation")
    fe = effects[0]
    G = fe.basis.evaluate(rho)
    if not fe.effect.feature_constant:
        G = G[:, 1:]
    g = np.hstack([_gradients_intrinsic(model, rho, lag_moment_weights(model, "stiffness")),
                   np.tile(G, (1, np.shape(fe.Theta)[0]))])  # Theta flattened row by row, as fitted
    cov = np.asarray(u["covariance"], dtype=float)[: g.shape[1], : g.shape[1]]
    se = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", g, cov, g), 0.0, None))
    K, bias = intrinsic_interval_parts(model, "stiffness", rho)[::2]
    est = relaxation_stiffnesses(model, rho)[1]
    half = bias_aware_critical_value((bias["specification"] + bias["structures"] + bias["reflex_leak"])
                                     / np.maximum(se, 1e-300), level) * se
    return est, est - half, est + half


def structural_bias_bound(model, quantity: str, rho, est) -> np.ndarray:
    """Bound on the structural bias of an intrinsic quantity at ``rho`` (its units): the sum
    of the absolute shifts of the quantity under the stored neighbouring specifications of
    the intrinsic pathway (the IRF one lag shorter, the scheduling basis one order higher;
    each refitted to the same intrinsic torque). Biases from separate parts of the
    specification add, so the sum (not the root sum of squares) bounds them. Zeros when
    the file stores none (then the intervals are the plain HAC ones).

    The shorter IRF does not count for viscosity, the IRF's first lag moment
    (``lag_moment_weights``): dropping the outermost lags shifts it by those lags' own
    moment arm, not by the estimator's bias. With it the viscosity intervals covered 100 %
    of 20 seeds in every stiffness family at twice the noise band's width; a shorter IRF
    the data support is counted anyway, as one of the near-equivalent structures
    (:func:`structural_shift`). Inertia keeps it: at 100 Hz its second moment is barely
    resolved (the noise band alone covered 17-56 %) and without it the sum-of-exponentials
    inertia was covered at 73 % (``benchmarks/results/coverage_families.txt``).

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
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
    if trunc and quantity != "viscosity":  # (see the docstring)
        g = _gradients_intrinsic(model, rho, lag_moment_weights(model, quantity, trunc["lags"]))
        bias += np.abs(g @ np.asarray(trunc["H"], dtype=float).ravel() - est)
    richer = u.get("richer_basis")
    if richer:
        G = Basis.from_dict(richer["basis"]).evaluate(rho)
        H = np.asarray(richer["H"], dtype=float)
        bias += np.abs((G @ H.T) @ lag_moment_weights(model, quantity) - est)
    return bias


def structural_shift(model, quantity: str, rho) -> np.ndarray:
    """Largest absolute shift of an intrinsic quantity (its units) at ``rho`` over the
    near-equivalent structures stored by
    :func:`lpvpc.identification.structural_uncertainty.add_structural_uncertainty` (and, for the quantities
    it names, the shift between the model's own estimate and the search's refit of its
    structure, ``path``); zeros when the model stores none.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> from lpvpc.identification.structural_uncertainty import add_structural_uncertainty
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0, stiffness_family="piecewise")
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(d)  # its selection ran: the term is stored
    ...     fixed = identify(d, structure="fixed")
    >>> rho = np.array([-0.2, 0.0])  # rad
    >>> bool(np.all(structural_shift(model, "stiffness", rho) > 0))  # N m/rad
    True
    >>> structural_shift(fixed, "stiffness", rho).tolist()  # nothing stored
    [0.0, 0.0]
    >>> bool(np.all(structural_shift(add_structural_uncertainty(fixed, d), "stiffness", rho) > 0))
    True
    """
    from .basis import Basis

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    st = (getattr(model, "uncertainty", None) or {}).get("structural")
    shifts = list(st["shifts"]) if st else []
    path = (st or {}).get("path")
    if path and quantity in path["quantities"]:  # the model's estimate against the refit of its structure
        shifts.append(path["shift"])
    if not shifts:
        return np.zeros(len(rho))
    basis = Basis.from_dict(st["basis"])
    G = basis.evaluate(np.clip(rho, basis.lo, basis.hi))  # (len(rho), n_basis)
    w = lag_moment_weights(model, quantity, st["lags"])
    dH = np.asarray(shifts, dtype=float)  # (n_s, n_lags, n_basis)
    return np.max(np.abs(np.einsum("l,slj,rj->sr", w, dH, G)), axis=0)


def reflex_leak_shift(model, quantity: str, rho) -> np.ndarray:
    """Absolute shift of an intrinsic quantity (its units) at ``rho`` when the reflex dynamics
    are left free (the ``leak`` entry that
    :func:`lpvpc.identification.structural_uncertainty.structural_term` stores, counted for the
    quantities it names); zeros when the model stores none.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(pair_trials(sim.pt, sim.ut))  # its selection ran: the term is stored
    >>> rho = np.array([-0.2, 0.0])  # rad
    >>> bool(np.all(reflex_leak_shift(model, "stiffness", rho) >= 0)), reflex_leak_shift(model, "inertia", rho).tolist()
    (True, [0.0, 0.0])
    """
    from .basis import Basis

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    st = (getattr(model, "uncertainty", None) or {}).get("structural") or {}
    leak = st.get("leak")
    if not leak or quantity not in leak["quantities"]:
        return np.zeros(len(rho))
    basis = Basis.from_dict(st["basis"])
    G = basis.evaluate(np.clip(rho, basis.lo, basis.hi))
    w = lag_moment_weights(model, quantity, st["lags"])
    return np.abs(np.einsum("l,lj,rj->r", w, np.asarray(leak["shift"], dtype=float), G))


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


class Interval(tuple):
    """(lower, upper) arrays of a confidence interval, unpacked like a pair.

    Parameters
    ----------
    lower, upper : numpy.ndarray
        The interval's bounds, in the quantity's unit.
    biased : bool, default False
        True when the estimate is known to be biased (``note`` says why and how the
        interval allows for it).
    note : str, default ""
        Why the estimate is biased and how the interval allows for it.
    determined : numpy.ndarray of bool, optional
        False where the interval spans most of the plausible range: the quantity is "not
        determined by these data" there (:data:`NOT_DETERMINED`); default all True.

    Examples
    --------
    >>> lo, hi = Interval(np.array([1.0]), np.array([2.0]))
    >>> float(hi[0] - lo[0]), Interval(lo, hi, biased=True, note="why")
    (1.0, Interval(lower=array([1.]), upper=array([2.]), biased=True))
    """

    def __new__(cls, lower, upper, biased: bool = False, note: str = "", determined=None):
        self = super().__new__(cls, (lower, upper))
        self.biased, self.note = bool(biased), note
        # False where the interval spans most of the plausible range ("not determined by these data")
        self.determined = np.ones(np.shape(lower), dtype=bool) if determined is None else np.asarray(determined, dtype=bool)
        return self

    def __getnewargs__(self):  # pickling/copying keeps the flags
        return (self[0], self[1], self.biased, self.note, self.determined)

    def __repr__(self):
        flag = ", biased=True" if self.biased else ""
        lo, hi = np.asarray(self[0]), np.asarray(self[1])
        if lo.size <= 4:  # a few values: show them
            return f"Interval(lower={self[0]!r}, upper={self[1]!r}{flag})"
        span = lambda x: f"{float(np.min(x)):.4g}..{float(np.max(x)):.4g}"  # noqa: E731
        return f"Interval({lo.size} values: lower {span(lo)}, upper {span(hi)}{flag})"

    @property
    def lower(self):
        return self[0]

    @property
    def upper(self):
        return self[1]


#: What the summary, the report and Fig. 5A say instead of a value or a curve.
NOT_DETERMINED = "not determined by these data"
