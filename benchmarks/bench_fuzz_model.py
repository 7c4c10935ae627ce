"""Fuzz benchmark of the model loader (lpvpc.models.modelfile): random mutations of a real model file.

    python benchmarks/bench_fuzz_model.py [--model model.json] [--cases 5000] [--seed 0] [--no-limits]

Without ``--model`` it identifies a model from the virtual subject (seed 0, 60 s
multilevel record at 100 Hz) and an extended model with every catalog effect (fuzzed with
half as many cases). Each case mutates the model's JSON tree (a value replaced
by a hostile one, a key deleted, a list grown, shrunk or duplicated, a container's type
changed, a number scaled) or its text (truncated, a byte flipped or inserted), writes it
to a file and loads it with ``LPVPCModel.load`` (the path every command takes). A case
passes when it either loads, and then predicts a finite torque on a short record, or is
refused with a one-line :class:`~lpvpc.errors.ModelFileError`; anything else (another
exception, a multi-line message, a non-finite prediction) is counted as a traceback.

It then measures what the largest model the limits let through costs (:mod:`lpvpc.models.modelfile`:
MAX_LAG, MAX_DELAY, MAX_BASIS_ORDER, MAX_STATE_ORDER at 1 kHz): the CasADi and FMU export
times of both variants, and the peak memory (tracemalloc) of predicting a 5-minute record
with it, in blocks (the default) and as one block (what prediction did before).
Prints a table and writes it to ``benchmarks/results/fuzz_model.txt``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.errors import ModelFileError  # noqa: E402
from lpvpc.models.model import LPVPCModel  # noqa: E402
from _results import write_results  # noqa: E402

HOSTILE_VALUES = [0, -1, 1, 2, 3.9, -0.5, 1e300, -1e308, 1e-320, math.inf, -math.inf, math.nan, True, False, None,
                  "", "x", "rad", "deg", "chebyshev", "hinge", "linear", [], {}, [[]], [0.0], [[1.0, 2.0]],
                  10**9, -10**9, 2**63, 10**400, 100_000, 0.0, 1.0, -1.0]


def _paths(tree, prefix=()):
    """Every (path, value) in a JSON tree."""
    out = [(prefix, tree)]
    if isinstance(tree, dict):
        for k, v in tree.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out += _paths(v, prefix + (i,))
    return out


def _mutate_tree(d, rng):
    paths = [p for p, _ in _paths(d) if p]
    path = paths[rng.integers(len(paths))]
    parent = d
    for k in path[:-1]:
        parent = parent[k]
    key, value = path[-1], parent[path[-1]]
    op = rng.integers(9)
    if op == 0:
        parent[key] = HOSTILE_VALUES[rng.integers(len(HOSTILE_VALUES))]
    elif op == 1 and isinstance(parent, dict):
        del parent[key]
    elif op == 2 and isinstance(value, (int, float)) and not isinstance(value, bool):
        parent[key] = value * float(10.0 ** rng.uniform(-12, 12)) * (-1 if rng.random() < 0.3 else 1)
    elif op == 3 and isinstance(value, list):
        n = int(rng.choice([1, 2, 10, 1000, 50_000]))
        filler = value[-1] if value else 0.0
        value.extend(copy.deepcopy(filler) for _ in range(n))
    elif op == 4 and isinstance(value, list) and value:
        del value[rng.integers(len(value)):]
    elif op == 5 and isinstance(value, list) and value:
        value.insert(rng.integers(len(value)), copy.deepcopy(value[rng.integers(len(value))]))
    elif op == 6 and isinstance(value, list):
        parent[key] = {str(i): v for i, v in enumerate(value)}
    elif op == 7 and isinstance(value, (int, float)) and not isinstance(value, bool):
        parent[key] = value + int(rng.choice([-1, 1, 10**6]))
    elif op == 8:
        parent[key] = f"__DEEP_{int(rng.choice([10, 40, 1000, 100_000]))}__"  # nested lists, put in as text
    else:
        parent[key] = HOSTILE_VALUES[rng.integers(len(HOSTILE_VALUES))]
    return d


def _mutate_text(text, rng):
    op = rng.integers(3)
    i = int(rng.integers(len(text)))
    if op == 0:
        return text[:i]
    if op == 1:
        return text[:i] + chr(int(rng.integers(32, 127))) + text[i + 1:]
    return text[:i] + "[{\"}],:0e9-"[rng.integers(11)] + text[i:]


def _record(n=300, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    position = 0.03 * np.sign(np.sin(2 * np.pi * t / 37.0)) + 0.002 * rng.standard_normal(n)
    scheduling = -0.1 + 0.2 * np.sin(2 * np.pi * t / n)
    return position, scheduling


def _signals(model, n):
    return {s: np.linspace(0.0, 1.0, n) for s in model.signals}


def fuzz(base: dict, n_cases: int = 5000, seed: int = 0) -> dict:
    """Run ``n_cases`` mutations of the model dict ``base``; returns counts, the slowest
    case (s) and the failures (case index, mutation, message)."""
    rng = np.random.default_rng(seed)
    position, scheduling = _record()
    base_text = json.dumps(base)
    out = {"cases": n_cases, "loaded": 0, "refused": 0, "tracebacks": [], "slowest_s": 0.0}
    with tempfile.TemporaryDirectory(prefix="lpvpc-fuzz-") as tmp:
        path = Path(tmp) / "model.json"
        for case in range(n_cases):
            if rng.random() < 0.2:
                text, what = _mutate_text(base_text, rng), "text"
            else:
                d = copy.deepcopy(base)
                for _ in range(int(rng.integers(1, 4))):
                    d = _mutate_tree(d, rng)
                text, what = json.dumps(d), "tree"
                while "\"__DEEP_" in text:
                    i = text.index("\"__DEEP_")
                    j = text.index("__\"", i + 8)
                    depth = int(text[i + 8:j])
                    text = text[:i] + "[" * depth + "]" * depth + text[j + 3:]
            path.write_text(text)
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    model = LPVPCModel.load(path)
                    pred = model.predict(position, scheduling, signals=_signals(model, len(position)))
                    pred_c = model.predict(position, scheduling, causal=True, signals=_signals(model, len(position)))
                if not (np.all(np.isfinite(pred.total)) and np.all(np.isfinite(pred_c.total))):
                    out["tracebacks"].append((case, what, "loaded, but the prediction is not finite"))
                else:
                    out["loaded"] += 1
            except ModelFileError as exc:
                if "\n" in str(exc) or not str(exc):
                    out["tracebacks"].append((case, what, f"refused, not in one line: {str(exc)[:200]!r}"))
                else:
                    out["refused"] += 1
            except Exception:  # noqa: BLE001 - the point is to catch everything else
                out["tracebacks"].append((case, what, traceback.format_exc(limit=3)[-600:]))
            out["slowest_s"] = max(out["slowest_s"], time.perf_counter() - t0)
    return out


def limits_model(base: dict) -> dict:
    """``base`` grown to every limit of lpvpc.models.modelfile (a stable reflex, small coefficients)."""
    from lpvpc.models import modelfile as mf

    d = copy.deepcopy(base)
    rng = np.random.default_rng(0)
    L, o, m = mf.MAX_LAG, mf.MAX_BASIS_ORDER, mf.MAX_STATE_ORDER
    d["fs"] = 1000.0
    d.pop("effects", None)
    d["format_version"] = 1
    # the largest intrinsic order for which all coefficients stay within MAX_COEFFICIENTS
    rest = (o + 1) ** 2 + m * m + 2 * m + 1
    oi = min(o, (mf.MAX_COEFFICIENTS - rest) // ((2 * L + 1) + (L + 5)) - 1)
    d["intrinsic"].update(lags=list(range(-L, L + 1)), causal_lags=list(range(0, L + 3)),
                          H=(0.01 * rng.standard_normal((2 * L + 1, oi + 1))).tolist(),
                          H_causal=(0.01 * rng.standard_normal((L + 5, oi + 1))).tolist())
    d["intrinsic"]["basis"]["order"] = oi
    d["reflex"].update(delay=mf.MAX_DELAY, Omega=(0.01 * rng.standard_normal((o + 1, o + 1))).tolist(),
                       A=(np.diag(np.full(m, 0.5)) + np.diag(np.full(m - 1, 0.1), 1)).tolist(),
                       B=[0.1] * m, C=[1.0] + [0.0] * (m - 1))
    d["reflex"]["velocity_basis"]["order"] = o
    d["reflex"]["rho_basis"]["order"] = o
    return d


def at_the_limits(base: dict, minutes: float = 5.0) -> list:
    """Table lines: export times and prediction memory of :func:`limits_model`."""
    import tracemalloc

    from lpvpc.models import equations as eq
    from lpvpc.export import exporter as export
    from lpvpc.models.model import LPVPCModel

    model = LPVPCModel.from_dict(limits_model(base), "limits model")
    lines = [f"{'model at the limits':>28}: {len(model.lags)} lags, causal lags 0..{max(model.causal_lags)}, delay "
             f"{model.delay} samples, basis orders {model.intrinsic_basis.order} (intrinsic) and "
             f"{model.velocity_basis.order}, state order {model.state_order}, "
             f"{sum(a.size for a in (model.H, model.H_causal, model.Omega, model.A, model.B, model.C)) + 1} "
             f"coefficients in the file, at {model.fs:g} Hz"]
    ordinary = LPVPCModel.from_dict(base, "base model")
    with tempfile.TemporaryDirectory() as tmp:
        for variant in ("causal", "exact"):
            times = []
            for m in (ordinary, model):
                t0 = time.perf_counter()
                export.export_casadi(m, Path(tmp) / f"{variant}.casadi", variant=variant)
                t1 = time.perf_counter()
                export.export_fmu(m, Path(tmp) / f"{variant}.fmu", variant=variant)
                times.append((t1 - t0, time.perf_counter() - t1))
            (c0, f0), (c1, f1) = times
            lines.append(f"{'export ' + variant:>28}: CasADi {c1:.2f} s, FMU {f1:.2f} s at the limits; the "
                         f"ordinary model {c0:.2f} s, {f0:.2f} s (FMU x{f1 / f0:.1f})")
    n = int(minutes * 60 * model.fs)
    position, scheduling = _record(n)
    scheduling = np.clip(scheduling, -0.3, 0.1)
    for label, cells in (("in blocks (default)", eq.BLOCK_CELLS), ("one block (before)", 10**12)):
        saved, eq.BLOCK_CELLS = eq.BLOCK_CELLS, cells
        try:
            tracemalloc.start()
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model.predict(position, scheduling)
            elapsed = time.perf_counter() - t0
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
            eq.BLOCK_CELLS = saved
        lines.append(f"{'predict ' + label:>28}: peak {peak / 2**20:.0f} MB, {elapsed:.2f} s for {n} samples "
                     f"({minutes:g} min at {model.fs:g} Hz)")
    return lines


def _virtual_subject_model(tmp, effects=False):
    """The virtual subject's model; ``effects``: an extended model with every catalog effect
    (from a subject with drift and background activation)."""
    from lpvpc.io import load_identification_data, write_trial_csv
    from lpvpc.models.effects import CATALOG
    from lpvpc.identification.identify import LPVPCEstimator
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=0, duration=60.0,
                         effects=("drift", "background_activation") if effects else ())
    pt, ut = Path(tmp) / "PT.csv", Path(tmp) / "UT.csv"
    write_trial_csv(pair.pt, pt)
    write_trial_csv(pair.ut, ut)
    est = LPVPCEstimator(effects=tuple(CATALOG) if effects else ())
    return est.fit(load_identification_data(pt=pt, ut=ut)).model_.to_dict()


def _table(title, r, elapsed) -> list:
    return [
        title,
        f"{'cases':>28}: {r['cases']}",
        f"{'loaded (finite prediction)':>28}: {r['loaded']}",
        f"{'refused in one line':>28}: {r['refused']}",
        f"{'tracebacks / other failures':>28}: {len(r['tracebacks'])}",
        f"{'slowest case':>28}: {r['slowest_s'] * 1000:.0f} ms (load + two predictions of 300 samples)",
        f"{'total':>28}: {elapsed:.1f} s",
    ] + [line for case, what, msg in r["tracebacks"][:10] for line in ("", f"case {case} ({what}):", msg)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", help="model file to mutate (default: identified from the virtual subject)")
    ap.add_argument("--cases", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "fuzz_model.txt"))
    ap.add_argument("--no-limits", action="store_true", help="skip the export and prediction at the limits")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.model:
            models = {args.model: json.loads(Path(args.model).read_text())}
        else:
            models = {"virtual subject, seed 0, 60 s at 100 Hz": _virtual_subject_model(tmp),
                      "the same with every catalog effect (extended model)": _virtual_subject_model(tmp, True)}
    lines = ["Fuzz benchmark of the model loader (benchmarks/bench_fuzz_model.py)",
             f"seed {args.seed}; load average {os.getloadavg()[0]:.1f}"]
    failures = 0
    for k, (name, base) in enumerate(models.items()):
        n = args.cases if k == 0 else max(1, args.cases // 2)
        t0 = time.perf_counter()
        r = fuzz(base, n, args.seed + k)
        failures += len(r["tracebacks"])
        lines += ["", *_table(f"model: {name}", r, time.perf_counter() - t0)]
    if not args.no_limits:
        lines += ["", *at_the_limits(next(iter(models.values())))]
    write_results(Path(args.out), lines, echo=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
