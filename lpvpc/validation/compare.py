"""Comparison metrics: prediction routes against the measured torque and against each other,
and where in the record the model fails.

Units: torque N m, position rad, velocity rad/s, time s, frequency Hz; VAF in percent.
All functions take plain arrays at one sampling rate and return JSON-ready dicts/lists.
"""

from __future__ import annotations

import numpy as np
import scipy.signal
from scipy.integrate import trapezoid

from lpvpc.models.model import vaf

__all__ = ["vaf", "rmse", "relative_difference", "route_agreement", "scheduling_summary", "binned_errors",
           "errors_over_time", "band_errors", "quantile_edges", "symmetric_edges", "error_spectrum", "worst_segments", "FREQUENCY_BANDS"]

#: Frequency bands (Hz) of the error table; the last one ends at the Nyquist rate.
FREQUENCY_BANDS = ((0.0, 1.0), (1.0, 3.0), (3.0, 8.0), (8.0, 20.0), (20.0, None))


def rmse(measured, predicted) -> float:
    """Root-mean-square error (N m).

    >>> rmse([1.0, 2.0, 3.0], [1.0, 2.0, 5.0])  # N m
    1.1547005383792515
    """
    d = np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float)
    return float(np.sqrt(np.mean(d * d))) if d.size else float("nan")


