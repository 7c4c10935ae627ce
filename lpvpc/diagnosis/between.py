"""Between-record candidates: effects whose signal differs between the identification record
and the diagnosed one, fitted on the first and scored on the second.

The diagnosis's candidates are cross-validated within the diagnosed record, so an effect whose
signal stays nearly constant there is invisible to them: a subject whose background
activation drifts to another level between two trials gives a held-out record in which the
activation hardly moves, while the model, identified at the other level, carries the wrong
stiffness over. Only a fit on the identification record, where the activation moved, can
say what a change of activation does; its prediction of the diagnosed record says whether
that explains the model's error there (docs/design_notes.md, "Between-record candidates").

Units: torque N m, VAF gains in percentage points (pp).
"""

from __future__ import annotations

import warnings

import numpy as np

from .candidates import CandidateResult, _passes
from .cv import robust_paired_test
from ..errors import LpvpcError, LpvpcWarning
from ..models.effects import CATALOG, signals_from_data, with_model_activation

#: Signals that can change level between two records of one subject while staying nearly
#: constant within each (the background activation between trials of a session); catalog
#: effects reading one of them get a between-record candidate.
BETWEEN_SIGNALS = ("activation",)
#: pp: the model's structure refitted on the diagnosed record must explain it by this much more
#: than the model does (its transfer gap) for a between-record candidate to be fitted at all:
#: with no gap there is no between-record error to explain.
MIN_TRANSFER_GAP = 0.15
SCOPE = "between records"


def refit_settings(model) -> tuple:
    """The estimator settings and effects that refit ``model``'s own structure: (settings,
    effects).

    The structure its cross-validation chose (and the reflex path), its state order and
    effects, with the selection switched off, so a refit with one more effect changes one
    thing only (as each step of :func:`lpvpc.diagnosis.improve.improve` does).

    Examples
    --------
    >>> from lpvpc import identify, pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut))
    >>> settings, effects = refit_settings(model)
    >>> settings["structure"], settings["state_order"] == model.fit["state_order"], effects
    ('fixed', True, ())
    """
    st = dict(model.settings)
    eff = tuple(st.pop("effects", ()) or ())
    selected = model.fit.get("structure_selection") or {}
    if selected.get("chosen"):
        st.update(selected["chosen"])
        st.update((selected.get("reflex_path") or {}).get("chosen") or {})
    st.update(state_order=model.fit["state_order"], structure="fixed")
    eff += tuple(fe.name for fe in model.effects or () if fe.name not in eff)
    return st, eff


