"""Diagnosis: where a model fails on data it was not fitted to, and which physical effect
is missing.

Units: torque N m, position rad, velocity rad/s, time s, frequency Hz; VAF and VAF gains
in percent / percentage points (pp).

Two questions (see :func:`diagnose`):

1. *Where does it fail?* (:func:`where_it_fails`) The residual (measured minus predicted
   torque) of the model as it is, binned by position, perturbation velocity and its sign,
   slow-movement direction, time in the trial, frequency band, around perturbation steps
   and trajectory transitions; its whiteness; its cross-correlation with the perturbation
   position, velocity and delayed velocity at negative and positive lags.

2. *Which physical effect is missing?* Every candidate of the catalog
   (:mod:`lpvpc.effects`: effects and settings) is fitted and scored on held-out data.
   Scoring uses the model's linear surrogate: with the model's structure held (IRF lags,
   bases and their ranges, reflex delay and linear dynamics), the torque is linear in the
   intrinsic IRF coefficients, in the reflex nonlinearity's coefficients (its basis
   functions filtered by the model's reflex dynamics), in the numerator of those dynamics
   (the model's reflex drive through its states) and in the coefficients of the model's
   effects. The reflex dynamics stay position-independent, as in the model: the blocks of
   eq. 25 (a free numerator for every basis function of the nonlinearity) would let the
   numerator vary with rho and so absorb most of a position-dependent reflex dynamics
   before its candidate is tried. Each candidate adds columns to it (an effect)
   or replaces some (a setting: its variants are selected inside each training fold by
   training error). Base and candidate are fitted on K - 1 contiguous folds of the record
   and predict the held-out fold (blocked cross-validation, K = 10): the held-out VAF gain
   pools all folds. Significance: the paired, one-sided test of the mean of
   d(k) = r_base(k)^2 - r_candidate(k)^2 over held-out samples, with the variance from
   means over 2-s blocks (the residual is coloured, samples are not independent); extra
   parameters are accounted for because every residual is held out. A candidate is
   significant when its p-value is below alpha / n_candidates (Bonferroni, alpha = 0.1) AND
   its gain is at least ``min_gain`` (0.15) pp: a real but negligible improvement is not an
   alarm. (The thresholds were set on the virtual subject; benchmarks/bench_diagnose.py
   records the false-alarm and detection rates they give.)

   When no candidate is significant, :func:`signal_dependence` says which measured or
   derived signal the residual depends on most, and through which pathway: the same
   cross-validated test for probes "static function of s", "intrinsic IRF modulated by
   s" and "reflex modulated by s" for each signal s. A probe's shape follows the signal's
   rank in the record (its empirical distribution), so it resolves the values the record
   dwells on (e.g. slow speeds near zero) whatever their spread. Trial time is probed as a
   slowly varying gain of each pathway (cubic B-splines, knots every TIME_KNOT_S s) scored
   with interleaved folds: a contiguous fold would have to extrapolate a time-local gain
   into a block no training fold saw.

:class:`Diagnosis` holds the answer; ``to_dict()`` is the ``diagnosis.json`` format
(candidates in rank order with ``effect``, ``vaf_gain``, ``significant``,
``explanation``, ...), :func:`write_report` writes a markdown report with plots.
"""

from __future__ import annotations

import html
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal
import scipy.stats

from . import equations as eq
from .basis import Basis
from .effects import CATALOG, SETTINGS, EffectDesign, reflex_latency, signals_from_data
from .intrinsic import two_sided_lags
from .model import vaf
from .reflex import reflex_input_regressor
from .report_html import breakable as _breakable
from .report_html import escape as _e
from .report_html import inline_figure as _html_img
from .report_html import page as _html_page
from .report_html import table as _table

FOLDS = 10
BLOCK_S = 2.0  # s: blocks of the variance estimate of the paired test
MIN_GAIN = 0.15  # pp of held-out VAF: smaller gains are never called significant
ALPHA = 0.1  # family-wise level (Bonferroni over the candidates tested)
OUTSIDE_RATIO = 1.5  # a signal probe this many times better than the top candidate: say so
# s: knot spacing of the trial-time gain probes: a pathway's gain that changes on time scales of
# ~20 s and longer (attention, fatigue, habituation, a slow swing of excitability), a handful of
# parameters per pathway and minute
TIME_KNOT_S = 10.0
LEAK_R2 = 0.2  # a signal this well explained by the model's reflex drive is not used to name an effect
MIN_RECORD_S = 20.0  # s: shorter records are refused (10 folds of 2 s, each a few perturbation steps)
SANE_DROP = 2.0  # pp: a refitted base this much below the model's own VAF is not trusted (short/narrow record)
RANGE_TOL = 0.02  # fraction of the identified range: scheduling beyond it counts as outside
MAX_OUTSIDE = 0.5  # records with more samples outside the identified range are refused
# pp: a refitted structure this much better than the model itself is worth a note: the model
# does not carry over to the record (the mirror of SANE_DROP; an effect that is constant within
# the record but differs from the identification record shows only here)
TRANSFER_GAP = SANE_DROP
# Candidates the data may not tell apart, and what to say when they tie. At 100 Hz, behind the
# reflex's slow activation dynamics, a reflex delay that changes with position and reflex
# dynamics that change with it give nearly the same phase lag (measured on the virtual
# subject: their held-out gains within 0.03 pp of each other on a delay of 30-80 ms).
TIES = {
    frozenset(("position_dependent_reflex_delay", "position_dependent_reflex_dynamics")):
        "reflex timing varies with position: delay or dynamics (not separable at this sampling rate)",
    frozenset(("reflex_habituation", "activation_reflex_gain")):
        "the reflex gain changes over the trial: with trial time or with the EMG-derived activation "
        "(the data explain it about equally well)",
}
# When such a tie is between a signal derived from the EMG (which carries the reflex's own
# output, however well its bursts are taken off) and one that is not, the underived one is
# preferred: EMG-derived -> its underived rival.
PREFER_UNDERIVED = {"activation_reflex_gain": "reflex_habituation"}
TIE_P = 0.05  # two-sided: the top candidate's held-out residual not smaller than its rival's at this level
# The EMG breaks that tie: it is recorded before the muscle's activation and contraction, so
# its reflex latency moves with the reflex delay and not with the reflex dynamics. A latency
# trend with position (p below EMG_TREND_P, change over the range at least one sample and
# EMG_MIN_CHANGE) names the delay; a flat latency names the dynamics.
EMG_TIE = ("position_dependent_reflex_delay", "position_dependent_reflex_dynamics")  # (trend, flat)
EMG_TREND_P = 0.05
EMG_MIN_CHANGE = 0.01  # s


# --------------------------------------------------------------------------- cross-validation


def _kron_rows(a, b):
    return (a[:, :, None] * b[:, None, :]).reshape(len(a), -1)


