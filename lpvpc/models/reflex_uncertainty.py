"""Confidence intervals of the reflex pathway: the rectifier's gain and threshold at each
position, where the data determine them, and the gain's trend along the joint angle.

The reflex gain and threshold come from a half-wave-rectifier fit to the scaled
nonlinearity (:meth:`lpvpc.models.model.LPVPCModel.reflex_gain_threshold`): a parametric
bootstrap through the product of the nonlinearity and the dynamics' DC gain (only the product
is identifiable, :func:`nonlinearity_jacobian`, taken linearly) and the rectifier fit itself,
whose knee makes the threshold a kinked function of the curve (:func:`reflex_interval`);
checked against the spread over noise realisations of the same trials (benchmark row "vs
noise-free identification"). The parameters' covariance is the identification's
(:mod:`lpvpc.models.uncertainty`, stored in the model file). Bias-aware like K's, with :func:`reflex_bias_bound` (the elastic curvature freed in
the intrinsic pathway) and, when the structure was selected, :func:`reflex_structural_shift`.

A model-rate nonlinearity (the rectifier of 1 kHz velocity pulses seen at 100 Hz: gain biased
-10..+5 % over position on the virtual subject, threshold trend x0.3) is marked
``Interval.biased``: its gain interval adds the knee-softness bound, its threshold is not
observable and is reported "not determined by these data"
(:data:`lpvpc.models.uncertainty.NOT_DETERMINED`); as is any reflex quantity whose interval spans
most of its plausible range (:func:`reflex_determination`). From 1 kHz files the record's
regressors round the rectifier's knee by a known amount (:func:`knee_rounding`), which the
estimates are mapped back through (:func:`unrounded_rectifier`). :func:`reflex_gain_slope`
gives the gain's slope along the joint angle, or says it is not determined. Measured coverage:
``benchmarks/results/uncertainty.txt``, ``benchmarks/results/population.txt``.
"""

from __future__ import annotations

import numpy as np

from .equations import static_gain
from .uncertainty import NOT_DETERMINED, Interval, _cov_blocks, _stored, bias_aware_critical_value, z_value


#: What the reflex intervals of a model-rate nonlinearity leave out (Interval.note).
MODEL_RATE_BIAS_NOTE = ("reflex nonlinearity identified on the model-rate velocity: gain and threshold are biased "
                        "(the ~20 ms reflex-evoking pulses are smoothed; LPVPCModel.reflex_threshold_biased); the "
                        "gain interval is widened for the smoothed knee, the threshold is not observable (its "
                        "interval spans the fitted velocity range); identify with high_rate_reflex=True from "
                        ">= 500 Hz files")


def _reflex_covariance(model):
    """(covariance of the reflex parameters [omega, B, D, den], number of den entries): den
    only when the file holds the poles' covariance."""
    cov, n_i, _ = _cov_blocks(model)
    return cov[n_i:, n_i:], _stored(model)["parameters"].get("den", 0)


def _dc_gain_gradient(model, n_den):
    """Gradient of the reflex DC gain C (I - A)^-1 B + D with respect to [B, D, den]."""
    from .equations import companion_form

    m = model.state_order
    grad = np.empty(m + 1 + n_den)
    grad[:m] = np.linalg.solve((np.eye(m) - model.A).T, model.C)  # d/dB = C (I - A)^-1
    grad[m] = 1.0
    den = -model.A[:, 0]
    for k in range(n_den):  # the companion form's denominator: central differences
        h = 1e-6 * max(1.0, abs(den[k]))
        dc = []
        for sgn in (1.0, -1.0):
            d = den.copy()
            d[k] += sgn * h
            A, C = companion_form(d)
            dc.append(static_gain(A, model.B, C, model.D))
        grad[m + 1 + k] = (dc[0] - dc[1]) / (2 * h)
    return grad


def nonlinearity_jacobian(model, velocity, rho):
    """The scaled reflex nonlinearity f (N m), shape (len(rho), len(velocity)), and its
    Jacobian with respect to the reflex parameters [omega, B, D, den] (the stored
    covariance's order), shape (p, len(rho), len(velocity)).

    f = dc(B, D, den) * G_r(rho) Omega' V(v) is a product of the nonlinearity and the
    dynamics' DC gain; their scale is not identifiable separately (|omega| = 1 fixes it),
    only the product, and the two factors are each far less certain than it (on the virtual
    subject's 1 kHz path the DC gain and the nonlinearity's slope are each ~30 % uncertain,
    strongly anti-correlated, their product 5-10 %). So the covariance is propagated
    linearly: Gaussian draws of the factors (the former method) add the product of the
    two deviations, a second-order term that made the gain intervals 2-3x wider than the
    estimate's spread over noise realisations.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> v, rho = np.linspace(0.0, 1.0, 5), np.array([-0.1, 0.1])  # rad/s, rad
    >>> f, J = nonlinearity_jacobian(model, v, rho)
    >>> bool(np.allclose(f, model.reflex_nonlinearity(v, rho))), J.shape[1:]
    (True, (2, 5))
    """
    _, n_den = _reflex_covariance(model)
    basis, Omega = model.nonlinearity()
    Vb = basis.evaluate(np.atleast_1d(np.asarray(velocity, dtype=float)))
    Rb = model.reflex_rho_basis.evaluate(np.atleast_1d(np.asarray(rho, dtype=float)))
    s = Rb @ Omega.T @ Vb.T  # the unit-norm nonlinearity, (rho, v)
    dc = model.reflex_static_gain()
    J_om = dc * np.einsum("vi,rj->ijrv", Vb, Rb).reshape(Omega.size, len(Rb), len(Vb))
    J_dyn = _dc_gain_gradient(model, n_den)[:, None, None] * s[None]
    return dc * s, np.concatenate([J_om, J_dyn])


