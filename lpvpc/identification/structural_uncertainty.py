"""Structural uncertainty of the intrinsic intervals: the spread of K(theta) and viscosity
over the structures cross-validation cannot tell apart.

The noise intervals (:mod:`lpvpc.models.uncertainty`) are right for the noise but assume the
position basis holds the true K(theta). When it does not (a steep sum of exponentials, a
kinked curve: :data:`lpvpc.simulation.subject.STIFFNESS_FAMILIES`) the estimate is biased by the
basis's misfit, which the noise does not show. The cross-validated structure search
(:mod:`lpvpc.identification.selection`) measures which structures predict left-out levels equally well:
every structure whose CV error is within one standard error of the best one is as
supported by the data as the chosen one. Their K(theta) curves differ where the data do not
decide the structure -- about as much as the chosen curve's structural error, since the set
holds richer structures that follow the curve more closely. So:

- the search runs from the model's structure (the chosen one after ``structure='cv'``),
  with the model's reflex dynamics held, as identify's selection does;
- of the structures within one standard error of the best, those that differ from the
  model's structure in the intrinsic pathway only (:data:`INTRINSIC_SETTINGS`: IRF
  half-width, position-basis order, elastic curvature term; the reflex settings held at the
  model's) count: they are the other descriptions of K(theta) the data support. A structure
  that changes the reflex pathway moves K through the intrinsic/reflex split instead, which
  the joint covariance of the noise intervals already carries; counted as structure it
  over-covered (docs/design_notes.md, "Structural uncertainty");
- each of them and the model's own structure are refitted to the whole record in that same
  linear problem (the dynamics held: a small solve on the summed per-fold normal
  equations, no new regressor);
- the structural term at theta is the largest absolute difference between one of them and
  the model structure's refit (the same machinery for both, so the reflex dynamics'
  refinement does not count as structure);
- :func:`lpvpc.models.uncertainty.structural_shift` evaluates it at any theta (the stored
  shifts' largest absolute value) and :func:`lpvpc.models.uncertainty.intrinsic_interval` adds it
  to the neighbouring-specification bound as the bias bound of its bias-aware critical
  value (Armstrong and Kolesar). The two see different parts of the bias; the larger of
  the two alone under-covered the kinked K on 100 Hz files; their sum (with the reflex
  dynamics' term below) covers K within the target on every family, file rate and seed
  range (``benchmarks/results/coverage_families.txt``).

The reflex gain has a term of its own (``reflex``; :func:`lpvpc.models.reflex_uncertainty.reflex_interval`
adds it to the gain's bias bound), stored only when the model's structure was chosen by
identify's cross-validation. Why: the one-standard-error rule picks the simplest reflex
structure within noise of the best, which can be a constant or linear reflex scheduling basis
that cannot follow an exponential gain trend (measured under-coverage: docs/design_notes.md,
"Structural uncertainty"). The alternatives
the selection could not exclude are the reflex scheduling basis one order higher and the
near-equivalent structures that differ from the model's in :data:`REFLEX_SETTINGS` only; each
is refitted like the model's own structure, and the largest shift of the rectifier's gain is
the term (intrinsic-only structures hardly move the gain). A structure the caller fixed, and the explicit
1 kHz path (selection skipped), get no reflex term.

The model's own estimate is one more: ``path`` stores the model's IRF minus the search's refit
of the model's structure (model-rate reflex columns through the held dynamics, intrinsic and
reflex in one least squares), counted for :data:`~lpvpc.models.modelfile.PATH_QUANTITIES`
(viscosity) as one more near-equivalent structure. On the 1 kHz path (``high_rate_reflex``)
the two differ in the reflex's velocity path, which the selection did not compare when the
caller gave it. At the model rate they differ in the reflex structure the intrinsic estimate
sees: the model's IRF is the paper's orthogonal projection (eq. 27-28), which projects out the
unstructured reflex space (every reflex state with its own input coefficients), the refit
holds the rank-1 reflex. The data hardly choose between them, and the viscosity, whose viscous
torque the reflex of delayed velocity resembles below the reflex dynamics' corner frequency,
moves between them by up to 10 % on population subjects whose viscosity intervals missed
(docs/design_notes.md, "Structural uncertainty"). Extended models count their structure
without the effects instead (below).

The reflex's linear dynamics are one more part of the structure the data may not pin down,
and a misfit there moves K: under the lab's ramp-and-hold pulses the reflex torque lasts into
the hold, where it is collinear with the displacement, so whatever the identified reflex
dynamics miss of it is taken for stiffness (docs/design_notes.md, "Structural uncertainty").
``leak`` stores the IRF refitted with the reflex dynamics free (a
finite impulse response of :data:`LEAK_FIR_S` on each reflex input column) minus the refit
with the model's dynamics held, both in one least squares with the model's intrinsic columns;
:func:`lpvpc.models.uncertainty.reflex_leak_shift` evaluates it for :data:`~lpvpc.models.modelfile.LEAK_QUANTITIES`,
and the intrinsic intervals add it to the other two bias bounds (separate parts of the
structure: the biases add).

An extended model (an allowed effect chosen by the selection, e.g. stress relaxation) counts
more structures:

- the effect's other variants the selection could not exclude (another relaxation time:
  ``effect_variant_shifts``, refitted in identify's effect search), and a single time's
  neighbours on the grid whatever their score: K trades with the relaxation's time, which the
  data hardly determine;
- its own structure without the effects (the search's refit of it, the effects' columns
  absent, minus the model's IRF), when the effect won narrowly (less than
  ``ESTABLISHED_EFFECT_GAIN`` of the CV error). The selection compared the effects on and
  off and the effect can win by a margin just above its bar; the effects' slow columns then
  trade with the IRF, and without that structure the extended models' K and viscosity
  intervals under-cover (docs/design_notes.md, "Structural uncertainty").

identify adds it whenever its selection ran (reusing that search: only the refits);
:func:`add_structural_uncertainty` adds it to any other model with intervals.

Stored in ``model.uncertainty["structural"]`` (the model file round-trips it)::

    method        text
    basis         the largest scheduling basis of the search (Basis.to_dict)
    lags          IRF lags of the shifts (the search's longest IRF)
    shifts        n_s x len(lags) x n_basis: each near-equivalent structure's IRF weights
                  minus the model structure's, refitted alike (N m/rad per sample)
    structures    the near-equivalent structures' settings and CV VAF (%)
                  (those differing from the model's in INTRINSIC_SETTINGS only)
    n_scored      structures the search scored
    path          (models without effects) {"quantities": PATH_QUANTITIES, "shift":
                  len(lags) x n_basis: the model's IRF minus the search's refit of its structure}
    leak          {"quantities": LEAK_QUANTITIES, "fir_s": LEAK_FIR_S, "shift": len(lags) x
                  n_basis: the IRF refitted with the reflex dynamics free minus the refit with
                  them held (:func:`reflex_leak_shift`)}; absent where it cannot be computed
    reflex        (selected structures only) {"rho_basis": the search's reflex scheduling
                  basis, "reference": the model structure's refit, "structures": [{"settings",
                  ...}]}, each refit as {"velocity_basis": Basis.to_dict, "coefficients":
                  n_v x n_r of the nonlinearity scaled by the held dynamics' DC gain (N m)}

Measured coverage on three stiffness families: ``benchmarks/results/coverage_families.txt``.
"""

