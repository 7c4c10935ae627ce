"""A study: a cohort of records identified in parallel, their physiology on a common grid of
positions, groups compared, one report.

:func:`run_study` reads a manifest (:mod:`lpvpc.study.manifest`), runs one job per record
(:mod:`lpvpc.study.run`: serially, in a local process pool, or on a Dask cluster; cached by
content), writes ``records.csv`` and ``groups.csv`` (:mod:`lpvpc.study.tables`) and
``report.html`` (:mod:`lpvpc.study.report`). :func:`lpvpc.study.cohort.write_cohort` writes a
virtual cohort with its manifest and truth. The guide: docs/guide/study.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from .manifest import ManifestError, ManifestRow, read_manifest

__all__ = ["run_study", "StudyResult", "read_manifest", "ManifestError", "ManifestRow", "DEFAULT_HELDOUT"]

#: The later fraction of each record held out unless its manifest row says otherwise.
DEFAULT_HELDOUT = 0.3


@dataclass
class StudyResult:
    """What :func:`run_study` did.

    Parameters
    ----------
    rows : list of lpvpc.study.manifest.ManifestRow
        The manifest.
    results : list of dict
        One per record (:func:`lpvpc.study.run.analyse_record`'s, with ``cached``).
    grid : list
        The common position grid's indices.
    computed, cached, failed : int
        Records whose job ran in this run (failed or not), records taken from the cache,
        and records that failed (a record whose files cannot be read fails before any job
        and is neither computed nor cached).
    comparisons : list, optional
        The group comparisons.
    paths : dict, optional
        The files written (records, groups, report, summary)."""

    rows: list
    results: list
    grid: list
    computed: int
    cached: int
    failed: int
    comparisons: list = field(default_factory=list)
    paths: dict = field(default_factory=dict)

    @property
    def exit_status(self) -> int:
        """0 when every record was identified, 1 when some failed."""
        return 1 if self.failed else 0

    def failures(self) -> list:
        """(record, reason) of each failed record, in manifest order."""
        return [(row.record, r["reason"]) for row, r in zip(self.rows, self.results) if r["status"] != "ok"]

    def summary_lines(self) -> list:
        """The run in lines a person reads."""
        n = len(self.rows)
        lines = [f"study: {n} records, {n - self.failed} identified, {self.failed} failed; {self.computed} "
                 f"computed, {self.cached} from the cache"]
        if self.grid:
            from .run import GRID_STEP

            lines.append(f"common range: {self.grid[0] * GRID_STEP:+.2f} .. {self.grid[-1] * GRID_STEP:+.2f} rad "
                         f"({len(self.grid)} positions)")
        lines += [f"failed: {rec}: {reason}" for rec, reason in self.failures()]
        lines += [f"{k}: {v}" for k, v in self.paths.items()]
        return lines


def _comparisons(rows, compare):
    groups = list(dict.fromkeys(row.group for row in rows))
    if compare is not None:
        ref, other = compare
        missing = [g for g in (ref, other) if g not in groups]
        if missing:
            raise ManifestError(f"compare: no group {missing[0]!r} in the manifest (groups: {', '.join(groups)})")
        return [(ref, other)]
    return [(groups[0], g) for g in groups[1:]]  # every group against the first in the manifest


def run_study(manifest, out, *, jobs: int = 1, scheduler=None, heldout: float = DEFAULT_HELDOUT,
              identify_settings: dict | None = None, level: float = 0.95, compare=None,
              report: bool = True, diagnose: bool = False) -> StudyResult:
    """Identify every record of ``manifest`` and compare the groups; write the results to ``out``.

    Parameters
    ----------
    manifest : str or pathlib.Path
        The study's CSV manifest (:mod:`lpvpc.study.manifest`; docs/guide/study.md).
    out : str or pathlib.Path
        The study folder (created): ``records.csv``, ``groups.csv``, ``report.html``,
        ``summary.json``, ``models/RECORD.json`` and ``cache/`` (kept between runs: a rerun
        redoes only the records whose files or settings changed, and those not finished).
    jobs : int
        Records identified at once in a local process pool (1: in this process).
    scheduler : str or dask.distributed.Client, optional
        Run the records on this Dask scheduler instead (``jobs`` is then ignored).
    heldout : float
        The later fraction of each record held out for the VAF (a row's ``heldout`` overrides it).
    identify_settings : dict, optional
        Estimator settings for every record (:func:`lpvpc.identify <lpvpc.identification.identify.identify>`).
    level : float
        Confidence level of every interval.
    compare : tuple of str, optional
        ``(reference, other)``: the groups to compare (difference other - reference); default: every group against
        the manifest's first.
    report : bool
        Write ``report.html``.
    diagnose : bool
        Also diagnose each model on its held-out part (which effect is missing; a row's
        ``diagnose`` overrides it): ``records.csv`` then names the missing effect.

    Returns
    -------
    StudyResult
        Its ``exit_status`` is 1 when a record failed (the others are finished all the same).

    Raises
    ------
    lpvpc.study.ManifestError
        A manifest that cannot be used (one line naming row and column), before any work.
    """
    from ..io.outputs import write_text
    from ..progress import report as progress
    from . import run, tables
    from .report import report_html

    rows = read_manifest(manifest)
    if not 0.0 < float(heldout) < 1.0:
        raise ManifestError(f"held-out fraction {heldout!r}: give a number between 0 and 1")
    comparisons = _comparisons(rows, compare)
    out = Path(out)
    cache, models = out / "cache", out / "models"
    for d in (out, cache, models):
        d.mkdir(parents=True, exist_ok=True)
    study_settings = {"heldout": float(heldout), "identify": identify_settings or {}, "level": float(level),
                      "grid_step": run.GRID_STEP, "diagnose": bool(diagnose)}
    results: list = [None] * len(rows)
    todo, specs = [], []
    for i, row in enumerate(rows):
        try:
            key = run.record_key(row, study_settings)
        except OSError as exc:
            results[i] = {"record": row.record, "status": "failed", "reason": run._reason(exc), "warnings": [],
                          "cached": False}
            continue
        entry = cache / f"{key}.json"
        if entry.is_file():
            try:
                res = json.loads(entry.read_text())
                results[i] = dict(res, record=row.record, cached=True)
                continue
            except (OSError, ValueError):
                pass  # a damaged entry is computed again
        spec = {"record": row.record, "key": key, "pt": row.pt, "ut": row.ut, "data": row.data,
                "torque_sign": row.torque_sign, "position_unit": row.position_unit, "stationary": row.stationary,
                "heldout_row": row.heldout, "heldout": float(heldout), "identify": identify_settings or {},
                "level": float(level), "diagnose": bool(diagnose) if row.diagnose is None else row.diagnose}
        todo.append(i)
        specs.append(spec)
    n_cached = sum(1 for r in results if r is not None and r.get("cached"))
    progress(f"study: {len(rows)} records; {n_cached} from the cache, {len(specs)} to identify"
             + (f" on {scheduler if isinstance(scheduler, str) else 'the Dask cluster'}" if scheduler is not None
                else f" with {max(1, int(jobs))} worker{'s' if jobs > 1 else ''}"))
    finished = [0]

    def on_result(j, res):
        i = todo[j]
        model = res.pop("model", None)
        res["cached"] = False
        if res["status"] == "ok":
            write_text(models / f"{rows[i].record}.json", json.dumps(model))
            write_text(cache / f"{specs[j]['key']}.json", json.dumps(res))
        results[i] = res
        finished[0] += 1
        what = (f"held-out VAF {res['vaf_heldout']:.1f} %" if res["status"] == "ok" else f"failed: {res['reason']}")
        progress(f"study: {finished[0]}/{len(specs)} {rows[i].record}: {what} ({res.get('seconds', float('nan')):.1f} s)")

    run.execute(specs, jobs=max(1, int(jobs)), scheduler=scheduler, on_result=on_result)
    grid = tables.common_grid(results)
    rec_rows = tables.records_rows(results, rows, grid)
    grp_rows = tables.group_rows(results, rows, grid, comparisons, level)
    paths = {"records": tables.write_csv(out / "records.csv", rec_rows, tables.RECORD_COLUMNS),
             "groups": tables.write_csv(out / "groups.csv", grp_rows, tables.GROUP_COLUMNS)}
    computed = len(specs)
    failed = sum(1 for r in results if r["status"] != "ok")
    res = StudyResult(rows=rows, results=results, grid=grid, computed=computed, cached=n_cached, failed=failed,
                      comparisons=comparisons, paths=paths)
    if report:
        paths["report"] = write_text(out / "report.html", report_html(
            results, rows, grid, grp_rows, comparisons, counts={"computed": computed, "cached": n_cached},
            title=f"lpvpc study: {Path(manifest).name}"))
    summary = {"records": len(rows), "identified": len(rows) - failed, "failed": failed, "computed": computed,
               "cached": n_cached, "failures": [{"record": r, "reason": why} for r, why in res.failures()],
               "common_range": [grid[0] * run.GRID_STEP, grid[-1] * run.GRID_STEP] if grid else None,
               "comparisons": [f"{o} - {r}" for r, o in comparisons],
               "workers": [{"record": row.record, "pid": r.get("pid"), "peak_rss_mb": r.get("peak_rss_mb"),
                            "seconds": r.get("seconds")} for row, r in zip(rows, results)]}
    paths["summary"] = write_text(out / "summary.json", json.dumps(summary, indent=1))
    return res