def _rectifier_sensitivity(v, g, th):
    """Rows d(gain)/d(curve) and d(threshold)/d(curve), (2, len(v)), of the least-squares
    rectifier G * max(v - th, 0) + c at its solution: the pseudo-inverse of its Jacobian
    (the linearised least squares, threshold free)."""
    J = np.column_stack([np.maximum(v - th, 0.0), -g * (v > th), np.ones_like(v)])
    return np.linalg.pinv(J)[:2]


def reflex_bias_bound(model, rho):
    """Bounds (gain N m s/rad, threshold rad/s) on the structural bias of the reflex gain
    and threshold at ``rho``: their shifts when the elastic torque's second-order term
    0.5 K'(theta) p^2 is fitted freely (columns p^2 G_i(theta), refitted with the final
    separable least squares) instead of as the model has it (tied to the IRF's K'(theta),
    :func:`lpvpc.models.intrinsic.curvature_from_irf`; or absent, in files before it). The
    reflex nonlinearity of stretch velocity takes up whatever of that term the
    intrinsic pathway misses (PRALDS steps make velocity and p^2 move together). Zeros
    when the file stores no such refit.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> g_bound, th_bound = reflex_bias_bound(model, np.array([-0.1, 0.1]))  # N m s/rad, rad/s
    >>> bool(np.all(g_bound >= 0)), th_bound.shape
    (True, (2,))
    """
    return tuple(np.abs(x) for x in _curvature_reflex_shift(model, rho))


def _curvature_reflex_shift(model, rho):
    """Signed shifts (gain N m s/rad, threshold rad/s) at ``rho`` of the rectifier fit when the
    elastic torque's second-order term is fitted freely, minus the model's
    (:func:`reflex_bias_bound` gives their sizes); zeros without that refit."""
    from .reflex import rectifier_fit

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    alt = _stored(model).get("curvature_reflex")
    if not alt:
        return np.zeros(len(rho)), np.zeros(len(rho))
    basis, Omega = model.nonlinearity()
    v, _ = model.rectifier_velocity_grid()
    bd = np.asarray(alt["bd"], dtype=float)
    m = model.state_order
    dc = static_gain(model.A, bd[:m], model.C, bd[m])
    Om = np.asarray(alt["omega"], dtype=float).reshape(Omega.shape)
    f = dc * (model.reflex_rho_basis.evaluate(rho) @ Om.T @ basis.evaluate(v).T)
    g_alt, th_alt = rectifier_fit(v, f)
    g, th = model.reflex_gain_threshold(rho, knee_corrected=False)  # both read alike
    return g_alt - g, th_alt - th


def reflex_structural_shift(model, rho) -> np.ndarray:
    """Largest absolute shift of the reflex gain (N m s/rad) at ``rho`` over the reflex
    structures the selection could not exclude, stored by
    :func:`lpvpc.identification.structural_uncertainty.add_structural_uncertainty` when the model's
    structure was chosen by cross-validation (``structural["reflex"]``): each one's
    rectifier fit minus that of the model structure's own refit (the same machinery, the
    dynamics held). Zeros when none is stored.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model, fixed = identify(d), identify(d, structure="fixed")
    >>> rho = np.array([-0.2, 0.0])  # rad
    >>> bool(np.all(reflex_structural_shift(model, rho) > 0)), reflex_structural_shift(fixed, rho).tolist()
    (True, [0.0, 0.0])
    """
    return _structural_spread(model, rho, 0)


def _structural_spread(model, rho, which: int) -> np.ndarray:
    """Largest absolute shift of the rectifier's gain (``which`` 0) or threshold (1) at ``rho``
    over the stored reflex structures the selection could not exclude (zeros when none)."""
    shifts = _structural_shifts(model, rho, which)
    return np.max(np.abs(shifts), axis=0) if len(shifts) else np.zeros(len(np.atleast_1d(rho)))


def _structural_shifts(model, rho, which: int) -> np.ndarray:
    """Signed shifts, (structures, len(rho)), of the rectifier's gain (``which`` 0) or
    threshold (1) at ``rho``: each stored reflex structure the selection could not exclude
    minus the model structure's own refit (no rows when none is stored)."""
    from .basis import Basis
    from .reflex import rectifier_fit

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    term = ((getattr(model, "uncertainty", None) or {}).get("structural") or {}).get("reflex")
    if not term or not term["structures"]:
        return np.zeros((0, len(rho)))
    G_r = Basis.from_dict(term["rho_basis"])
    G = G_r.evaluate(np.clip(rho, G_r.lo, G_r.hi))
    v, _ = model.rectifier_velocity_grid()

    def fitted(entry):
        C = np.asarray(entry["coefficients"], dtype=float)
        return rectifier_fit(v, G @ C.T @ Basis.from_dict(entry["velocity_basis"]).evaluate(v).T)[which]

    ref = fitted(term["reference"])
    return np.array([fitted(s) - ref for s in term["structures"]])


#: Monte Carlo draws of the reflex parameters behind the gain and threshold intervals.
N_REFLEX_DRAWS = 500
#: A threshold interval wider than this fraction of the velocity range the rectifier is fitted
#: over (0 to the 99th percentile of the stretch velocities seen) spans most of the plausible
#: range: the threshold is "not determined by these data" there.
THRESHOLD_UNDETERMINED_FRACTION = 2 / 3