class BlockCV:
    """Blocked K-fold cross-validation of least-squares fits built from named column blocks.

    Gram products of every pair of blocks are computed once per fold, so fitting any
    combination of blocks on K - 1 folds costs only a small solve per fold. Columns are
    scaled to unit RMS; solves use an eigenvalue pseudo-inverse (rank-deficient
    combinations are handled, not refused).
    """

    def __init__(self, y, folds=FOLDS, mask=None, interleave=None):
        """``mask``: boolean (N,), samples left out of every fit and score (rows zeroed).
        ``interleave``: None (K contiguous folds) or a block length in samples: blocks of
        that length are dealt to the folds in turn, so every fold holds parts of the whole
        record (on a short record each position level is then seen by the other folds too)."""
        self.w = None if mask is None else np.asarray(mask, dtype=float)
        self.y = np.asarray(y, dtype=float) * (1.0 if self.w is None else self.w)
        n = len(self.y)
        self.edges = np.linspace(0, n, folds + 1).astype(int)
        if interleave:
            fold_of = (np.arange(n) // int(interleave)) % folds
            self.parts = [np.flatnonzero(fold_of == f) for f in range(folds)]
        else:
            self.parts = [slice(a, b) for a, b in zip(self.edges[:-1], self.edges[1:])]
        self.K = folds
        self.ridge = RIDGE
        self.blocks = {}
        self._cross = {}
        self._yb = {}
        self.yy = np.array([self.y[ix] @ self.y[ix] for ix in self.parts])


    def add(self, name, X):
        X = np.asarray(X, dtype=float)
        if X.ndim == 1:
            X = X[:, None]
        if self.w is not None:
            X = X * self.w[:, None]
        s = np.sqrt(np.mean(X**2, axis=0))
        s[s == 0] = 1.0
        self.blocks[name] = X / s
        return name

    def _pair(self, a, b):
        """Per-fold products A_f^T B_f, shape (K, p_a, p_b) (cached, either order)."""
        if (a, b) in self._cross:
            return self._cross[(a, b)]
        if (b, a) in self._cross:
            return np.transpose(self._cross[(b, a)], (0, 2, 1))
        A, B = self.blocks[a], self.blocks[b]
        self._cross[(a, b)] = np.stack([A[ix].T @ B[ix] for ix in self.parts])
        return self._cross[(a, b)]

    def _ycross(self, a):
        if a not in self._yb:
            A = self.blocks[a]
            self._yb[a] = np.stack([A[ix].T @ self.y[ix] for ix in self.parts])
        return self._yb[a]

    def fold_systems(self, names):
        """Per fold: (G_f, b_f) of the held-out fold for the blocks ``names``."""
        G = np.concatenate([np.concatenate([self._pair(a, b) for b in names], axis=2) for a in names], axis=1)
        b = np.concatenate([self._ycross(a) for a in names], axis=1)
        return G, b

    def fit(self, names):
        """Held-out residual (N,) and training RSS per fold for the blocks ``names``."""
        if not names:  # nothing fitted: the target itself
            return self.y.copy(), self.yy.sum() - self.yy
        G_f, b_f = self.fold_systems(names)
        G_all, b_all, yy_all = G_f.sum(0), b_f.sum(0), self.yy.sum()
        resid = np.empty_like(self.y)
        rss_train = np.empty(self.K)
        X = np.hstack([self.blocks[a] for a in names])
        for f, ix in enumerate(self.parts):
            G, b = G_all - G_f[f], b_all - b_f[f]
            beta = _solve_psd(G, b, self.ridge)
            resid[ix] = self.y[ix] - X[ix] @ beta
            rss_train[f] = (yy_all - self.yy[f]) - 2 * beta @ b + beta @ G @ beta
        return resid, rss_train


RIDGE = 1e-8  # relative to the largest eigenvalue of the (column-scaled) Gram matrix
FIXED_RIDGE = 1e-4  # the fixed design's candidates model a small residual: shrink them toward the model


def _solve_psd(G, b, ridge=RIDGE):
    """Least-squares coefficients from normal equations with a tiny relative ridge.

    The reflex columns are nearly collinear (neighbouring basis functions of the
    nonlinearity through the same filter, the drive through filters that differ little);
    without the ridge, directions with eigenvalues ~1e-12 of the largest turn fold-to-fold
    noise into large held-out errors. The intrinsic block's smallest
    eigenvalues (~1e-5) are untouched."""
    w, V = scipy.linalg.eigh(G, check_finite=False)
    w = np.maximum(w, 0.0)
    return V @ ((V.T @ b) / (w + ridge * max(w[-1], 1e-300)))


def paired_test(r0, r1, fs, block_s=BLOCK_S):
    """One-sided test that the squared held-out residual r1 is smaller than r0 on average.

    Returns (t, p). The variance of the mean of d = r0^2 - r1^2 comes from means over
    blocks of ``block_s`` seconds (batch means), which absorbs the residual's colour.
    """
    d = r0**2 - r1**2
    b = max(1, int(round(block_s * fs)))
    nb = len(d) // b
    if nb < 3:
        return 0.0, 1.0
    means = d[: nb * b].reshape(nb, b).mean(axis=1)
    sd = means.std(ddof=1)
    if sd == 0:
        return (np.inf, 0.0) if means.mean() > 0 else (0.0, 1.0)
    t = float(means.mean() / (sd / np.sqrt(nb)))
    return t, float(scipy.stats.t.sf(t, nb - 1))


# --------------------------------------------------------------------------- the surrogate


class Surrogate:
    """The model's structure on a record as blocks of a linear least-squares problem.

    Base blocks: ``intrinsic`` (the IRF, model lags and basis), ``effects`` (the model's
    own effect terms, if any) and ``reflex`` (:meth:`reflex_block` at the model's delay).
    """

    def __init__(self, model, data, folds=FOLDS, *, design="refit", mask=None, prediction=None):
        """``design``: "refit" (the model's structure refitted with every candidate) or
        "fixed" (the model held as it is: candidates are fitted to its residual, which
        holds on records too short or narrow to refit the whole structure; settings
        candidates then add their columns instead of replacing the model's).
        ``mask``: samples left out (e.g. outside the identified range); ``prediction``:
        the model's torque on the data (needed by the fixed design)."""
        self.model = model
        self.data = data
        self.design = design
        self.p = np.asarray(data.position, dtype=float)
        self.rho = np.asarray(data.scheduling, dtype=float)
        self.fs = float(data.fs)
        self.signals = signals_from_data(data)
        self.L = -min(model.lags)
        self.z = None
        y = np.asarray(data.torque, dtype=float)
        yin = y if mask is None else y[np.asarray(mask, dtype=bool)]
        self.sst = float(np.sum((yin - yin.mean()) ** 2))  # of the measured torque: VAF gains are relative to it
        if design == "fixed":
            self.cv = BlockCV(y - prediction, folds, mask, interleave=int(round(BLOCK_S * self.fs)))
            self.cv.ridge = FIXED_RIDGE
            self.base = []
            return
        self.cv = BlockCV(y, folds, mask)
        self.base = ["intrinsic", "reflex"]
        self.cv.add("intrinsic", self.intrinsic_block(model.lags, model.intrinsic_basis))
        self.cv.add("reflex", self.reflex_block(model.delay, model.velocity_basis, model.reflex_rho_basis))
        names = [fe.name for fe in model.effects]
        if names:
            design = EffectDesign(names, self.p, self.rho, self.fs, model.lags, model.intrinsic_basis, self.signals,
                                  source=data.source or "data")
            X_r, _ = design.reflex_columns(model)
            self.cv.add("effects", np.hstack([design.columns, X_r]))
            self.base.insert(1, "effects")

    def with_change(self, blocks, repl):
        """Blocks after a settings change ``repl`` ({base block: replacement}): replaced in
        the refit design, added in the fixed one."""
        if self.design == "fixed":
            return list(blocks) + [v for v in repl.values() if v not in blocks]
        return [repl.get(b, b) for b in blocks]

    def intrinsic_block(self, lags, basis: Basis):
        return _kron_rows(eq.lagged(self.p, lags), basis.evaluate(self.rho))

    def reflex_block(self, delay, velocity_basis: Basis, rho_basis: Basis):
        """Reflex columns at ``delay`` (samples): every basis function of the nonlinearity
        (eq. 17) through the model's reflex dynamics C (zI - A)^-1 B + D, and the model's
        own nonlinearity at that delay through each state and the feedthrough (a free,
        position-independent numerator)."""
        m = self.model
        dvel = eq.delayed_velocity(self.p, self.fs, delay)
        U = reflex_input_regressor(velocity_basis.evaluate(dvel), rho_basis.evaluate(self.rho))
        num, den = scipy.signal.ss2tf(m.A, m.B[:, None], m.C[None, :], np.array([[m.D]]))
        z = m.reflex_drive(self.p, self.rho, delay=delay)
        return np.hstack([scipy.signal.lfilter(num[0], den, U, axis=0), eq.state_trajectory(m.A, m.B, z), z[:, None]])

    def interleaved(self):
        """(BlockCV, held-out base residual) of the same base on interleaved folds (2-s
        blocks dealt to the folds in turn; the fixed design's own folds already are): a
        held-out block then lies between training blocks, which a slowly varying function
        of trial time needs."""
        if self.cv.parts and not isinstance(self.cv.parts[0], slice):
            return self.cv, self.cv.fit(self.base)[0]
        if not hasattr(self, "_interleaved"):
            w = None if self.cv.w is None else self.cv.w > 0
            cv = BlockCV(np.asarray(self.data.torque, dtype=float), self.cv.K, w,
                         interleave=int(round(BLOCK_S * self.fs)))
            cv.ridge = self.cv.ridge
            for b in self.base:
                cv.add(b, self.cv.blocks[b])
            self._interleaved = (cv, cv.fit(self.base)[0])
        return self._interleaved

    def emg_latency(self):
        """:func:`lpvpc.effects.reflex_latency` of the perturbed trial's EMG against the
        model's reflex nonlinearity on the undelayed velocity (None without EMG)."""
        if not hasattr(self, "_emg_latency"):
            self._emg_latency = None
            if "emg" in self.signals:
                z = self.model.reflex_drive(self.p, self.rho, delay=0)  # the undelayed velocity
                mask = None if self.cv.w is None else self.cv.w > 0
                self._emg_latency = reflex_latency(self.signals["emg"], z, self.rho, self.fs, mask=mask)
        return self._emg_latency

    def reflex_drive(self):
        if self.z is None:
            self.z = self.model.reflex_drive(self.p, self.rho)
        return self.z


# --------------------------------------------------------------------------- candidates


@dataclass
class CandidateResult:
    effect: str
    kind: str  # "effect" or "setting"
    pathway: str
    explanation: str
    vaf_gain: float = float("nan")  # pp, held-out (cross-validated)
    t: float = float("nan")
    p_value: float = float("nan")
    significant: bool = False
    n_params: int = 0
    variant: dict | None = None  # settings: the chosen change
    available: bool = True
    reason: str = ""
    signals: tuple = ()
    conditional_gain: float = float("nan")  # pp over the base plus the candidates ranked above it
    given: tuple = ()  # the candidates ranked above it that the conditional gain is over
    tied_with: str = ""  # a rival the data do not tell apart from it (TIES), if any
    tie_p: float = float("nan")  # two-sided p of the difference between the two
    settled_by: dict | None = None  # the EMG's reflex latency that broke the tie (EMG_TIE), if it did
    blocks: dict | None = None  # surrogate blocks: {"add": name} or {"replace": {base: block}}
    residual: np.ndarray | None = None  # held-out residual of its (marginal) fit

    def __repr__(self):
        if not self.available:
            return f"CandidateResult({self.effect!r}: not available, {self.reason})"
        sig = "significant" if self.significant else "not significant"
        return f"CandidateResult({self.effect!r}: held-out VAF {self.vaf_gain:+.2f} pp, p = {self.p_value:.2g}, {sig})"

    def to_dict(self) -> dict:
        d = {"effect": self.effect, "kind": self.kind, "pathway": self.pathway,
             "vaf_gain": _r(self.vaf_gain), "conditional_gain": _r(self.conditional_gain),
             "given": list(self.given), "significant": bool(self.significant),
             "p_value": _g(self.p_value), "t": _r(self.t, 3), "n_params": int(self.n_params),
             "explanation": self.explanation, "available": bool(self.available)}
        if self.variant is not None:
            d["variant"] = self.variant
        if self.tied_with:
            d["tied_with"] = self.tied_with
            d["tie_p_value"] = _g(self.tie_p)
        if self.settled_by:
            d["settled_by"] = self.settled_by
        if self.signals:
            d["signals"] = list(self.signals)
        if self.reason:
            d["reason"] = self.reason
        return d


def _r(x, nd=4):
    x = float(x)
    return None if not np.isfinite(x) else round(x, nd)


def _g(x):
    """Three significant digits (p-values)."""
    x = float(x)
    return None if not np.isfinite(x) else float(f"{x:.3g}")


def _effect_candidate(sur: Surrogate, name):
    """Column block of a catalog effect on the surrogate's record, or a reason it can't be."""
    e = CATALOG[name]
    missing = [s for s in e.signals if s not in sur.signals]
    if missing:
        return None, f"needs channel(s) {', '.join(missing)}, not in the data"
    design = EffectDesign([name], sur.p, sur.rho, sur.fs, sur.model.lags, sur.model.intrinsic_basis, sur.signals)
    X = design.columns
    if e.uses_reflex:
        X, _ = design.reflex_columns(sur.model)
    return X, ""


def _setting_variants(sur: Surrogate, name):
    """[(variant dict, {base block name: replacement block name})] for a settings candidate."""
    m = sur.model
    st = dict(m.settings or {})
    st.setdefault("reflex_delay", m.delay / m.fs)
    st.setdefault("irf_lags", sur.L)
    st.setdefault("intrinsic_order", m.intrinsic_basis.order)
    st.setdefault("reflex_order", m.reflex_rho_basis.order)
    st.setdefault("velocity_order", m.velocity_basis.order)
    out = []
    for k, v in enumerate(SETTINGS[name].variants(st, m.fs)):
        key = f"{name}:{k}"
        if "reflex_delay" in v:
            d = int(round(v["reflex_delay"] * m.fs))
            if d < 1 or d <= sur.L:
                continue
            sur.cv.add(key, sur.reflex_block(d, m.velocity_basis, m.reflex_rho_basis))
            out.append((v, {"reflex": key}))
        elif "irf_lags" in v:
            if v["irf_lags"] >= m.delay + 1:
                continue
            sur.cv.add(key, sur.intrinsic_block(two_sided_lags(v["irf_lags"]), m.intrinsic_basis))
            out.append((v, {"intrinsic": key}))
        elif "intrinsic_order" in v:
            b = m.intrinsic_basis
            sur.cv.add(key, sur.intrinsic_block(m.lags, Basis(b.family, v["intrinsic_order"], b.lo, b.hi, b.extrapolation)))
            out.append((v, {"intrinsic": key}))
        elif "reflex_order" in v or "velocity_order" in v:
            rb, vb = m.reflex_rho_basis, m.velocity_basis
            if "reflex_order" in v:
                rb = Basis(rb.family, v["reflex_order"], rb.lo, rb.hi, rb.extrapolation)
            else:
                vb = Basis(vb.family, v["velocity_order"], vb.lo, vb.hi, vb.extrapolation)
            sur.cv.add(key, sur.reflex_block(m.delay, vb, rb))
            out.append((v, {"reflex": key}))
    return out


def reflex_leak(sur: Surrogate, x) -> float:
    """R^2 of signal ``x`` explained by the model's reflex drive (the drive z at lags 0..5
    samples and the reflex states, plus a constant): how much of the signal is what the
    reflex itself does. A perturbed trial's raw EMG carries reflex-evoked bursts and scores
    high; a background activation taken between the bursts scores near zero."""
    z = np.asarray(sur.reflex_drive(), dtype=float)
    m = sur.model
    X = np.column_stack([np.ones_like(z), eq.lagged(z, list(range(6))), eq.state_trajectory(m.A, m.B, z)])
    x = np.asarray(x, dtype=float)
    if sur.cv.w is not None:
        X, x = X[sur.cv.w > 0], x[sur.cv.w > 0]
    xc = x - x.mean()
    if xc @ xc <= 0:
        return 0.0
    beta = np.linalg.lstsq(X, x, rcond=None)[0]
    r = x - X @ beta
    return float(max(0.0, 1.0 - (r @ r) / (xc @ xc)))


def signal_leaks(sur: Surrogate) -> dict:
    """{signal: R^2 explained by the model's reflex drive} for the measured channels an
    effect may read (EMG-derived ones)."""
    return {k: round(reflex_leak(sur, sur.signals[k]), 4) for k in ("emg", "emg_ut", "activation")
            if k in sur.signals}


def score_candidates(sur: Surrogate, *, candidates=None, min_gain=MIN_GAIN, alpha=ALPHA, block_s=BLOCK_S,
                     leaks=None):
    """Fit and score every candidate on the surrogate; returns (results in rank order,
    base held-out residual).

    Marginal scores first (each candidate over the base). A candidate reading a signal
    that the model's reflex drive explains (``leaks``, R^2 >= LEAK_R2) is not named.
    Then the conditional ranking: the best significant candidate joins the base, the
    others are re-scored over it, and so on; a candidate whose gain disappears given the
    ones above it is no longer significant (its signal was a proxy for theirs)."""
    cv = sur.cv
    y = cv.y
    sst = sur.sst
    r0, rss0 = cv.fit(sur.base)
    leaks = leaks if leaks is not None else signal_leaks(sur)
    have = {fe.name for fe in sur.model.effects}
    names = candidates if candidates is not None else [n for n in CATALOG if n not in have] + list(SETTINGS)
    results = []
    for name in names:
        if name in CATALOG:
            e = CATALOG[name]
            res = CandidateResult(name, "effect", e.pathway, e.explanation, signals=tuple(e.signals))
            X, reason = _effect_candidate(sur, name)
            if X is None:
                res.available, res.reason = False, reason
                results.append(res)
                continue
            cv.add(name, X)
            r1, _ = cv.fit(sur.base + [name])
            res.n_params = X.shape[1]
            res.blocks = {"add": name}
        else:
            st = SETTINGS[name]
            res = CandidateResult(name, "setting", st.pathway, st.explanation)
            if sur.design == "fixed":
                res.available, res.reason = False, "needs a refit (model held fixed)"
                results.append(res)
                continue
            variants = _setting_variants(sur, name)
            if not variants:
                res.available, res.reason = False, "no admissible variant (e.g. the IRF lags may not exceed the reflex delay)"
                results.append(res)
                continue
            fits = []
            for v, repl in variants:
                blocks = sur.with_change(sur.base, repl)
                r, rss = cv.fit(blocks)
                n_par = sum(cv.blocks[b].shape[1] for b in blocks)
                fits.append((v, r, rss, n_par, repl))
            # Nested selection: in each fold the variant with the least training error
            # predicts the held-out fold (no held-out data are used to choose).
            r1 = np.empty_like(y)
            chosen = []
            for f, ix in enumerate(cv.parts):
                k = int(np.argmin([ft[2][f] for ft in fits]))
                chosen.append(k)
                r1[ix] = fits[k][1][ix]
            k_best = max(set(chosen), key=chosen.count)
            res.variant = fits[k_best][0]
            res.blocks = {"replace": fits[k_best][4]}
            res.n_params = fits[k_best][3] - sum(cv.blocks[b].shape[1] for b in sur.base)
        res.vaf_gain = 100.0 * float(r0 @ r0 - r1 @ r1) / sst
        res.conditional_gain = res.vaf_gain
        res.t, res.p_value = paired_test(r0, r1, sur.fs, block_s)
        res.residual = r1
        results.append(res)
    n_tested = max(1, sum(r.available for r in results))
    level = alpha / n_tested
    for r in results:
        r.significant = bool(r.available and r.vaf_gain >= min_gain and r.p_value <= level)
        leaky = [f"{k} (R^2 {leaks[k]:.2f})" for k in r.signals if leaks.get(k, 0.0) >= LEAK_R2]
        if r.significant and leaky:
            r.significant = False
            r.reason = (f"not named: its signal {', '.join(leaky)} is largely explained by the model's own reflex "
                        f"drive, so its gain may be reflex misfit")
    order = _conditional_ranking(sur, results, r0, sst, min_gain, level, block_s)
    rest = sorted((r for r in results if r not in order),
                  key=lambda r: (not r.available, -(r.vaf_gain if np.isfinite(r.vaf_gain) else -1e9)))
    _mark_ties(order, results, sur.fs, block_s)
    return order + rest, r0


def _tie_p(resid_a, resid_b, fs, block_s) -> float:
    """Two-sided p of the difference between two candidates' held-out residuals (the paired
    test of the gains, made two-sided): above TIE_P the data do not tell them apart."""
    t, p = paired_test(resid_a, resid_b, fs, block_s)
    return 1.0 if t == 0 else min(1.0, 2.0 * min(p, 1.0 - p))


def _mark_ties(order, results, fs, block_s):
    """Mark the candidates named (``order``) that the data do not tell apart from their
    rival of :data:`TIES`: the paired test of the two held-out residuals (the same test as
    the gains') does not reject equality at TIE_P (two-sided)."""
    by_name = {r.effect: r for r in results}
    for top in order:
        for pair in TIES:
            if top.effect not in pair:
                continue
            (rival,) = pair - {top.effect}
            other = by_name.get(rival)
            if other is None or not other.available or other.residual is None or top.residual is None:
                continue
            p2 = _tie_p(other.residual, top.residual, fs, block_s)
            if p2 > TIE_P:
                top.tied_with, top.tie_p = rival, p2


def _emg_tie_break(sur, best, r1, scored, min_gain, level, block_s):
    """(candidate, residual) to join the base: ``best``, or its EMG_TIE rival when the two
    tie on torque and the EMG's reflex latency names the rival. The rival must pass the
    same test as ``best`` (it only reorders; nothing becomes significant). The one the
    EMG names gets ``settled_by``."""
    if best.effect not in EMG_TIE:
        return best, r1
    (rival_name,) = set(EMG_TIE) - {best.effect}
    hit = next(((r, res) for r, res in scored if r.effect == rival_name), None)
    if hit is None:
        return best, r1
    if _tie_p(hit[1], r1, sur.fs, block_s) <= TIE_P:
        return best, r1
    lat = sur.emg_latency()
    if lat is None:
        return best, r1
    change = lat["latency_hi"] - lat["latency_lo"]
    trend = lat["p_value"] < EMG_TREND_P and abs(change) >= max(EMG_MIN_CHANGE, 1.0 / sur.fs)
    named = EMG_TIE[0] if trend else EMG_TIE[1]
    if named == rival_name:
        r = hit[0]
        if not (r.conditional_gain >= min_gain and r.p_value <= level):
            return best, r1
        best, r1 = hit
    best.settled_by = {"signal": "emg", "latency_lo_ms": _r(1000 * lat["latency_lo"], 1),
                       "latency_hi_ms": _r(1000 * lat["latency_hi"], 1),
                       "position_lo": _r(lat["position_lo"], 3), "position_hi": _r(lat["position_hi"], 3),
                       "p_value": _g(lat["p_value"]), "trend": bool(trend), "blocks": lat["blocks"]}
    return best, r1


def _prefer_underived(sur, best, r1, scored, min_gain, level, block_s):
    """(candidate, residual) to join the base: ``best``, or its :data:`PREFER_UNDERIVED`
    rival when the two tie on torque (two-sided p above TIE_P) and the rival passes the
    same test as ``best``: a reflex-gain change explained equally by trial time and by an
    EMG-derived signal is named by trial time (the tie is reported either way)."""
    rival_name = PREFER_UNDERIVED.get(best.effect)
    hit = next(((r, res) for r, res in scored if r.effect == rival_name), None)
    if hit is None or _tie_p(hit[1], r1, sur.fs, block_s) <= TIE_P:
        return best, r1
    r = hit[0]
    if not (r.conditional_gain >= min_gain and r.p_value <= level):
        return best, r1
    return hit


def _conditional_ranking(sur, results, r0, sst, min_gain, level, block_s) -> list:
    """Forward selection among the significant candidates: returns them in the order they
    join the base; the ones that lose significance given those above are marked."""
    cv = sur.cv
    base, r_base = list(sur.base), r0
    pool = [r for r in results if r.significant]
    chosen = []
    replaced = set()
    while pool:
        scored = []
        for r in pool:
            if chosen:
                if "add" in r.blocks:
                    blocks = base + [r.blocks["add"]]
                else:
                    if set(r.blocks["replace"]) & replaced:  # the same block as a change above
                        r.significant = False
                        r.reason = f"changes the same part of the model as {chosen[-1].effect}, ranked above"
                        continue
                    blocks = sur.with_change(base, r.blocks["replace"])
                r1, _ = cv.fit(blocks)
                r.conditional_gain = 100.0 * float(r_base @ r_base - r1 @ r1) / sst
                r.t, r.p_value = paired_test(r_base, r1, sur.fs, block_s)
                r.given = tuple(c.effect for c in chosen)
            else:
                r1 = r.residual
            scored.append((r, r1))
        pool = [r for r, _ in scored]
        if not scored:
            break
        best, r1 = max(scored, key=lambda t: t[0].conditional_gain)
        best, r1 = _emg_tie_break(sur, best, r1, scored, min_gain, level, block_s)
        best, r1 = _prefer_underived(sur, best, r1, scored, min_gain, level, block_s)
        if not (best.conditional_gain >= min_gain and best.p_value <= level):
            for r in pool:
                r.significant = False
                r.reason = (f"explained by {', '.join(c.effect for c in chosen)} ranked above: "
                            f"{r.conditional_gain:+.2f} pp given them")
            break
        chosen.append(best)
        pool.remove(best)
        if "add" in best.blocks:
            base = base + [best.blocks["add"]]
        else:
            base = sur.with_change(base, best.blocks["replace"])
            replaced |= set(best.blocks["replace"])
        r_base = r1
    return chosen


# --------------------------------------------------------------------------- signal dependence


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

    Each signal's shape is :func:`_rank_cheb` (T1..T3 static; T1, T2 modulating the
    intrinsic IRF's lags and the reflex's states and drive). Trial time: the model's
    intrinsic and reflex torques (``pathways``, default the model's prediction), each times
    :func:`time_basis`, and the basis alone (static), on :meth:`Surrogate.interleaved`
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
            probes = {"static": T, "intrinsic": _kron_rows(P, T[:, :2]), "reflex": _kron_rows(R, T[:, :2])}
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


# --------------------------------------------------------------------------- where it fails


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
    total = float(np.sqrt(np.mean(r**2)))
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


# --------------------------------------------------------------------------- the diagnosis


@dataclass
class Diagnosis:
    model_hash: str
    data_source: str
    n_samples: int
    fs: float
    vaf: float  # % of the model as it is on these data
    rmse: float  # N m
    surrogate_vaf: float  # % cross-validated, model structure refitted on these data
    candidates: list
    dependence: list
    where: dict
    settings: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    residual: np.ndarray | None = None
    prediction: np.ndarray | None = None
    design: str = "refit"
    design_reason: str = ""
    coverage: dict = field(default_factory=dict)
    leaks: dict = field(default_factory=dict)
    base_residual: np.ndarray | None = None  # held-out (cross-validated) residual of the surrogate base

    def __repr__(self):
        top = self.top
        found = "no significant candidate" if top is None else f"top {top.effect} (+{top.vaf_gain:.2f} pp)"
        return (f"Diagnosis({self.n_samples} samples at {self.fs:g} Hz; model VAF {self.vaf:.2f} %; "
                f"{len(self.candidates)} candidates, {len(self.significant)} significant, {found})")

    @property
    def significant(self) -> list:
        return [c for c in self.candidates if c.significant]

    @property
    def top(self):
        sig = self.significant
        return sig[0] if sig else None

    @property
    def signal_finding(self) -> dict | None:
        """The signal probe the answer names: the best one whose signal is not explained by
        the model's reflex drive, if it passes the candidates' test (gain >= min_gain, p
        below alpha / number of probes); else None."""
        usable = [d for d in self.dependence if d.get("leak", 0.0) < LEAK_R2]
        dep = usable[0] if usable else None
        if dep is not None:
            level = self.settings.get("alpha", ALPHA) / len(self.dependence)  # Bonferroni over the probes
            if not (dep["vaf_gain"] is not None and dep["vaf_gain"] >= self.settings.get("min_gain", MIN_GAIN)
                    and dep["p_value"] is not None and dep["p_value"] <= level):
                dep = None
        return dep

    def answer(self) -> str:
        """One paragraph: the missing effect, or the signal and pathway the residual depends on."""
        top = self.top
        dep = self.signal_finding
        if dep is not None:
            where = (f"{dep['signal']} ({dep['description']}): {FORMS[dep['form']]}, {dep['pathway']} pathway "
                     f"(held-out VAF +{dep['vaf_gain']:.2f} pp, p = {dep['p_value']:.1e})")
        if top is not None:
            extra = f" ({', '.join(f'{k}={v:g}' for k, v in top.variant.items())})" if top.variant else ""
            carried = (f"carried by the {top.pathway} pathway"
                       + (f" and the signal{'s' if len(top.signals) > 1 else ''} {', '.join(top.signals)}"
                          if top.signals else ""))
            text = (f"Missing: {top.effect}{extra}, {carried}: held-out VAF +{top.vaf_gain:.2f} pp "
                    f"(p = {top.p_value:.1e}). {top.explanation}")
            if top.tied_with:
                rival = next((c for c in self.candidates if c.effect == top.tied_with), None)
                what = TIES[frozenset((top.effect, top.tied_with))]
                sb = top.settled_by
                if sb:
                    how = (f"rises from {sb['latency_lo_ms']:.0f} to {sb['latency_hi_ms']:.0f} ms"
                           if sb["latency_hi_ms"] >= sb["latency_lo_ms"] else
                           f"falls from {sb['latency_lo_ms']:.0f} to {sb['latency_hi_ms']:.0f} ms")
                    emg = (f"the EMG's reflex latency {how} over the range {sb['position_lo']:+.2f}..{sb['position_hi']:+.2f} rad "
                           f"(p = {sb['p_value']:.1e}), so the delay changes"
                           if sb["trend"] else
                           f"the EMG's reflex latency stays at {sb['latency_lo_ms']:.0f} ms "
                           f"(change {sb['latency_hi_ms'] - sb['latency_lo_ms']:+.1f} ms) "
                           f"over the range {sb['position_lo']:+.2f}..{sb['position_hi']:+.2f} rad, so the delay does not "
                           f"change: the dynamics do")
                    text = (f"Missing: {top.effect}, carried by the {top.pathway} pathway and the signal scheduling "
                            f"(operating position): held-out VAF +{top.vaf_gain:.2f} pp (p = {top.p_value:.1e}). "
                            f"On torque it ties with {top.tied_with} (+{rival.vaf_gain:.2f} pp, p = {top.tie_p:.2f}: "
                            f"{what}); the EMG settles it: {emg} (the EMG precedes the reflex's activation "
                            f"dynamics, so only a delay moves its bursts). {top.explanation}")
                else:
                    text = (f"Missing: {what}, carried by the {top.pathway} pathway and the signal scheduling "
                            f"(operating position): {top.effect} +{top.vaf_gain:.2f} pp (p = {top.p_value:.1e}), "
                            f"{top.tied_with} +{rival.vaf_gain:.2f} pp: the difference is within the noise "
                            f"(p = {top.tie_p:.2f}), so the data do not say which. {top.explanation}")
            more = self.significant[1:]
            if more:
                text += " Also significant given the ones before: " + "; ".join(
                    f"{c.effect}{_variant_text(c.variant)} ({c.pathway}, +{c.conditional_gain:.2f} pp)" for c in more) + "."
            if dep is not None and dep["vaf_gain"] > OUTSIDE_RATIO * top.vaf_gain:
                text += (f" But it explains only part of the structure: the residual depends more on {where}; "
                         f"the missing effect may lie outside the catalog.")
            return text
        if dep is not None:
            return f"No catalog effect explains the residual. It depends most on {where}."
        return "Nothing significant: no candidate effect or signal explains a meaningful part of the residual."

    def base_description(self) -> str:
        """What the candidates' gains are measured against, with its VAF (%)."""
        if self.design == "refit":
            return (f"its structure refitted with {self.settings['folds']}-fold blocked cross-validation: "
                    f"{self.surrogate_vaf:.2f} %")
        return f"model held fixed (see the note), on the samples scored: {self.surrogate_vaf:.2f} %"

    def notes(self) -> list:
        """What the reader must know about this diagnosis's design and data (sentences)."""
        out = []
        if self.design == "fixed":
            out.append(f"Model held fixed: {self.design_reason} Each candidate was fitted to the model's residual "
                       f"alone (cross-validated); gains are relative to the model as it is.")
        if self.coverage.get("outside_fraction", 0) > 0:
            c = self.coverage
            out.append(f"{100 * c['outside_fraction']:.1f} % of the samples ({c['outside_samples']}) have a scheduling "
                       f"value outside the identified range [{c['identified_range'][0]:+.3f}, "
                       f"{c['identified_range'][1]:+.3f}] rad; they were left out of every fit and score.")
        if self.design == "refit" and self.surrogate_vaf - self.vaf > TRANSFER_GAP:
            out.append(f"The model explains {self.vaf:.1f} % of these data, its structure refitted on them "
                       f"{self.surrogate_vaf:.1f} % (cross-validated): the candidates are judged on the structure; "
                       f"the model's own parameters do not carry over to this record (identification record too "
                       f"short, or different from it: a trajectory that moves differently, e.g. faster, or another "
                       f"state of the subject). A missing effect that stays nearly constant within this record is "
                       f"invisible to the candidates and shows only in this gap.")
        leaky = [f"{k} (R^2 {v:.2f})" for k, v in self.leaks.items() if v >= LEAK_R2]
        if leaky:
            out.append(f"Explained by the model's reflex drive, not used to name an effect: {', '.join(leaky)}.")
        return out

    def to_dict(self) -> dict:
        return {
            "format": "lpvpc-diagnosis",
            "model_hash": self.model_hash,
            "data": self.data_source,
            "n_samples": self.n_samples,
            "fs": self.fs,
            "vaf": _r(self.vaf, 3),
            "rmse": _r(self.rmse, 6),
            "surrogate_cv_vaf": _r(self.surrogate_vaf, 3),
            "answer": self.answer(),
            "design": self.design,
            "design_reason": self.design_reason,
            "notes": self.notes(),
            "coverage": self.coverage,
            "signal_leak_r2": self.leaks,
            "candidates": [c.to_dict() for c in self.candidates],
            "signal_dependence": self.dependence,
            "where": self.where,
            "settings": self.settings,
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            "units": {"vaf": "%", "vaf_gain": "percentage points of held-out VAF", "rmse": "N m", "fs": "Hz"},
        }

    def save(self, path):
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")


def _variant_text(v) -> str:
    return f" ({', '.join(f'{k}={x:g}' for k, x in v.items())})" if v else ""


def record_coverage(model, data) -> dict:
    """Length and scheduling coverage of a record against what a diagnosis needs."""
    rho = np.asarray(data.scheduling, dtype=float)
    lo, hi = (float(v) for v in model.scheduling_range)
    tol = RANGE_TOL * (hi - lo)
    outside = (rho < lo - tol) | (rho > hi + tol)
    span = (float(np.clip(rho.min(), lo, hi)), float(np.clip(rho.max(), lo, hi)))
    return {"duration_s": len(rho) / float(data.fs), "min_duration_s": MIN_RECORD_S,
            "identified_range": [lo, hi], "record_range": [float(rho.min()), float(rho.max())],
            "covered_fraction_of_range": (span[1] - span[0]) / (hi - lo) if hi > lo else 1.0,
            "outside_fraction": float(outside.mean()), "outside_samples": int(outside.sum()),
            "max_outside_fraction": MAX_OUTSIDE, "outside_mask": outside}


def check_record(model, data) -> dict:
    """Coverage of ``data`` (:func:`record_coverage`); raises InsufficientExcitationError
    (one line naming what is missing) when the record is too short or mostly outside the
    identified range for any diagnosis to hold."""
    from .errors import InsufficientExcitationError

    cov = record_coverage(model, data)
    src = getattr(data, "source", "") or "data"
    if cov["duration_s"] < MIN_RECORD_S:
        raise InsufficientExcitationError(
            f"{src}: record too short for a diagnosis: {cov['duration_s']:.1f} s; it needs at least {MIN_RECORD_S:g} s "
            f"({FOLDS} cross-validation folds of >= {MIN_RECORD_S / FOLDS:g} s)")
    if cov["outside_fraction"] > MAX_OUTSIDE:
        lo, hi = cov["identified_range"]
        raise InsufficientExcitationError(
            f"{src}: {100 * cov['outside_fraction']:.0f} % of the samples have a scheduling value outside the "
            f"model's identified range [{lo:+.3f}, {hi:+.3f}] rad (at most {100 * MAX_OUTSIDE:.0f} % allowed): "
            f"diagnose on a record within the range the model was identified on")
    return cov


def diagnose(model, data, *, folds=FOLDS, min_gain=MIN_GAIN, alpha=ALPHA, block_s=BLOCK_S,
             candidates=None, dependence=True, design="auto") -> Diagnosis:
    """Diagnose ``model`` on ``data`` (:class:`lpvpc.data.PerturbationData`, ideally not used
    to fit the model). ``candidates``: names to score (default: the whole catalog and all
    settings candidates, minus effects the model already has).

    ``design``: "refit" (the model's structure refitted with each candidate, blocked
    cross-validation), "fixed" (the model held, candidates fitted to its residual) or
    "auto": refit, unless the refitted base's cross-validated VAF falls more than
    SANE_DROP pp below the model's own VAF on these data (a record too short or too narrow
    for the structure: each fold holds positions the others do not visit), then fixed.
    Records shorter than MIN_RECORD_S or mostly outside the identified range are refused
    (InsufficientExcitationError); samples outside the range are left out of the scores."""
    if design not in ("auto", "refit", "fixed"):
        raise ValueError(f"design must be 'auto', 'refit' or 'fixed', not {design!r}")
    t0 = time.perf_counter()
    timings = {}
    if abs(float(data.fs) - float(model.fs)) > 1e-6 * model.fs:
        from .errors import DataError

        raise DataError(f"sampling rate {data.fs:g} Hz of the data differs from the model's {model.fs:g} Hz",
                        source=getattr(data, "source", None) or None)
    if getattr(data, "segments", ()):  # its blocked cross-validation runs along one record
        from .errors import DataError

        raise DataError(f"the diagnosis takes one trial; got {len(data.segments)} joined trials",
                        source=getattr(data, "source", None) or None)
    cov = check_record(model, data)
    outside = cov.pop("outside_mask")
    mask = ~outside if outside.any() else None
    sig = signals_from_data(data)
    pred = model.predict(data.position, data.scheduling, warn=False, signals=sig)
    y = np.asarray(data.torque, dtype=float)
    resid = y - pred.total
    inside = ~outside
    model_vaf_inside = vaf(y[inside], pred.total[inside])
    timings["predict"] = time.perf_counter() - t0
    t = time.perf_counter()
    reason = ""
    sur = Surrogate(model, data, folds, design="fixed" if design == "fixed" else "refit", mask=mask,
                    prediction=pred.total)
    if design == "fixed":
        reason = "requested."
    if design == "auto":
        r0, _ = sur.cv.fit(sur.base)
        base_vaf = 100 * (1 - float(r0 @ r0) / sur.sst)
        if base_vaf < model_vaf_inside - SANE_DROP:
            reason = (f"refitting the model's structure on this record ({cov['duration_s']:.0f} s, "
                      f"{100 * cov['covered_fraction_of_range']:.0f} % of the identified range) gives a "
                      f"cross-validated VAF of {base_vaf:.1f} % against {model_vaf_inside:.1f} % for the model itself: "
                      f"the record is too short or narrow for a refit (each fold must see positions the others "
                      f"visit too), or a large missing effect makes the refit unstable.")
            sur = Surrogate(model, data, folds, design="fixed", mask=mask, prediction=pred.total)
    timings["design"] = time.perf_counter() - t
    t = time.perf_counter()
    leaks = signal_leaks(sur)
    results, r0 = score_candidates(sur, candidates=candidates, min_gain=min_gain, alpha=alpha, block_s=block_s,
                                   leaks=leaks)
    timings["candidates"] = time.perf_counter() - t
    t = time.perf_counter()
    dep = (signal_dependence(sur, r0, block_s=block_s, leaks=leaks, pathways=(pred.intrinsic, pred.reflex))
           if dependence else [])
    timings["dependence"] = time.perf_counter() - t
    t = time.perf_counter()
    where = where_it_fails(model, data, resid, signals=sig)
    timings["where"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    # refit: the structure refitted (cross-validated); fixed: the model itself on the samples scored
    surrogate_vaf = 100 * (1 - float(r0 @ r0) / sur.sst)
    return Diagnosis(
        model_hash=model.model_hash, data_source=getattr(data, "source", "") or "", n_samples=len(y), fs=float(data.fs),
        vaf=vaf(y, pred.total), rmse=float(np.sqrt(np.mean(resid**2))), surrogate_vaf=surrogate_vaf,
        candidates=results, dependence=dep, where=where,
        settings={"folds": folds, "min_gain": min_gain, "alpha": alpha, "block_s": block_s, "design": design,
                  "leak_r2": LEAK_R2,
                  "test": "paired one-sided t on held-out squared residuals, 2-s batch means, Bonferroni over candidates"},
        timings=timings, residual=resid, prediction=pred.total, design=sur.design, design_reason=reason,
        coverage=cov, leaks=leaks, base_residual=r0)


# --------------------------------------------------------------------------- report


def format_table(diag: Diagnosis, n=None) -> str:
    """Plain-text ranking table of the candidates."""
    lines = [f"{'rank':>4}  {'candidate':44} {'kind':8} {'pathway':9} {'gain (pp)':>9} {'p':>9}  significant"]
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        if not c.available:
            lines.append(f"{i:>4}  {c.effect:44} {c.kind:8} {c.pathway:9} {'-':>9} {'-':>9}  n/a: {c.reason}")
            continue
        name = c.effect + (" (" + ", ".join(f"{k}={v:g}" for k, v in c.variant.items()) + ")" if c.variant else "")
        lines.append(f"{i:>4}  {name:44} {c.kind:8} {c.pathway:9} {c.vaf_gain:>+9.3f} {c.p_value:>9.1e}  "
                     f"{'YES' if c.significant else 'no'}")
    return "\n".join(lines)


def candidates_html(diag: Diagnosis, n=None) -> str:
    """The ranked candidates as an HTML table (significant ones first, in conditional order).
    A candidate's note (why it is not available, or what its refit found) takes a full-width
    row under it: as a ninth column it was squeezed to a word per line."""
    rows, notes = [], []
    for i, c in enumerate(diag.candidates[:n] if n else diag.candidates, 1):
        name = f"<code>{_e(c.effect)}</code>{_e(_variant_text(c.variant))}"
        if not c.available:
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), "–", "–", "–", "n/a"])
        else:
            cond = (f"{c.conditional_gain:+.3f}" + (f" (given {', '.join(c.given)})" if c.given else "")
                    if c.significant else "–")
            rows.append([str(i), name, _e(c.kind), _e(c.pathway), f"{c.vaf_gain:+.3f}", _e(cond), f"{c.p_value:.1e}",
                         '<span class="pass">YES</span>' if c.significant else "no"])
        notes.append(_breakable(c.reason) if c.reason else "")
    return '<div class="wide">' + _table(["rank", "candidate", "kind", "pathway", "gain (pp)", "conditional gain (pp)",
                                          "p", "significant"], rows, left=(1, 2, 3, 5), notes=notes) + "</div>"