from __future__ import annotations

import numpy as np

from ..models.modelfile import LEAK_QUANTITIES, MAX_STRUCTURES, PATH_QUANTITIES

__all__ = ["add_structural_uncertainty", "structural_term", "structure_search", "near_equivalent",
           "reflex_leak_shift", "INTRINSIC_SETTINGS", "REFLEX_SETTINGS", "PATH_QUANTITIES", "LEAK_QUANTITIES",
           "LEAK_FIR_S"]

METHOD = ("spread of the IRF's quantities over the structures within one standard error of the best "
          "cross-validated one (leave-one-level-out) that differ from the model's in the intrinsic pathway only, "
          "each refitted to the record with the reflex dynamics held")
#: An effect chosen by identify's selection that lowered the CV squared error by at least this
#: fraction (twice identify's bar, MIN_EFFECT_GAIN) is established: the structure without it no
#: longer counts as near-equivalent. Below it the effect won narrowly and its columns trade with
#: the IRF; above it the structure without it would make K's interval span short-range and
#: relaxed stiffness alike (docs/design_notes.md, "Structural uncertainty").
ESTABLISHED_EFFECT_GAIN = 0.10
#: Length (s) of the free reflex impulse response of :func:`reflex_leak_shift`: the reflex
#: dynamics of the population's subjects (natural frequency 12-50 rad/s, damping 0.4-1) have
#: decayed within it.
LEAK_FIR_S = 0.3
#: The search's settings of the intrinsic pathway: the near-equivalent structures that count
#: differ from the model's in these only (the reflex order, velocity order, delay and
#: extrapolation held at the model's).
INTRINSIC_SETTINGS = ("irf_length", "intrinsic_order", "elastic_curvature")
#: The search's settings of the reflex pathway: the alternatives of the reflex gain's
#: structural term differ from the model's in these only.
REFLEX_SETTINGS = ("reflex_order", "velocity_order", "reflex_delay")


