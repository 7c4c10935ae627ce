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
- :func:`scan_channel_skew`: the same peak from one fitted model, its structure and reflex
  dynamics held, its least squares solved once per candidate on the torque shifted by it (one
  regressor for every candidate: ~0.05 s for a 2-minute record against ~11 fits). identify runs
  it on every record it fits (``model.fit["channel_skew"]``) and warns when it finds a skew;
- :func:`load_aligned`: load files with the skew given, or found (``"auto"``: one identify
  and its scan), undone at the file's rate. The CLI's identify does this by default.

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

__all__ = ["delayed", "delay_position", "ChannelSkew", "estimate_channel_skew", "scan_channel_skew", "load_aligned",
           "MIN_RESIDUAL_REDUCTION", "CANDIDATES"]

# A skew is undone only when lining the channels up removes at least this share of the
# in-sample residual variance (and the best candidate is inside the grid: ChannelSkew.interior).
# Measured (benchmarks/results/real_pilot.txt), refitting per candidate / identify's scan: the
# virtual subject without skew 0.0-0.5 % / 0.2-0.5 % (its estimate then 0.2-0.4 ms: noise, not a
# skew), with its torque 1 ms late 5.7-6.1 % / 3.9-4.8 %, the lab's pilot trial 4.9 % / 3.4 %.
MIN_RESIDUAL_REDUCTION = 0.02
#: Candidate skews (s): -2..+3 ms in 0.5 ms steps (a torque channel late is the usual case).
CANDIDATES = np.arange(-2.0, 3.01, 0.5) * 1e-3


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
        if not self.interior:
            return 0.0
        return self.delay if not np.isfinite(r) or r >= MIN_RESIDUAL_REDUCTION else 0.0

    @property
    def interior(self) -> bool:
        """Whether the best candidate lies inside the grid: a skew shows as a peak; a fit that
        still improves at the grid's end shows a model mismatch, not a skew (the lab's stationary
        trial z_df2: -2 ms, the end, 2.4 % of the residual; lining up by it cost 1 point held out)."""
        return 0 < int(np.argmax(self.scores)) < len(self.scores) - 1

    def to_dict(self) -> dict:
        """What the choice rests on, as recorded in a model's fit and a loaded record's meta:
        candidates (s), in-sample VAF (%), the estimate (s), the share of residual variance it
        removes and the skew chosen (s)."""
        return {"candidates_s": self.candidates.tolist(), "in_sample_vaf": self.scores.round(4).tolist(),
                "estimate_s": self.delay, "residual_reduction": self.residual_reduction, "chosen_s": self.chosen}


def _peak(cand, scores) -> float:
    """The peak of the parabola through the best candidate and its two neighbours (s)."""
    i = int(np.clip(np.argmax(scores), 1, len(cand) - 2))
    y0, y1, y2 = scores[i - 1: i + 2]
    curvature = y0 - 2 * y1 + y2
    step = 0.5 * (cand[i + 1] - cand[i - 1])
    offset = 0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0
    return float(cand[i] + np.clip(offset, -1.0, 1.0) * step)


def _candidates(candidates) -> np.ndarray:
    cand = CANDIDATES if candidates is None else np.asarray(candidates, float)
    if cand.ndim != 1 or len(cand) < 3 or not np.all(np.diff(cand) > 0):
        raise ValueError("candidates: at least 3 increasing delays (s)")
    return cand


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

    cand = _candidates(candidates)
    scores = []
    for c in cand:
        aligned = delay_position(data, float(c))
        # one structure for every candidate (structure selection could change it with the
        # delay, and the scores would compare structures, not alignments)
        model = identify(aligned, **{"structure": "fixed", **settings})
        scores.append(vaf(aligned.torque, model.predict(aligned, warn=False).total))
    scores = np.array(scores)
    return ChannelSkew(delay=_peak(cand, scores), candidates=cand, scores=scores)


def scan_channel_skew(model, data, candidates=None) -> ChannelSkew:
    """The channel skew a fitted ``model`` sees in its identification ``data``: for each
    candidate delay (s; default :data:`CANDIDATES`) the in-sample VAF of the model's structure
    (its bases' orders, IRF half-width, reflex delay and curvature term, the reflex on the
    model-rate velocity, no effects) with its reflex dynamics held, fitted to the torque
    advanced by the candidate (the same alignment as the position delayed by it); the estimate
    is the parabola's peak as in :func:`estimate_channel_skew`. One regressor serves every
    candidate (:func:`lpvpc.selection.in_sample_vaf`), so the scan costs about one least-squares
    solve; the dynamics are not refitted per candidate, which leaves the estimate ~0.3-0.5 ms
    later than the refitting one on the virtual subject (either way under the threshold without
    a skew: benchmarks/results/real_pilot.txt).

    >>> import warnings
    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.identify import identify
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0)
    >>> for trial in (sim.pt, sim.ut):  # the 1 kHz torque written 2 ms late
    ...     trial.torque = np.r_[trial.torque[:2], trial.torque[:-2]]
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     m = identify(d)
    >>> skew = scan_channel_skew(m, d)
    >>> bool(1.5e-3 < skew.delay < 3e-3), skew.chosen == skew.delay
    (True, True)
    """
    from .identify import _fitted_structure
    from .segments import Segments
    from .selection import in_sample_vaf

    cand = _candidates(candidates)
    y = np.asarray(data.torque, dtype=float)
    seg = Segments.of(data, len(y))
    # each trial's torque advanced on its own (as delay_position delays each trial's position)
    Y = np.column_stack([seg.map(lambda x, c=c: delayed(x, data.fs, -c), y) for c in cand])
    settings = _fitted_structure(model, model.intrinsic_basis.extrapolation)
    dynamics = (model.A, np.atleast_2d(model.C), np.append(model.B, model.D))
    scores = in_sample_vaf(data.position, Y, data.scheduling, data.fs, dynamics, settings, model.intrinsic_basis.family,
                           model.velocity_basis.family, seg)
    return ChannelSkew(delay=_peak(cand, scores), candidates=cand, scores=scores)


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

    import warnings

    from .identify import identify

    skew = check_channel_skew(channel_skew, allow_auto=True)
    if skew != "auto":
        return load_identification_data(pt, ut, data, channel_skew=skew, **load_settings)
    raw = load_identification_data(pt, ut, data, **load_settings)
    with warnings.catch_warnings():  # (the model is only the scan's: its warnings come with the real fit)
        warnings.simplefilter("ignore")
        found = ChannelSkew(**_from_dict(identify(raw).fit["channel_skew"]))
    return aligned_as_found(raw, found, pt, ut, data, **load_settings)


def aligned_as_found(raw, found: ChannelSkew, pt=None, ut=None, data=None, **load_settings):
    """``raw`` (loaded without alignment) reloaded from the same files with ``found.chosen``
    undone at the file's rate (``raw`` itself when nothing is chosen), the choice in
    ``meta["channel_skew_choice"]`` (:meth:`ChannelSkew.to_dict`)."""
    from .data import load_identification_data

    out = load_identification_data(pt, ut, data, channel_skew=found.chosen, **load_settings) if found.chosen else raw
    out.meta["channel_skew_choice"] = found.to_dict()
    return out


def _from_dict(d: dict) -> dict:
    """ChannelSkew's fields from :meth:`ChannelSkew.to_dict`."""
    return {"delay": d["estimate_s"], "candidates": np.array(d["candidates_s"]), "scores": np.array(d["in_sample_vaf"])}