def write_report(diag: Diagnosis, data, folder, *, title="Diagnosis") -> Path:
    """Report folder: ``report.html`` (self-contained: the answer, the ranked candidates,
    residual before/after the top candidate, where the model fails, signal dependence),
    ``diagnosis.md`` (the same in markdown), ``diagnosis.json`` and the figures. Returns
    the path of report.html."""
    from . import plotting

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    diag.save(folder / "diagnosis.json")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 7))
    plotting.plot_residual_diagnosis(diag, data, fig=fig)
    figs = folder / "residual.png"
    fig.savefig(figs, dpi=100)
    plt.close(fig)
    change = None
    first = next((c for c in diag.candidates if c.available and c.residual is not None), None)
    if first is not None and diag.base_residual is not None:
        fig, axes = plt.subplots(1, 2, figsize=(12, 3.6))
        plotting.plot_residual_change(data.time, data.torque, diag.base_residual, first.residual,
                                      labels=("model (cross-validated)", f"+ {first.effect}"), fs=data.fs, axes=axes)
        fig.tight_layout()
        change = folder / "residual_change.png"
        fig.savefig(change, dpi=100)
        plt.close(fig)
    _write_html(diag, folder / "report.html", title, figs, change, first)
    w = diag.where
    lines = [f"# {title}", "", f"Model `{diag.model_hash[:12]}` on `{diag.data_source}` ({diag.n_samples} samples at "
             f"{diag.fs:g} Hz): VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m; {diag.base_description()}.", "",
             "## Answer", "", diag.answer(), "", "## Candidates (held-out VAF gain)", "", "```", format_table(diag), "```", "",
             "Significant: p below alpha / number of candidates (alpha = "
             f"{diag.settings['alpha']}) and a gain of at least {diag.settings['min_gain']} pp.", "",
             "## Signal dependence (top 8)", "", "| signal | form | pathway | gain (pp) | p |", "|---|---|---|---|---|"]
    for d in diag.dependence[:8]:
        lines.append(f"| {d['signal']} | {FORMS[d['form']]} | {d['pathway']} | {d['vaf_gain']:+.3f} | {d['p_value']:.1e} |")
    lines += ["", "## Where the model fails", ""]
    for key in ("position", "velocity", "slow_movement", "time", "emg"):
        if key in w:
            lines += [f"### by {w[key]['by']}", "", "| bin | n | residual RMS (N m) | relative | VAF % |", "|---|---|---|---|---|"]
            lines += [f"| {b['bin']} | {b['n']} | {b['residual_rms']} | {b['relative_rms']} | {b['vaf']} |" for b in w[key]["bins"]]
            lines.append("")
    lines += ["### frequency bands", "", "| band (Hz) | unexplained fraction | share of residual power |", "|---|---|---|"]
    lines += [f"| {b['band_hz'][0]}-{b['band_hz'][1]} | {b['unexplained_fraction']} | {b['residual_power_share']} |" for b in w["frequency"]]
    lines += ["", "### events", ""]
    for k, e in w["events"].items():
        lines.append(f"- {e['description']} ({100 * e['fraction_of_samples']:.0f} % of samples): residual RMS "
                     f"{e['residual_rms_inside']} vs {e['residual_rms_outside']} N m elsewhere (ratio {e['ratio']})")
    wh = w["whiteness"]
    lines += ["", "### whiteness and cross-correlation", "",
              f"- residual autocorrelation outside +-2/sqrt(N) at {100 * wh['fraction_outside_2_over_sqrt_n']:.0f} % of lags "
              f"1..{wh['lags']} (Ljung-Box Q = {wh['ljung_box_q']}); {wh['note']}"]
    for k, c in w["cross_correlation"].items():
        lines.append(f"- with {k}: max |c| = {c['max_abs']} at lag {c['at_lag_s']:+.3f} s "
                     f"(99 % band +-{c['band_99']}{', OUTSIDE' if c['outside_band'] else ''})")
    lines += ["", f"![residual]({Path(figs).name})", ""]
    (folder / "diagnosis.md").write_text("\n".join(lines))
    return folder / "report.html"