def _start(model) -> dict:
    """The model's structure in the search's settings (lpvpc.identification.selection.SEARCH)."""
    s, fs = model.settings, model.fs
    return {"irf_length": int(s["irf_lags"]) / fs, "intrinsic_order": int(s["intrinsic_order"]),
            "reflex_order": int(s["reflex_order"]), "velocity_order": int(s["velocity_order"]),
            "reflex_delay": model.delay / fs, "elastic_curvature": bool(s.get("elastic_curvature", False)),
            "scheduling_extrapolation": s.get("scheduling_extrapolation", "clip")}


def structure_search(model, data):
    """(search, start, fixed): a :class:`lpvpc.identification.selection.StructureSearch` on ``data`` (the
    record the model was identified from, at the model's rate) with the model's reflex
    dynamics, the model's structure as its start and the settings the model fixed.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(d)
    >>> search, start, fixed = structure_search(model, d)
    >>> selection = search.run(start, fixed)
    >>> near = near_equivalent(search, selection)  # within one SE of the best CV structure
    >>> near[0].settings == selection.best, start["intrinsic_order"] == model.settings["intrinsic_order"]
    (True, True)
    """
    from ..io.segments import Segments
    from .selection import StructureSearch, search_space

    families = (model.settings.get("basis", "chebyshev"), model.settings.get("velocity_basis", "chebyshev"))
    if any(f not in ("chebyshev", "legendre") for f in families):
        raise ValueError(f"the structural term needs polynomial bases, whose candidates' columns nest; this model "
                         f"has {families[0]!r} in position and {families[1]!r} in velocity")
    start = _start(model)
    fixed = {"irf_length" if k == "irf_lags" else k for k in model.settings.get("structure_fixed") or ()}
    search = search_space(start, fixed)
    p, y, rho = (np.asarray(x, dtype=float) for x in (data.position, data.torque, data.scheduling))
    s = StructureSearch(p, y, rho, model.fs, (model.A, model.C[None, :], np.append(model.B, model.D)),
                        model.settings.get("basis", "chebyshev"), model.settings.get("velocity_basis", "chebyshev"),
                        search, Segments.of(data, len(y)))
    return s, start, fixed


