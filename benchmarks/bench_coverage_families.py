"""Coverage of the 95 % intervals on three stiffness families of the virtual subject
(issue 22, item 3): today's ("standard", which the position basis holds), the textbook sum
of exponentials with steep ends and a piecewise-linear K with a kink (which it does not).

For each family and seed: simulate a 2-minute multilevel pair (1 kHz files, paired and
decimated as the loaders do; or 100 Hz files with ``--files-fs 100``), identify with
``structure='cv'`` and ``high_rate_reflex=True`` (from 1 kHz files the reflex nonlinearity
on the 1 kHz velocity; identify skips its selection on that path, so the structural term
runs its own search: its cost is the whole search), then add the structural term
(:func:`lpvpc.identification.structural_uncertainty.add_structural_uncertainty`). From 1 kHz files the
same record is also identified at every default (``identify(data)``: the reflex on the
model-rate velocity, selection runs): rows "defaults". Truth at 9 positions over the
central 80 % of the identified range: K at the perturbation amplitude
(SubjectParams.incremental_stiffness), the constant viscosity and inertia, reflex gain and
threshold. Where the selection chose an allowed effect (stress relaxation), the extended
model's intervals count like any other (K's is the short-range stiffness's; no family
relaxes, so the subject's K is both its short-range and its relaxed stiffness).

Rows per family, from the same fits: K, viscosity and inertia with
- "noise only": estimate +- z * HAC standard error;
- "neighbouring specifications only": bias-aware for the IRF one lag shorter (not for
  viscosity) and the basis one order higher (:func:`lpvpc.models.uncertainty.structural_bias_bound`);
- "previous rule": the last release's intervals (sum of that bound, with the shorter IRF
  for viscosity too, and the spread over every structure within one SE of the
  best cross-validated one), recomputed from the same search;
- "new intervals" (:func:`lpvpc.models.uncertainty.intrinsic_interval`): the sum of the
  neighbouring bound and the spread over the near-equivalent structures that differ from
  the model's in the intrinsic pathway only;
- the larger of the two bounds, and their root sum of squares (with the new structure set):
  the alternative combinations, recorded to show why they are not used;
and reflex gain and threshold (1 kHz path and defaults; where the selection ran, the gain also
without the reflex structures the selection could not exclude, "previous rule: no reflex
structures", to show what that term does). Coverage % pooled over seeds and
positions (a threshold "not determined by these data" has the whole fitted velocity range
as its interval: it counts as covered when the truth lies in that range; the columns "not
determined %" and "coverage where determined" separate it), seeds with every position
covered, median half-width (absolute and % of the estimate), median |error| %; the cost of
the structural term against the identification.

The rule was chosen on seeds 0-19 (both file rates); seeds 20-39 (``--first-seed 20``) are
the check.

Run: nice python benchmarks/bench_coverage_families.py [n_seeds] [--first-seed S] [--files-fs 100] [family ...]
(default 20 seeds of each family from seed 0, 1 kHz files; writes
benchmarks/results/coverage_families.txt; a run with --first-seed or --files-fs is recorded
as its own section below the default run's table)
"""

from __future__ import annotations

import copy
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.simulation.simulate import SubjectParams, simulate_pair  # noqa: E402
from lpvpc.identification.structural_uncertainty import (  # noqa: E402
    _refit_irf, add_structural_uncertainty, near_equivalent, structural_term, structure_search)
from lpvpc.simulation.subject import STIFFNESS_FAMILIES  # noqa: E402
from lpvpc.models.uncertainty import (  # noqa: E402
    _gradients_intrinsic, bias_aware_critical_value, intrinsic_interval, intrinsic_interval_parts, lag_moment_weights,
    z_value)
from _results import write_results  # noqa: E402

N_POS = 9
LEVEL = 0.95
NEW = "new intervals: neighbours + intrinsic near-equivalent structures"
PREVIOUS = "previous rule: shorter IRF for viscosity too + every near-equivalent structure"
PREVIOUS_REFLEX = "previous rule: no reflex structures (not used)"
QUANTITIES = (("K", "stiffness"), ("viscosity", "viscosity"), ("inertia", "inertia"))


def _half(bias, se):
    return bias_aware_critical_value(bias / np.maximum(se, 1e-300), LEVEL) * se


