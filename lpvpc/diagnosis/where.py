"""Where the model fails: the structure of its residual on a record.

The residual binned by position, perturbation velocity, slow-movement direction, time in
the trial and EMG level; its share of the measured power by frequency band; around
perturbation steps and trajectory transitions; its whiteness; its cross-correlation with
the perturbation at negative and positive lags. Descriptive only: no refit.
"""

from __future__ import annotations

import numpy as np
import scipy.signal
import scipy.stats

from ..models import equations as eq
from .cv import _g, _r
from ..models.effects import signals_from_data


def _binned(name, x, r, y, edges, labels):
    rows = []
    total = float(np.sqrt(np.mean(r**2)))
    for lo, hi, lab in zip(edges[:-1], edges[1:], labels):
        sel = (x >= lo) & (x < hi)
        if sel.sum() < 10:
            continue
        rr = r[sel]
        rows.append({"bin": lab, "n": int(sel.sum()), "residual_rms": _r(np.sqrt(np.mean(rr**2)), 5),
                     "relative_rms": _r(np.sqrt(np.mean(rr**2)) / total if total > 0 else np.nan, 3),
                     "residual_mean": _r(np.mean(rr), 5),
                     "vaf": _r(100 * (1 - np.var(rr) / np.var(y[sel])) if np.var(y[sel]) > 0 else np.nan, 2)})
    return {"by": name, "bins": rows}


def _acf(x, nlags):
    x = x - x.mean()
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: nlags + 1]
    return ac / ac[0]


def _ccf(r, u, maxlag):
    """Normalised cross-correlation c(k) = corr(r(t), u(t - k)) for k = -maxlag..maxlag."""
    r = r - r.mean()
    u = u - u.mean()
    n = len(r)
    denom = np.sqrt((r @ r) * (u @ u))
    out = []
    for k in range(-maxlag, maxlag + 1):
        if k >= 0:
            out.append(r[k:] @ u[: n - k])
        else:
            out.append(r[: n + k] @ u[-k:])
    return np.array(out) / denom