def relative_difference(a, b) -> float:
    """max |a - b| / max |b|: agreement of two predictions of the same torque.

    >>> relative_difference([1.0, 2.0, 4.1], [1.0, 2.0, 4.0])  # max |a - b| / max |b|
    0.02499999999999991
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    scale = float(np.max(np.abs(b))) if b.size else 0.0
    return float(np.max(np.abs(a - b)) / scale) if scale > 0 else float(np.max(np.abs(a - b), initial=0.0))


def route_agreement(reference, others: dict, tolerance: float) -> dict:
    """{name: {"max_relative_difference", "rmse_difference", "pass"}} of each route in
    ``others`` against ``reference`` (``pass``: max relative difference <= tolerance).

    >>> ref = np.sin(np.arange(100) / 10.0)
    >>> a = route_agreement(ref, {"fmu": ref + 1e-12, "bad": 1.1 * ref}, tolerance=1e-9)
    >>> a["fmu"]["pass"], a["bad"]["pass"]
    (True, False)
    """
    out = {}
    for name, x in others.items():
        d = relative_difference(x, reference)
        out[name] = {"max_relative_difference": d, "rmse_difference": rmse(x, reference), "pass": bool(d <= tolerance)}
    return out


def worst_route_difference(agreement: dict) -> float:
    """Largest max relative difference among the numerical route comparisons of
    :func:`route_agreement` results merged into ``agreement`` (the entries with a ``pass``)."""
    return max(v["max_relative_difference"] for v in agreement.values() if isinstance(v, dict) and "pass" in v)


def _fit(measured, predicted, mask) -> dict:
    n = int(np.count_nonzero(mask))
    if n == 0:
        return {"n": 0, "fraction": 0.0, "vaf": None, "rmse": None, "rms_measured": None}
    m, p = np.asarray(measured)[mask], np.asarray(predicted)[mask]
    v = vaf(m, p) if n > 2 and np.var(m) > 0 else None
    return {"n": n, "fraction": n / len(mask), "vaf": v, "rmse": rmse(m, p),
            "rms_measured": float(np.sqrt(np.mean(m * m)))}


def scheduling_summary(scheduling, identified_range, measured, predictions: dict) -> dict:
    """Held-out scheduling range against the identified one, the out-of-range fraction, and
    the fit of each prediction inside and outside the identified range separately.

    A held-out record that leaves the identified range [-0.4, 0.2] rad a quarter of the time:

    >>> rho = np.r_[np.linspace(-0.3, 0.1, 75), np.full(25, 0.25)]
    >>> tq = np.sin(np.arange(100.0))
    >>> s = scheduling_summary(rho, (-0.4, 0.2), tq, {"model": tq})
    >>> s["out_of_range_fraction"], round(s["max_excursion"], 3), s["in_range"]["model"]["vaf"]
    (0.25, 0.05, 100.0)
    """
    rho = np.asarray(scheduling, dtype=float)
    lo, hi = (float(x) for x in identified_range)
    below, above = rho < lo, rho > hi
    outside = below | above
    out = {
        "identified_range": [lo, hi],
        "heldout_range": [float(rho.min()), float(rho.max())],
        "out_of_range_fraction": float(np.mean(outside)),
        "below_fraction": float(np.mean(below)),
        "above_fraction": float(np.mean(above)),
        "max_excursion": float(max(lo - rho.min(), rho.max() - hi, 0.0)),
        "units": {"range": "rad", "max_excursion": "rad", "rmse": "N m", "vaf": "%"},
        "in_range": {}, "out_of_range": {},
    }
    for name, pred in predictions.items():
        out["in_range"][name] = _fit(measured, pred, ~outside)
        out["out_of_range"][name] = _fit(measured, pred, outside)
    return out


def binned_errors(x, measured, predictions: dict, edges) -> list:
    """Error statistics of each prediction in bins of ``x`` (edges ascending): per bin the
    centre, count, RMS measured torque and each prediction's RMSE (N m).

    >>> x = np.linspace(-1.0, 1.0, 200)
    >>> rows = binned_errors(x, np.zeros(200), {"m": np.where(x > 0, 0.5, 0.0)}, [-1.0, 0.0, 1.0])
    >>> [(r["centre"], r["n"], r["rmse_m"]) for r in rows]  # the error lives above zero
    [(-0.5, 100, 0.0), (0.5, 100, 0.5)]
    """
    x = np.asarray(x, dtype=float)
    measured = np.asarray(measured, dtype=float)
    rows = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (x >= a) & (x < b) if b != edges[-1] else (x >= a) & (x <= b)
        n = int(np.count_nonzero(sel))
        row = {"lo": float(a), "hi": float(b), "centre": float(0.5 * (a + b)), "n": n,
               "rms_measured": float(np.sqrt(np.mean(measured[sel] ** 2))) if n else None}
        for name, p in predictions.items():
            row[f"rmse_{name}"] = rmse(measured[sel], np.asarray(p)[sel]) if n else None
        rows.append(row)
    return rows


def quantile_edges(x, n_bins: int, lo=None, hi=None) -> np.ndarray:
    """Bin edges with equal counts (robust to long tails), optionally clipped to [lo, hi].

    >>> quantile_edges(np.arange(101.0), 4)
    array([  0.,  25.,  50.,  75., 100.])
    """
    x = np.asarray(x, dtype=float)
    edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
    if lo is not None:
        edges[0] = min(edges[0], lo)
    if hi is not None:
        edges[-1] = max(edges[-1], hi)
    return edges


def symmetric_edges(x, quantiles=(0.5, 0.8, 0.95)) -> np.ndarray:
    """Bin edges symmetric about zero at the given quantiles of |x|, out to max |x|: for
    signals that sit near zero most of the time and matter in their tails (a perturbation
    velocity during PRALDS holds and steps).

    >>> e = symmetric_edges(np.linspace(-2.0, 2.0, 401))  # rad/s
    >>> bool(np.allclose(e, -e[::-1])), float(e[-1])  # symmetric, out to max |x|
    (True, 2.0)
    """
    a = np.abs(np.asarray(x, dtype=float))
    q = np.unique(np.quantile(a, quantiles))
    q = q[q > 0]
    top = float(a.max()) if a.size else 1.0
    pos = np.concatenate([q[q < top], [top]])
    return np.concatenate([-pos[::-1], pos]) if len(pos) > 1 else np.array([-top, 0.0, top])


def errors_over_time(time, measured, predictions: dict, window: float) -> dict:
    """RMSE (N m) of each prediction in consecutive windows of ``window`` s.

    >>> t = np.arange(400) / 100.0  # s
    >>> e = errors_over_time(t, np.zeros(400), {"m": np.r_[np.zeros(300), np.ones(100)]}, window=1.0)
    >>> np.round(e["t_centre"], 9).tolist(), e["rmse_m"]  # the last second is wrong by 1 N m
    ([0.5, 1.5, 2.5, 3.5], [0.0, 0.0, 0.0, 1.0])
    """
    time = np.asarray(time, dtype=float)
    measured = np.asarray(measured, dtype=float)
    dt = float(np.median(np.diff(time)))
    n = max(1, int(round(window / dt)))
    starts = np.arange(0, len(time) - n + 1, n)
    out = {"t_centre": [float(time[s] + 0.5 * n * dt) for s in starts], "window": float(n * dt),
           "rms_measured": [float(np.sqrt(np.mean(measured[s:s + n] ** 2))) for s in starts]}
    for name, p in predictions.items():
        p = np.asarray(p, dtype=float)
        out[f"rmse_{name}"] = [rmse(measured[s:s + n], p[s:s + n]) for s in starts]
    return out


def _welch(x, fs):
    nper = int(min(len(x), max(64, 2 ** int(np.log2(len(x) / 8)))))
    return scipy.signal.welch(np.asarray(x, dtype=float), fs=fs, nperseg=nper, detrend="constant")


def error_spectrum(measured, predictions: dict, fs: float) -> dict:
    """Welch power spectral densities (N^2 m^2/Hz) of the measured torque and of each
    prediction's error.

    >>> fs = 100.0
    >>> t = np.arange(4000) / fs
    >>> s = error_spectrum(np.sin(2 * np.pi * 5 * t), {"zero": np.zeros(4000)}, fs)
    >>> round(float(s["f"][np.argmax(s["zero"])]))  # Hz: the error is the 5 Hz sine
    5
    """
    f, pm = _welch(measured, fs)
    out = {"f": f, "measured": pm}
    for name, p in predictions.items():
        out[name] = _welch(np.asarray(measured) - np.asarray(p), fs)[1]
    return out


def band_errors(measured, predictions: dict, fs: float, bands=FREQUENCY_BANDS) -> list:
    """Per frequency band: the measured torque power and, for each prediction, the error
    power as a fraction of it (``vaf_<name>`` = 100 (1 - error power / measured power)).

    An error at 10 Hz shows in the 8-20 Hz band only:

    >>> fs = 100.0
    >>> t = np.arange(6000) / fs
    >>> measured = np.sin(2 * np.pi * 0.5 * t) + 0.3 * np.sin(2 * np.pi * 10 * t)
    >>> rows = band_errors(measured, {"m": np.sin(2 * np.pi * 0.5 * t)}, fs)
    >>> [(r["lo"], r["hi"]) for r in rows if r["error_power_m"] > 1e-3]  # Hz
    [(8.0, 20.0)]
    >>> bool(rows[0]["vaf_m"] > 99.99)  # the 0.5 Hz sine is predicted (spectral leakage aside)
    True
    """
    spec = error_spectrum(measured, predictions, fs)
    f = spec["f"]
    rows = []
    for lo, hi in bands:
        hi_ = fs / 2 if hi is None else hi
        sel = (f >= lo) & (f < hi_) if hi is not None else (f >= lo) & (f <= hi_)
        pm = float(trapezoid(spec["measured"][sel], f[sel])) if np.count_nonzero(sel) > 1 else float(
            np.sum(spec["measured"][sel]) * (f[1] - f[0]))
        row = {"lo": float(lo), "hi": float(hi_), "power_measured": pm}
        for name in predictions:
            pe = float(trapezoid(spec[name][sel], f[sel])) if np.count_nonzero(sel) > 1 else float(
                np.sum(spec[name][sel]) * (f[1] - f[0]))
            row[f"error_power_{name}"] = pe
            row[f"vaf_{name}"] = float(100.0 * (1.0 - pe / pm)) if pm > 0 else None
        rows.append(row)
    return rows


def worst_segments(time, measured, predicted, length: float, n: int = 3) -> list:
    """The ``n`` non-overlapping windows of ``length`` s with the largest RMSE of
    ``predicted``; each as {"start", "stop" (s), "i0", "i1" (indices), "rmse" (N m)}.

    >>> t = np.arange(1000) / 100.0  # s
    >>> err = np.zeros(1000)
    >>> err[600:650] = 2.0
    >>> w = worst_segments(t, err, np.zeros(1000), length=0.5, n=1)
    >>> w[0]["start"], w[0]["rmse"]  # s, N m
    (6.0, 2.0)
    """
    time = np.asarray(time, dtype=float)
    err2 = (np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float)) ** 2
    dt = float(np.median(np.diff(time)))
    w = max(2, int(round(length / dt)))
    if len(err2) <= w:
        return [{"start": float(time[0]), "stop": float(time[-1]), "i0": 0, "i1": len(time),
                 "rmse": float(np.sqrt(np.mean(err2)))}]
    c = np.concatenate([[0.0], np.cumsum(err2)])
    score = (c[w:] - c[:-w]) / w  # mean square error of the window starting at i
    taken = np.zeros(len(score), dtype=bool)
    out = []
    for i in np.argsort(score)[::-1]:
        if taken[i]:
            continue
        out.append({"start": float(time[i]), "stop": float(time[min(i + w, len(time) - 1)]), "i0": int(i),
                    "i1": int(i + w), "rmse": float(np.sqrt(score[i]))})
        taken[max(0, i - w + 1): i + w] = True
        if len(out) == n:
            break
    return out