def _knee_softness_shift(model, rho):
    """Signed gain shift (N m s/rad) of a rectifier seen on smoothed (model-rate) velocity,
    whose size bounds its gain bias: the slope of the nonlinearity over the top half of the
    fitted velocity range, where smoothing the knee no longer reaches, minus the rectifier
    fit's gain. A true half-wave rectifier has both equal; the smoothed one's knee fit lowers
    the gain in plantarflexion and raises it in dorsiflexion (benchmarks/results/uncertainty.txt)."""
    v, v_top = model.rectifier_velocity_grid()
    f = model.reflex_nonlinearity(v, rho)
    top = v >= 0.5 * v_top
    X = np.column_stack([v[top], np.ones(int(top.sum()))])
    slope = np.linalg.lstsq(X, f[:, top].T, rcond=None)[0][0]
    return slope - model.reflex_gain_threshold(rho, knee_corrected=False)[0]


def _velocity_weight(model, vv):
    """How many identification samples had delayed velocity near each of ``vv`` (rad/s; the
    model file's ``fit["data_density"]``, summed over position; uniform without it)."""
    dens = model.fit.get("data_density") if isinstance(model.fit, dict) else None
    if not dens:
        return np.ones_like(vv)
    edges = np.asarray(dens["velocity_edges"], dtype=float)
    counts = np.asarray(dens["counts"], dtype=float).sum(axis=0)
    return np.interp(vv, 0.5 * (edges[1:] + edges[:-1]), counts) + 1e-9 * max(counts.max(), 1.0)


def _basis_resolution_shift(model, rho, gain, th):
    """Signed shifts (gain N m s/rad, threshold rad/s) of the rectifier fit from the velocity
    basis's resolution: the estimated rectifier itself, G max(v - th, 0), projected onto the
    nonlinearity's velocity basis (least squares weighted by the velocities seen at
    identification, ``fit["data_density"]``; uniform without it) and refitted, minus the
    estimate. A polynomial rounds the knee, and a rounded knee is fitted later: the threshold
    shift is positive, and the estimate sits above the truth by up to that much. On the
    virtual subject's three stiffness families (1 kHz files, defaults, 40 seeds each) the
    estimate was above the truth at 74-90 % of the seeds over the upper half of the range,
    where the error is largest, and at 44-77 % below, where the noise covers it. The gain's
    shift has no reliable sign: counted one way, its coverage fell from 94-96 % to 85-90 %."""
    g2, th2 = _rounded_rectifier_fit(model, gain, th)
    return g2 - gain, th2 - th


#: Thresholds (rad/s) at which :func:`knee_rounding` measures the rounding, evenly over the
#: rectifier fit's threshold range.
N_KNEE_ROUNDING = 40


def knee_rounding(model, U_r, dvel, q: int, segments=None, n: int = N_KNEE_ROUNDING) -> dict:
    """What the identification makes of a true half-wave rectifier, measured through the
    record's own reflex regressors.

    For each threshold t of a grid over the rectifier fit's range, the drive max(v - t, 0) of
    the record's high-rate delayed velocity is decimated as the regressors are, fitted by
    least squares on the model-rate reflex regressor (eq. 17, the columns the nonlinearity
    was identified on) and read by the rectifier fit, averaged over five positions. Why the
    record's regressors and not the velocity histogram: the nonlinearity is fitted to the
    decimated drive, which weighs each ~20 ms velocity pulse as a whole, not each sample, and
    a polynomial velocity basis rounds the knee by an amount that depends on where the knee
    is (a low threshold read high with its gain too high, a high one's gain too low;
    docs/design_notes.md). The fit's threshold does not depend on the gain, and its gain is
    proportional to it (the fit is linear in the drive), so one curve serves every gain.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model being identified (its nonlinearity's basis and scheduling range).
    U_r : numpy.ndarray
        The model-rate reflex regressor, samples x (n_v n_r).
    dvel : numpy.ndarray
        The record's delayed velocity at the file's rate (rad/s).
    q : int
        The decimation factor from the file's rate to the model's.
    segments : list of tuple, optional
        Trials joined end to end, (start, stop) sample pairs at the file's rate.
    n : int, default N_KNEE_ROUNDING
        Thresholds of the grid.

    Returns
    -------
    dict
        The model file's ``uncertainty["knee_rounding"]``: {"threshold": t, "gain_factor":
        the fitted gain per unit true gain, "fitted_threshold": the fitted threshold}.

    Examples
    --------
    ``identify`` measures it on the 1 kHz path and stores it:

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0)  # 1 kHz files
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(pair_trials(sim.pt, sim.ut), high_rate_reflex=True)
    >>> kr = model.uncertainty["knee_rounding"]
    >>> sorted(kr), len(kr["threshold"]) == N_KNEE_ROUNDING
    (['fitted_threshold', 'gain_factor', 'threshold'], True)
    """
    from ..io import decimate_signal
    from ..io.segments import Segments
    from .reflex import rectifier_fit

    basis = model.nonlinearity()[0]
    v, _ = model.rectifier_velocity_grid()
    dvel = np.asarray(dvel, dtype=float)
    seg = Segments(segments or [(0, len(dvel))], len(dvel))
    ts = np.linspace(v[0], v[-6], n)
    Z = np.column_stack([seg.map(lambda x: decimate_signal(x, q), np.maximum(dvel - t, 0.0)) for t in ts])
    k = min(len(Z), len(U_r))
    om = np.linalg.lstsq(U_r[:k], Z[:k], rcond=None)[0].reshape(basis.size, -1, n)  # (n_v, n_r, n)
    lo, hi = model.scheduling_range
    Rb = model.reflex_rho_basis.evaluate(np.linspace(lo, hi, 5) if hi > lo else np.array([lo]))
    F = np.einsum("rj,ijn,vi->nv", Rb, om, basis.evaluate(v)) / len(Rb)  # averaged over positions
    g, t2 = rectifier_fit(v, F)
    return {"threshold": ts.tolist(), "gain_factor": np.asarray(g, float).tolist(),
            "fitted_threshold": np.asarray(t2, float).tolist()}


