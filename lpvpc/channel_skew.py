"""A relative delay between a recording's position and torque channels (a measurement artefact).

A torque channel recorded a little after the position channel (different sensor filters or
acquisition paths; the lab's pilot trial: ~1 ms, a tenth of a 100 Hz sample) costs the model
points it cannot win back: the two-sided IRF absorbs a skew only in part, the causal form and
the reflex not at all. The loaders undo a known skew at the file's rate, before decimation
(``channel_skew`` of :func:`lpvpc.data.load_identification_data`: the position channels are
delayed by it). This module finds it from the record itself:

- :func:`choose_channel_skew`: cross-validation over a few candidate skews on the structure
  selection's contiguous folds, the candidate nearest 0 within one standard error of the
  best (the virtual subject, recorded without skew: 0);
- :func:`estimate_channel_skew`: the peak of the in-sample VAF over a finer grid (biased by
  ~+0.3 ms on the virtual subject; kept for the closed-loop fit's ``position_delay``);
- :func:`load_aligned`: load files with the skew given or chosen (``"auto"``) and undone at
  the file's rate.

The skew belongs to the recording, not to the ankle: a model identified on aligned data maps
the true angle to the true torque. ``lpvpc predict`` loads new files with the model's recorded
skew (so it predicts what that rig records); a plant in a loop gives the true angle and gets
the torque without any delay (the FMUs apply none). Units: s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .identification_data import SINC_HALF_WIDTH, check_channel_skew, delayed  # noqa: F401

__all__ = ["delayed", "delay_position", "ChannelSkew", "estimate_channel_skew", "choose_channel_skew",
           "CV_SKEW_CANDIDATES", "load_aligned"]


def delay_position(data, delay: float):
    """Perturbation data (:class:`lpvpc.data.PerturbationData`) with the position channel delayed
    by ``delay`` s relative to the torque (a fraction of a sample allowed; :func:`delayed`), to
    undo a torque channel recorded ``delay`` s late. The scheduling is left as is (it moves at
    < 1 Hz); the high-rate copy of the position, when present, is delayed the same.
    ``meta["position_delay_s"]`` records the delay.

    >>> from lpvpc.data import PerturbationData
    >>> d = PerturbationData(np.arange(6.0), np.zeros(6), np.zeros(6), 100.0)
    >>> aligned = delay_position(d, 0.01)  # one sample at 100 Hz
    >>> aligned.position.round(12).tolist(), aligned.meta["position_delay_s"]
    ([0.0, 0.0, 1.0, 2.0, 3.0, 4.0], 0.01)
    """
    import dataclasses

    def each_trial(x, fs, segments):  # joined trials: each delayed on its own (ends held)
        return np.concatenate([delayed(x[a:b], fs, delay) for a, b in (list(segments) or [(0, len(x))])])

    high = data.high_rate
    if high is not None:
        high = dataclasses.replace(high, position=each_trial(high.position, high.fs, high.segments))
    meta = {**data.meta, "position_delay_s": float(delay) + float(data.meta.get("position_delay_s", 0.0))}
    return dataclasses.replace(data, position=each_trial(data.position, data.fs, data.segments), high_rate=high,
                               meta=meta)


@dataclass
class ChannelSkew:
    """The relative delay of the torque channel behind the position channel (s; negative: the
    torque leads) that :func:`estimate_channel_skew` found: ``delay`` (the parabola's peak
    through the best grid point and its neighbours), ``candidates`` (s) and ``scores`` (the
    two-sided model's in-sample VAF, %, on the data aligned by each candidate).

    >>> ChannelSkew(0.001, np.array([0.0, 0.001, 0.002]), np.array([93.5, 93.8, 93.5])).delay
    0.001
    """

    delay: float
    candidates: np.ndarray
    scores: np.ndarray
    method: str = "in-sample"  # or "cv": :func:`choose_channel_skew` (scores: pooled CV VAF, %)
    standard_error: float = float("nan")  # cv: one standard error of the best candidate's lead (VAF points)


def estimate_channel_skew(data, candidates=None, **settings) -> ChannelSkew:
    """Estimate a delay between a record's position and torque channels from the data alone.

    For each candidate delay (s; default -2 to +3 ms in 0.5 ms steps) the position is delayed
    by it (:func:`delay_position`), an LPV-PC model identified (``settings`` as for
    :func:`lpvpc.identify.identify`) and its in-sample VAF recorded; the estimate is the peak
    of the parabola through the best candidate and its two neighbours. The two-sided model
    can absorb a skew with its future lags, but only in part (the reflex and the scheduling
    bases cannot), so its fit peaks at the channels' alignment; on the virtual subject (no
    skew) the estimate is within ~0.3 ms of 0 and of an imposed 1 ms (tests). Use the
    identification part only, then :func:`delay_position` the whole record by the estimate.

    A torque channel recorded 2 ms late (the virtual subject's 1 kHz torque shifted by 2 samples):

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=40.0)
    >>> for trial in (sim.pt, sim.ut):
    ...     trial.torque = np.r_[trial.torque[:2], trial.torque[:-2]]
    >>> skew = estimate_channel_skew(pair_trials(sim.pt, sim.ut), np.array([0.0, 1.0, 2.0, 3.0]) * 1e-3)
    >>> bool(abs(skew.delay - 0.002) < 0.0005)
    True
    """
    from .identify import identify
    from .model import vaf

    cand = np.arange(-2.0, 3.01, 0.5) * 1e-3 if candidates is None else np.asarray(candidates, float)
    if cand.ndim != 1 or len(cand) < 3 or not np.all(np.diff(cand) > 0):
        raise ValueError("candidates: at least 3 increasing delays (s)")
    scores = []
    for c in cand:
        aligned = delay_position(data, float(c))
        # one structure for every candidate (structure selection could change it with the
        # delay, and the scores would compare structures, not alignments)
        model = identify(aligned, **{"structure": "fixed", **settings})
        scores.append(vaf(aligned.torque, model.predict(aligned, warn=False).total))
    scores = np.array(scores)
    i = int(np.clip(np.argmax(scores), 1, len(cand) - 2))
    y0, y1, y2 = scores[i - 1: i + 2]
    curvature = y0 - 2 * y1 + y2
    step = 0.5 * (cand[i + 1] - cand[i - 1])
    offset = 0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0
    return ChannelSkew(delay=float(cand[i] + np.clip(offset, -1.0, 1.0) * step), candidates=cand, scores=scores)


CV_SKEW_CANDIDATES = (0.0, 0.5e-3, 1.0e-3, 1.5e-3, 2.0e-3)  # s: torque late by 0 to 2 ms (the pilot: ~1 ms)
MIN_CV_PIECE_S = 1.0  # s: training stretches shorter than this are left out (too short for the subspace step)


def choose_channel_skew(data, candidates=CV_SKEW_CANDIDATES, folds: str = "level", **settings) -> ChannelSkew:
    """Choose the channel skew by cross-validation on contiguous folds (s; the candidate kept).

    The folds are the structure selection's (:func:`lpvpc.selection.level_folds`: each level
    of a staircase, the two end plateaus not scored, or contiguous blocks); for each candidate delay the position is delayed
    by it (:func:`delay_position`), a model identified on the record without the fold (its
    stretches as trials; ``settings`` as for :func:`lpvpc.identify.identify`, one fixed
    structure for all candidates) and the fold predicted. The choice is the candidate
    closest to 0 whose pooled CV VAF is within one standard error (of the per-fold VAF
    differences) of the best: a skew is adopted only when predicting unseen stretches says
    so (the virtual subject, recorded without skew: 0). Costs one fixed-structure fit per
    candidate and fold.

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0)
    >>> choose_channel_skew(pair_trials(sim.pt, sim.ut), (0.0, 1e-3, 2e-3)).delay
    0.0
    """
    from .data import join_trials
    from .identify import identify
    from .selection import BLOCK_FOLDS, level_folds

    cand = np.asarray(candidates, dtype=float)
    if cand.ndim != 1 or len(cand) < 2 or len(set(cand.tolist())) != len(cand):
        raise ValueError("candidates: at least 2 distinct delays (s)")
    if folds == "block":  # contiguous blocks of time (every level seen in training)
        labels, kind = (np.arange(data.n) * BLOCK_FOLDS // max(data.n, 1)).astype(int), "block"
    else:
        labels, kind = level_folds(data.scheduling, data.fs)
    folds = np.unique(labels)
    if kind == "level" and len(folds) >= 5:
        # the end plateaus score extrapolation beyond the training range, whose errors (tens of
        # points, changing with any small change of the fit) would drown the alignment's
        med = [np.median(data.scheduling[labels == f]) for f in folds]
        folds = np.delete(folds, [int(np.argmin(med)), int(np.argmax(med))])
    bounds = list(data.segments) or [(0, data.n)]
    y = np.asarray(data.torque, dtype=float)
    ss = np.array([np.sum((y[labels == f] - y.mean()) ** 2) for f in folds])
    sse = np.zeros((len(cand), len(folds)))
    min_len = MIN_CV_PIECE_S * data.fs
    for i, c in enumerate(cand):
        aligned = delay_position(data, float(c))
        for j, f in enumerate(folds):
            pieces = []
            for a, b in bounds:  # the stretches outside the fold, trial by trial
                keep = np.r_[False, labels[a:b] != f, False]
                e = np.flatnonzero(np.diff(keep.astype(int)))
                pieces += [aligned.segment(a + u, a + v) for u, v in zip(e[::2], e[1::2]) if v - u >= min_len]
            model = identify(join_trials(pieces), **{"structure": "fixed", **settings})
            test = labels == f
            r = y[test] - model.predict(aligned, warn=False).total[test]
            sse[i, j] = r @ r
    scores = 100 * (1 - sse.sum(axis=1) / ss.sum())
    per_fold = 100 * (1 - sse / ss)  # VAF (%) of each candidate on each fold
    best = int(np.argmax(scores))
    lead = per_fold[best] - per_fold
    se = np.std(lead, axis=1, ddof=1) / np.sqrt(len(folds)) if len(folds) > 1 else np.zeros(len(cand))
    ok = scores >= scores[best] - se
    pick = min(np.flatnonzero(ok), key=lambda i: (abs(cand[i]), i))
    return ChannelSkew(delay=float(cand[pick]), candidates=cand, scores=scores, method="cv",
                       standard_error=float(se[pick]))


def load_aligned(pt=None, ut=None, data=None, *, channel_skew="auto", **load_settings):
    """:func:`lpvpc.data.load_identification_data` with the channel skew undone at the file's
    rate: ``channel_skew`` in s, or ``"auto"``: chosen from these data by
    :func:`choose_channel_skew` (on the record loaded as is; everything given is treated as
    identification data, so load only what you identify from). ``meta["channel_skew_s"]``
    records the skew applied (absent when 0), ``meta["channel_skew_choice"]`` the candidates
    (s) and their CV VAF (%) when chosen."""
    from .data import load_identification_data

    skew = check_channel_skew(channel_skew)
    if skew != "auto":
        return load_identification_data(pt, ut, data, channel_skew=skew, **load_settings)
    raw = load_identification_data(pt, ut, data, **load_settings)
    found = choose_channel_skew(raw)
    out = load_identification_data(pt, ut, data, channel_skew=found.delay, **load_settings) if found.delay else raw
    out.meta["channel_skew_choice"] = {"candidates_s": found.candidates.tolist(), "cv_vaf": found.scores.round(4).tolist(),
                                       "chosen_s": found.delay}
    return out