def _intrinsic_only(settings, start) -> bool:
    """True when ``settings`` differ from ``start`` in :data:`INTRINSIC_SETTINGS` only.

    >>> a = {"intrinsic_order": 4, "reflex_order": 2, "irf_length": 0.03}
    >>> _intrinsic_only({**a, "intrinsic_order": 6}, a), _intrinsic_only({**a, "reflex_order": 3}, a)
    (True, False)
    """
    return _differs_only_in(settings, start, INTRINSIC_SETTINGS)


def _differs_only_in(settings, start, keys) -> bool:
    """True when ``settings`` differ from ``start`` in ``keys`` only.

    >>> a = {"intrinsic_order": 4, "reflex_order": 2, "velocity_order": 4}
    >>> _differs_only_in({**a, "reflex_order": 3}, a, REFLEX_SETTINGS)
    True
    >>> _differs_only_in({**a, "intrinsic_order": 5}, a, REFLEX_SETTINGS)
    False
    """
    return all(v == start.get(k) for k, v in settings.items() if k not in keys)


def near_equivalent(search, selection, limit=MAX_STRUCTURES) -> list:
    """The scored structures (lpvpc.identification.selection.Scored) within one standard error of the
    best (the paired standard error over folds of the difference in held-out error, as
    the one-standard-error rule), closest to the best first, at most ``limit`` (None: all;
    ``search`` is not used; kept for symmetry with :func:`structural_term`).

    >>> from lpvpc.identification.selection import Scored, Selection
    >>> best = Scored({"order": 5}, 60, np.array([1.0, 1.9, 1.4]), 97.1)  # N m^2 per fold, CV VAF %
    >>> close = Scored({"order": 3}, 40, np.array([1.0, 1.95, 1.35]), 97.0)
    >>> poor = Scored({"order": 2}, 30, np.array([3.0, 4.0, 5.0]), 90.0)
    >>> sel = Selection(chosen={"order": 3}, start={"order": 5}, fold_kind="level", n_folds=3,
    ...                 scored=[best, close, poor], best={"order": 5})
    >>> [s.settings["order"] for s in near_equivalent(None, sel)]
    [5, 3]
    """
    scored = sorted(selection.scored, key=lambda s: -s.cv_vaf)
    best, K = scored[0], selection.n_folds
    out = []
    for s in scored:
        diff = K * (s.fold_sse - best.fold_sse)
        se = np.std(diff, ddof=1) / np.sqrt(K) if K > 1 else 0.0
        if np.mean(diff) <= se:
            out.append(s)
    return out if limit is None else out[:limit]


def _refit(search, settings):
    """(theta, L, d): a structure's parameters refitted to the whole record (its columns of
    the search's largest regressor, the reflex dynamics held), IRF half-width and reflex
    delay in samples."""
    from .crossval import solve_normal
    from .selection import RIDGE, _mapped

    D = search.design
    fs = search.fs
    L = max(1, int(round(settings["irf_length"] * fs)))
    d = max(1, int(round(settings["reflex_delay"] * fs)))
    idx, cur = search.columns(settings)
    G, b = _mapped(D.G.sum(axis=0), D.b.sum(axis=0), idx, cur)
    return solve_normal(G, b, RIDGE), L, d


def _refit_irf(search, settings) -> np.ndarray:
    """IRF weights (2 L_max + 1, n_i max + 1) of a structure refitted to the whole record
    (:func:`_refit`), zero where the structure has no lag or basis function."""
    D = search.design
    theta, L, _ = _refit(search, settings)
    ni = settings["intrinsic_order"]
    H = np.zeros((2 * D.L_max + 1, D.ni_max + 1))
    H[D.L_max - L : D.L_max + L + 1, : ni + 1] = theta[: (2 * L + 1) * (ni + 1)].reshape(2 * L + 1, ni + 1)
    return H