def _knee_rounding(model):
    """The model file's ``knee_rounding`` entry (:func:`knee_rounding`), or None."""
    return (getattr(model, "uncertainty", None) or {}).get("knee_rounding")


def unrounded_rectifier(model, gain, threshold):
    """The true rectifier whose reading through the record's regressors
    (:func:`knee_rounding`) is ``gain``, ``threshold``.

    The threshold is the t whose rounded reading is ``threshold`` (the fitted thresholds'
    running maximum inverted, clipped to the measured range), the gain ``gain`` / r(t).
    Mapped back this way, the gain slope over population draws is right on average where the
    reading was about 1.15 times too steep (docs/design_notes.md).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        An identified model; unchanged values when its file stores no knee rounding
        (model-rate nonlinearity, 100 Hz files, files written before it).
    gain : float or numpy.ndarray
        The gain as read (N m s/rad).
    threshold : float or numpy.ndarray
        The threshold as read (rad/s).

    Returns
    -------
    tuple of numpy.ndarray
        (gain N m s/rad, threshold rad/s) of the true rectifier.

    Examples
    --------
    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0)  # 1 kHz files
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(pair_trials(sim.pt, sim.ut), high_rate_reflex=True)
    >>> g, t = unrounded_rectifier(model, 5.0, 0.3)
    >>> bool(np.isfinite(g) and 0.0 <= t <= 0.3 + 1e-9)
    True
    """
    kr = _knee_rounding(model)
    gain, threshold = np.asarray(gain, dtype=float), np.asarray(threshold, dtype=float)
    if not kr:
        return gain, threshold
    t = np.asarray(kr["threshold"], dtype=float)
    t_true = np.interp(threshold, np.maximum.accumulate(np.asarray(kr["fitted_threshold"], dtype=float)), t)
    r = np.interp(t_true, t, kr["gain_factor"])
    return gain / np.where(np.abs(r) > 1e-9, r, 1e-9), t_true


def _rounded_rectifier_fit(model, gains, thresholds, measured: bool = True):
    """(gain, threshold) of the rectifier fit to each rectifier G max(v - t, 0) of ``gains``,
    ``thresholds`` after projection onto the model's velocity basis: what the basis makes of
    that rectifier. Measured through the record's own regressors when the model file stores
    it (:func:`knee_rounding`) and ``measured``; else least squares weighted by the velocities
    seen at identification (files before it)."""
    from .reflex import rectifier_fit

    kr = _knee_rounding(model)
    if kr and measured:
        t = np.asarray(kr["threshold"], dtype=float)
        th = np.asarray(thresholds, dtype=float)
        return (np.asarray(gains, dtype=float) * np.interp(th, t, kr["gain_factor"]),
                np.interp(th, t, kr["fitted_threshold"]))
    basis = model.nonlinearity()[0]
    v, _ = model.rectifier_velocity_grid()
    vv = np.linspace(basis.lo, basis.hi, 400)
    sw = np.sqrt(_velocity_weight(model, vv))[:, None]
    hinges = np.asarray(gains)[None, :] * np.maximum(vv[:, None] - np.asarray(thresholds)[None, :], 0.0)
    coef = np.linalg.lstsq(basis.evaluate(vv) * sw, hinges * sw, rcond=None)[0]
    return rectifier_fit(v, (basis.evaluate(v) @ coef).T)


def _gain_rounding_range(model, gain, t_lo, t_hi, n: int = 50):
    """(lowest, highest) bias (N m s/rad, estimate minus truth) of the gain ``gain`` from the
    knee's rounding when the true threshold lies in [``t_lo``, ``t_hi``] (rad/s, one pair per
    position): the rounding multiplies the true gain by r(t) (``_rounded_rectifier_fit``
    at unit gain), so the truth is gain / r(t) and the bias gain (1 - 1 / r(t)). Taken over
    the thresholds the data allow rather than at the estimate's: the estimate's threshold is
    itself rounded (a polynomial basis reads a true 0.05 rad/s near 0.3), and r falls from
    about 1.2 to 0.7 over the range (:func:`knee_rounding`)."""
    gain = np.asarray(gain, dtype=float)
    t_lo, t_hi = np.asarray(t_lo, dtype=float), np.asarray(t_hi, dtype=float)
    tt = t_lo[:, None] + (t_hi - t_lo)[:, None] * np.linspace(0.0, 1.0, n)[None, :]
    r = _rounded_rectifier_fit(model, np.ones(tt.size), tt.ravel())[0].reshape(tt.shape)
    bias = gain[:, None] * (1.0 - 1.0 / np.where(np.abs(r) > 1e-9, r, 1e-9))
    return bias.min(axis=1), bias.max(axis=1)