def _previous_bounds(model, search, sel, quantity, rho, est):
    """The last release's two bounds: the shorter IRF counted for every quantity, and the
    largest shift over every structure within one SE of the best (reflex settings too)."""
    from lpvpc.identification.structural_uncertainty import _start

    u = model.uncertainty
    spec = intrinsic_interval_parts(model, quantity, rho)[2]["specification"]
    if quantity == "viscosity" and u.get("truncation"):
        t = u["truncation"]
        g = _gradients_intrinsic(model, rho, lag_moment_weights(model, quantity, t["lags"]))
        spec = spec + np.abs(g @ np.asarray(t["H"], dtype=float).ravel() - est)
    start = _start(model)
    ref = _refit_irf(search, start)
    near = [s for s in near_equivalent(search, sel) if s.settings != start]
    if not near:
        return spec, np.zeros(len(rho))
    basis = search.design.G_i
    G = basis.evaluate(np.clip(rho, basis.lo, basis.hi))
    w = lag_moment_weights(model, quantity, np.arange(-search.design.L_max, search.design.L_max + 1))
    shifts = np.array([np.einsum("l,lj,rj->r", w, _refit_irf(search, s.settings) - ref, G) for s in near])
    return spec, np.abs(shifts).max(axis=0)


def _intrinsic_rows(rows, model, truth, pair, rho, prefix="", search=None, sel=None):
    for q, name in QUANTITIES:
        tr = {"K": truth.incremental_stiffness(rho, pair.truth["perturbation_amplitude"]),
              "viscosity": np.full(len(rho), truth.viscosity), "inertia": np.full(len(rho), truth.inertia)}[q]
        est, se, bias = intrinsic_interval_parts(model, name, rho)
        spec, struct = bias["specification"], bias["structures"]
        _, lo, hi = intrinsic_interval(model, name, rho, LEVEL)
        if prefix:  # the defaults: the new intervals only
            rows[f"{q}, {prefix}{NEW}"] = (est, lo, hi, tr)
            continue
        bands = {"noise only": z_value(LEVEL) * se, "neighbouring specifications only": _half(spec, se)}
        if search is not None:
            bands[PREVIOUS] = _half(sum(_previous_bounds(model, search, sel, name, rho, est)), se)
        bands[NEW] = None
        bands["larger of the two bounds (not used)"] = _half(np.maximum(spec, struct), se)
        bands["root sum of squares (not used)"] = _half(np.hypot(spec, struct), se)
        for k, half in bands.items():
            rows[f"{q}, {k}"] = (est, lo, hi, tr) if half is None else (est, est - half, est + half, tr)


def _reflex_rows(rows, model, truth, rho, label):
    gain, thr = model.reflex_gain_threshold(rho)
    g_iv, th_iv = model.reflex_gain_interval(rho), model.reflex_threshold_interval(rho)
    # the defaults choose the velocity per record: one key for every seed
    at = f"{label} (velocity chosen per record)" if label == "defaults" else f"{label} ({model.nonlinearity_fs:g} Hz velocity)"
    rows[f"reflex gain, {at}"] = (gain, *g_iv, truth.reflex_gain(rho), g_iv.determined)
    if label != "high_rate_reflex=True":  # selection ran: the same model without the reflex structures it could not exclude
        bare = copy.deepcopy(model)
        bare.uncertainty.get("structural", {}).pop("reflex", None)
        b_iv = bare.reflex_gain_interval(rho)
        rows[f"reflex gain, {at}, {PREVIOUS_REFLEX}"] = (gain, *b_iv, truth.reflex_gain(rho), b_iv.determined)
    rows[f"reflex threshold, {at}"] = (thr, *th_iv, truth.reflex_threshold(rho), th_iv.determined)


