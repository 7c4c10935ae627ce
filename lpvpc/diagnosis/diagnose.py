"""Diagnosis: where a model fails on data it was not fitted to, and which physical effect
is missing.

Units: torque N m, position rad, velocity rad/s, time s, frequency Hz; VAF and VAF gains
in percent / percentage points (pp).

Two questions (see :func:`diagnose`):

1. *Where does it fail?* (:func:`~lpvpc.diagnosis.where.where_it_fails`) The residual (measured minus predicted
   torque) of the model as it is, binned by position, perturbation velocity and its sign,
   slow-movement direction, time in the trial, frequency band, around perturbation steps
   and trajectory transitions; its whiteness; its cross-correlation with the perturbation
   position, velocity and delayed velocity at negative and positive lags.

2. *Which physical effect is missing?* Every candidate of the catalog
   (:mod:`lpvpc.models.effects`: effects and settings) is fitted and scored on held-out data.
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
   means over 2-s blocks (the residual is coloured, samples are not independent), and the
   Wilcoxon signed-rank test on the same block means: the smaller p, doubled (one block that
   swings the other way takes the t test's power, an effect confined to a few blocks the
   signed rank's; :func:`lpvpc.diagnosis.cv.robust_paired_test`); extra parameters are accounted
   for because every residual is held out. A candidate is
   significant when its p-value is below alpha / n_candidates (Bonferroni, alpha = 0.1) AND
   its gain is at least ``min_gain`` (0.15) pp (0.4 x min_gain for a catalog effect on the
   reflex pathway reading no EMG-derived signal: the reflex carries a small share of the torque), or 0.6 x min_gain with a p-value
   ten times below the level (:func:`lpvpc.diagnosis.candidates.passes`: effects that carry
   little torque, such as reflex habituation): a real but negligible improvement is not an
   alarm. (The thresholds were set on the virtual subject; benchmarks/bench_diagnose.py
   records the false-alarm and detection rates they give.)

   When no candidate is significant, :func:`~lpvpc.diagnosis.signals.signal_dependence` says which measured or
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
``explanation``, ...), :func:`~lpvpc.diagnosis.report.write_report` writes a markdown report with plots.

The parts live in modules of their own, re-exported here: :mod:`lpvpc.diagnosis.cv` (blocked
cross-validation, the paired test), :mod:`lpvpc.diagnosis.surrogate` (the model's structure as
least-squares blocks), :mod:`lpvpc.diagnosis.candidates` (the catalog scored and ranked),
:mod:`lpvpc.diagnosis.signals` (signal dependence), :mod:`lpvpc.diagnosis.where` (where it fails)
and :mod:`lpvpc.diagnosis.report` (text table, HTML and markdown report). This module holds
the entry point :func:`diagnose`, its result :class:`Diagnosis` and the record checks.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .candidates import (ALPHA, EMG_MIN_CHANGE, EMG_TIE, EMG_TREND_P, LEAK_R2, MIN_GAIN,  # noqa: F401
                                  PREFER_UNDERIVED, TIE_P, TIES, CandidateResult, _variant_text,
                                  reflex_leak, score_candidates, signal_leaks)
from .cv import BLOCK_S, FIXED_RIDGE, FOLDS, RIDGE, BlockCV, _r, paired_test, robust_paired_test  # noqa: F401
from .report import candidates_html, diagnosis_html, format_table, write_report  # noqa: F401
from .signals import FORMS, TIME_KNOT_S, candidate_signals, signal_dependence, time_basis  # noqa: F401
from .between import between_record_candidates, merge
from .surrogate import Surrogate
from .where import where_it_fails  # noqa: F401
from ..io.trial import check_model_rate
from ..linalg import on_one_blas_thread
from ..models.effects import signals_from_data, with_model_activation
from ..models.model import vaf

OUTSIDE_RATIO = 1.5  # a signal probe this many times better than the top candidate: say so
MIN_RECORD_S = 20.0  # s: shorter records are refused (10 folds of 2 s, each a few perturbation steps)
SANE_DROP = 2.0  # pp: a refitted base this much below the model's own VAF is not trusted (short/narrow record)
RANGE_TOL = 0.02  # fraction of the identified range: scheduling beyond it counts as outside
MAX_OUTSIDE = 0.5  # records with more samples outside the identified range are refused
# pp: a refitted structure this much better than the model itself is worth a note: the model
# does not carry over to the record (the mirror of SANE_DROP; an effect that is constant within
# the record but differs from the identification record shows only here)
TRANSFER_GAP = SANE_DROP


@dataclass
class Diagnosis:
    """What :func:`diagnose` found: the candidates' scores and where the model fails.

    Attributes
    ----------
    model_hash, data_source : str
        The diagnosed model's hash and the record's source.
    n_samples : int
        Samples of the record.
    fs : float
        Its rate (Hz).
    vaf : float
        The model's VAF (%) on the record, as it is.
    rmse : float
        Its RMS error (N m).
    surrogate_vaf : float
        Cross-validated VAF (%) of the model's structure refitted on the record.
    candidates : list
        Every candidate's score: held-out gain (pp), p-values, significance.
    dependence : list
        How the residual depends on each signal.
    where : dict
        Where in the record (positions, velocities, time) the model fails.
    settings, timings : dict
        The diagnosis's settings, and its durations (s).
    residual, prediction : numpy.ndarray or None
        The model's residual and prediction (N m) on the record.
    design : {"refit", "fixed"}
        The design the candidates were scored with.
    design_reason : str
        Why that design.
    coverage, leaks : dict
        How much of the record lies within the identified range; signals the model's
        reflex drive already explains.
    base_residual : numpy.ndarray or None
        The held-out (cross-validated) residual of the surrogate base (N m).

    See Also
    --------
    diagnose : makes it (with an example).
    """

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
    model: object = field(default=None, repr=False, compare=False)  # the model diagnosed (not saved)

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
            if top.scope != "record":
                text += (f" Found between records: fitted on the identification record and scored on this one, "
                         f"where the model's structure refitted explains {self.surrogate_vaf - self.vaf:.2f} pp more "
                         f"than the model itself: the {', '.join(top.signals)} differs between the two records.")
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

    def notes(self, *, weighed: bool = False) -> list:
        """What the reader must know about this diagnosis's design and data (sentences).
        ``weighed``: (sentence, changes_conclusion) pairs instead, True for a note that changes
        what the reader may conclude (a report shows only those as a warning)."""
        out = []
        if self.design == "fixed":
            out.append((f"Model held fixed: {self.design_reason} Each candidate was fitted to the model's residual "
                        f"alone (cross-validated); gains are relative to the model as it is.", False))
        if self.coverage.get("outside_fraction", 0) > 0:
            c = self.coverage
            out.append((f"{100 * c['outside_fraction']:.1f} % of the samples ({c['outside_samples']}) have a scheduling "
                        f"value outside the identified range [{c['identified_range'][0]:+.3f}, "
                        f"{c['identified_range'][1]:+.3f}] rad; they were left out of every fit and score.", False))
        if self.design == "refit" and self.surrogate_vaf - self.vaf > TRANSFER_GAP:
            out.append((f"The model explains {self.vaf:.1f} % of these data, its structure refitted on them "
                        f"{self.surrogate_vaf:.1f} % (cross-validated): the candidates are judged on the structure; "
                        f"the model's own parameters do not carry over to this record (identification record too "
                        f"short, or different from it: a trajectory that moves differently, e.g. faster, or another "
                        f"state of the subject). "
                        + ("The catalog effects whose signal can differ between the records were also fitted on the "
                           "identification record and scored here (marked between records)."
                           if self.settings.get("reference") else
                           "A missing effect that stays nearly constant within this record is invisible to the "
                           "candidates and shows only in this gap (improve, or diagnose given the identification "
                           "record as reference: lpvpc diagnose --reference DATA0 or --reference-pt/--reference-ut, "
                           "diagnose(..., reference=) in Python, also tries the effects whose signal can differ "
                           "between records)."), True))
        leaky = [f"{k} (R^2 {v:.2f})" for k, v in self.leaks.items() if v >= LEAK_R2]
        if leaky:
            out.append((f"Not used to name an effect: {', '.join(leaky)}; these signals follow the model's own reflex "
                        f"drive so closely that they carry nothing the model lacks.", False))
        return out if weighed else [text for text, _ in out]

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


def record_coverage(model, data) -> dict:
    """Length and scheduling coverage of a record against what a diagnosis needs."""
    rho = np.asarray(data.scheduling, dtype=float)
    lo, hi = (float(v) for v in model.scheduling_range)
    tol = RANGE_TOL * (hi - lo)
    if model.one_position:  # a stationary trial's model: within the span identify itself calls one position
        from ..identification.identify import STATIONARY_RANGE

        tol = 0.5 * float(model.settings.get("stationary_range", STATIONARY_RANGE))
    outside = (rho < lo - tol) | (rho > hi + tol)
    span = (float(np.clip(rho.min(), lo, hi)), float(np.clip(rho.max(), lo, hi)))
    return {"duration_s": len(rho) / float(data.fs), "min_duration_s": MIN_RECORD_S,
            "identified_range": [lo, hi], "record_range": [float(rho.min()), float(rho.max())],
            "covered_fraction_of_range": (span[1] - span[0]) / (hi - lo) if hi > lo else 1.0,
            "outside_fraction": float(outside.mean()), "outside_samples": int(outside.sum()),
            "max_outside_fraction": MAX_OUTSIDE, "tolerance": tol, "outside_mask": outside}


def check_record(model, data) -> dict:
    """Coverage of ``data`` (:func:`record_coverage`); raises InsufficientExcitationError
    (one line naming what is missing) when the record is too short or mostly outside the
    identified range for any diagnosis to hold."""
    from ..errors import InsufficientExcitationError

    cov = record_coverage(model, data)
    src = getattr(data, "source", "") or "data"
    if cov["duration_s"] < MIN_RECORD_S:
        raise InsufficientExcitationError(
            f"{src}: record too short for a diagnosis: {cov['duration_s']:.1f} s; it needs at least {MIN_RECORD_S:g} s "
            f"({FOLDS} cross-validation folds of >= {MIN_RECORD_S / FOLDS:g} s)")
    if cov["outside_fraction"] > MAX_OUTSIDE and model.one_position:
        raise InsufficientExcitationError(
            f"{src}: {100 * cov['outside_fraction']:.0f} % of the samples lie more than {1e3 * cov['tolerance']:.1f} "
            f"mrad from the model's one operating position {cov['identified_range'][0]:+.4f} rad (at most "
            f"{100 * MAX_OUTSIDE:.0f} % allowed; the stationary trial's model does not vary with position): diagnose "
            f"on a record at that position")
    if cov["outside_fraction"] > MAX_OUTSIDE:
        lo, hi = cov["identified_range"]
        raise InsufficientExcitationError(
            f"{src}: {100 * cov['outside_fraction']:.0f} % of the samples have a scheduling value outside the "
            f"model's identified range [{lo:+.3f}, {hi:+.3f}] rad (at most {100 * MAX_OUTSIDE:.0f} % allowed): "
            f"diagnose on a record within the range the model was identified on")
    return cov


@dataclass
class SurrogateSetup:
    """What :func:`diagnosis_surrogate` prepares: the record with its activation estimates
    (``data``) and its extra signals (``signals``), its coverage of the identified range
    (``coverage``, and ``outside``: the samples left out), the model's prediction, its VAF
    inside the range, the surrogate and why it holds the model fixed ("" when it refits).

    >>> import dataclasses
    >>> [f.name for f in dataclasses.fields(SurrogateSetup)]
    ['data', 'signals', 'coverage', 'outside', 'prediction', 'model_vaf_inside', 'surrogate', 'reason', 'timings']
    """

    data: object
    signals: dict
    coverage: dict
    outside: np.ndarray
    prediction: object
    model_vaf_inside: float
    surrogate: Surrogate
    reason: str
    timings: dict

    @property
    def mask(self):
        """The samples scored (inside the identified range), or None when that is all of them."""
        return ~self.outside if self.outside.any() else None


def diagnosis_surrogate(model, data, folds=FOLDS, design="auto") -> SurrogateSetup:
    """The surrogate :func:`diagnose` scores every candidate on (``design`` as it takes it):
    the model's structure refitted on ``data`` in ``folds`` blocks, or the model held
    ("fixed") when asked or when the refit's cross-validated VAF falls more than
    ``SANE_DROP`` pp below the model's own on the samples inside the identified range.

    The EMG's reflex bursts are explained by the model's own reflex drive (not the measured
    velocity), once, for every fit on the record (:func:`lpvpc.models.effects.with_model_activation`).
    A record too short or mostly outside the identified range raises as :func:`diagnose` says;
    a ``design`` other than "auto", "refit" or "fixed" raises ValueError.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> train = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(train.pt, train.ut))
    >>> test = simulate_pair("multilevel", seed=1, duration=60.0, fs_out=100.0)
    >>> setup = diagnosis_surrogate(model, pair_trials(test.pt, test.ut))
    >>> setup.surrogate.design, setup.surrogate.base, setup.reason
    ('refit', ['intrinsic', 'reflex'], '')

    A 24-s record is too short to refit the structure on: the model is held, and the reason
    says why.

    >>> short = simulate_pair("multilevel", seed=1, duration=24.0, fs_out=100.0)
    >>> setup = diagnosis_surrogate(model, pair_trials(short.pt, short.ut))
    >>> setup.surrogate.design, setup.reason.startswith("refitting the model's structure on this record (24 s")
    ('fixed', True)
    """
    if design not in ("auto", "refit", "fixed"):
        raise ValueError(f"design must be 'auto', 'refit' or 'fixed', not {design!r}")
    t0 = time.perf_counter()
    data = with_model_activation(data, model)
    cov = check_record(model, data)
    outside = cov.pop("outside_mask")
    mask = ~outside if outside.any() else None
    sig = signals_from_data(data)
    pred = model.predict(data, warn=False, signals=sig)  # as every door predicts it
    y = np.asarray(data.torque, dtype=float)
    model_vaf_inside = vaf(y[~outside], pred.total[~outside])
    timings = {"predict": time.perf_counter() - t0}
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
    return SurrogateSetup(data, sig, cov, outside, pred, model_vaf_inside, sur, reason, timings)


@on_one_blas_thread
def diagnose(model, data, *, folds=FOLDS, min_gain=MIN_GAIN, alpha=ALPHA, block_s=BLOCK_S,
             candidates=None, dependence=True, design="auto", reference=None) -> Diagnosis:
    """Where ``model`` fails on ``data`` and which missing effect or setting would explain it.

    Every candidate (an effect of :data:`lpvpc.models.effects.CATALOG` or a setting of
    :data:`lpvpc.models.effects.SETTINGS`) is scored by blocked cross-validation on the
    record and tested for a significant held-out gain; samples outside the identified range
    are left out of the scores.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model to diagnose.
    data : lpvpc.io.PerturbationData
        One record at the model's rate, ideally not used to fit the model, at least
        ``MIN_RECORD_S`` (20 s) long and mostly inside the identified range.
    folds : int, default 10
        Blocks of the cross-validation.
    min_gain : float, default 0.15
        Held-out VAF gain (percentage points) below which a candidate needs stronger
        evidence.
    alpha : float, default 0.1
        Family-wise significance level (Bonferroni over the candidates tested).
    block_s : float, default 2.0
        Length (s) of the blocks of the paired test's variance estimate.
    candidates : list of str, optional
        Names to score; default the whole catalog and every setting candidate, minus the
        effects the model already has.
    dependence : bool, default True
        Also report how the residual depends on each signal (:func:`~lpvpc.diagnosis.signals.signal_dependence`).
    design : {"auto", "refit", "fixed"}, default "auto"
        "refit": the model's structure refitted with each candidate; "fixed": the model held,
        candidates fitted to its residual; "auto": refit, unless the refitted base's
        cross-validated VAF falls more than ``SANE_DROP`` pp below the model's own VAF on
        these data (a record too short or too narrow for the structure), then fixed.
    reference : lpvpc.io.PerturbationData, optional
        The record ``model`` was identified on. With it, the catalog effects whose signal can
        change level between records (the background activation) are also fitted on it and
        scored on ``data`` against the model (:mod:`lpvpc.diagnosis.between`), when the
        structure refitted on ``data`` explains it better than the model does: an effect that
        stays nearly constant within ``data`` but differs from the identification record is
        invisible to the within-record candidates. On the command line: ``lpvpc diagnose
        --reference DATA0`` (or ``--reference-pt PT0 --reference-ut UT0``).

    Returns
    -------
    Diagnosis
        The candidates' scores, the significant ones (``significant``), the answer in words
        (:meth:`Diagnosis.answer`) and where in the record the model fails (``where``).

    Raises
    ------
    lpvpc.errors.DataError
        Data (or ``reference``) at another rate than the model's, or joined trials.
    TypeError
        A ``reference`` that is not a record.
    lpvpc.errors.InsufficientExcitationError
        A record shorter than ``MIN_RECORD_S`` or mostly outside the identified range.
    ValueError
        An unknown ``design``.

    Examples
    --------
    A model of the virtual subject diagnosed on another record of it: nothing is missing.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> train = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(train.pt, train.ut))
    >>> test = simulate_pair("multilevel", seed=1, duration=24.0, fs_out=100.0)
    >>> diagnosis = diagnose(model, pair_trials(test.pt, test.ut))
    >>> diagnosis.significant, bool(diagnosis.vaf > 90.0)
    ([], True)
    """
    t0 = time.perf_counter()
    timings = {}
    check_model_rate(data.fs, model.fs, source=getattr(data, "source", None), tolerance=1e-6)
    if getattr(data, "segments", ()):  # its blocked cross-validation runs along one record
        from ..errors import DataError

        raise DataError(f"the diagnosis takes one trial; got {len(data.segments)} joined trials",
                        source=getattr(data, "source", None) or None)
    if reference is not None:  # the identification record: a record at the model's rate
        if not hasattr(reference, "torque") or not hasattr(reference, "fs"):
            raise TypeError(f"reference must be the identification record (lpvpc.io.PerturbationData, e.g. from "
                            f"lpvpc.load_identification_data), not {type(reference).__name__}")
        check_model_rate(reference.fs, model.fs, what="reference record", source=getattr(reference, "source", None),
                         tolerance=1e-6)
    setup = diagnosis_surrogate(model, data, folds, design)
    data, cov, pred, sur, reason = setup.data, setup.coverage, setup.prediction, setup.surrogate, setup.reason
    mask, sig = setup.mask, setup.signals
    y = np.asarray(data.torque, dtype=float)
    resid = y - pred.total
    model_vaf_inside = setup.model_vaf_inside
    timings.update(setup.timings)
    t = time.perf_counter()
    leaks = signal_leaks(sur)
    results, r0 = score_candidates(sur, candidates=candidates, min_gain=min_gain, alpha=alpha, block_s=block_s,
                                   leaks=leaks)
    timings["candidates"] = time.perf_counter() - t
    # refit: the structure refitted (cross-validated); fixed: the model itself on the samples scored
    surrogate_vaf = 100 * (1 - float(r0 @ r0) / sur.sst)
    if reference is not None and sur.design == "refit":
        t = time.perf_counter()
        between = between_record_candidates(model, reference, data, pred.total, mask=mask,
                                            transfer_gap=surrogate_vaf - model_vaf_inside, block_s=block_s)
        n_tested = sum(r.available for r in results) + sum(r.available for r in between)
        results = merge(results, between, min_gain=min_gain, level=alpha / max(1, n_tested))
        timings["between"] = time.perf_counter() - t
    t = time.perf_counter()
    dep = (signal_dependence(sur, r0, block_s=block_s, leaks=leaks, pathways=(pred.intrinsic, pred.reflex))
           if dependence else [])
    timings["dependence"] = time.perf_counter() - t
    t = time.perf_counter()
    where = where_it_fails(model, data, resid, signals=sig)
    timings["where"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    return Diagnosis(
        model_hash=model.model_hash, data_source=getattr(data, "source", "") or "", n_samples=len(y), fs=float(data.fs),
        vaf=vaf(y, pred.total), rmse=float(np.sqrt(np.mean(resid**2))), surrogate_vaf=surrogate_vaf,
        candidates=results, dependence=dep, where=where,
        settings={"folds": folds, "min_gain": min_gain, "alpha": alpha, "block_s": block_s, "design": design,
                  "leak_r2": LEAK_R2, "reference": None if reference is None else (getattr(reference, "source", "")
                                                                                   or "given"),
                  "test": ("paired one-sided test on held-out squared residuals, 2-s batch means: t or Wilcoxon "
                           "signed rank, the smaller p doubled; Bonferroni over candidates")},
        timings=timings, residual=resid, prediction=pred.total, design=sur.design, design_reason=reason,
        coverage=cov, leaks=leaks, base_residual=r0, model=model)