def _threshold_shift_curve(model):
    """(thresholds t, shifts s(t)) rad/s: the knee-rounding shift of :func:`_basis_resolution_shift`
    as a function of the true threshold, for every t of the rectifier fit's grid. A rectifier
    G max(v - t, 0) projected onto the velocity basis (weighted by the velocities seen) and
    refitted is fitted at t + s(t); the gain G does not change it (the fit's threshold is
    scale-free), so one curve serves every position."""
    t = model.rectifier_velocity_grid()[0][:-5]  # the rectifier fit's own threshold grid
    return t, _rounded_rectifier_fit(model, np.ones_like(t), t)[1] - t


def _threshold_shift_range(model):
    """(thresholds t, (lowest, highest) shift) rad/s: the knee rounding's shift as measured
    through the record's regressors (:func:`knee_rounding`) and as the velocity histogram's
    projection gives it, the range between the two. Neither is exact: the measured one drives
    a rectifier whose threshold is the same at every position, the truth's changes with it and
    the scheduling basis couples the positions (own virtual subject, Chebyshev order 4: a true
    0.66 rad/s read at 0.73, where the measured curve says 0.63 and the histogram's 0.80); the
    histogram's misses how the decimated fit weighs each velocity pulse (population draws: a
    true 0.05 rad/s read near 0.3, where it says 0.1). One curve when the file stores no
    measured rounding."""
    t, s_t = _threshold_shift_curve(model)
    if not _knee_rounding(model):
        return t, (s_t, s_t)
    s_h = _rounded_rectifier_fit(model, np.ones_like(t), t, measured=False)[1] - t
    return t, (np.minimum(s_t, s_h), np.maximum(s_t, s_h))


def _bias_range_interval(lo, hi, b, s, level):
    """(lower, upper) around the noise interval [lo, hi] when the bias (estimate minus truth)
    lies in [min(s, 0) - b, max(s, 0) + b]: centred on that range and widened for its half-width
    (:func:`~lpvpc.models.uncertainty.bias_aware_critical_value`), not for |s| both ways. Broadcasts."""
    z = z_value(level)
    se = np.maximum((hi - lo) / (2 * z), 1e-300)
    extra = (bias_aware_critical_value((b + 0.5 * np.abs(s)) / se, level) - z) * se
    return lo - 0.5 * s - extra, hi - 0.5 * s + extra


def _inverted_threshold_interval(lo, hi, b, t, s_t, level):
    """The thresholds t consistent with the data: those inside the interval their own bias
    range [min(s(t), 0) - b, max(s(t), 0) + b] gives (bias-aware, as the estimate's), i.e. the
    test of each t inverted. ``lo``, ``hi`` (the noise interval), ``b``: one per position;
    ``s_t``: one shift per t, or a (lowest, highest) pair of them (the bias range then
    [min(lowest, 0) - b, max(highest, 0) + b]: :func:`_threshold_shift_range`).
    Returns (lower, upper) arrays, NaN where no t is consistent.

    >>> t = np.arange(0, 1001) / 1000.0  # rad/s
    >>> lower, upper = _inverted_threshold_interval([0.5], [0.7], [0.0], t, np.zeros_like(t), 0.95)
    >>> float(lower[0]), float(upper[0])  # no shift: the noise interval itself, on the grid
    (0.5, 0.7)
    >>> s_t = np.where(t < 0.4, 0.3, 0.0)  # low knees rounded up into the noise interval
    >>> round(float(_inverted_threshold_interval([0.5], [0.7], [0.0], t, s_t, 0.95)[0][0]), 2)
    0.22
    """
    lo, hi, b = (np.atleast_1d(np.asarray(x, dtype=float))[:, None] for x in (lo, hi, b))
    s1, s2 = (s_t, s_t) if not isinstance(s_t, tuple) else s_t  # one shift, or a (lowest, highest) range
    a1, a2 = np.minimum(np.asarray(s1), 0.0)[None, :], np.maximum(np.asarray(s2), 0.0)[None, :]
    c = 0.5 * (a1 + a2)  # the bias range [a1 - b, a2 + b], centred (as _bias_range_interval does for one shift)
    lower_t, upper_t = _bias_range_interval(lo - c, hi - c, b + 0.5 * (a2 - a1), 0.0, level)  # (positions, t)
    inside = (lower_t <= t) & (t <= upper_t)
    lower = np.where(inside, t, np.inf).min(axis=1)
    upper = np.where(inside, t, -np.inf).max(axis=1)
    ok = inside.any(axis=1)
    return np.where(ok, lower, np.nan), np.where(ok, upper, np.nan)