def one_seed(family, seed, files_fs=1000.0):
    truth = SubjectParams().with_stiffness_family(family)
    pair = simulate_pair("multilevel", seed=seed, fs_out=files_fs, stiffness_family=family)
    d = pair_trials(pair.pt, pair.ut)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # physiology notes on the unusual families
        t = time.perf_counter()
        model = identify(d, structure="cv", high_rate_reflex=True)  # 100 Hz files: model-rate reflex, selection runs
        t_ident = time.perf_counter() - t
        if not model.has_intervals:  # its covariance could not be computed (identify warned): not covered
            nan = float("nan")
            return {"rows": {}, "t_ident": t_ident, "t_struct": nan, "t_build": nan, "t_run": nan, "t_refit": nan,
                    "t_unc": nan, "n_near": 0, "n_scored": 0, "n_near_all": 0, "defaults_without_intervals": False,
                    "without_intervals": True, "effects": [fe.name for fe in model.effects],
                    "defaults_effects": [],
                    "selection": model.fit.get("structure_selection", {}).get("skipped", "ran")}
        t = time.perf_counter()
        if "structural" not in model.uncertainty:  # identify adds it itself when its selection ran (100 Hz files)
            add_structural_uncertainty(model, d)
        t_struct = time.perf_counter() - t
        # its parts: the search's regressor and Gram matrices, the coordinate search, the refits
        # (with identify's own search reused, on its selection path, only the refits remain)
        t = time.perf_counter()
        search, start, fixed = structure_search(model, d)
        t_build = time.perf_counter() - t
        sel = search.run(start, fixed)
        t_run = time.perf_counter() - t - t_build
        t = time.perf_counter()
        structural_term(model, d, search, sel)
        t_refit = time.perf_counter() - t
        defaults = identify(d) if getattr(d, "high_rate", None) is not None else None  # every default
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), N_POS)
    rows = {}
    _intrinsic_rows(rows, model, truth, pair, rho, search=search, sel=sel)
    _reflex_rows(rows, model, truth, rho, "high_rate_reflex=True" if defaults is not None else "every setting")
    no_intervals = defaults is not None and not defaults.has_intervals
    if no_intervals:  # its covariance could not be computed (identify warned): counted as not covered
        nan = np.full(len(rho), np.nan)
        for q, _ in QUANTITIES:
            rows[f"{q}, defaults, {NEW}"] = (nan, nan, nan, nan)
        for q in ("reflex gain", "reflex threshold", f"reflex gain, defaults (velocity chosen per record), {PREVIOUS_REFLEX}"):
            key = q if q.endswith(PREVIOUS_REFLEX) else f"{q}, defaults (velocity chosen per record)"
            rows[key] = (nan, nan, nan, nan, np.zeros(len(rho), bool))
    elif defaults is not None:
        _intrinsic_rows(rows, defaults, truth, pair, rho, prefix="defaults, ")
        _reflex_rows(rows, defaults, truth, rho, "defaults")
    st = model.uncertainty["structural"]
    return {"rows": rows, "t_ident": t_ident, "t_struct": t_struct, "t_build": t_build, "t_run": t_run,
            "t_refit": t_refit, "t_unc": model.fit["timings_s"]["uncertainty"],
            "n_near": len(st["shifts"]), "n_scored": st["n_scored"],
            "n_near_all": len([s for s in near_equivalent(search, sel) if s.settings != start]),
            "selection": model.fit.get("structure_selection", {}).get("skipped", "ran"),
            "defaults_without_intervals": bool(no_intervals), "without_intervals": False,
            # an allowed effect chosen (stress relaxation): the extended model's intervals, K's the short-range
            # stiffness's, compared with the subject's K (none of the families relaxes: short-range = relaxed)
            "effects": [fe.name for fe in model.effects],
            "defaults_effects": [fe.name for fe in defaults.effects] if defaults is not None else []}


