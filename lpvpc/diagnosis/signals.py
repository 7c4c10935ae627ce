"""Signal dependence: which measured or derived signal the residual depends on, and
through which pathway, when no catalog candidate explains it.

For each signal s, probes "static function of s", "intrinsic IRF modulated by s" and
"reflex modulated by s" are scored with the candidates' cross-validated test; a probe's
shape follows the signal's rank in the record. Trial time is probed as a slowly varying
gain of each pathway (cubic B-splines) on interleaved folds.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from ..models import equations as eq
from .cv import BLOCK_S, _g, _r, paired_test
from .surrogate import Surrogate

# s: knot spacing of the trial-time gain probes: a pathway's gain that changes on time scales of
# ~20 s and longer (attention, fatigue, habituation, a slow swing of excitability), a handful of
# parameters per pathway and minute
TIME_KNOT_S = 10.0


def _cheb(x, order):
    """Chebyshev T1..T_order of x mapped from its 1st-99th percentile range to [-1, 1] (clipped)."""
    lo, hi = np.percentile(x, [1, 99])
    if hi - lo < 1e-12:
        return None
    return _cheb_of(np.clip((2 * x - (hi + lo)) / (hi - lo), -1, 1), order)


def _cheb_of(s, order):
    T = [np.ones_like(s), s]
    for _ in range(1, order):
        T.append(2 * s * T[-1] - T[-2])
    return np.column_stack(T[1:order + 1])


def _rank_cheb(x, order):
    """Chebyshev T1..T_order of x's rank in the record (its empirical distribution function,
    mapped to [-1, 1]; ties share their mean rank): the probe's resolution goes where the
    samples are, and outliers do not stretch it. None for a constant signal."""
    x = np.asarray(x, dtype=float)
    if np.ptp(x) < 1e-12 * max(1.0, float(np.max(np.abs(x)))):
        return None
    u = (scipy.stats.rankdata(x) - 0.5) / len(x)
    return _cheb_of(2 * u - 1, order)


def time_basis(t, knot_s=TIME_KNOT_S):
    """Cubic B-splines of trial time ``t`` (s) over the record, knots every ~``knot_s`` s,
    each minus its mean (N, n_knots + 2): their span holds every smooth function of time
    except a constant, so a gain they modulate changes with time but not on average.

    >>> t = np.arange(0.0, 60.0, 0.01)  # a 60-s record at 100 Hz
    >>> B = time_basis(t)
    >>> B.shape  # 6 intervals of 10 s: 9 cubic B-splines
    (6000, 9)
    >>> g = np.sin(2 * np.pi * t / 30.0)  # a gain swinging every 30 s is followed ...
    >>> c = np.linalg.lstsq(B, g - g.mean(), rcond=None)[0]
    >>> bool(np.max(np.abs(B @ c - (g - g.mean()))) < 0.1)
    True
    >>> c = np.linalg.lstsq(B, np.ones_like(t), rcond=None)[0]  # ... a constant is not
    >>> bool(np.max(np.abs(B @ c)) < 1e-9)
    True
    """
    import scipy.interpolate

    t = np.asarray(t, dtype=float)
    a, b = float(t.min()), float(t.max())
    n_int = max(1, int(np.ceil((b - a) / knot_s - 1e-9)))
    knots = np.r_[[a] * 3, np.linspace(a, b, n_int + 1), [b] * 3]
    B = scipy.interpolate.BSpline.design_matrix(np.clip(t, a, b), knots, 3).toarray()
    return B - B.mean(axis=0)


def candidate_signals(sur: Surrogate) -> dict:
    """Measured and derived signals the residual may depend on: name -> (values, description)."""
    m = sur.model
    p, fs = sur.p, sur.fs
    v = eq.velocity(p, fs)
    dv = eq.delayed_velocity(p, fs, m.delay)
    out = {
        "position": (p, "perturbation position (rad)"),
        "velocity": (v, "perturbation velocity, undelayed (rad/s)"),
        "speed": (np.abs(v), "|perturbation velocity| (rad/s)"),
        "acceleration": (eq.acceleration(p, fs), "perturbation acceleration (rad/s^2)"),
        "delayed_velocity": (dv, f"perturbation velocity delayed by the reflex delay {1000 * m.delay / fs:.0f} ms (rad/s)"),
        "scheduling": (sur.rho, "operating position rho (rad)"),
        "scheduling_velocity": (sur.signals["scheduling_velocity"], "slow-movement velocity (rad/s)"),
        "scheduling_speed": (np.abs(sur.signals["scheduling_velocity"]),
                             "slow-movement speed, |velocity| whichever the direction (rad/s)"),
        "trial_time": (sur.signals["trial_time"], "time in the trial (s)"),
    }
    for k, text in (("emg", "EMG of the perturbed trial, as recorded (reflex bursts included)"),
                    ("emg_ut", "EMG of the unperturbed trial"),
                    ("activation", "background activation (perturbed trial's EMG between reflex bursts)")):
        if k in sur.signals:
            out[k] = (sur.signals[k], text)
    return out


FORMS = {
    "static": "a static function of the signal adds torque",
    "intrinsic": "the intrinsic impulse response is modulated by the signal",
    "reflex": "the reflex torque is modulated by the signal",
}


def signal_dependence(sur: Surrogate, r0=None, *, block_s=BLOCK_S, top=None, leaks=None, pathways=None) -> list:
    """Cross-validated VAF gain of probes (signal x form) over the surrogate base, in
    descending order: [{signal, form, pathway, vaf_gain, t, p_value, description, folds,
    leak}] (``leak``: R^2 of the signal explained by the model's reflex drive, EMG
    channels; ``folds``: "contiguous" or "interleaved", the cross-validation the probe was
    scored with, its gain relative to the base on the same folds).

    Each signal's shape is ``_rank_cheb`` (T1..T3 static; T1, T2 modulating the
    intrinsic IRF's lags and the reflex's states and drive). Trial time: the model's
    intrinsic and reflex torques (``pathways``, default the model's prediction), each times
    :func:`time_basis`, and the basis alone (static), on :meth:`~lpvpc.diagnosis.surrogate.Surrogate.interleaved`
    folds."""
    leaks = leaks or {}
    cv = sur.cv
    sst = sur.sst
    if r0 is None:
        r0, _ = cv.fit(sur.base)
    m = sur.model
    P = eq.lagged(sur.p, m.lags)
    reflex_parts = eq.state_trajectory(m.A, m.B, sur.reflex_drive())
    R = np.column_stack([reflex_parts, sur.reflex_drive()])
    out = []
    for name, (x, desc) in candidate_signals(sur).items():
        delayed = name == "delayed_velocity"
        if name == "trial_time":
            if pathways is None:
                pred = m.predict(sur.p, sur.rho, warn=False, signals=sur.signals)
                pathways = (pred.intrinsic, pred.reflex)
            B = time_basis(x)
            probes = {"static": B, "intrinsic": np.asarray(pathways[0], dtype=float)[:, None] * B,
                      "reflex": np.asarray(pathways[1], dtype=float)[:, None] * B}
            pcv, pr0, folds = *sur.interleaved(), "interleaved"
        else:
            T = _rank_cheb(x, 3)
            if T is None:
                continue
            probes = {"static": T, "intrinsic": eq.kron_rows(P, T[:, :2]), "reflex": eq.kron_rows(R, T[:, :2])}
            pcv, pr0 = cv, r0
            folds = "contiguous" if isinstance(cv.parts[0], slice) else "interleaved"
        for form, X in probes.items():
            key = pcv.add(f"probe:{name}:{form}", X)
            r1, _ = pcv.fit(sur.base + [key])
            t, pv = paired_test(pr0, r1, sur.fs, block_s)
            pathway = form if form != "static" else ("reflex" if delayed else
                                                     "neither (tonic)" if name in ("emg", "emg_ut", "trial_time") else
                                                     "intrinsic")
            out.append({"signal": name, "form": form, "pathway": pathway, "description": desc,
                        "vaf_gain": _r(100.0 * float(pr0 @ pr0 - r1 @ r1) / sst), "t": _r(t, 3), "p_value": _g(pv),
                        "folds": folds, **({"leak": leaks[name]} if name in leaks else {})})
    out.sort(key=lambda d: -d["vaf_gain"])
    return out[:top] if top else out