def _refit_reflex(search, settings, velocity_family="chebyshev") -> dict:
    """A structure's reflex nonlinearity refitted to the whole record (:func:`_refit`),
    scaled by the held dynamics' DC gain (N m): {"velocity_basis": the search's velocity
    basis at the structure's delay (Basis.to_dict), "coefficients": (n_v max + 1) x (n_r
    max + 1), zero where the structure has no basis function}; f(v, rho) = G_r(rho) C' V(v)
    with G_r the search's reflex scheduling basis."""
    from ..models import equations as eq
    from ..models.basis import basis_from_data

    D = search.design
    theta, L, d = _refit(search, settings)
    ni, nr, nv = settings["intrinsic_order"], settings["reflex_order"], settings["velocity_order"]
    om = np.zeros((D.nv_max + 1, D.nr_max + 1))
    om[: nv + 1, : nr + 1] = theta[(2 * L + 1) * (ni + 1):].reshape(nv + 1, nr + 1)
    dv = D.seg.map(eq.delayed_velocity, D.p, fs=search.fs, delay=d)
    basis = basis_from_data(dv, velocity_family, D.nv_max, extrapolation="linear")
    dc = eq.static_gain(D.A, D.bd[:-1], D.C[0], D.bd[-1])
    return {"velocity_basis": basis.to_dict(), "coefficients": (dc * om).tolist()}


def structural_term(model, data, search=None, selection=None, effects=None) -> dict:
    """The ``structural`` entry of ``model.uncertainty`` (module docstring) from ``data``,
    the record the model was identified from. ``search``/``selection``: a search already
    run on these data with these dynamics (identify's), else one is run here. ``effects``:
    of a model whose effects identify's selection chose, {"gain": the fraction by which they
    lowered the CV squared error, "variants": [(settings, CV VAF, IRF shift)] of
    ``effect_variant_shifts``}.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0, stiffness_family="piecewise")
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(d)
    >>> term = structural_term(model, d)
    >>> len(term["shifts"]) == len(term["structures"]) > 0, len(term["lags"]) == len(term["shifts"][0])
    (True, True)
    """
    if search is None or selection is None:
        search, start, fixed = structure_search(model, data)
        selection = search.run(start, fixed)
    else:
        start = _start(model)
    if search.score(start) is None:
        raise ValueError(f"the model's structure is not one the search can score: {start}")
    ref = _refit_irf(search, start)
    D = search.design
    H_model = _model_irf(model, D) if getattr(model, "effects", None) else None
    near = [s for s in near_equivalent(search, selection, limit=None) if s.settings != start
            and _intrinsic_only(s.settings, start)][:MAX_STRUCTURES - (H_model is not None)]
    shifts = [_refit_irf(search, s.settings) - ref for s in near]
    structures = [{"settings": _plain(s.settings), "cv_vaf": float(s.cv_vaf)} for s in near]
    for settings, cv_vaf, shift in (effects or {}).get("variants", ()):  # the effect's other terms CV could not
        # exclude (another relaxation time): zero-padded to the search's lags and basis
        L, n = (shift.shape[0] - 1) // 2, shift.shape[1]
        padded = np.zeros_like(ref)
        padded[D.L_max - L : D.L_max + L + 1, :n] = shift
        shifts.append(padded)
        structures.append({"settings": settings, "cv_vaf": float(cv_vaf)})
    if H_model is not None and (effects is None or effects["gain"] < ESTABLISHED_EFFECT_GAIN):
        # an extended model whose effect did not win clearly: its structure without the effects
        shifts.append(ref - H_model)
        structures.append({"settings": {**_plain(start), "effects": []}, "cv_vaf": float(search.score(start).cv_vaf)})
    out = {"method": METHOD, "basis": D.G_i.to_dict(),
           "lags": list(range(-D.L_max, D.L_max + 1)),
           "shifts": [h.tolist() for h in shifts],
           "structures": structures,
           "n_scored": len(selection.scored)}
    leak = reflex_leak_shift(model, data)
    if leak is not None and (padded := _padded(model, leak, D)) is not None:
        out["leak"] = {"quantities": list(LEAK_QUANTITIES), "fir_s": LEAK_FIR_S, "shift": padded.tolist()}
    if _reflex_selected(model):
        out["reflex"] = _reflex_term(model, search, selection, start)
    if not getattr(model, "effects", None) and (H := _model_irf(model, D)) is not None:
        # the model's own estimate against the search's refit of its structure (module docstring)
        out["path"] = {"quantities": list(PATH_QUANTITIES), "shift": (H - ref).tolist()}
    return out