def diagnosis_html(diag: Diagnosis, figs=None, change=None, first=None, *, level=2) -> str:
    """The body of a diagnosis (used by the diagnose report and by each step of the improve
    report)."""
    h = f"h{level}"
    c = diag.coverage
    parts = [f"<p>Model <code>{_e(diag.model_hash[:12])}</code> on <code>{_e(diag.data_source)}</code>: "
             f"{diag.n_samples} samples at {diag.fs:g} Hz ({c.get('duration_s', 0):.1f} s, "
             f"{100 * c.get('covered_fraction_of_range', 1):.0f} % of the identified range); VAF {diag.vaf:.2f} %, "
             f"RMSE {diag.rmse:.4g} N m; design <b>{_e(diag.design)}</b>: "
             f"{_e(diag.base_description())}.</p>",
             f"<{h}>Answer</{h}>", f"<p class=\"what\">{_e(diag.answer())}</p>"]
    for note in diag.notes():
        parts.append(f'<p class="flag">{_e(note)}</p>')
    parts += [f"<{h}>Candidates, ranked</{h}>",
              "<p class=\"small\">Gain: held-out VAF gain over the base (pp). Significant candidates are ranked by "
              "what each adds given the ones above it (conditional gain); a candidate is significant when its p-value "
              f"is below {diag.settings['alpha']} / number of candidates and its gain at least "
              f"{diag.settings['min_gain']} pp.</p>", candidates_html(diag)]
    if change is not None:
        parts.append(_html_img(change, f"Held-out residual of the model (cross-validated base) and with "
                                       f"{first.effect} added: before and after, over time and as spectra"))
    if diag.dependence:
        rows = [[_e(d["signal"]), _e(FORMS[d["form"]]), _e(d["pathway"]), f"{d['vaf_gain']:+.3f}", f"{d['p_value']:.1e}",
                 "–" if "leak" not in d else f"{d['leak']:.2f}"] for d in diag.dependence[:8]]
        parts += [f"<{h}>Which signal the residual depends on (top 8)</{h}>",
                  '<div class="wide">' + _table(["signal", "form", "pathway", "gain (pp)", "p",
                                                 "R² by reflex drive"], rows, left=(0, 1, 2)) + "</div>"]
    if figs is not None:
        parts += [f"<{h}>Where the model fails</{h}>",
                  _html_img(figs, "Residual over time, by position and velocity, by frequency band, its "
                                  "cross-correlation with the input, and the candidates' gains")]
    return "\n".join(parts)


def _write_html(diag, path, title, figs, change, first):
    body = f"<h1>{html.escape(title)}</h1>" + diagnosis_html(diag, figs, change, first)
    Path(path).write_text(_html_page(title, body))