def reflex_interval(model, rho, level: float = 0.95):
    """Intervals of reflex gain (N m s/rad) and threshold (rad/s) at ``rho``:
    ((gain_lo, gain_hi), (threshold_lo, threshold_hi)), each an :class:`~lpvpc.models.uncertainty.Interval` of
    arrays of len(rho) whose ``determined`` (bool array) is False where the interval spans
    most of the plausible range (:func:`reflex_determination`).

    Parametric bootstrap of the half-wave-rectifier fit: :data:`N_REFLEX_DRAWS` Gaussian
    draws of the reflex parameters from the stored covariance, each taken linearly through
    the scaled nonlinearity (:func:`nonlinearity_jacobian`: the identifiable product, no
    second-order term) and refitted by the rectifier fit, threshold free; the percentile
    interval of the draws, widened for the structural bias bounds :func:`reflex_bias_bound`
    (either sign) and the velocity basis's knee rounding (of known sign: the interval extends
    by it on one side only; :func:`~lpvpc.models.uncertainty.bias_aware_critical_value` over
    the bias's range). That rounding depends on where the true knee is, so the threshold's interval is the set of
    thresholds t whose own shift s(t) (``_threshold_shift_curve``) leaves them inside it:
    the test of each t inverted (s taken at the estimate instead covered 97.2-99.4 % at every
    default and 93.1-95.0 % on the 1 kHz path; this 95.8-98.9 % and 94.7-96.4 %, 40 seeds per
    stiffness family: benchmarks/results/threshold_alternatives.txt). The gain's rounding is a
    factor of the true gain that depends on the true threshold as well: its bias range is taken
    over the thresholds of that interval (``_gain_rounding_range``) when the model file
    stores the rounding measured through the record's regressors (:func:`knee_rounding`; the
    reported estimate, mapped back through it by :func:`unrounded_rectifier`, is put inside both
    intervals); files without it take the gain's shift at the estimate, either sign. The rectifier's knee makes the threshold a
    nonlinear, kinked function of the curve: linearising it there (the former delta method)
    gave intervals ~25 % too narrow (threshold coverage 77 % over 20 seeds of the virtual
    subject; this: benchmarks/results/uncertainty.txt).

    On a model whose nonlinearity saw velocity below ``RECTIFIER_MIN_FS`` (model rate,
    ``Interval.biased``) the ~20 ms reflex-evoking pulses are smoothed: the threshold is
    not observable (its interval is the whole fitted range, so "not determined"), and the
    gain's interval is widened for the knee's softness (``_knee_softness_shift``).

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> (g_lo, g_hi), (th_lo, th_hi) = reflex_interval(model, np.array([0.0]))
    >>> gain, threshold = model.reflex_gain_threshold([0.0])  # N m s/rad, rad/s
    >>> bool(g_lo[0] < gain[0] < g_hi[0]) and bool(th_lo[0] <= threshold[0] < th_hi[0])
    True
    >>> g, th = reflex_interval(model, np.array([0.0]))  # 100 Hz velocity
    >>> g.biased, th.biased, bool(th.determined[0])
    (True, True, False)
    """
    return _reflex_interval_parts(model, rho, level)["intervals"]


def _reflex_interval_parts(model, rho, level: float = 0.95) -> dict:
    """:func:`reflex_interval` and what it is made of: {"intervals": its answer, "gain": the
    rectifier fit's reading, "draws": (:data:`N_REFLEX_DRAWS`, len(rho)) its parametric bootstrap
    draws, "reported": the reported (knee-corrected) gain, "shifts": list of signed gain shifts
    (each an alternative reading minus this one) whose sizes bound the rest of the bias, either
    sign, "structural": (structures, len(rho)) the signed shifts of the reflex structures the
    selection could not exclude, the largest of which in size is one more bound, "threshold_draws": the bootstrap draws' thresholds (rad/s, paired with
    "draws"), "threshold_bound": the threshold reading's bias bound of either sign} (gains
    N m s/rad, one per position)."""
    from .reflex import rectifier_fit

    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    cov, _ = _reflex_covariance(model)
    v, v_top = model.rectifier_velocity_grid()
    f, J = nonlinearity_jacobian(model, v, rho)
    gain, th = rectifier_fit(v, f)
    w, U = np.linalg.eigh(cov)
    draws = np.random.default_rng(20141).standard_normal((N_REFLEX_DRAWS, len(w))) @ (U * np.sqrt(np.clip(w, 0, None))).T
    curves = f[None] + np.einsum("np,prv->nrv", draws, J)
    g_d, th_d = (x.reshape(N_REFLEX_DRAWS, len(rho)) for x in rectifier_fit(v, curves.reshape(-1, len(v))))
    curv = _curvature_reflex_shift(model, rho)
    bound = [np.abs(x) for x in curv]  # |bias| <= bound, either sign
    structural = _structural_shifts(model, rho, 0)
    shifts = [curv[0]]
    if len(structural):  # reflex_structural_shift: the largest in size
        bound[0] = bound[0] + np.max(np.abs(structural), axis=0)
    shift = np.zeros(len(rho))  # the threshold's bias of known sign: estimate minus truth between 0 and shift
    biased = model.reflex_threshold_biased
    if biased:  # the knee's softness, whatever rounds it (smoothed pulses, the basis), bounds the gain's bias
        soft = _knee_softness_shift(model, rho)
        bound[0] = bound[0] + np.abs(soft)
        shifts.append(soft)
    else:
        g_shift, shift = _basis_resolution_shift(model, rho, gain, th)
        if not _knee_rounding(model):  # files before it: the gain's shift at the estimate, either sign
            bound[0] = bound[0] + np.abs(g_shift)
            shifts.append(g_shift)
    out, noise = [], []
    for est, d, b, s in ((gain, g_d, bound[0], 0.0), (th, th_d, bound[1], shift)):
        lo, hi = np.percentile(d, [50 * (1 - level), 50 * (1 + level)], axis=0)
        lo, hi = np.minimum(lo, est), np.maximum(hi, est)  # the estimate inside its own interval
        noise.append((lo, hi))
        out.append(list(_bias_range_interval(lo, hi, b, s, level)))
    if not biased:  # the knee's shift belongs to the true threshold, not the estimate: invert the test
        t, s_t = _threshold_shift_range(model)
        lower, upper = _inverted_threshold_interval(*noise[1], bound[1], t, s_t, level)
        ok = np.isfinite(lower)  # (where no threshold is consistent, the shift at the estimate stands)
        out[1][0], out[1][1] = np.where(ok, lower, out[1][0]), np.where(ok, upper, out[1][1])
        if _knee_rounding(model):  # the gain's rounding factor belongs to the true threshold
            # too: its bias range over the thresholds the data allow (measured through the record's regressors)
            a1, a2 = _gain_rounding_range(model, gain, np.clip(out[1][0], v[0], v[-6]), np.clip(out[1][1], v[0], v[-6]))
            out[0] = list(_bias_range_interval(noise[0][0] - 0.5 * (a1 + a2), noise[0][1] - 0.5 * (a1 + a2),
                                               bound[0] + 0.5 * (a2 - a1), 0.0, level))
    th_lo, th_hi = np.clip(out[1][0], v[0], v[-6]), np.clip(out[1][1], v[0], v[-6])
    g_c = gain
    if not biased and _knee_rounding(model):  # the reported (mapped-back) estimate inside its interval
        g_c, th_c = unrounded_rectifier(model, gain, th)
        out[0] = [np.minimum(out[0][0], g_c), np.maximum(out[0][1], g_c)]
        th_lo, th_hi = np.minimum(th_lo, th_c), np.maximum(th_hi, th_c)
    if biased:  # smoothed pulses: the threshold is not observable (benchmarks/results/reflex_observability.txt)
        th_lo, th_hi = np.full(len(rho), v[0]), np.full(len(rho), v[-6])
    g_ok, th_ok = _determined(out[0][0], th_lo, th_hi, v_top)
    note = MODEL_RATE_BIAS_NOTE if biased else ""
    return {"intervals": (Interval(out[0][0], out[0][1], biased, note, g_ok), Interval(th_lo, th_hi, biased, note, th_ok)),
            "gain": gain, "draws": g_d, "reported": g_c, "shifts": shifts,
            "structural": structural, "threshold_draws": th_d, "threshold_bound": bound[1]}