def effect_variant_shifts(search, chosen: dict, candidates: dict) -> list:
    """[(settings, CV VAF %, IRF shift)] of the chosen effects' other variants (another
    relaxation time: :data:`lpvpc.identification.selection.RELAXATION_VARIANTS`) within one standard error
    of the best of them (:func:`near_equivalent`), each refitted to the whole record in
    identify's effect search (``search``, held at the structure ``chosen`` with its effects'
    values, so its largest IRF is the structure's; ``candidates``:
    lpvpc.identification.selection.effect_candidates) minus the chosen one's; and, a single time chosen,
    the grid's times next to it whatever their score. The relaxation's time trades with K and
    the data hardly tell the times apart (virtual subject, truth 0.6 s, 100 Hz: 0.45 s chosen
    on 5 of 6 seeds, by the CV and by the in-sample fit alike, 0.01-0.04 points of VAF from
    0.6 s, consistently over folds, so one standard error did not reach it on 2 seeds, while
    K was 6-11 % apart): the time is known to the grid's resolution at best."""
    from .selection import Selection, chosen_effects, effect_key

    ref = _refit_irf(search, chosen)
    scored, neighbours = [], []
    for name in chosen_effects(chosen):
        by_value = candidates[name]
        scored += [search.score({**chosen, effect_key(name): v}) for v in by_value]
        singles = sorted((c[3]["relaxation_times"][0], v) for v, c in by_value.items()
                         if len(c[3].get("relaxation_times", ())) == 1)
        values = [v for _, v in singles]
        if chosen[effect_key(name)] in values:
            i = values.index(chosen[effect_key(name)])
            neighbours += [{**chosen, effect_key(name): values[j]} for j in (i - 1, i + 1) if 0 <= j < len(values)]
    near = near_equivalent(None, Selection(chosen=chosen, start=chosen, fold_kind="", n_folds=len(scored[0].fold_sse),
                                           scored=scored), limit=None)
    near_ids = {id(sc) for sc in near}  # (Scored holds arrays: compared by identity)
    out = [sc for sc in scored if sc.settings != chosen and (id(sc) in near_ids or sc.settings in neighbours)]
    return [(_plain(sc.settings), sc.cv_vaf, _refit_irf(search, sc.settings) - ref)
            for sc in sorted(out, key=lambda sc: -sc.cv_vaf)][:MAX_STRUCTURES]