def main(n_seeds=20, families=STIFFNESS_FAMILIES, first_seed=0, files_fs=1000.0):
    t0 = time.time()
    load0 = os.getloadavg()[0]
    opt = (f" --first-seed {first_seed}" if first_seed else "") + (f" --files-fs {files_fs:g}" if files_fs != 1000.0 else "")
    lines = [f"# Interval coverage on three stiffness families (nice python benchmarks/bench_coverage_families.py "
             f"{n_seeds}{opt}{' ' + ' '.join(families) if tuple(families) != STIFFNESS_FAMILIES else ''})", "",
             f"2-minute multilevel pairs at {files_fs:g} Hz (18 dB), model at 100 Hz, identify(structure='cv', "
             f"high_rate_reflex=True: {'the 1 kHz' if files_fs > 100 else 'the model-rate'} velocity); {n_seeds} seeds per family (seeds {first_seed}..{first_seed + n_seeds - 1}), {N_POS} positions per seed over the central 80 % "
             f"of the identified range; 95 % intervals"
             + ("; rows 'defaults': the same records identified at every default (identify(data): selection "
                "runs, the reflex velocity and the allowed effects chosen per record)" if files_fs > 100 else "")
             + (". The interval rule was chosen on seeds 0-19 (both file rates): this is the check on fresh seeds"
                if first_seed >= 20 else ". The interval rule was chosen on these seeds (0-19, both file rates)"), ""]
    if not opt:  # the main table: the commands of every section of the file first
        lines[1:1] = ["", COMMANDS]
    summary = []
    for family in families:
        results = []
        for seed in range(first_seed, first_seed + n_seeds):
            r = one_seed(family, seed, files_fs)
            results.append(r)
            cov = {k: np.mean((lo <= tr) & (tr <= hi)) for k, (est, lo, hi, tr, *_) in r["rows"].items()}
            print(f"{family} seed {seed}: " + ", ".join(f"{k} {100 * v:.0f}" for k, v in cov.items())
                  + f"; identify {r['t_ident']:.2f} s, structural {r['t_struct']:.2f} s ({r['n_near']} structures)",
                  flush=True)
        lines += [f"## {family}", "",
                  "| quantity, interval | coverage % (pooled) | seeds with all positions covered | median half-width "
                  "| median half-width % of estimate | median abs error % | not determined % | coverage % where "
                  "determined |", "|---|---|---|---|---|---|---|---|"]
        keys = next(r["rows"] for r in results if r["rows"])
        nan_row = (*(np.full(N_POS, np.nan) for _ in range(4)), np.zeros(N_POS, bool))
        for r in results:  # a model without intervals: every row not covered
            r["rows"] = {k: r["rows"].get(k, nan_row) for k in keys}
        for k in keys:
            est, lo, hi, tr = (np.concatenate([r["rows"][k][i] for r in results]) for i in range(4))
            det = np.concatenate([r["rows"][k][4] if len(r["rows"][k]) > 4 else np.ones(N_POS, bool) for r in results])
            inside = (lo <= tr) & (tr <= hi)
            per_seed = sum(bool(np.all((r["rows"][k][1] <= r["rows"][k][3]) & (r["rows"][k][3] <= r["rows"][k][2])))
                           for r in results)
            hw = (hi - lo) / 2
            lines.append(f"| {k} | {100 * inside.mean():.1f} | {per_seed}/{n_seeds} | {np.nanmedian(hw):.4g} | "
                         f"{100 * np.nanmedian(hw / np.abs(est)):.1f} | {100 * np.nanmedian(np.abs(est / tr - 1)):.1f} | "
                         f"{100 * np.mean(~det):.0f} | {f'{100 * inside[det].mean():.1f}' if det.any() else '-'} |")
            if k.endswith(NEW) or k.startswith("reflex") or k.endswith(PREVIOUS):
                summary.append(f"- {family}: {k}: {100 * inside.mean():.1f} % ({per_seed}/{n_seeds} seeds fully), "
                               f"median half-width {100 * np.nanmedian(hw / np.abs(est)):.1f} %")
        t_i = np.array([r["t_ident"] for r in results])
        t_s = np.array([r["t_struct"] for r in results])
        t_u = np.array([r["t_unc"] for r in results])
        sel = sorted({r["selection"] for r in results})
        n_none = sum(r["without_intervals"] for r in results)
        if n_none:
            summary.append(f"- {family}: identify(structure='cv', high_rate_reflex=True) gave no intervals on "
                           f"{n_none}/{n_seeds} seeds (covariance not computed): counted as not covered in every row")
        n_eff = sum(r["defaults_without_intervals"] for r in results)
        if n_eff:
            summary.append(f"- {family}: at every default no intervals on {n_eff}/{n_seeds} seeds (covariance not "
                           f"computed): counted as not covered")
        for key, label in (("effects", "identify(structure='cv', high_rate_reflex=True)"), ("defaults_effects", "every default")):
            ext = [str(seed) for seed, r in zip(range(first_seed, first_seed + n_seeds), results) if r.get(key)]
            if ext:
                summary.append(f"- {family}: at {label} the selection chose an allowed effect (stress relaxation) on "
                               f"{len(ext)}/{n_seeds} seeds ({', '.join(ext)}): their rows are the extended models' "
                               f"intervals (K: the short-range stiffness, against the subject's K, which does not relax)")
        parts = {k: np.nanmedian([r[k] for r in results]) for k in ("t_build", "t_run", "t_refit")}
        lines += ["", f"identify median {np.median(t_i):.2f} s (its interval step {1000 * np.nanmedian(t_u):.0f} ms); "
                      f"structural term median {np.nanmedian(t_s):.2f} s = {100 * np.nanmedian(t_s / t_i):.0f} % of "
                      f"identify (max {100 * np.nanmax(t_s / t_i):.0f} %); near-equivalent structures per seed median "
                      f"{np.median([r['n_near'] for r in results]):.0f} of "
                      f"{np.median([r['n_scored'] for r in results]):.0f} scored (all within one SE, reflex settings too: median "
                      f"{np.median([r['n_near_all'] for r in results]):.0f}); identify's selection: {', '.join(sel)}",
                  f"structural term's parts (medians, timed again separately): search regressor and Gram matrices "
                  f"{1000 * parts['t_build']:.0f} ms, coordinate search {1000 * parts['t_run']:.0f} ms, refits of the "
                  f"near-equivalent structures {1000 * parts['t_refit']:.0f} ms (= {100 * parts['t_refit'] / np.median(t_i):.1f} % "
                  f"of identify: the cost when identify's own search is handed over)",
                  ""]
    lines += ["## Summary", ""] + summary + [
        "", "units: K N m/rad, viscosity N m s/rad, inertia kg m^2, reflex gain N m s/rad, threshold rad/s",
        f"conditions: CPUs {os.cpu_count()}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
        f"load {load0:.1f} at the start and {os.getloadavg()[0]:.1f} at the end; wall time {(time.time() - t0) / 60:.1f} min"]
    write_results("coverage_families.txt", _merged(lines, opt.strip()), echo=True)