def _determined(gain_lo, th_lo, th_hi, v_top):
    """(gain determined, threshold determined) bool arrays: the gain where its interval
    excludes zero (the data tell a reflex from none); the threshold where the gain is and
    its interval is narrower than THRESHOLD_UNDETERMINED_FRACTION of 0..v_top."""
    g_ok = np.asarray(gain_lo) > 0
    th_ok = g_ok & (np.asarray(th_hi) - np.asarray(th_lo) < THRESHOLD_UNDETERMINED_FRACTION * v_top)
    return g_ok, th_ok


def reflex_determination(model, n_positions: int = 9, level: float = 0.95) -> dict:
    """Where the data determine the reflex gain and threshold, at ``n_positions`` positions
    evenly over the identified range (what the model file records as
    ``uncertainty.reflex_determined``): {"rho": rad, "gain": [bool], "threshold": [bool],
    "level", "rule"}. Empty when the model carries no intervals.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> det = reflex_determination(identify(pair_trials(sim.pt, sim.ut)))
    >>> all(det["gain"]), any(det["threshold"])  # 100 Hz velocity: a threshold is not observable
    (True, False)
    """
    if not getattr(model, "uncertainty", None):
        return {}
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, n_positions) if hi - lo > 1e-6 else np.array([lo])
    try:
        g, th = reflex_interval(model, rho, level)
    except (ValueError, np.linalg.LinAlgError):  # e.g. a covariance that does not fit: no record, the file still saves
        return {}
    return {"rho": rho.tolist(), "gain": [bool(x) for x in g.determined],
            "threshold": [bool(x) for x in th.determined], "level": level,
            "rule": (f"gain: its interval excludes 0; threshold: the gain is determined and its interval is "
                     f"narrower than {THRESHOLD_UNDETERMINED_FRACTION:.2f} of the fitted velocity range (0 to the "
                     f"99th percentile of the stretch velocities); velocity below the model's RECTIFIER_MIN_FS: "
                     f"threshold never determined")}


#: The reflex gain slope is "determined" when every slope of its interval is within this
#: fraction of the estimate's ratio to it (|estimate / s - 1| <= tolerance for all s inside).
SLOPE_TOLERANCE = 0.2
#: Share of the identified range (centred) over which the gain slope is the least-squares line.
SLOPE_CENTRAL = 0.8


