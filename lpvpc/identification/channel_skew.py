"""A relative delay between a recording's position and torque channels (a measurement artefact).

A torque channel recorded a little after the position channel (different sensor filters or
acquisition paths; the lab's pilot trial: ~1 ms, a tenth of a 100 Hz sample) costs the model
points it cannot win back: the two-sided IRF absorbs a skew only in part, the causal form and
the reflex not at all. The loaders undo a known skew at the file's rate, before decimation
(``channel_skew`` of :func:`lpvpc.io.load_identification_data`: the position channels are
delayed by it). This module finds it from the record itself:

- :func:`estimate_channel_skew`: the peak of the in-sample VAF of a fixed-structure model
  over candidate skews -2..+3 ms (aligned at the model rate, a fraction of a sample allowed);
  :attr:`ChannelSkew.chosen <lpvpc.identification.skew_scan.ChannelSkew.chosen>` keeps it only when it removes at least MIN_RESIDUAL_REDUCTION of
  the residual variance (the virtual subject without skew: 0; its torque 1 ms late: ~1.3 ms);
- :func:`~lpvpc.identification.skew_scan.scan_channel_skew`: the same peak from one fitted model, its structure and reflex
  dynamics held, its least squares solved once per candidate on the torque shifted by it (one
  regressor for every candidate: ~15 ms, 1 % of an identify, against ~11 fits). identify runs
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

import numpy as np

from ..io.identification_data import check_channel_skew, delayed
from .skew_scan import (MIN_RESIDUAL_REDUCTION, ChannelSkew, _candidates, _peak,  # noqa: F401
                        edge_samples, scan_channel_skew, skew_from_dict)

__all__ = ["delay_position", "estimate_channel_skew", "load_aligned"]  # (ChannelSkew, the scan: lpvpc.identification.skew_scan)



def delay_position(data, delay: float):
    """Perturbation data (:class:`lpvpc.io.PerturbationData`) with the position channel delayed
    by ``delay`` s relative to the torque (a fraction of a sample allowed; :func:`~lpvpc.io.identification_data.delayed`), to
    undo a torque channel recorded ``delay`` s late. The scheduling is left as is (it moves at
    < 1 Hz); the high-rate copy of the position, when present, is delayed the same.
    ``meta["position_delay_s"]`` records the delay.

    >>> from lpvpc.io import PerturbationData
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


def estimate_channel_skew(data, candidates=None, **settings) -> ChannelSkew:
    """Estimate a delay between a record's position and torque channels from the data alone.

    For each candidate delay (s; default -2 to +3 ms in 0.5 ms steps) the position is delayed
    by it (:func:`delay_position`), an LPV-PC model identified (``settings`` as for
    :func:`lpvpc.identification.identify.identify`) and its in-sample VAF recorded; the estimate is the peak
    of the parabola through the best candidate and its two neighbours. The two-sided model
    can absorb a skew with its future lags, but only in part (the reflex and the scheduling
    bases cannot), so its fit peaks at the channels' alignment; on the virtual subject (no
    skew) the estimate is within ~0.4 ms of 0 and of an imposed 1 ms (the subject's own
    half-millisecond: tests). Each trial's first and last samples are left out of the score, as
    in :func:`~lpvpc.identification.skew_scan.scan_channel_skew`. Use the identification part only, then
    :func:`delay_position` the whole record by the estimate.

    A torque channel recorded 2 ms late (the virtual subject's 1 kHz torque shifted by 2 samples):

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=40.0)
    >>> for trial in (sim.pt, sim.ut):
    ...     trial.torque = np.r_[trial.torque[:2], trial.torque[:-2]]
    >>> skew = estimate_channel_skew(pair_trials(sim.pt, sim.ut), np.array([0.0, 1.0, 2.0, 3.0]) * 1e-3)
    >>> bool(abs(skew.delay - 0.002) < 0.0005)
    True
    """
    from .identify import identify
    from ..models.model import vaf
    from ..io.segments import Segments
    from .selection import fitted_structure, trial_edges

    cand = _candidates(candidates)
    scores = []
    for c in cand:
        aligned = delay_position(data, float(c))
        # one structure for every candidate (structure selection could change it with the
        # delay, and the scores would compare structures, not alignments)
        model = identify(aligned, **{"structure": "fixed", **settings})
        # scored without each trial's edges, as the scan is (lpvpc.identification.skew_scan.scan_channel_skew)
        keep = ~trial_edges(Segments.of(aligned, aligned.n), aligned.n,
                            edge_samples(fitted_structure(model, model.intrinsic_basis.extrapolation), aligned.fs))
        scores.append(vaf(aligned.torque[keep], model.predict(aligned, warn=False).total[keep]))
    scores = np.array(scores)
    return ChannelSkew(delay=_peak(cand, scores), candidates=cand, scores=scores)


def load_aligned(pt=None, ut=None, data=None, *, channel_skew="auto", **load_settings):
    """:func:`lpvpc.io.load_identification_data` with the channel skew undone at the file's
    rate: ``channel_skew`` in s, or ``"auto"``: found by the default identify's scan of the
    record loaded as is (:func:`~lpvpc.identification.skew_scan.scan_channel_skew`, :attr:`ChannelSkew.chosen <lpvpc.identification.skew_scan.ChannelSkew.chosen>`; one extra fit;
    everything given is treated as identification data, so load only what you identify
    from). ``meta["channel_skew_s"]`` records the skew applied (absent when 0),
    ``meta["channel_skew_choice"]`` the scan (:meth:`ChannelSkew.to_dict <lpvpc.identification.skew_scan.ChannelSkew.to_dict>`). Records the scan
    does not apply to (stationary, or a model with effects) are returned as recorded.

    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=5.0)  # 1 kHz trials
    >>> load_aligned(pt=sim.pt, ut=sim.ut, channel_skew=1e-3).meta["channel_skew_s"]  # given: no estimate
    0.001
    """
    import warnings

    from ..io import load_identification_data
    from .identify import identify

    skew = check_channel_skew(channel_skew, allow_auto=True)
    if skew != "auto":
        return load_identification_data(pt, ut, data, channel_skew=skew, **load_settings)
    raw = load_identification_data(pt, ut, data, **load_settings)
    with warnings.catch_warnings():  # (the model is only the scan's: its warnings come with the real fit)
        warnings.simplefilter("ignore")
        scanned = identify(raw).fit.get("channel_skew")
    if scanned is None:  # (a stationary record, or a model with effects: not scanned, left as recorded)
        return raw
    found = skew_from_dict(scanned)
    out = load_identification_data(pt, ut, data, channel_skew=found.chosen, **load_settings) if found.chosen else raw
    out.meta["channel_skew_choice"] = found.to_dict()
    return out
