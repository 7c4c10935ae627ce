"""Finding a channel skew from one fitted model (lpvpc.identification.channel_skew has the whole story).

identify calls :func:`scan_channel_skew` on the model it has just fitted: for each candidate
skew the model's structure and reflex dynamics are held and its least squares solved again
on the torque shifted by the candidate; one regressor serves every candidate, so the scan
costs about one solve. :class:`ChannelSkew` holds the scores and the rule that turns them
into a skew to undo (or none). Kept apart from lpvpc.identification.channel_skew, whose loaders call
identify, so that identify can use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.identification_data import SINC_HALF_WIDTH, delayed

__all__ = ["ChannelSkew", "scan_channel_skew", "skew_from_dict", "MIN_RESIDUAL_REDUCTION", "CANDIDATES"]

# A skew is undone only when lining the channels up removes at least this share of the
# in-sample residual variance (and the best candidate is inside the grid: ChannelSkew.interior):
# above what records without a skew show, below what a 1-ms skew shows (docs/design_notes.md,
# "Channel skew").
MIN_RESIDUAL_REDUCTION = 0.02
#: Candidate skews (s): -2..+3 ms in 0.5 ms steps (a torque channel late is the usual case).
CANDIDATES = np.arange(-2.0, 3.01, 0.5) * 1e-3


@dataclass
class ChannelSkew:
    """The relative delay of the torque channel behind the position channel (s; negative: the
    torque leads) that :func:`~lpvpc.identification.channel_skew.estimate_channel_skew` found: ``delay`` (the parabola's peak
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
        trial z_df2, scanned before stationary records were left out: -2 ms, the end, 2.4 % of the
        residual; lining up by it cost 1 point held out)."""
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


def edge_samples(settings: dict, fs: float) -> int:
    """Samples at each trial's start and end that a skew estimate leaves out for a structure
    ``settings`` (its ``irf_length`` and ``reflex_delay``, s) at ``fs`` Hz: the IRF's half-width,
    the reflex delay and the fractional-delay filter's reach (:func:`~lpvpc.io.identification_data.delayed`).

    >>> edge_samples({"irf_length": 0.04, "reflex_delay": 0.04}, 100.0)
    25
    """
    return SINC_HALF_WIDTH + 1 + int(round(settings["irf_length"] * fs)) + int(round(settings["reflex_delay"] * fs))


def scan_channel_skew(model, data, candidates=None) -> ChannelSkew:
    """The channel skew a fitted ``model`` sees in its identification ``data``: for each
    candidate delay (s; default :data:`CANDIDATES`) the in-sample VAF of the model's structure
    (its bases' orders, IRF half-width, reflex delay and curvature term, the reflex on the
    model-rate velocity, no effects) with its reflex dynamics held, fitted to the torque
    advanced by the candidate (the same alignment as the position delayed by it); the estimate
    is the parabola's peak as in :func:`~lpvpc.identification.channel_skew.estimate_channel_skew`. One regressor serves every
    candidate (:func:`lpvpc.identification.selection.in_sample_vaf`), so the scan costs about one least-squares
    solve. Each trial's first and last samples are left out (see the comment below). The
    dynamics are not refitted per candidate: the estimate reads 0.13-0.29 ms later than the
    refitting one (scored without the same edges) on the virtual subject and 0.09 ms on the lab's
    pilot trial (either way under the threshold without a skew: benchmarks/results/real_pilot.txt).

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
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
    from ..io.segments import Segments
    from .selection import fitted_structure, in_sample_vaf

    cand = _candidates(candidates)
    y = np.asarray(data.torque, dtype=float)
    seg = Segments.of(data, len(y))
    # each trial's torque advanced on its own (as delay_position delays each trial's position)
    Y = np.column_stack([seg.map(lambda x, c=c: delayed(x, data.fs, -c), y) for c in cand])
    settings = fitted_structure(model, model.intrinsic_basis.extrapolation)
    dynamics = (model.A, np.atleast_2d(model.C), np.append(model.B, model.D))
    # each trial's first and last samples left out: there the IRF's lags and the reflex delay
    # reach past the trial (the record-edge rules stand in) and the advanced torque holds its
    # end values. Kept, a trial's first samples decided the scan: a 60-s virtual record without
    # a skew cut into 4 trials read -1.2 ms, removing 2.3 % of the residual (a skew found);
    # the uncut record -0.3 ms; without those samples both read +0.5 ms, removing 0.6 %
    edge = edge_samples(settings, data.fs)
    scores = in_sample_vaf(data.position, Y, data.scheduling, data.fs, dynamics, settings, model.intrinsic_basis.family,
                           model.velocity_basis.family, seg, edge=edge)
    return ChannelSkew(delay=_peak(cand, scores), candidates=cand, scores=scores)


def skew_from_dict(d: dict) -> ChannelSkew:
    """The ChannelSkew that :meth:`ChannelSkew.to_dict` wrote (a model's ``fit[\"channel_skew\"]``).

    >>> s = ChannelSkew(0.001, np.array([0.0, 0.001, 0.002]), np.array([93.5, 93.8, 93.5]))
    >>> skew_from_dict(s.to_dict()).chosen
    0.001
    """
    return ChannelSkew(**{"delay": d["estimate_s"], "candidates": np.array(d["candidates_s"]), "scores": np.array(d["in_sample_vaf"])})