SECTION = "# Also recorded: "
COMMANDS = ("Commands (OPENBLAS_NUM_THREADS=1, one at a time): nice python benchmarks/bench_coverage_families.py 20 "
            "(this table: 1 kHz files, seeds 0-19); ... 20 --files-fs 100 (100 Hz files, seeds 0-19); ... 20 "
            "--first-seed 20 (1 kHz, seeds 20-39: the check); ... 20 --first-seed 20 --files-fs 100 (100 Hz, "
            "seeds 20-39: the check). Each writes its own section below.")


def _merged(lines, options):
    """The file's lines (one file, which the docs' results page shows): the default run
    replaces the main table and keeps the other runs' sections below it; a run with
    ``options`` (fresh seeds, 100 Hz files) replaces its own section and keeps the rest."""
    path = ROOT / "benchmarks" / "results" / "coverage_families.txt"
    old = path.read_text().splitlines() if path.exists() else []
    starts = [i for i, x in enumerate(old) if x.startswith(SECTION)] + [len(old)]
    head, sections = old[: starts[0]], {old[a]: old[a:b] for a, b in zip(starts, starts[1:])}
    if not options:
        return lines + [x for sec in sections.values() for x in [""] + sec]
    what = ("a check on fresh seeds (the rule was chosen on seeds 0-19)" if "--first-seed" in options
            else "files at the model's rate (identify's selection runs)")
    key = f"{SECTION}{options}: {what}"
    sections[key] = [key, ""] + ["#" + x if x.startswith("#") else x for x in lines]
    while head and not head[-1]:
        head = head[:-1]
    return (head or ["(no default run recorded yet)"]) + [x for sec in sections.values() for x in [""] + sec]


if __name__ == "__main__":
    args = sys.argv[1:]
    first = 0
    if "--first-seed" in args:  # fresh seeds: a check of the rule chosen on seeds 0..19
        i = args.index("--first-seed")
        first = int(args[i + 1])
        del args[i:i + 2]
    files_fs = 1000.0
    if "--files-fs" in args:  # 100: files at the model's rate, where identify's own selection runs
        i = args.index("--files-fs")
        files_fs = float(args[i + 1])
        del args[i:i + 2]
    n = int(args[0]) if args else 20
    main(n, tuple(args[1:]) or STIFFNESS_FAMILIES, first, files_fs)