def reflex_leak_shift(model, data, fir_s: float = LEAK_FIR_S, covariance: bool = False):
    """How far the model's IRF moves when the reflex's linear dynamics are left free.

    Both refits are one least squares on ``data`` (the record the model was identified from,
    at its rate) with the model's intrinsic columns (its lags and scheduling basis) and its
    reflex input columns (its nonlinearity's basis at its delay): once with those columns
    through the model's reflex dynamics, once through a free finite impulse response of
    ``fir_s`` s each. The IRF's difference is what the held dynamics may have put into the
    intrinsic pathway (module docstring).

    The difference is also noise: the free refit has many more reflex columns and its IRF
    is the noisier of the two. ``covariance=True`` returns that noise's covariance, a
    Hausman-style HAC estimate: each refit's IRF weights are linear in the torque, ``M y``,
    so the difference's error is ``(M_free - M_held) e`` with the free refit's residual
    ``e``, whose long-run covariance (:func:`lpvpc.models.uncertainty.long_run_covariance`,
    batches of ``lpvpc.models.uncertainty.BLOCK_LENGTH``) the residual's colour does not
    bias. It is what showed the viscosity's shift to be mostly noise (a standard deviation
    of about 20 % of the viscosity on every subject tried) and K's to be signal where K is
    biased; the intervals count the raw shift (docs/design_notes.md, "Structural
    uncertainty").

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        An identified model.
    data : lpvpc.io.PerturbationData
        The record it was identified from; joined trials are refitted trial by trial in one
        least squares.
    fir_s : float, default LEAK_FIR_S
        Length of the free reflex impulse response (s).
    covariance : bool, default False
        Also return the shift's noise covariance.

    Returns
    -------
    numpy.ndarray or None
        len(model.lags) x n_basis IRF weights (N m/rad per sample); None for a model without
        a reflex pathway or a record too short for the free refit. With ``covariance``, a
        pair (shift, covariance): the covariance is over the shift's weights flattened row by
        row (lag-major), (N m/rad per sample)^2.

    Examples
    --------
    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0)
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(d, structure="fixed")
    >>> shift = reflex_leak_shift(model, d)
    >>> shift.shape == model.H.shape, bool(np.all(np.isfinite(shift)))
    (True, True)
    >>> shift, cov = reflex_leak_shift(model, d, covariance=True)
    >>> cov.shape == (shift.size, shift.size), bool(np.all(np.diag(cov) > 0))
    (True, True)
    """
    import scipy.signal

    from ..models import equations as eq
    from ..models.uncertainty import BLOCK_LENGTH, long_run_covariance

    if model.A is None or np.size(model.A) == 0:
        return None
    n_fir = int(round(fir_s * model.fs))
    num, den = scipy.signal.ss2tf(model.A, model.B[:, None], model.C[None, :], np.array([[model.D]]))
    bounds = list(getattr(data, "segments", ()) or ()) or [(0, len(data.position))]
    Xi, Xp, Xf, y = [], [], [], []
    for a, b in bounds:
        p, rho = np.asarray(data.position[a:b], float), np.asarray(data.scheduling[a:b], float)
        U = model.reflex_input(p, rho)
        Xi.append(eq.kron_rows(eq.lagged(p, model.lags), model.intrinsic_basis.evaluate(rho)))
        Xp.append(scipy.signal.lfilter(num[0], den, U, axis=0))
        Xf.append(np.hstack([eq.lagged(U[:, j], list(range(n_fir + 1))) for j in range(U.shape[1])]))
        y.append(np.asarray(data.torque[a:b], float))
    Xi, y = np.vstack(Xi), np.concatenate(y)
    n_i = Xi.shape[1]
    H, M, e = [], [], None
    for Xr in (np.vstack(Xp), np.vstack(Xf)):
        X = np.hstack([Xi, Xr, np.ones((len(y), 1))])
        if X.shape[0] < 2 * X.shape[1]:
            return None
        Ginv = _normal_pseudo_inverse(X)
        beta = Ginv @ (X.T @ y)
        H.append(beta[:n_i].reshape(model.H.shape))
        if covariance:  # the rows of M^T: X (X^T X)^+ on the IRF's columns
            M.append(X @ Ginv[:, :n_i])
            e = y - X @ beta  # ends as the free refit's residual
    shift = H[1] - H[0]
    if not covariance:
        return shift
    block = max(1, int(round(BLOCK_LENGTH * model.fs)))
    return shift, long_run_covariance((M[1] - M[0]) * e[:, None], block)


def _normal_pseudo_inverse(X):
    """(X^T X)^+ of a least squares whose columns are scaled to unit RMS first: the free
    reflex columns are nearly collinear, so eigenvalues below 1e-12 of the largest are
    dropped (as :func:`numpy.linalg.lstsq` drops small singular values); one Gram product
    gives both the refit and its noise."""
    s = np.sqrt(np.mean(X**2, axis=0))
    s[s == 0] = 1.0
    Xs = X / s
    lam, V = np.linalg.eigh(Xs.T @ Xs)
    keep = lam > 1e-12 * lam.max()
    return ((V[:, keep] / lam[keep]) @ V[:, keep].T) / s[:, None] / s[None, :]