def between_record_candidates(model, reference, data, prediction, *, transfer_gap, mask=None,
                              block_s=2.0) -> list:
    """Candidates for the catalog effects reading a :data:`BETWEEN_SIGNALS` signal: each
    fitted on ``reference`` (the identification record) with ``model``'s structure
    (:func:`refit_settings`) plus the effect, and scored on ``data`` with its signal held at
    ``data``'s level against the same fit with the signal held at ``reference``'s level: the
    gain of the level's change alone, not of the effect's extra terms.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model diagnosed.
    reference : lpvpc.io.PerturbationData
        The record ``model`` was identified on.
    data : lpvpc.io.PerturbationData
        The diagnosed record (its background activation already estimated with ``model``'s
        reflex drive: :func:`lpvpc.models.effects.with_model_activation`).
    prediction : numpy.ndarray
        ``model``'s torque on ``data`` (N m).
    transfer_gap : float
        How much better (pp) the model's structure refitted on ``data`` explains it than the
        model does; below :data:`MIN_TRANSFER_GAP` nothing is fitted (an empty list).
    mask : numpy.ndarray, optional
        Samples scored (bool); default all.
    block_s : float, default 2.0
        Blocks (s) of the paired test.

    Returns
    -------
    list of lpvpc.diagnosis.candidates.CandidateResult
        One per catalog effect whose signal both records carry (none without it): ``scope``
        "between records", ``vaf_gain`` the held-out VAF gain (pp) of the level's
        change, ``conditional_gain`` the fit's gain over ``model`` on ``data``, ``p_value``
        the paired test of the level's two residuals (:func:`lpvpc.diagnosis.cv.robust_paired_test`);
        ``significant`` is left for the caller, who knows the Bonferroni level.

    Examples
    --------
    A record whose trials carry no EMG has no activation to carry between records, so no
    candidate:

    >>> import dataclasses
    >>> from lpvpc import identify, pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> model = identify(data)
    >>> bare = dataclasses.replace(data, extra={})
    >>> between_record_candidates(model, bare, bare, model.predict(bare).total, transfer_gap=1.0)
    []
    """
    from ..identification.identify import LPVPCEstimator

    if transfer_gap < MIN_TRANSFER_GAP:
        return []
    st, eff = refit_settings(model)
    names = [n for n, e in CATALOG.items() if set(e.signals) & set(BETWEEN_SIGNALS) and n not in eff]
    y = np.asarray(data.torque, dtype=float)
    w = np.ones(len(y), bool) if mask is None else np.asarray(mask, dtype=bool)
    r0 = np.where(w, y - prediction, 0.0)
    sst = float(np.sum((y[w] - y[w].mean()) ** 2))
    sig = signals_from_data(data)
    ref = with_model_activation(reference, model)
    ref_sig = signals_from_data(ref)
    have = set(ref_sig)
    out = []
    for name in names:
        e = CATALOG[name]
        if any(s not in sig or s not in have for s in e.signals):
            continue  # a record without the signal: nothing to carry between them (its within-record entry says so)
        res = CandidateResult(name, "effect", e.pathway, e.explanation, signals=tuple(e.signals), scope=SCOPE)
        out.append(res)
        try:
            with warnings.catch_warnings():  # notes on this scoring fit, not on the user's model
                warnings.simplefilter("ignore", LpvpcWarning)
                fitted = LPVPCEstimator(**st, effects=eff + (name,)).fit(ref).model_
        except LpvpcError as exc:
            res.available, res.reason = False, f"its fit on the identification record failed: {exc}"
            continue
        # the effect model on this record at this record's level of the signal against the same
        # model at the identification record's level: the gain of the level's change alone. (Against
        # the model itself, the effect's extra terms gain by their flexibility too: a clean PRBS
        # record's activation-scaled reflex gained 0.19 pp at p 3e-12 that way.) A constant level
        # cannot stand in for the reflex misfit that the signal's fast part may carry.
        def at(level):
            held = {k: np.full(len(y), level[k]) for k in e.signals}
            return np.where(w, y - fitted.predict(data, warn=False, signals={**sig, **held}).total, 0.0)

        here = {k: float(np.mean(np.asarray(sig[k])[w])) for k in e.signals}
        there = {k: float(np.mean(ref_sig[k])) for k in e.signals}
        r_there, r1 = at(there), at(here)
        res.vaf_gain = 100.0 * float(r_there @ r_there - r1 @ r1) / sst
        res.conditional_gain = 100.0 * float(r0 @ r0 - r1 @ r1) / sst  # over the model itself
        res.t, res.p_value, res.p_mean = robust_paired_test(r_there, r1, float(data.fs), block_s)
        res.residual = r1
    return out


def merge(results, between, *, min_gain, level) -> list:
    """The within-record ranking ``results`` with the between-record candidates ``between``
    judged at ``level`` as the within-record ones are (:func:`lpvpc.diagnosis.candidates.passes`)
    and put in: a significant one before the first within-record candidate that is not
    significant or gains less, the others after every available candidate that gains more.

    >>> a = CandidateResult("a", "effect", "intrinsic", "", vaf_gain=0.5, p_value=1e-6, significant=True)
    >>> b = CandidateResult("b", "effect", "intrinsic", "", vaf_gain=2.0, p_value=1e-6, scope=SCOPE)
    >>> [c.effect for c in merge([a], [b], min_gain=0.15, level=0.01)], b.significant
    (['b', 'a'], True)
    """
    out = list(results)
    for r in sorted(between, key=lambda r: -(r.vaf_gain if np.isfinite(r.vaf_gain) else -1e9)):
        r.significant = bool(r.available and not r.reason and _passes(r, r.vaf_gain, min_gain, level))
        if r.significant:
            i = next((k for k, c in enumerate(out) if not c.significant or c.vaf_gain < r.vaf_gain), len(out))
        else:
            i = next((k for k, c in enumerate(out) if not c.significant and (
                not c.available or not np.isfinite(c.vaf_gain) or c.vaf_gain < r.vaf_gain)), len(out))
        out.insert(i, r)
    return out
