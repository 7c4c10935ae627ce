"""Running a study: one job per record (load, hold out, identify, predict the held-out part,
the physiology on a position grid), cached by the content of the record's files and the
settings, run serially, in a local process pool or on a Dask cluster, each record's failure
its own.

Each job (:func:`analyse_record`) is a plain function of a JSON-serialisable spec, so the
three ways of running it give the same numbers: the job pins BLAS to one thread and nothing
in it depends on the process it runs in. A job never raises: a record that cannot be loaded
or identified comes back as ``status: "failed"`` with a one-line ``reason``.

A finished record is written to the cache (``DIR/cache/KEY.json``, KEY a SHA-256 of the
files' bytes, the record's settings and the study's) as soon as it arrives, so a study that
is stopped and run again redoes only the records that had not finished, and a changed file
or setting redoes only its record. Failures are not cached: they are tried again.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import resource
import sys
import time
import traceback
import warnings

import numpy as np

__all__ = ["analyse_record", "record_key", "execute", "diagnosis_summary", "GRID_STEP", "CACHE_VERSION"]

#: rad: the spacing of the absolute position grid every record is evaluated on (multiples of
#: it within the record's identified range), so that records line up without interpolation
#: and a record's result does not depend on the others'.
GRID_STEP = 0.01
#: Changes when what a job computes changes: older cache entries are then not used.
CACHE_VERSION = 1


def _digest(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def record_key(row, study_settings: dict) -> str:
    """The cache key of one record: SHA-256 of its files' content (not their names), its own
    settings and the study's (held-out fraction, identification settings, interval level,
    grid). Raises OSError when a file cannot be read."""
    payload = {"version": CACHE_VERSION, "files": {role: _digest(getattr(row, role)) for role in ("pt", "ut", "data")
                                                   if getattr(row, role)},
               "record": row.settings(), "study": study_settings}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


def _one_line(text: str, limit: int = 400) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _reason(exc: BaseException) -> str:
    from ..errors import LpvpcError

    if isinstance(exc, FileNotFoundError):
        return f"file not found: {exc.filename}"
    if isinstance(exc, OSError):
        return _one_line(f"cannot read {exc.filename}: {exc.strerror or exc}")
    if isinstance(exc, LpvpcError):
        return _one_line(str(exc))
    return _one_line(f"{type(exc).__name__}: {exc}")


def _peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports kB)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def _structure(model) -> str:
    s = model.settings or {}
    sel = (model.fit or {}).get("structure_selection") or {}
    how = "as given" if "skipped" in sel or not sel else "chosen by cross-validation"
    return (f"IRF {len(model.lags)} lags, intrinsic order {s.get('intrinsic_order')}, reflex state order "
            f"{model.state_order}, delay {1000 * model.delay / model.fs:.0f} ms ({how})")


def _floats(a) -> list:
    return [float(x) for x in np.asarray(a, dtype=float)]


def analyse_record(spec: dict) -> dict:
    """One record's job; ``spec`` holds the manifest row's fields, ``heldout`` (fraction),
    ``identify`` (estimator settings) and ``level`` (interval level).

    Returns a JSON-serialisable dict: ``status`` ("ok" or "failed"), ``reason`` (one line,
    failed records), ``vaf_heldout`` and ``vaf_identification`` (%), ``structure``,
    ``range`` (the identified position range, rad), ``grid_index`` (integers k: positions
    k * :data:`GRID_STEP` rad inside the range) and at those positions ``stiffness``,
    ``viscosity``, ``reflex_gain``, ``reflex_threshold`` with ``*_lower`` / ``*_upper``
    (the ``level`` interval) and, for the reflex, ``*_determined`` (False: "not determined
    by these data"); ``warnings`` (the library's warnings, one line each), ``seconds``,
    ``peak_rss_mb`` (the worker process's peak so far) and ``model`` (the model's dict);
    with ``spec["diagnose"]`` also ``diagnosis`` (:func:`diagnosis_summary` of the model
    diagnosed on the held-out part).
    """
    from threadpoolctl import threadpool_limits

    start = time.perf_counter()
    out = {"record": spec["record"], "status": "failed", "reason": "", "warnings": []}
    try:
        with threadpool_limits(1), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out.update(_analyse(spec))
        out["warnings"] = sorted({_one_line(f"{w.category.__name__}: {w.message}", 300) for w in caught
                                  if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))})
        out["status"] = "ok"
    except Exception as exc:  # one record's failure is its own: reported, never raised
        out["reason"] = _reason(exc)
        if not out["reason"]:
            out["reason"] = _one_line(traceback.format_exc(limit=1))
    out["seconds"] = time.perf_counter() - start
    out["peak_rss_mb"] = _peak_rss_mb()
    out["pid"] = os.getpid()
    return out


def _analyse(spec: dict) -> dict:
    from ..identification.identify import identify
    from ..io import hold_out, load_identification_data
    from ..models.model import vaf

    kw = {k: spec[k] for k in ("torque_sign", "position_unit") if spec.get(k) is not None}
    if spec.get("data"):
        data = load_identification_data(data=spec["data"], **kw)
    else:
        data = load_identification_data(pt=spec["pt"], ut=spec.get("ut"), stationary=bool(spec.get("stationary")),
                                        **kw)
    fraction = spec["heldout"] if spec.get("heldout_row") is None else spec["heldout_row"]
    ident, held = hold_out(data, fraction)
    model = identify(ident, **(spec.get("identify") or {}))
    pred = model.predict(held)
    v_held = float(vaf(held.torque, pred.total))
    lo, hi = (float(x) for x in model.scheduling_range)
    k0, k1 = math.ceil(lo / GRID_STEP - 1e-9), math.floor(hi / GRID_STEP + 1e-9)
    ks = list(range(k0, k1 + 1)) if k1 >= k0 else [int(round(0.5 * (lo + hi) / GRID_STEP))]
    theta = np.array(ks, dtype=float) * GRID_STEP
    level = float(spec.get("level", 0.95))
    res = {"vaf_heldout": v_held, "vaf_identification": float((model.fit or {}).get("vaf", float("nan"))),
           "structure": _structure(model), "range": [lo, hi], "grid_index": ks,
           "heldout_fraction": float(fraction), "identification_s": ident.n / ident.fs, "heldout_s": held.n / held.fs}
    res["stiffness"] = _floats(model.elastic_stiffness(theta))
    res["viscosity"] = _floats(model.viscosity(theta))
    gain, thr = model.reflex_gain_threshold(theta)
    res["reflex_gain"], res["reflex_threshold"] = _floats(gain), _floats(thr)
    if model.has_intervals:
        for name, interval in (("stiffness", model.elastic_stiffness_interval(theta, level)),
                               ("viscosity", model.viscosity_interval(theta, level)),
                               ("reflex_gain", model.reflex_gain_interval(theta, level)),
                               ("reflex_threshold", model.reflex_threshold_interval(theta, level))):
            res[f"{name}_lower"], res[f"{name}_upper"] = _floats(interval[0]), _floats(interval[1])
            if name.startswith("reflex"):
                res[f"{name}_determined"] = [bool(x) for x in getattr(interval, "determined", np.ones(len(ks)))]
    else:  # no covariance: no intervals, nothing to judge "determined" by
        for name in ("stiffness", "viscosity", "reflex_gain", "reflex_threshold"):
            res[f"{name}_lower"] = res[f"{name}_upper"] = [float("nan")] * len(ks)
        res["reflex_gain_determined"] = res["reflex_threshold_determined"] = [True] * len(ks)
    if spec.get("diagnose"):
        from ..diagnosis.diagnose import diagnose
        from ..errors import LpvpcError

        try:
            res["diagnosis"] = diagnosis_summary(diagnose(model, held))
        except LpvpcError as exc:  # the model stands; only its diagnosis is missing, with the reason
            res["diagnosis"] = {"missing": None, "error": _reason(exc)}
    res["model"] = model.to_dict()
    return res


def diagnosis_summary(d) -> dict:
    """What a study keeps of a :class:`lpvpc.diagnosis.diagnose.Diagnosis` (JSON-serialisable):
    ``missing`` (the first significant candidate's effect, or None), its ``pathway``,
    ``signals``, ``vaf_gain`` (held-out pp) and ``p_value``, the names of all ``significant``
    candidates, and ``answer`` (the diagnosis' one paragraph). A record the diagnosis refuses
    (e.g. a held-out part too short) keeps its model and gets ``error`` (one line) instead."""
    top = d.top
    return {"missing": None if top is None else top.effect,
            "pathway": None if top is None else top.pathway,
            "signals": [] if top is None else list(top.signals),
            "vaf_gain": None if top is None else float(top.vaf_gain),
            "p_value": None if top is None else float(top.p_value),
            "significant": [c.effect for c in d.significant],
            "answer": _one_line(d.answer(), 600)}


# ---------------------------------------------------------------------------------------
# Running the jobs
# ---------------------------------------------------------------------------------------


def execute(specs: list, *, jobs: int = 1, scheduler=None, on_result=None) -> list:
    """Run :func:`analyse_record` on every spec and return the results in spec order.

    ``scheduler`` None: ``jobs`` == 1 runs in this process, more in a local process pool of
    ``jobs`` workers. ``scheduler`` given: a ``dask.distributed`` scheduler address (str),
    ``Client`` or cluster (e.g. ``LocalCluster``); the jobs are submitted to it.
    ``on_result(index, result)`` is called as each finishes (in the calling process), so
    that results can be saved before the others are done. A job lost with its worker (a
    crash, out of memory) comes back failed with the reason.
    """
    results = [None] * len(specs)

    def done(i, res):
        results[i] = res
        if on_result is not None:
            on_result(i, res)

    if not specs:
        return results
    if scheduler is not None:
        _dask(specs, scheduler, done)
    elif jobs <= 1 or len(specs) == 1:
        for i, spec in enumerate(specs):
            done(i, analyse_record(spec))
    else:
        _pool(specs, jobs, done)
    return results


def _lost(spec, exc) -> dict:
    return {"record": spec["record"], "status": "failed", "warnings": [], "seconds": float("nan"),
            "peak_rss_mb": float("nan"), "reason": _one_line(f"the worker running it was lost ({type(exc).__name__}: "
                                                             f"{exc})")}


def _pool(specs, jobs, done) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # fork: the workers start at once with the parent's imports (spawn re-imports numpy,
    # scipy and lpvpc in every worker); the parent runs no threads of its own here
    ctx = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else None)
    with ProcessPoolExecutor(max_workers=min(jobs, len(specs)), mp_context=ctx,
                             initializer=_worker_init) as pool:
        futures = {pool.submit(analyse_record, spec): i for i, spec in enumerate(specs)}
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                res = fut.result()
            except Exception as exc:  # BrokenProcessPool: the worker died
                res = _lost(specs[i], exc)
            done(i, res)


def _worker_init() -> None:
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _dask(specs, scheduler, done) -> None:
    from ..errors import LpvpcError

    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise LpvpcError("a Dask scheduler was given but dask.distributed is not installed "
                         "(pip install 'lpvpc[study]')") from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler) if own else scheduler
    except OSError as exc:
        raise LpvpcError(f"cannot reach the Dask scheduler {scheduler}: {_one_line(exc)}") from None
    try:
        futures = client.map(analyse_record, specs, pure=False,
                             key=[f"lpvpc-study-{s['record']}-{s['key']}" for s in specs])
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                res = fut.result()
            except Exception as exc:  # a lost worker (KilledWorker) or a cancelled job
                res = _lost(specs[i], exc)
            done(i, res)
    finally:
        if own:
            client.close()