def _padded(model, H, D):
    """IRF weights ``H`` on the model's lags and basis, zero-padded to the search's (2 L_max +
    1, n_i max + 1) (polynomial bases on the same range nest); None when they do not fit."""
    b, G = model.intrinsic_basis, D.G_i
    L = (len(model.lags) - 1) // 2
    if (b.family, b.lo, b.hi) != (G.family, G.lo, G.hi) or b.order > G.order or L > D.L_max:
        return None
    out = np.zeros((2 * D.L_max + 1, D.ni_max + 1))
    out[D.L_max - L : D.L_max + L + 1, : b.order + 1] = H
    return out


def _model_irf(model, D):
    """The model's IRF weights in the search's lags and basis (:func:`_padded`)."""
    return _padded(model, model.H, D)


def _plain(settings) -> dict:
    return {k: (float(v) if isinstance(v, float) else v) for k, v in settings.items()}


def _reflex_selected(model) -> bool:
    """True when the model's structure was chosen by identify's cross-validation (its
    reflex settings are a selection's outcome, not the caller's or the defaults')."""
    sel = (getattr(model, "fit", None) or {}).get("structure_selection")
    return bool(sel) and "skipped" not in sel


def _reflex_term(model, search, selection, start) -> dict:
    """The ``reflex`` entry of the structural term (module docstring): the model
    structure's reflex nonlinearity refitted with the dynamics held, and the alternatives
    the selection could not exclude: the reflex scheduling basis one order higher (the
    one-standard-error rule picks the simplest structure within noise of the best, so the
    next richer one is as supported; a constant or linear reflex basis chosen on 1 kHz
    sum-of-exponentials records missed the gain's exponential trend by up to 40-86 %) and
    the near-equivalent structures that differ from the model's in
    :data:`REFLEX_SETTINGS` only."""
    D = search.design
    family = model.settings.get("velocity_basis", "chebyshev")
    alternatives = []
    if start["reflex_order"] + 1 <= D.nr_max and search.score({**start, "reflex_order": start["reflex_order"] + 1}):
        alternatives.append({**start, "reflex_order": start["reflex_order"] + 1})
    alternatives += [s.settings for s in near_equivalent(search, selection, limit=None)
                     if s.settings != start and _differs_only_in(s.settings, start, REFLEX_SETTINGS)
                     and s.settings not in alternatives][: MAX_STRUCTURES - len(alternatives)]
    return {"rho_basis": D.G_r.to_dict(), "reference": _refit_reflex(search, start, family),
            "structures": [{"settings": _plain(s), **_refit_reflex(search, s, family)} for s in alternatives]}


def add_structural_uncertainty(model, data, search=None, selection=None, effects=None):
    """Store :func:`structural_term` in ``model.uncertainty`` (the model's intrinsic
    intervals then include it) and return the model. Requires a model with intervals.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=60.0, fs_out=100.0, stiffness_family="piecewise")
    >>> d = pair_trials(sim.pt, sim.ut)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     model = identify(d, structure="fixed")  # with selection (the default) identify adds it itself
    >>> theta = np.array([-0.2, 0.0])  # rad
    >>> narrow = model.elastic_stiffness_interval(theta)
    >>> wide = add_structural_uncertainty(model, d).elastic_stiffness_interval(theta)
    >>> bool(np.all(wide.upper - wide.lower >= narrow.upper - narrow.lower))
    True
    """
    from ..errors import ModelFileError

    if not getattr(model, "uncertainty", None):  # what the interval methods would say (lpvpc.models.uncertainty
        # imports this module's constants through lpvpc.models.modelfile: its _stored cannot be called here)
        raise ModelFileError("this model carries no uncertainty (identified by an older lpvpc, whose extended models "
                             "had none, or a fit whose parameters were not all identified): re-identify it to get "
                             "intervals")
    model.uncertainty["structural"] = structural_term(model, data, search, selection, effects)
    return model
