"""Structure selection by cross-validation that imitates predicting unseen data.

Folds are contiguous stretches of the record, never random samples. On a staircase
trial (the scheduling variable held at a few levels, as in the paper's multilevel
trajectory) each fold is one level, every visit to it and the movements nearest it
(leave-one-level-out), end plateaus included: a fold at an end of the range is predicted
by a model whose scheduling basis spans only the other levels, so extrapolation to the
edges of the range is part of the score, under each candidate extrapolation rule of the
basis ("clip": held at the boundary; "linear": continued along the tangent). A record
that is not a staircase gets ``BLOCK_FOLDS`` contiguous blocks.

What is selected (estimator settings): the IRF half-width, the basis orders in the
scheduling variable (intrinsic, reflex) and in delayed velocity, the reflex delay, the
elastic curvature term and the scheduling extrapolation rule. Settings the caller fixes
stay as given. The reflex dynamics (A, C, B, D) come from a fit at the starting settings
and are held for the candidates (its state order is chosen there by BIC); with them the
model is linear in the IRF weights and the nonlinearity's coefficients, so every
candidate is a set of columns of one largest regressor (the tied curvature term adds a
column to each IRF column: a linear map of it). Per fold the Gram matrices of the
held-out rows are computed once; each candidate and fold is then a small solve on the
other folds' normal equations. An end fold's model has its bases on the other levels'
range; for polynomial bases that is the same fit on the training rows, and only the
fold's own rows take the extrapolation rule (``_held_basis``; the reflex filters run over
the whole record, so training rows just after a visit to the end level keep its unheld
values in their filter memory: within 0.2 % of refitting with the narrower bases,
tests/test_selection.py). The search moves one setting at a time from the starting
settings until no change lowers the cross-validated error, then picks, among every
structure it scored, the one with the fewest parameters whose error is within one
standard error of the best (the paired standard error over folds of its difference
from the best: the one-standard-error rule toward the simpler structure), its IRF no
shorter than the best's (K(theta) is the IRF's sum over lags: a truncated IRF biases it,
which the torque CV hardly sees).

Effects the caller allows (``effects=`` of :class:`StructureSearch`; identify's
``allow_effects``) are candidates of the same search, setting ``effect:NAME``: off, or one
of the effect's variants (stress relaxation: the position averaged over one time of a grid
with order-3 weights in position, or over 0.3, 1 and 3 s with order-1 weights,
:data:`RELAXATION_VARIANTS`). An intrinsic effect with static features is linear in its
coefficients once the reflex dynamics are held, so every variant's columns join the
largest regressor and each is a column subset like any other candidate, scored on the same
folds (end folds take the extrapolation rule on the effect's basis too); its columns count
in the one-SE rule.
identify switches them at the chosen structure, with reflex dynamics fitted with the
effects' columns (``LPVPCEstimator._choose_effects``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models import equations as eq
from ..models.basis import Basis, basis_from_data
from ..models.intrinsic import curvature_regressor, intrinsic_regressor, two_sided_lags
from ..models.reflex import reflex_input_regressor, reflex_response_regressor
from ..io.segments import Segments
from .crossval import fold_fits, held_out_sse, solve_normal

#: Candidate values of each selected setting (IRF half-widths in s, delays in s).
SEARCH = {
    "irf_length": (0.02, 0.03, 0.04, 0.05),
    "intrinsic_order": (2, 3, 4, 5, 6, 7),
    "reflex_order": (0, 1, 2, 3),
    "velocity_order": (2, 3, 4, 5, 6),
    "reflex_delay": (0.03, 0.04, 0.05),
    "elastic_curvature": (False, True),
    "scheduling_extrapolation": ("clip", "linear"),
}
#: Folds of a record that is not a staircase.
BLOCK_FOLDS = 5
#: A level is a run of at least HOLD_S s where the scheduling variable moves slower than
#: HOLD_SPEED rad/s (smoothed over 0.2 s); levels within LEVEL_TOL rad of each other are one.
HOLD_S, HOLD_SPEED, LEVEL_TOL = 1.0, 0.05, 0.015
MIN_LEVELS = 4
#: Forward-in-time folds: the last FORWARD_FOLDS x FORWARD_BLOCK of the record in contiguous
#: stretches, each predicted by a model fitted on everything before it (expanding window)
#: less a gap of the longest IRF lag (no input sample of the scored stretch enters a training row).
FORWARD_FOLDS, FORWARD_BLOCK = 3, 0.1
RIDGE = 1e-10  # relative to the scaled Gram matrix's unit diagonal


def search_space(start: dict, fixed=()) -> dict:
    """The candidate values of each selected setting: :data:`SEARCH` with the starting value
    added, a fixed setting held at its start.

    >>> space = search_space({**{k: v[0] for k, v in SEARCH.items()}, "intrinsic_order": 9}, fixed={"reflex_delay"})
    >>> space["intrinsic_order"][-1], space["reflex_delay"]
    (9, (0.03,))
    """
    space = {k: tuple(sorted({*SEARCH[k], start[k]}, key=str)) for k in SEARCH}
    space.update({k: (start[k],) for k in fixed if k in SEARCH})
    return space


EFFECT_PREFIX = "effect:"


def effect_key(name: str) -> str:
    """The search's setting that switches an allowed effect on or off.

    >>> effect_key("stress_relaxation")
    'effect:stress_relaxation'
    """
    return EFFECT_PREFIX + name


def chosen_effects(settings: dict) -> list:
    """Names of the effects a structure's settings switch on.

    >>> chosen_effects({"intrinsic_order": 3, "effect:stress_relaxation": True, "effect:drift": False})
    ['stress_relaxation']
    """
    return [k[len(EFFECT_PREFIX):] for k, v in settings.items() if k.startswith(EFFECT_PREFIX) and v]


def effect_settings(settings: dict, candidates: dict) -> dict:
    """The estimator settings of the effect variants a structure's settings switch on
    (``candidates``: :func:`effect_candidates`), e.g. the relaxation's times and order.

    >>> effect_settings({"effect:stress_relaxation": "0.6 s, order 3"},
    ...                 {"stress_relaxation": {"0.6 s, order 3": (None, None, True, {"relaxation_order": 3})}})
    {'relaxation_order': 3}
    """
    out = {}
    for name in chosen_effects(settings):
        out.update(candidates[name][settings[effect_key(name)]][3])
    return out


def structure_settings(settings: dict) -> dict:
    """The settings without the effect switches (the estimator settings identify records as
    ``chosen``; the effects are recorded next to them).

    >>> structure_settings({"intrinsic_order": 3, "effect:stress_relaxation": True})
    {'intrinsic_order': 3}
    """
    return {k: v for k, v in settings.items() if not k.startswith(EFFECT_PREFIX)}


def cv_effect_problem(name: str) -> str | None:
    """Why the catalog effect ``name`` cannot be a candidate of the selection (None: it can).
    Candidates are intrinsic effects with static features from the position alone: linear
    in their coefficients with the reflex held, so their columns join the largest regressor.

    >>> cv_effect_problem("stress_relaxation") is None, cv_effect_problem("drift") is not None
    (True, True)
    """
    from ..models.effects import CATALOG

    e = CATALOG.get(name)
    if e is None:
        return f"unknown effect {name!r}; known: {sorted(CATALOG)}"
    if e.features is None or e.channels is not None or e.uses_reflex or e.signals or e.optional_signals:
        return (f"effect {name!r} cannot be chosen by the cross-validation (only intrinsic effects with static "
                f"features of the position alone can: "
                f"{', '.join(n for n in CATALOG if _eligible(CATALOG[n]))}); to force it on, name it as an effect (effects= in Python, --effect on the command line)")
    return None


def _eligible(e) -> bool:
    return e.features is not None and e.channels is None and not e.uses_reflex and not e.signals \
        and not e.optional_signals


#: Stress-relaxation terms the selection chooses from (``effect:stress_relaxation``): (averaging
#: times in s, order of the position weights). The relaxation's time trades with K: one
#: average at the virtual subject's 0.6 s gives K within 1.2 %, at 0.3 or 1.5 s K is off by
#: 17 and 13 % (benchmarks/results/relaxed_stiffness_causes.txt); so one time per record from a
#: grid, the lab's stationary trials preferring 0.45-1.5 s and beyond (relaxed_stiffness_real.txt),
#: and the mix of three times as shipped before (it fit 3 of those 5 trials best). Order 3:
#: the relaxing torque is a share of the elastic one, so its weights follow K's curve, which a line
#: does not hold (exact time, order 1: K off by 4.3 %, order 3: 1.2 %).
RELAXATION_VARIANTS = (*(((t,), 3) for t in (0.3, 0.45, 0.6, 0.8, 1.0, 1.5, 3.0)), ((0.3, 1.0, 3.0), 1))


def variant_label(times, order) -> str:
    """The search's value of ``effect:stress_relaxation`` for one relaxation term.

    >>> variant_label((0.6,), 3), variant_label((0.3, 1.0, 3.0), 1)
    ('0.6 s, order 3', '0.3+1+3 s, order 1')
    """
    return f"{'+'.join(f'{t:g}' for t in times)} s, order {int(order)}"


def effect_candidates(names, p, rho, fs, family="chebyshev", intrinsic_order=5) -> dict:
    """The inputs of allowed effects as selection candidates: {name: {value of its setting:
    (features (N, n_f), basis in position (lpvpc.models.basis.Basis), keep its constant function,
    the estimator settings that build it)}}: one value (True) per effect, the effect's own
    basis order (lpvpc.models.effects.effect_basis) on the record's range; stress relaxation one per
    :data:`RELAXATION_VARIANTS` (:func:`variant_label`). Raises ValueError for an effect that
    cannot be a candidate (:func:`cv_effect_problem`).

    >>> p, rho = np.full(500, 0.02), np.linspace(-0.2, 0.1, 500)  # rad: a held displacement, a slow ramp
    >>> c = effect_candidates(["stress_relaxation"], p, rho, 100.0)["stress_relaxation"]
    >>> F, basis, constant, settings = c["0.6 s, order 3"]
    >>> F.shape, basis.order, constant, settings  # the position averaged over 0.6 s; order 3 in rho
    ((500, 1), 3, True, {'relaxation_times': (0.6,), 'relaxation_order': 3})
    >>> round(float(F[-1, 0]), 4)  # rad: the average has caught up with the displacement
    0.02
    """
    from ..models.basis import NUMPY, basis_from_data
    from ..models.effects import CATALOG, default_signals, effect_basis, effect_options, record_context

    out = {}
    p, rho = np.asarray(p, dtype=float), np.asarray(rho, dtype=float)
    sig = default_signals(rho, fs, None)
    rho_basis = basis_from_data(rho, family, intrinsic_order)
    for name in names:
        problem = cv_effect_problem(name)
        if problem:
            raise ValueError(problem)
        e = CATALOG[name]
        variants = RELAXATION_VARIANTS if "relaxation" in e.derived else ((None, None),)
        out[name] = {}
        for times, order in variants:
            extra = {} if times is None else {"relaxation": times}
            ctx = record_context(p, rho, fs, sig, derived=e.derived, **extra)
            F = np.column_stack([np.asarray(f, dtype=float).reshape(-1)
                                 for f in e.features(ctx, NUMPY, effect_options(e, sig, **extra))])
            basis = effect_basis(e, rho_basis, order)  # (order 0 on a stationary trial, whatever asked)
            value = True if times is None else variant_label(times, basis.order)
            settings = {} if times is None else {"relaxation_times": tuple(times), "relaxation_order": basis.order}
            out[name].setdefault(value, (F, basis, bool(e.feature_constant), settings))
    return out


def design_columns(search: dict, fs: float) -> int:
    """Columns of the largest regressor of a search (its IRF lags at rate ``fs`` Hz, curvature
    shares, each delay's reflex columns, a zero column): memory is 8 bytes x samples x this.

    >>> design_columns(SEARCH, 100.0)  # 11 lags x 8, 8, 3 delays x 7 x 4, 1
    181
    """
    n_lags = 2 * max(max(1, int(round(x * fs))) for x in search["irf_length"]) + 1
    n_i = max(search["intrinsic_order"]) + 1
    n_delays = len({max(1, int(round(x * fs))) for x in search["reflex_delay"]})
    return n_lags * n_i + n_i + n_delays * (max(search["velocity_order"]) + 1) * (max(search["reflex_order"]) + 1) + 1


def level_folds(rho, fs):
    """Fold label of each sample (N,) and the fold kind ("level" or "block").

    Leave-one-level-out on a staircase: levels are held stretches of ``rho`` (rad), each
    sample joins the level nearest its value; fewer than MIN_LEVELS levels: BLOCK_FOLDS
    contiguous blocks.

    >>> rho = np.repeat([0.0, -0.2, 0.1, -0.2, 0.2], 300)  # five holds of 3 s at 100 Hz, four levels
    >>> labels, kind = level_folds(rho, 100.0)
    >>> kind, sorted(set(labels.tolist())), int(labels[0]), int(labels[-1])
    ('level', [0, 1, 2, 3], 1, 3)
    """
    rho = np.asarray(rho, dtype=float)
    n = len(rho)
    w = max(1, int(round(0.2 * fs)))
    smooth = np.convolve(rho, np.ones(w) / w, mode="same")
    hold = np.abs(np.gradient(smooth) * fs) < HOLD_SPEED
    edges = np.flatnonzero(np.diff(np.r_[0, hold.astype(int), 0]))
    plateaus = [float(np.median(rho[a:b])) for a, b in zip(edges[::2], edges[1::2]) if b - a >= HOLD_S * fs]
    centres = []
    for v in sorted(plateaus):
        if centres and v - centres[-1][-1] <= LEVEL_TOL:
            centres[-1].append(v)
        else:
            centres.append([v])
    centres = np.array([np.mean(c) for c in centres])
    if len(centres) < MIN_LEVELS:
        return (np.arange(n) * BLOCK_FOLDS // max(n, 1)).astype(int), "block"
    return np.argmin(np.abs(rho[:, None] - centres[None, :]), axis=1), "level"


def forward_folds(n: int, n_folds: int | None = None, block: float | None = None, gap: int = 0) -> list:
    """Forward-in-time folds of an n-sample record: (training rows, scored rows) as
    ``(slice(0, a - gap), slice(a, b))`` pairs, the scored stretches ``block`` of the record each,
    the last ending at the record's end, each fitted on the record before it (expanding window)
    less ``gap`` samples (the IRF's forward lags: no input of the scored stretch enters training).

    >>> [(t.stop, (s.start, s.stop)) for t, s in forward_folds(100, 3, 0.1, gap=2)]
    [(68, (70, 80)), (78, (80, 90)), (88, (90, 100))]
    """
    n_folds = FORWARD_FOLDS if n_folds is None else n_folds
    m = max(1, int(round((FORWARD_BLOCK if block is None else block) * n)))
    starts = [n - (n_folds - k) * m for k in range(n_folds)]
    return [(slice(0, a - gap), slice(a, n if k == n_folds - 1 else a + m))
            for k, a in enumerate(starts) if a - gap > 0]


@dataclass
class Scored:
    """One structure's cross-validated score: its settings, parameter count, held-out
    squared error per fold and pooled CV VAF.

    ``forward_sse`` / ``forward_vaf``: the same on forward-in-time folds (:func:`forward_folds`;
    the VAF over the scored stretches, each about its own mean), when they were scored.

    >>> s = Scored({"intrinsic_order": 3}, 40, np.array([1.0, 2.0]), 97.5)
    >>> s.to_dict()
    {'settings': {'intrinsic_order': 3}, 'n_params': 40, 'cv_vaf': 97.5}
    >>> Scored({}, 40, np.ones(2), 97.5, np.ones(3), 95.25).to_dict()["forward_vaf"]
    95.25
    """

    settings: dict
    n_params: int
    fold_sse: np.ndarray  # N m^2 per fold
    cv_vaf: float = float("nan")  # %
    forward_sse: np.ndarray | None = None  # N m^2 per forward-in-time fold
    forward_vaf: float = float("nan")  # %

    def to_dict(self) -> dict:
        out = {"settings": dict(self.settings), "n_params": int(self.n_params), "cv_vaf": float(self.cv_vaf)}
        if self.forward_sse is not None:
            out["forward_vaf"] = float(self.forward_vaf)
        return out


@dataclass
class Selection:
    """The chosen settings and the table of scored structures (:meth:`StructureSearch.run`).

    >>> a, b = Scored({"order": 3}, 40, np.ones(2), 97.5), Scored({"order": 5}, 60, np.ones(2), 97.6)
    >>> sel = Selection(chosen={"order": 3}, start={"order": 5}, fold_kind="level", n_folds=2, scored=[b, a],
    ...                 best={"order": 5})
    >>> [row.settings for row in sel.table()]  # the chosen first, then the best of the rest
    [{'order': 3}, {'order': 5}]
    """

    chosen: dict
    start: dict
    fold_kind: str
    n_folds: int
    scored: list = field(default_factory=list)  # Scored, best CV first
    best: dict = field(default_factory=dict)
    rule: str = "level"  # the choice rule (:func:`choose`)
    n_forward: int = 0  # forward-in-time folds scored (0: none)
    forward_best: dict = field(default_factory=dict)  # the best structure on them

    def table(self, top: int = 6) -> list:
        """Rows (settings, n_params, CV VAF %) of the chosen, the best and the next best."""
        rows = sorted(self.scored, key=lambda s: -s.cv_vaf)
        pick = [s for s in rows if s.settings == self.chosen][:1]
        return pick + [s for s in rows if s.settings != self.chosen][: top - len(pick)]

    def to_dict(self) -> dict:
        chosen = next(s for s in self.scored if s.settings == self.chosen)
        lolo = f"leave-one-{self.fold_kind}-out cross-validation ({self.n_folds} folds)"
        if self.n_forward:
            method = (f"{lolo} and forward in time ({self.n_forward} folds: each later "
                      f"{100 * FORWARD_BLOCK:g} % predicted from the record before it), "
                      + ("one-standard-error rule toward fewer parameters among the structures near the best on both "
                         "(else the best worse rank)" if self.rule == "both" else
                         "the best worse rank over the two" if self.rule == "worst_rank" else
                         "one-standard-error rule toward fewer parameters on the first"))
        else:
            method = f"{lolo}, one-standard-error rule toward fewer parameters"
        forward = ({"chosen_forward_vaf": float(chosen.forward_vaf), "n_forward_folds": int(self.n_forward),
                    "forward_best": _jsonable(structure_settings(self.forward_best)), "rule": self.rule}
                   if self.n_forward else {})
        return {"method": method, "chosen": _jsonable(structure_settings(self.chosen)),
                "start": _jsonable(structure_settings(self.start)), "chosen_cv_vaf": float(chosen.cv_vaf), **forward,
                "best": _jsonable(structure_settings(self.best)), "fold_kind": self.fold_kind,
                "n_folds": int(self.n_folds),
                "table": [{**s.to_dict(), "settings": _jsonable(structure_settings(s.settings)),
                           **({"effects": chosen_effects(s.settings)} if len(structure_settings(s.settings))
                              < len(s.settings) else {})} for s in self.table()],
                "n_scored": len(self.scored)}


def _jsonable(d):
    return {k: (float(v) if isinstance(v, float) else v) for k, v in d.items()}


def _held_basis(basis, rho, lo, hi, rule):
    """Values (N, n) of ``basis``'s functions beyond a narrower range [lo, hi] as a model
    identified on that range would take them: held at its boundary ("clip") or continued
    along the tangent there ("linear"). Exact for polynomial bases: a polynomial basis on
    [lo, hi] spans the same functions as ``basis``, and the rule acts on the fitted function."""
    rho = np.asarray(rho, dtype=float)
    G = basis.evaluate(np.clip(rho, lo, hi))
    if rule == "linear":
        h = 1e-6 * (basis.hi - basis.lo)
        for edge, beyond in ((lo, rho < lo), (hi, rho > hi)):
            if beyond.any():
                slope = (basis.evaluate([edge + h]) - basis.evaluate([edge - h])) / (2 * h)
                G[beyond] += (rho[beyond] - edge)[:, None] * slope
    return G


class _Design:
    """The largest regressor's per-fold Gram matrices: ``G[f]``, ``b[f]`` of fold f's rows
    (the scheduling basis on the whole range), and for an end fold, whose training range is
    narrower, its rows' Gram matrices under each extrapolation rule (``end[rule][f]``)."""

    def __init__(self, p, y, rho, fs, labels, n_folds, family, velocity_family, dynamics, top, rules, segments,
                 reflex_input=None, effects=None, forward=()):
        self.p, self.rho, self.fs, (self.A, self.C, self.bd) = p, rho, fs, dynamics
        self.seg = segments
        self.L_max, self.ni_max, self.nr_max, self.nv_max, self.delays = top
        self.delays = list(self.delays)
        # (name, value of its setting) -> (features, basis, keep constant): columns after the zero one
        self.effects = {(n, v): c[:3] for n, by_value in (effects or {}).items() for v, c in by_value.items()}
        lo, hi = float(np.min(rho)), float(np.max(rho))
        top_hi = max(hi, lo + 1e-9)  # a stationary trial: one position
        self.G_i = Basis(family, self.ni_max, lo, top_hi)
        self.G_r = Basis(family, self.nr_max, lo, top_hi)
        # reflex_input (one delay): U_r from a scheduling basis, in place of the model-rate
        # velocity's (the high-rate path: lpvpc.models.reflex.HighRateReflexInput, nv_max + 1 velocity functions)
        self.reflex_input = reflex_input
        self.V = [None] if reflex_input is not None else [
            basis_from_data(dv, velocity_family, self.nv_max, extrapolation="linear").evaluate(dv)
            for dv in (segments.map(eq.delayed_velocity, p, fs=fs, delay=d) for d in self.delays)]
        Gi, Gr = self.G_i.evaluate(rho), self.G_r.evaluate(rho)
        X = self._regressor(Gi, Gr)
        rows = [np.flatnonzero(labels == f) for f in range(n_folds)]
        # each fold's Gram matrix summed over its contiguous runs: views of X, no row copies
        self.G = np.zeros((n_folds, self.n_cols, self.n_cols))
        self.b = np.zeros((n_folds, self.n_cols) + np.shape(y)[1:])  # (several outputs: a column each)
        cuts = np.r_[0, np.flatnonzero(np.diff(labels)) + 1, len(labels)]
        for a, c in zip(cuts[:-1], cuts[1:]):
            self.G[labels[a]] += X[a:c].T @ X[a:c]
            self.b[labels[a]] += X[a:c].T @ y[a:c]
        self.end = {rule: {} for rule in rules}
        for f, r in enumerate(rows if n_folds > 1 else ()):  # (one fold: the whole record, no end folds)
            train = rho[labels != f]
            t_lo, t_hi = float(np.min(train)), float(np.max(train))
            if t_lo <= lo and t_hi >= hi:
                continue
            for rule in rules:  # an end level: its model's basis spans only the other levels
                Xe = self._held_rows(X, Gi, Gr, r, t_lo, t_hi, rule)
                self.end[rule][f] = (Xe.T @ Xe, Xe.T @ y[r])
        # Forward-in-time folds: the training rows' normal equations (sums of pieces between the
        # folds' edges) and the scored rows'; a scored stretch that leaves its training range takes
        # each extrapolation rule on its basis, as an end level does.
        self.forward = list(forward)
        nf = len(self.forward)
        self.fG_train = np.zeros((nf, self.n_cols, self.n_cols))
        self.fb_train = np.zeros((nf, self.n_cols) + np.shape(y)[1:])
        self.fG, self.fb = np.zeros_like(self.fG_train), np.zeros_like(self.fb_train)
        self.f_end = {rule: {} for rule in rules}
        if nf:
            cuts = sorted({0, *(t.stop for t, _ in self.forward), *(sc.start for _, sc in self.forward)})
            pieces = {}
            for a, c in zip(cuts[:-1], cuts[1:]):
                pieces[(a, c)] = (X[a:c].T @ X[a:c], X[a:c].T @ y[a:c])
            for k, (t, sc) in enumerate(self.forward):
                for (a, c), (g, bb) in pieces.items():
                    if c <= t.stop:
                        self.fG_train[k] += g
                        self.fb_train[k] += bb
                self.fG[k], self.fb[k] = X[sc].T @ X[sc], X[sc].T @ y[sc]
                t_lo, t_hi = float(np.min(rho[t])), float(np.max(rho[t]))
                r = np.arange(sc.start, sc.stop)
                if np.min(rho[r]) >= t_lo and np.max(rho[r]) <= t_hi:
                    continue
                for rule in rules:
                    Xe = self._held_rows(X, Gi, Gr, r, t_lo, t_hi, rule)
                    self.f_end[rule][k] = (Xe.T @ Xe, Xe.T @ y[r])
        del X

    def _held_rows(self, X, Gi, Gr, r, t_lo, t_hi, rule):
        """Rows ``r`` of the largest regressor as a model whose bases span only [t_lo, t_hi] takes
        them (``rule``: beyond it held at the boundary or continued along the tangent)."""
        rho = self.rho
        Xe = X[r] + self._change(Gi, Gr, _held_basis(self.G_i, rho, t_lo, t_hi, rule),
                                 _held_basis(self.G_r, rho, t_lo, t_hi, rule), r,
                                 _Evaluates(lambda x, a=t_lo, b=t_hi, u=rule: _held_basis(self.G_r, x, a, b, u)
                                            - self.G_r.evaluate(x)))
        for key, (F, eff_basis, const) in self.effects.items():  # the effect's basis takes the rule too
            dG = (_held_basis(eff_basis, rho[r], t_lo, t_hi, rule)
                  - eff_basis.evaluate(rho[r]))[:, 0 if const else 1:]
            Xe[:, self.effect_cols[key]] += (F[r][:, :, None] * dG[:, None, :]).reshape(len(r), -1)
        return Xe

    def _change(self, Gi, Gr, Gi_held, Gr_held, r, reflex_change=None):
        """Rows ``r`` of the regressor's change when the basis values change from (Gi, Gr) to
        the held ones (the regressor is linear in them; they differ only beyond the training
        range, so the reflex filters start from rest at the first such row: a window, not the record)."""
        dGi, dGr = Gi_held - Gi, Gr_held - Gr
        changed = np.flatnonzero(np.any(dGi != 0, axis=1) | np.any(dGr != 0, axis=1))
        out = np.zeros((len(r), self.n_cols))  # (the effects' change: added by the caller)
        if changed.size == 0:
            return out
        # the window: from the first change (the input is zero before it; rows before it change
        # by nothing) to the last row wanted (later inputs do not reach it)
        w0 = int(changed[0]) if len(self.seg) == 1 else 0
        w1 = int(r.max()) + 1 if len(self.seg) == 1 else len(self.p)
        seg = self.seg if len(self.seg) > 1 else None
        window = slice(w0, w1)
        n_lag = (2 * self.L_max + 1) * Gi.shape[1]
        P = self.seg.map(eq.lagged, self.p, lags=two_sided_lags(self.L_max))[r]  # the IRF columns at rows r only
        out[:, :n_lag] = (P[:, :, None] * dGi[r][:, None, :]).reshape(len(r), n_lag)
        out[:, n_lag : n_lag + Gi.shape[1]] = curvature_regressor(self.p[r], dGi[r], self.G_i)
        col, n_ref = n_lag + Gi.shape[1], (self.nv_max + 1) * Gr.shape[1]
        inside = r >= w0
        k = r[inside] - w0  # the rows within the window
        if self.reflex_input is not None:  # the high-rate inputs' change: over the record (it is linear in
            # the basis values), then filtered
            out[:, col : col + n_ref] = reflex_response_regressor(self.reflex_input(reflex_change), self.A, self.C,
                                                                  self.bd[:-1], self.bd[-1], self.seg)[r]
        elif w1 > w0:
            for V in self.V:
                out[inside, col : col + n_ref] = reflex_response_regressor(
                    reflex_input_regressor(V[window], dGr[window]), self.A, self.C, self.bd[:-1], self.bd[-1], seg)[k]
                col += n_ref
        return out

    def _regressor(self, Gi, Gr, basis=None):
        """The largest regressor, filled block by block into one array (a 30-minute record's is
        260 MB: no second copy): IRF columns, curvature shares, each delay's reflex columns, a zero column."""
        n_lag = (2 * self.L_max + 1) * Gi.shape[1]
        n_ref = V_cols = (self.nv_max + 1) * Gr.shape[1]
        self.n_cols = n_lag + Gi.shape[1] + len(self.V) * n_ref + 1
        effect_blocks, self.effect_cols = {}, {}
        for key, (F, eff_basis, const) in self.effects.items():  # after the zero column: the indices above stay
            G = eff_basis.evaluate(self.rho)[:, 0 if const else 1:]
            effect_blocks[key] = (F[:, :, None] * G[:, None, :]).reshape(len(self.p), -1)
            self.effect_cols[key] = np.arange(self.n_cols, self.n_cols + effect_blocks[key].shape[1])
            self.n_cols += effect_blocks[key].shape[1]
        X = np.zeros((len(self.p), self.n_cols))
        for key, block in effect_blocks.items():
            X[:, self.effect_cols[key]] = block
        X[:, :n_lag] = self.seg.map(intrinsic_regressor, self.p, Gi, lags=two_sided_lags(self.L_max))
        X[:, n_lag : n_lag + Gi.shape[1]] = curvature_regressor(self.p, Gi, basis or self.G_i)
        col = n_lag + Gi.shape[1]
        for V in self.V:
            U = reflex_input_regressor(V, Gr) if self.reflex_input is None else self.reflex_input(self.G_r)
            X[:, col : col + V_cols] = reflex_response_regressor(U, self.A, self.C, self.bd[:-1], self.bd[-1],
                                                                 self.seg)
            col += V_cols
        return X

    def columns(self, L, ni, nr, nv, d, curvature):
        """(columns, their curvature share's columns) of a candidate in the largest regressor."""
        n_i = self.ni_max + 1
        n_lags = 2 * self.L_max + 1
        zero = n_lags * n_i + n_i + len(self.delays) * (self.nv_max + 1) * (self.nr_max + 1)
        idx, cur = [], []
        for lag in range(-L, L + 1):
            for j in range(ni + 1):
                idx.append((lag + self.L_max) * n_i + j)
                cur.append(n_lags * n_i + j if curvature else zero)
        off = n_lags * n_i + n_i + self.delays.index(d) * (self.nv_max + 1) * (self.nr_max + 1)
        for v in range(nv + 1):
            for r in range(nr + 1):
                idx.append(off + v * (self.nr_max + 1) + r)
                cur.append(zero)
        return np.array(idx), np.array(cur)


def fitted_structure(model, scheduling_extrapolation) -> dict:
    """A fitted model's structure in the selection's settings (lpvpc.identification.selection.SEARCH): the
    orders of its bases as fitted (a stationary trial's intrinsic basis: 0, whatever asked).

    >>> import types
    >>> from lpvpc.models.basis import Basis
    >>> b = Basis("chebyshev", 3, -0.2, 0.1)
    >>> m = types.SimpleNamespace(fs=100.0, settings={"irf_lags": 4}, delay=4, curvature=None, intrinsic_basis=b,
    ...                           reflex_rho_basis=b, velocity_basis=b)
    >>> fitted_structure(m, "clip")["irf_length"], fitted_structure(m, "clip")["reflex_delay"]
    (0.04, 0.04)
    """
    fs = model.fs
    return {"irf_length": model.settings["irf_lags"] / fs, "intrinsic_order": model.intrinsic_basis.order,
            "reflex_order": model.reflex_rho_basis.order, "velocity_order": model.velocity_basis.order,
            "reflex_delay": model.delay / fs, "elastic_curvature": model.curvature is not None,
            "scheduling_extrapolation": scheduling_extrapolation}


def trial_edges(segments, n: int, edge: int) -> np.ndarray:
    """Bool mask (n,) of each trial's first and last ``edge`` samples (``segments``: the
    trials' (start, stop) pairs, empty for one trial): where a model's IRF lags and reflex delay
    reach past the trial and the record-edge rules stand in. A trial too short to spare them
    (not longer than 4 ``edge``) keeps its edges.

    >>> trial_edges([(0, 10), (10, 30)], 30, 3).nonzero()[0].tolist()  # the first trial is too short
    [10, 11, 12, 27, 28, 29]
    """
    mask = np.zeros(n, bool)
    for a, b in (list(segments) or [(0, n)]):
        if b - a > 4 * edge:
            mask[a:a + edge] = mask[b - edge:b] = True
    return mask


def in_sample_vaf(p, Y, rho, fs, dynamics, settings: dict, family="chebyshev", velocity_family="chebyshev",
                  segments=None, edge: int = 0) -> np.ndarray:
    """In-sample VAF (%) of the structure ``settings`` (lpvpc.identification.selection.SEARCH's keys) with the
    reflex ``dynamics`` held (as in :class:`StructureSearch`), fitted by least squares to each
    column of ``Y`` (N, k): one regressor and one Gram matrix for every output, so k outputs
    cost about one (lpvpc.identification.skew_scan scans shifted torques with it). ``edge``: samples at each
    trial's start and end left out of the fit and the score (where the record-edge rules
    stand in for samples the record does not have).

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=3, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     m = identify(d, structure="fixed")
    >>> settings = {"irf_length": 0.04, "intrinsic_order": 5, "reflex_order": 2, "velocity_order": 4,
    ...             "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}
    >>> noise = np.random.default_rng(0).standard_normal(d.n)
    >>> v = in_sample_vaf(d.position, np.c_[d.torque, noise], d.scheduling, d.fs, (m.A, m.C[None, :],
    ...                   np.append(m.B, m.D)), settings)
    >>> bool(v[0] > 95.0), bool(v[1] < 5.0)  # the torque is fitted, white noise hardly
    (True, True)
    """
    Y = np.asarray(Y, dtype=float)
    Y = Y[:, None] if Y.ndim == 1 else Y
    L = max(1, int(round(settings["irf_length"] * fs)))
    d = max(1, int(round(settings["reflex_delay"] * fs)))
    top = (L, settings["intrinsic_order"], settings["reflex_order"], settings["velocity_order"], [d])
    segments = segments if segments is not None else Segments((), len(Y))
    labels = trial_edges(segments, len(Y), edge).astype(int)  # 0: fitted and scored; 1: a trial's edge, left out
    D = _Design(np.asarray(p, dtype=float), Y, np.asarray(rho, dtype=float), float(fs), labels, 1 + int(labels.any()),
                family, velocity_family, dynamics, top, (), segments)
    idx, cur = D.columns(L, top[1], top[2], top[3], d, bool(settings["elastic_curvature"]))
    G, b = _mapped(D.G[0], D.b[0].T, idx, cur)  # b: (k, columns)
    theta = solve_normal(G, b.T, RIDGE).T
    Y = Y[labels == 0]
    sse = np.einsum("ij,ij->j", Y, Y) - 2.0 * np.einsum("ki,ki->k", theta, b) + np.einsum("ki,ij,kj->k", theta, G, theta)
    return 100.0 * (1.0 - sse / np.sum((Y - Y.mean(axis=0)) ** 2, axis=0))


class _Evaluates:
    """A basis stand-in whose ``evaluate`` is the given function (held minus full basis values)."""

    def __init__(self, fn):
        self.evaluate = fn


def _mapped(G, b, idx, cur):
    """(G, b) of the columns X[:, idx[k]] + X[:, cur[k]] from those of X (leading axes kept)."""
    Gc = (G[..., idx, :][..., :, idx] + G[..., idx, :][..., :, cur] + G[..., cur, :][..., :, idx]
          + G[..., cur, :][..., :, cur])
    return Gc, b[..., idx] + b[..., cur]


def _zero_column(D) -> int:
    """Index of the largest regressor's zero column (the curvature share of columns without one)."""
    return (2 * D.L_max + 1) * (D.ni_max + 1) + (D.ni_max + 1) + len(D.delays) * (D.nv_max + 1) * (D.nr_max + 1)


#: Choice rules over the scored structures (:func:`choose`).
CHOICE_RULES = ("level", "both", "worst_rank")
CHOICE_RULE = "both"


def _within(s, best, forward=False) -> bool:
    """``s`` within one paired standard error (over folds) of ``best``'s squared error: on the
    leave-one-level-out folds, or on the forward-in-time folds."""
    a, b = (s.forward_sse, best.forward_sse) if forward else (s.fold_sse, best.fold_sse)
    K = len(a)
    diff = K * (a - b)
    se = np.std(diff, ddof=1) / np.sqrt(K) if K > 1 else 0.0
    return bool(np.mean(diff) <= se)


def choose(scored: list, rule: str = CHOICE_RULE):
    """The structure a rule picks among :class:`Scored` structures.

    - ``"level"``: the one-standard-error rule on the leave-one-level-out folds: the fewest
      parameters among the structures within one paired standard error of the best, its IRF
      no shorter than the best's.
    - ``"both"``: the same among the structures within one paired standard error of the best
      on both fold kinds (leave-one-level-out and forward in time), the IRF no shorter than
      the shorter of the two bests'; when no structure is within on both, the one whose worse
      rank over the two criteria is best (``"worst_rank"``).
    - ``"worst_rank"``: the structure whose worse rank over the two criteria is best (ties:
      the smaller sum of ranks, then fewer parameters).

    The IRF half-width is not shortened for simplicity: K(theta) is the IRF's sum over lags,
    and an IRF shorter than the best's truncates the decimated inertia and viscosity terms
    into that sum, a bias the torque cross-validation hardly sees.

    >>> def row(o, n, level, forward):
    ...     return Scored({"irf_length": 0.04, "scheduling_extrapolation": "clip", "o": o}, n, np.array(level),
    ...                   float("nan"), np.array(forward), float("nan"))
    >>> a = row(5, 60, [1.0, 1.0, 1.1], [3.0, 3.2, 3.0])  # best on levels, poor forward
    >>> b = row(2, 30, [1.2, 1.3, 1.4], [1.0, 1.1, 1.0])  # best forward, poor on levels
    >>> c = row(3, 40, [0.98, 1.05, 1.1], [1.0, 1.12, 0.98])  # near the best on both
    >>> d = row(1, 20, [1.0, 1.0, 1.12], [2.0, 2.1, 2.0])  # near the best on levels, poor forward
    >>> for s in (a, b, c, d):
    ...     s.cv_vaf, s.forward_vaf = 100 - s.fold_sse.sum(), 100 - s.forward_sse.sum()
    >>> choose([a, b, c, d], "level").settings["o"], choose([a, b, c, d], "both").settings["o"]
    (1, 3)
    >>> choose([a, b], "both").settings["o"]  # none near the best on both: the best worse rank, then fewer parameters
    2
    """
    if rule not in CHOICE_RULES:
        raise ValueError(f"rule must be one of {CHOICE_RULES}, not {rule!r}")
    best = max(scored, key=lambda s: s.cv_vaf)
    key = lambda s: (s.n_params, s.settings["scheduling_extrapolation"] != "clip", -s.cv_vaf)  # noqa: E731
    if rule == "level" or any(s.forward_sse is None for s in scored):
        return min((s for s in scored if _within(s, best) and s.settings["irf_length"] >= best.settings["irf_length"]),
                   key=key)
    fbest = max(scored, key=lambda s: s.forward_vaf)
    if rule == "both":
        irf = min(best.settings["irf_length"], fbest.settings["irf_length"])
        ok = [s for s in scored if _within(s, best) and _within(s, fbest, forward=True) and s.settings["irf_length"] >= irf]
        if ok:
            return min(ok, key=key)
    by_level = {id(s): i for i, s in enumerate(sorted(scored, key=lambda s: -s.cv_vaf))}
    by_fwd = {id(s): i for i, s in enumerate(sorted(scored, key=lambda s: -s.forward_vaf))}
    return min(scored, key=lambda s: (max(by_level[id(s)], by_fwd[id(s)]), by_level[id(s)] + by_fwd[id(s)], *key(s)))


class StructureSearch:
    """Cross-validated scores of structures on one record, given the reflex dynamics.

    p, y, rho: perturbation position (rad), torque (N m), scheduling (rad) at fs (Hz);
    dynamics: (A, C (1, m), [B; D]) of a fit at the starting settings; family: the
    scheduling basis family (polynomial: orders nest); velocity_family likewise; segments:
    trials joined end to end (:class:`lpvpc.io.segments.Segments`), whose regressors are built
    trial by trial.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=3, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     m = identify(d)
    >>> search = StructureSearch(d.position, d.torque, d.scheduling, d.fs, (m.A, m.C[None, :], np.append(m.B, m.D)))
    >>> search.kind, search.n_folds >= 4
    ('level', True)
    >>> start = {"irf_length": 0.04, "intrinsic_order": 5, "reflex_order": 2, "velocity_order": 4,
    ...          "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}
    >>> bool(search.score(start).cv_vaf > 90.0)  # % of the torque predicted on left-out levels
    True
    >>> sel = search.run(start)
    >>> sel.chosen["reflex_delay"] in SEARCH["reflex_delay"], len(sel.table()) > 1
    (True, True)
    """

    def __init__(self, p, y, rho, fs, dynamics, family="chebyshev", velocity_family="chebyshev", search=None,
                 segments=None, reflex_input=None, effects=None, forward_folds_n=None, rule=None):
        self.fs = float(fs)
        self.rule = CHOICE_RULE if rule is None else rule
        if self.rule not in CHOICE_RULES:
            raise ValueError(f"rule must be one of {CHOICE_RULES}, not {self.rule!r}")
        self.search = dict(SEARCH if search is None else search)
        # allowed effects (effect_candidates): settings of the same search, off or one of its variants
        self.effects = dict(effects or {})
        for name, by_value in self.effects.items():
            self.search.setdefault(effect_key(name), (False, *by_value))
        self.keys = [*SEARCH, *(effect_key(n) for n in self.effects)]
        self.y = np.asarray(y, dtype=float)
        self.labels, self.kind = level_folds(rho, fs)
        self.n_folds = int(self.labels.max()) + 1
        # forward-in-time folds (none on a record too short for them, nor for a single-fold
        # search, nor for joined trials: their order in time is not known and the model must
        # not depend on the order they were given in, so there is no "later" to score)
        gap = max(max(1, int(round(x * fs))) for x in self.search["irf_length"])
        n_fwd = FORWARD_FOLDS if forward_folds_n is None else forward_folds_n
        if segments is not None and len(segments) > 1:
            n_fwd = 0
        self.forward = forward_folds(len(self.y), n_fwd, None, gap) if n_fwd else []
        self.forward = self.forward if len(self.forward) >= 2 else []
        self.lags = sorted({max(1, int(round(x * fs))) for x in self.search["irf_length"]})
        self.delays = sorted({max(1, int(round(x * fs))) for x in self.search["reflex_delay"]})
        top = (max(self.lags), max(self.search["intrinsic_order"]), max(self.search["reflex_order"]),
               max(self.search["velocity_order"]), self.delays)
        self.design = _Design(np.asarray(p, dtype=float), self.y, np.asarray(rho, dtype=float), fs, self.labels,
                              self.n_folds, family, velocity_family, dynamics, top,
                              self.search["scheduling_extrapolation"],
                              segments if segments is not None else Segments((), len(self.y)), reflex_input,
                              self.effects, self.forward)
        self.yy = np.array([self.y[self.labels == f] @ self.y[self.labels == f] for f in range(self.n_folds)])
        self.sst = float(np.sum((self.y - self.y.mean()) ** 2))
        self.f_yy = np.array([self.y[sc] @ self.y[sc] for _, sc in self.forward])
        self.f_sst = float(sum(np.sum((self.y[sc] - self.y[sc].mean()) ** 2) for _, sc in self.forward))
        self._cache = {}

    def score(self, settings: dict) -> Scored | None:
        """Scored for estimator settings (None: not a valid structure, e.g. IRF longer than the delay)."""
        L = max(1, int(round(settings["irf_length"] * self.fs)))
        d = max(1, int(round(settings["reflex_delay"] * self.fs)))
        if L > d or L not in self.lags or d not in self.delays:
            return None
        on = chosen_effects(settings)
        if any(n not in self.effects or settings[effect_key(n)] not in self.effects[n] for n in on):
            return None
        settings = {**{k: False for k in self.keys if k.startswith(EFFECT_PREFIX)},
                    **{k: v for k, v in settings.items() if k in SEARCH or k.startswith(EFFECT_PREFIX)}}
        key = tuple(sorted((k, settings[k]) for k in self.keys))
        if key in self._cache:
            return self._cache[key]
        D = self.design
        idx, cur = self.columns(settings)
        Gc, bc = _mapped(D.G, D.b, idx, cur)  # (K, n, n), (K, n): each fold's rows
        theta = fold_fits(Gc, bc, RIDGE)[0]  # each fit on the other folds' rows
        for f, (Ge, be) in D.end[settings["scheduling_extrapolation"]].items():  # end folds: their own rule
            Gc[f], bc[f] = _mapped(Ge, be, idx, cur)
        sse = held_out_sse(self.yy, theta, Gc, bc)
        out = Scored(dict(settings), len(idx), sse, 100.0 * (1.0 - float(sse.sum()) / self.sst))
        if self.forward:  # each stretch predicted by a fit on the record before it
            rule = settings["scheduling_extrapolation"]
            Gt, bt = _mapped(D.fG_train, D.fb_train, idx, cur)
            theta = solve_normal(Gt, bt, RIDGE)
            Gs, bs = _mapped(D.fG, D.fb, idx, cur)
            for k, (Ge, be) in D.f_end[rule].items():
                Gs[k], bs[k] = _mapped(Ge, be, idx, cur)
            out.forward_sse = held_out_sse(self.f_yy, theta, Gs, bs)
            out.forward_vaf = 100.0 * (1.0 - float(out.forward_sse.sum()) / self.f_sst)
        self._cache[key] = out
        return out

    def columns(self, settings: dict):
        """(columns of the largest regressor, their curvature shares) of a valid structure:
        the IRF's first, the effects' (their variants') last."""
        D = self.design
        L = max(1, int(round(settings["irf_length"] * self.fs)))
        d = max(1, int(round(settings["reflex_delay"] * self.fs)))
        idx, cur = D.columns(L, settings["intrinsic_order"], settings["reflex_order"], settings["velocity_order"], d,
                             bool(settings["elastic_curvature"]))
        on = chosen_effects(settings)
        if on:  # the effects' columns (no curvature share: the zero column)
            extra = np.concatenate([D.effect_cols[(n, settings[effect_key(n)])] for n in on])
            idx, cur = np.r_[idx, extra], np.r_[cur, np.full(len(extra), _zero_column(D))]
        return idx, cur

    def run(self, start: dict, fixed=(), max_sweeps: int = 3) -> Selection:
        """Coordinate search from ``start`` over the settings not in ``fixed``, then the
        one-standard-error rule over every structure scored."""
        current = {k: start.get(k, False) if k.startswith(EFFECT_PREFIX) else start[k] for k in self.keys}
        free = [k for k in self.keys if k not in fixed]
        first = self.score(current)
        if first is None:
            raise ValueError(f"the starting structure is not valid for selection: {current}")
        for _ in range(max_sweeps):
            changed = False
            for name in free:
                options = [self.score({**current, name: v}) for v in self.search[name]]
                options = [o for o in options if o is not None]
                best = max(options, key=lambda o: o.cv_vaf)
                if best.settings[name] != current[name] and best.cv_vaf > self.score(current).cv_vaf:
                    current[name] = best.settings[name]
                    changed = True
            if not changed:
                break
        scored = sorted(self._cache.values(), key=lambda s: -s.cv_vaf)
        best = scored[0]
        K = self.n_folds
        chosen = choose(scored, self.rule if self.forward else "level")
        fwd_best = max(scored, key=lambda s: s.forward_vaf) if self.forward else None
        return Selection(chosen=dict(chosen.settings), start=dict(first.settings), fold_kind=self.kind, n_folds=K,
                         scored=scored, best=dict(best.settings), rule=self.rule if self.forward else "level",
                         n_forward=len(self.forward), forward_best=dict(fwd_best.settings) if fwd_best else {})


def compare_state_orders(p, y, rho, fs, chosen: dict, dynamics: dict, bic_order: int, bic_score: Scored,
                         family="chebyshev", velocity_family="chebyshev", segments=None, effects=None):
    """The reflex state order by cross-validation: the chosen structure scored (same folds)
    under the reflex dynamics of each other order the first fit tried (``dynamics``: order ->
    (A, C, [B; D])). BIC's order stays unless another predicts the left-out folds better by
    more than one paired standard error. Returns (order, {order: CV VAF %}).

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import LPVPCEstimator
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=3, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     m = LPVPCEstimator(structure="fixed").fit(d).model_
    >>> settings = {"irf_length": 0.04, "intrinsic_order": 5, "reflex_order": 2, "velocity_order": 4,
    ...             "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}
    >>> one = {k: (v,) for k, v in settings.items()}
    >>> own = StructureSearch(d.position, d.torque, d.scheduling, d.fs, (m.A, m.C[None, :], np.append(m.B, m.D)),
    ...                       search=one).score(settings)
    >>> silent = (np.array([[0.5]]), np.array([[1.0]]), np.zeros(2))  # a made-up order 1 without reflex torque
    >>> order, cv = compare_state_orders(d.position, d.torque, d.scheduling, d.fs, settings, {1: silent},
    ...                                  m.state_order, own)
    >>> order == m.state_order, bool(cv[1] < cv[m.state_order])  # BIC's order stays: the other predicts worse
    (True, True)
    """
    scores = {bic_order: bic_score}
    for order, dyn in dynamics.items():
        if order != bic_order:
            on = {n: effects[n] for n in chosen_effects(chosen)} if effects else None  # the chosen effects' columns
            search = StructureSearch(p, y, rho, fs, dyn, family, velocity_family, {k: (chosen[k],) for k in SEARCH},
                                     segments, effects=on)
            scores[order] = search.score(chosen)
    best = min(scores, key=lambda k: float(scores[k].fold_sse.sum()))
    K = len(bic_score.fold_sse)
    diff = K * (scores[bic_order].fold_sse - scores[best].fold_sse)  # > 0 where ``best`` predicts better
    if best != bic_order and (K < 2 or np.mean(diff) <= np.std(diff, ddof=1) / np.sqrt(K)):
        best = bic_order
    return best, {int(k): float(v.cv_vaf) for k, v in sorted(scores.items())}


#: The reflex nonlinearity's velocity when the data keep their file's higher rate
#: (``data.high_rate``, e.g. 1 kHz files identified at 100 Hz): the model rate's (the
#: simpler candidate) or the high rate's with each of these (velocity basis family, order):
#: a piecewise-linear basis that can place the rectifier's kink, and the polynomial one that
#: held up under the lab's perturbation design (benchmarks/results/lab_perturbation.txt).
#: At the model rate the velocity basis kind is not a candidate: Chebyshev and Legendre
#: polynomials of one order span the same functions (the same fit, the same score).
HIGH_RATE_BASES = (("chebyshev", 4), ("hinge", 8))
#: The estimator settings of that choice (left as given when the caller sets any of them).
REFLEX_PATH_SETTINGS = ("high_rate_reflex", "high_rate_velocity_basis", "high_rate_velocity_order")


@dataclass
class PathChoice:
    """The reflex nonlinearity's velocity chosen by :func:`compare_reflex_paths`: ``chosen``
    (estimator settings), ``rows`` (settings, parameter count, CV VAF %), model rate first.

    >>> c = PathChoice({"high_rate_reflex": False}, [({"high_rate_reflex": False}, 60, 98.1)], fs_high=1000.0)
    >>> c.to_dict()["chosen"], c.label(c.chosen)
    ({'high_rate_reflex': False}, 'model-rate velocity')
    """

    chosen: dict
    rows: list
    fs_high: float
    fallback: str = ""  # why the chosen high-rate fit was replaced by the model-rate one (identify)

    def label(self, settings: dict) -> str:
        if not settings["high_rate_reflex"]:
            return "model-rate velocity"
        return (f"{self.fs_high:g} Hz velocity, {settings['high_rate_velocity_basis']} "
                f"{settings['high_rate_velocity_order']}")

    def to_dict(self) -> dict:
        return {"chosen": dict(self.chosen), "label": self.label(self.chosen), "fs_high": float(self.fs_high),
                "method": "same folds, one-standard-error rule toward the model-rate velocity while it has "
                          "fewer parameters than every high-rate candidate (else toward the high rate), then "
                          "fewer parameters",
                **({"fallback": self.fallback} if self.fallback else {}),
                "table": [{"settings": dict(s), "label": self.label(s), "n_params": int(n), "cv_vaf": float(v)}
                          for s, n, v in self.rows]}


def pick_reflex_path(scored: list) -> dict:
    """The one-standard-error rule over (settings, :class:`Scored`) pairs of the reflex paths:
    the first within one paired standard error of the best, in the order of simplicity. The
    model rate (``high_rate_reflex`` False) comes first while it has fewer parameters than
    every high-rate candidate (no high-rate signals needed to predict, no model-rate stand-in
    in exports); with as many or more, the high-rate candidates come first (by parameter
    count): the paths then differ only in the model rate's bias by construction (decimation
    smooths the velocity pulses the rectifier acts on).

    >>> model = ({"high_rate_reflex": False}, Scored({}, 60, np.array([1.00, 1.00, 1.00, 1.00])))
    >>> hinge = ({"high_rate_reflex": True, "high_rate_velocity_basis": "hinge"},
    ...          Scored({}, 72, np.array([0.90, 0.91, 0.92, 0.89])))  # better on every fold
    >>> cheb = ({"high_rate_reflex": True, "high_rate_velocity_basis": "chebyshev"},
    ...         Scored({}, 72, np.array([0.99, 1.00, 0.97, 1.02])))
    >>> pick_reflex_path([model, hinge])["high_rate_reflex"]  # the model rate is clearly worse
    True
    >>> pick_reflex_path([model, cheb])["high_rate_reflex"]  # a tie; the model rate is simpler
    False
    >>> same = ({**cheb[0]}, Scored({}, 60, cheb[1].fold_sse))  # a tie at as many parameters: the high rate
    >>> pick_reflex_path([model, same])["high_rate_reflex"]
    True
    """
    best = min((s for _, s in scored), key=lambda s: float(s.fold_sse.sum()))
    K = len(best.fold_sse)

    def within(s):
        diff = K * (s.fold_sse - best.fold_sse)
        return K < 2 or np.mean(diff) <= np.std(diff, ddof=1) / np.sqrt(K)

    # The model rate is the simpler path only while it has fewer parameters than every high-rate
    # candidate; with as many, what is left between them is the bias by construction (decimation
    # smooths the velocity pulses before the model-rate rectifier: docs/design_notes.md,
    # "Reflex nonlinearity at the file's own rate"), so the high rate goes first.
    model_params = min(s.n_params for st, s in scored if not st["high_rate_reflex"])
    high_params = min((s.n_params for st, s in scored if st["high_rate_reflex"]), default=np.inf)
    high_first = model_params >= high_params
    simplest = sorted(scored, key=lambda t: (bool(t[0]["high_rate_reflex"]) != high_first, t[1].n_params))
    return dict(next(settings for settings, s in simplest if within(s)))


def compare_reflex_paths(p, y, rho, fs, chosen: dict, dynamics, model_rate: Scored, high, candidates=HIGH_RATE_BASES,
                         family="chebyshev", segments=None) -> PathChoice:
    """Model-rate against high-rate reflex nonlinearity, at the chosen structure: each
    high-rate candidate (velocity family, order) replaces the reflex columns of ``chosen``
    (the reflex dynamics ``dynamics`` held, as for every candidate) and is scored on the
    same folds as ``model_rate`` (the chosen structure's score). The one-standard-error rule
    toward the simpler path (:func:`pick_reflex_path`): the model rate while it has fewer
    parameters than every high-rate candidate (no high-rate signals needed to predict,
    exports without a model-rate stand-in), else the high rate, whose rectifier sees the
    velocity pulses decimation smooths.
    ``high``: :class:`lpvpc.io.HighRate` of the record (its rate a multiple of ``fs``).

    Why per record: on the virtual subject's 1 kHz files the high-rate velocity recovers the
    reflex gain trend (benchmarks/results/reflex_1k.txt); on the lab's pilot trial it
    predicted held-out data worse (benchmarks/results/real_pilot.txt).

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import LPVPCEstimator
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=9, duration=60.0)  # 1 kHz trials
    >>> d = pair_trials(sim.pt, sim.ut)  # 100 Hz, the 1 kHz signals kept (d.high_rate)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     m = LPVPCEstimator(structure="fixed").fit(d).model_
    >>> settings = {"irf_length": 0.04, "intrinsic_order": 5, "reflex_order": 2, "velocity_order": 4,
    ...             "reflex_delay": 0.04, "elastic_curvature": True, "scheduling_extrapolation": "clip"}
    >>> dyn = (m.A, m.C[None, :], np.append(m.B, m.D))
    >>> own = StructureSearch(d.position, d.torque, d.scheduling, d.fs, dyn,
    ...                       search={k: (v,) for k, v in settings.items()}).score(settings)
    >>> choice = compare_reflex_paths(d.position, d.torque, d.scheduling, d.fs, settings, dyn, own, d.high_rate)
    >>> [row[0].get("high_rate_velocity_basis", "model rate") for row in choice.rows]
    ['model rate', 'chebyshev', 'hinge']
    >>> [n for _, n, _ in choice.rows]  # parameters: 5 velocity functions x 3, 9 x 3 in the reflex
    [69, 69, 81]
    >>> choice.chosen in [row[0] for row in choice.rows]
    True
    """
    from ..models.reflex import HighRateReflexInput

    q = int(round(float(high.fs) / float(fs)))
    scored = [({"high_rate_reflex": False}, model_rate)]
    for vfam, vorder in candidates:
        src = HighRateReflexInput(high, q, chosen["reflex_delay"], vfam, vorder)
        nv = src.n_velocity - 1  # the design's velocity "order": its columns per scheduling function, less one
        search = {k: (chosen[k],) for k in SEARCH}
        search["velocity_order"] = (nv,)
        sc = StructureSearch(p, y, rho, fs, dynamics, family, "chebyshev", search, segments,
                             reflex_input=src).score({**chosen, "velocity_order": nv})
        scored.append(({"high_rate_reflex": True, "high_rate_velocity_basis": vfam,
                        "high_rate_velocity_order": int(vorder)}, sc))
    pick = pick_reflex_path(scored)
    return PathChoice(chosen=pick, rows=[(st, s.n_params, s.cv_vaf) for st, s in scored], fs_high=float(high.fs))