def where_it_fails(model, data, residual, *, signals=None) -> dict:
    """The residual's structure: bins, frequency bands, events, whiteness, cross-correlations."""
    r = np.asarray(residual, dtype=float)
    y = np.asarray(data.torque, dtype=float)
    p, rho, fs = np.asarray(data.position, dtype=float), np.asarray(data.scheduling, dtype=float), float(data.fs)
    sig = signals or signals_from_data(data)
    n = len(r)
    out = {}
    lo, hi = model.scheduling_range
    e = np.linspace(min(rho.min(), lo), max(rho.max(), hi) + 1e-9, 7)
    out["position"] = _binned("operating position rho (rad)", rho, r, y, e,
                              [f"{a:+.3f}..{b:+.3f}" for a, b in zip(e[:-1], e[1:])])
    v = eq.velocity(p, fs)
    v50, v90 = np.percentile(np.abs(v), [50, 90])
    ev = [-np.inf, -v90, -v50, v50, v90, np.inf]
    out["velocity"] = _binned("perturbation velocity (rad/s)", v, r, y, ev,
                              [f"fast shortening (< -{v90:.3g})", "slow shortening", f"near zero (|v| < {v50:.3g})",
                               "slow stretch", f"fast stretch (> {v90:.3g})"])
    vs = sig["scheduling_velocity"]
    out["slow_movement"] = _binned("slow movement (rad/s)", vs, r, y, [-np.inf, -0.02, 0.02, np.inf],
                                   ["toward plantarflexion (< -0.02)", "holding", "toward dorsiflexion (> 0.02)"])
    t = sig["trial_time"]
    et = np.linspace(t[0], t[-1] + 1e-9, 7)
    out["time"] = _binned("time in the trial (s)", t, r, y, et, [f"{a:.0f}..{b:.0f} s" for a, b in zip(et[:-1], et[1:])])
    if "emg" in sig:
        ee = np.percentile(sig["emg"], [0, 33, 67, 100])
        ee[-1] += 1e-9
        out["emg"] = _binned("emg (normalised)", sig["emg"], r, y, ee, ["low", "middle", "high"])
    # frequency bands: share of the measured power left unexplained
    nper = int(min(n, 4 * fs * 4))
    f, Pr = scipy.signal.welch(r, fs, nperseg=nper)
    _, Py = scipy.signal.welch(y, fs, nperseg=nper)
    bands = [(0, 0.5), (0.5, 2), (2, 5), (5, 10), (10, 20), (20, fs / 2 + 1e-9)]
    rows = []
    for a, b in bands:
        sel = (f >= a) & (f < b)
        if sel.any() and Py[sel].sum() > 0:
            rows.append({"band_hz": [a, round(min(b, fs / 2), 3)], "unexplained_fraction": _r(Pr[sel].sum() / Py[sel].sum(), 4),
                         "residual_power_share": _r(Pr[sel].sum() / Pr.sum(), 4)})
    out["frequency"] = rows
    # events: perturbation steps (velocity peaks) and trajectory transitions
    near_step = _dilate(np.abs(v) > v90, int(round(0.1 * fs)))
    moving = np.abs(vs) > 0.05
    ev_rows = {}
    for key, sel, text in (("perturbation_steps", near_step, "within 100 ms of a fast perturbation movement"),
                           ("trajectory_transitions", moving, "while the slow trajectory moves faster than 0.05 rad/s")):
        if sel.any() and (~sel).any():
            ev_rows[key] = {"description": text, "fraction_of_samples": _r(sel.mean(), 3),
                            "residual_rms_inside": _r(np.sqrt(np.mean(r[sel] ** 2)), 5),
                            "residual_rms_outside": _r(np.sqrt(np.mean(r[~sel] ** 2)), 5),
                            "ratio": _r(np.sqrt(np.mean(r[sel] ** 2)) / max(np.sqrt(np.mean(r[~sel] ** 2)), 1e-300), 3)}
    out["events"] = ev_rows
    # whiteness
    nl = int(min(25, n // 10))
    ac = _acf(r, nl)
    band = 2.0 / np.sqrt(n)
    lb = n * (n + 2) * np.sum(ac[1:] ** 2 / (n - np.arange(1, nl + 1)))
    out["whiteness"] = {"lags": nl, "acf": [_r(a, 4) for a in ac[1:]],
                        "fraction_outside_2_over_sqrt_n": _r(np.mean(np.abs(ac[1:]) > band), 3),
                        "ljung_box_q": _r(lb, 2), "ljung_box_p": _g(scipy.stats.chi2.sf(lb, nl)),
                        "note": "torque sensor noise is coloured, so even a perfect model leaves a non-white residual"}
    # cross-correlations with the input, incl. negative lags; band from Bartlett's formula
    maxlag = int(round(0.25 * fs))
    cc = {}
    ar = _acf(r, min(n - 1, 4 * maxlag))
    for name, u in (("position", p), ("velocity", v), ("delayed_velocity", eq.delayed_velocity(p, fs, model.delay)),
                    ("rectified_delayed_velocity", np.maximum(eq.delayed_velocity(p, fs, model.delay), 0.0))):
        c = _ccf(r, u, maxlag)
        au = _acf(u, len(ar) - 1)
        se = np.sqrt((1 + 2 * np.sum(ar[1:] * au[1:])) / n)
        k = int(np.argmax(np.abs(c)))
        cc[name] = {"max_abs": _r(np.abs(c[k]), 4), "at_lag_s": _r((k - maxlag) / fs, 3),
                    "band_99": _r(2.576 * se, 4), "outside_band": bool(np.abs(c[k]) > 2.576 * se),
                    "lags_s": [-maxlag / fs, maxlag / fs], "ccf": [_r(x, 4) for x in c]}
    out["cross_correlation"] = cc
    out["cross_correlation_note"] = ("c(k) = corr(residual(t), input(t - k)); negative lags: the residual leads "
                                     "the input (future input, non-causal structure)")
    return out


def _dilate(mask, half):
    """True within ``half`` samples of a True sample."""
    if half <= 0:
        return mask
    return np.convolve(mask.astype(float), np.ones(2 * half + 1), mode="same") > 0