def reflex_gain_slope(model, level: float = 0.95, n_positions: int = 9, tolerance: float = SLOPE_TOLERANCE) -> dict:
    """The reflex gain's change with position: the slope (N m s/rad per rad) of the
    least-squares line of the gain over ``n_positions`` positions evenly over the central
    :data:`SLOPE_CENTRAL` of the model's ``scheduling_range``, its
    ``level`` confidence interval, and whether the data determine it.

    The slope is a fixed linear combination w of the gains at the positions, so the interval
    is built from the same parts as :func:`reflex_interval`'s gain intervals, taken through w:

    - noise: the percentile interval of w applied to each parametric bootstrap draw of the
      gains (the draws are joint over the positions, so their correlation counts);
    - biases of the reading that :func:`reflex_interval` bounds by an alternative reading
      (the elastic curvature fitted freely, :func:`reflex_bias_bound`; the reflex structures
      the selection could not exclude, :func:`reflex_structural_shift`; on model-rate
      velocity the knee's softness, ``_knee_softness_shift``; in files without a measured
      knee rounding the velocity basis's shift at the estimate): each bounds the slope's
      bias by the size of the same alternative's slope, w applied to its signed shifts. A
      bias that scales the gain alike at every position moves the slope by the same factor,
      and the alternative's slope carries exactly that; one that changes sign along the
      range moves the slope more than any single position's bound suggests, and so does it;
    - the knee rounding measured through the record's regressors (1 kHz path,
      :func:`knee_rounding`): the reported gains are the readings mapped back through it
      (:func:`unrounded_rectifier`), and so is each bootstrap draw, its gain with its own
      threshold. The threshold's noise then reaches the slope jointly with the gain's (the two
      readings are correlated), and the threshold reading's own bias bound enters as a shift
      of the draws' thresholds either way (the widest of the three percentile intervals).

    The noise interval is widened for the bias bounds with
    :func:`~lpvpc.models.uncertainty.bias_aware_critical_value`, as the per-position gains are,
    and holds the reported (knee-corrected) slope.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        An identified model with intervals (:attr:`~lpvpc.models.model.LPVPCModel.has_intervals`).
    level : float, default 0.95
        Confidence level of the interval.
    n_positions : int, default 9
        Positions the line is fitted over.
    tolerance : float, default :data:`SLOPE_TOLERANCE`
        The slope is determined when the estimate is within this fraction of every slope its
        interval holds: the interval excludes 0 and lies within [estimate / (1 + tolerance),
        estimate / (1 - tolerance)]. Then, whenever the interval covers the true slope, the
        estimate is within ``tolerance`` of it; otherwise the answer is
        :data:`~lpvpc.models.uncertainty.NOT_DETERMINED` (the interval is still given).

    Returns
    -------
    dict
        ``slope`` (N m s/rad per rad, the reported gains' line), ``lower``, ``upper`` (the
        interval), ``determined`` (bool), ``rho`` (rad, the positions), ``level``,
        ``biased`` (model-rate nonlinearity, as ``Interval.biased``), ``rule`` (the
        determination rule in words).

    Examples
    --------
    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(pair_trials(sim.pt, sim.ut))
    >>> out = reflex_gain_slope(model)  # N m s/rad per rad
    >>> bool(out["lower"] <= out["slope"] <= out["upper"]), len(out["rho"]), type(out["determined"])
    (True, 9, <class 'bool'>)
    """
    lo, hi = model.scheduling_range
    margin = 0.5 * (1.0 - SLOPE_CENTRAL) * (hi - lo)
    rho = np.linspace(lo + margin, hi - margin, n_positions)
    d = rho - rho.mean()
    w = d / max(float(d @ d), 1e-300)  # the least-squares slope is w @ gains
    parts = _reflex_interval_parts(model, rho, level)
    slope = float(w @ parts["reported"])
    bound = sum(abs(float(w @ x)) for x in parts["shifts"])
    if len(parts["structural"]):
        bound += float(np.max(np.abs(parts["structural"] @ w)))
    draw_sets = [parts["draws"]]  # the reading is the reported gain: its draws as they are
    if not parts["intervals"][0].biased and _knee_rounding(model):
        # each bootstrap draw's (gain, threshold) reading mapped back through the record's
        # rounding, as the estimate is: the threshold's noise reaches the slope jointly with
        # the gain's (they are correlated), and the threshold's own bias bound is a shift of
        # its readings either way
        tb = np.asarray(parts["threshold_bound"], dtype=float)
        draw_sets = [unrounded_rectifier(model, parts["draws"], parts["threshold_draws"] + k * tb)[0]
                     for k in (-1.0, 0.0, 1.0)]
    ends = [np.percentile(g @ w, [50 * (1 - level), 50 * (1 + level)]) for g in draw_sets]
    n_lo, n_hi = min(min(e[0] for e in ends), slope), max(max(e[1] for e in ends), slope)
    lower, upper = (float(x) for x in _bias_range_interval(n_lo, n_hi, bound, 0.0, level))
    lower, upper = min(lower, slope), max(upper, slope)
    sign = 1.0 if slope >= 0 else -1.0
    a, b = sorted((sign * lower, sign * upper))
    determined = bool(abs(slope) > 0 and a >= abs(slope) / (1 + tolerance) and b <= abs(slope) / (1 - tolerance))
    return {"slope": slope, "lower": lower, "upper": upper, "determined": determined, "rho": rho, "level": level,
            "biased": bool(model.reflex_threshold_biased),
            "rule": (f"determined when the {level:.0%} interval excludes 0 and the estimate is within "
                     f"{tolerance:.0%} of every slope inside it; else {NOT_DETERMINED}")}


def nonlinearity_band(model, velocity, rho, level: float = 0.95):
    """Pointwise band (lower, upper) of the scaled reflex nonlinearity (N m), shape
    (len(rho), len(velocity)) each (for figure bands): the estimate plus/minus z standard
    errors of the delta method (:func:`nonlinearity_jacobian`; the curve has no knee to
    linearise, unlike the rectifier fit of :func:`reflex_interval`).

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> v = np.linspace(0.0, 1.0, 5)  # rad/s
    >>> lower, upper = nonlinearity_band(model, v, np.array([0.0]))  # N m
    >>> f = model.reflex_nonlinearity(v, [0.0])
    >>> lower.shape, bool(np.all((lower <= f) & (f <= upper)))
    ((1, 5), True)
    """
    cov, _ = _reflex_covariance(model)
    f, J = nonlinearity_jacobian(model, np.atleast_1d(velocity), np.atleast_1d(rho))
    se = np.sqrt(np.clip(np.einsum("prv,pq,qrv->rv", J, cov, J), 0.0, None))
    half = z_value(level) * se
    return f - half, f + half
