"""A relative delay between a recording's position and torque channels (a measurement artefact).

A torque channel recorded a little after the position channel (different sensor filters or
acquisition paths; the lab's pilot trial: ~1 ms, a tenth of a 100 Hz sample) costs the model
points it cannot win back: the two-sided IRF absorbs a skew only in part, the causal form and
the reflex not at all. The loaders undo a known skew at the file's rate, before decimation
(``channel_skew`` of :func:`lpvpc.data.load_identification_data`: the position channels are
delayed by it). This module finds it from the record itself:

- :func:`estimate_channel_skew`: the peak of the in-sample VAF of a fixed-structure model
  over candidate skews -2..+3 ms (aligned at the model rate, a fraction of a sample allowed);
  :attr:`ChannelSkew.chosen` keeps it only when it removes at least MIN_RESIDUAL_REDUCTION of
  the residual variance (the virtual subject without skew: 0; its torque 1 ms late: ~1.3 ms);
- :func:`load_aligned`: load files with the skew given, or estimated (``"auto"``), undone at
  the file's rate.

Cross-validation over candidate skews on contiguous folds (left-out interior levels) was
measured and not adopted: the extrapolation and structure noise of the folds is larger than
the skew's effect, and it chose 0 even for the virtual subject with its torque 1 ms late
(benchmarks/bench_real_pilot.py).

The skew belongs to the recording, not to the ankle: a model identified on aligned data maps
the true angle to the true torque. ``lpvpc predict`` loads new files with the model's recorded
skew (so it predicts what that rig records); a plant in a loop gives the true angle and gets
the torque without any delay (the FMUs apply none). Units: s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .identification_data import SINC_HALF_WIDTH, check_channel_skew, delayed  # noqa: F401

__all__ = ["delayed", "delay_position", "ChannelSkew", "estimate_channel_skew", "load_aligned",
           "MIN_RESIDUAL_REDUCTION"]

# A skew is undone only when lining the channels up removes at least this share of the
# in-sample residual variance. Measured (benchmarks/results/real_pilot.txt): the virtual subject
# without skew 0.0-0.5 % (its estimate then 0.2-0.4 ms: noise, not a skew), with its torque 1 ms
# late 5.7-6.1 %, the lab's pilot trial 4.9 %.
MIN_RESIDUAL_REDUCTION = 0.02


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

    >>> skew = ChannelSkew(0.001, np.array([0.0, 0.001, 0.002]), np.array([93.5, 93.8, 93.5]))
    >>> round(skew.residual_reduction, 3), skew.chosen  # 0.3 of the 6.5 points left: 4.6 %
    (0.046, 0.001)
    """

    delay: float
    candidates: np.ndarray
    scores: np.ndarray

    @property
    def residual_reduction(self) -> float:
        """The share of the residual variance (0..1) that the best candidate removes against no
        alignment (the candidate 0): (VAF_best - VAF_0) / (100 - VAF_0); nan without a 0 candidate."""
        zero = np.flatnonzero(np.abs(self.candidates) < 1e-12)
        if len(zero) == 0:
            return float("nan")
        v0 = float(self.scores[zero[0]])
        return (float(np.max(self.scores)) - v0) / max(100.0 - v0, 1e-12)

    @property
    def chosen(self) -> float:
        """The skew to undo (s): ``delay`` when lining the channels up removes at least
        MIN_RESIDUAL_REDUCTION of the residual variance, else 0 (no skew shown by the data)."""
        r = self.residual_reduction
        return self.delay if not np.isfinite(r) or r >= MIN_RESIDUAL_REDUCTION else 0.0


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


def load_aligned(pt=None, ut=None, data=None, *, channel_skew="auto", **load_settings):
    """:func:`lpvpc.data.load_identification_data` with the channel skew undone at the file's
    rate: ``channel_skew`` in s, or ``"auto"``: chosen from these data by
    :func:`estimate_channel_skew` and :attr:`ChannelSkew.chosen` (on the record loaded as is;
    everything given is treated as identification data, so load only what you identify
    from). ``meta["channel_skew_s"]`` records the skew applied (absent when 0),
    ``meta["channel_skew_choice"]`` the estimate when chosen: candidates (s), in-sample VAF
    (%), the estimate (s) and the share of residual variance it removes.

    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=5.0)  # 1 kHz trials
    >>> load_aligned(pt=sim.pt, ut=sim.ut, channel_skew=1e-3).meta["channel_skew_s"]  # given: no estimate
    0.001
    """
    from .data import load_identification_data

    skew = check_channel_skew(channel_skew, allow_auto=True)
    if skew != "auto":
        return load_identification_data(pt, ut, data, channel_skew=skew, **load_settings)
    raw = load_identification_data(pt, ut, data, **load_settings)
    found = estimate_channel_skew(raw)
    out = load_identification_data(pt, ut, data, channel_skew=found.chosen, **load_settings) if found.chosen else raw
    out.meta["channel_skew_choice"] = {"candidates_s": found.candidates.tolist(),
                                       "in_sample_vaf": found.scores.round(4).tolist(), "estimate_s": found.delay,
                                       "residual_reduction": found.residual_reduction, "chosen_s": found.chosen}
    return out
