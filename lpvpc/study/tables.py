"""The study's tables: ``records.csv`` (one row per record and position of the common grid)
and ``groups.csv`` (per quantity and position, each group's mean over subjects with its
interval, and the difference between groups with its interval).

Statistics. The unit is the subject: a subject's sessions (records) are averaged first, and
the group's mean and interval are over its subjects' values, a t interval
``mean +- t_{n-1} s / sqrt(n)``. The difference of two groups (``other - reference``) has
Welch's interval ``d +- t_nu sqrt(s_a^2/n_a + s_b^2/n_b)`` with the Welch-Satterthwaite
degrees of freedom, which does not assume equal variances, when the groups hold different
subjects. When subjects were recorded in both groups (a within-subject design: before and
after an intervention, two conditions), the comparison is paired: a t interval of the
subjects' own differences, over the subjects in both (those in one group only do not enter
it; ``design`` says how many pairs). A reflex value
"not determined by these data" is left out of its subject's mean; a subject with none left
at a position does not count there (``n`` says how many did). The records' own intervals do
not enter: the spread between subjects already holds their estimation error.
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np
from scipy import stats

from .run import GRID_STEP

__all__ = ["QUANTITIES", "common_grid", "records_rows", "group_rows", "write_csv", "t_interval", "welch_interval",
           "compare_groups"]

#: Quantities compared along the position grid: name -> unit.
QUANTITIES = {"stiffness": "N m/rad", "viscosity": "N m s/rad", "reflex_gain": "N m s/rad",
              "reflex_threshold": "rad/s"}
NOT_DETERMINED = "not determined"


def t_interval(values, level: float = 0.95):
    """(mean, lower, upper, sd, n) of a t interval for the mean of ``values`` (NaN bounds for
    fewer than two values).

    >>> m, lo, hi, sd, n = t_interval([1.0, 2.0, 3.0])
    >>> m, round(lo, 4), round(hi, 4), n
    (2.0, -0.4841, 4.4841, 3)
    """
    x = np.asarray(values, dtype=float)
    n = len(x)
    if n == 0:
        return (math.nan,) * 4 + (0,)
    m = float(x.mean())
    if n < 2:
        return m, math.nan, math.nan, math.nan, n
    sd = float(x.std(ddof=1))
    h = float(stats.t.ppf(0.5 + level / 2, n - 1)) * sd / math.sqrt(n)
    return m, m - h, m + h, sd, n


def welch_interval(a, b, level: float = 0.95):
    """(difference mean(b) - mean(a), lower, upper, degrees of freedom) of Welch's interval.

    >>> d, lo, hi, df = welch_interval([1.0, 2.0, 3.0], [3.0, 4.0, 5.0, 6.0])
    >>> d, round(lo, 3), round(hi, 3), round(df, 2)
    (2.5, 0.268, 4.732, 4.96)
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if len(a) < 2 or len(b) < 2:
        d = float(b.mean() - a.mean()) if len(a) and len(b) else math.nan
        return d, math.nan, math.nan, math.nan
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    d = float(b.mean() - a.mean())
    se = math.sqrt(va + vb)
    if se == 0.0:
        return d, d, d, math.inf
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    h = float(stats.t.ppf(0.5 + level / 2, df)) * se
    return d, d - h, d + h, float(df)


def compare_groups(ref: dict, other: dict, level: float = 0.95) -> dict:
    """The difference ``other - reference`` of two groups' subject values ({subject: value}):
    paired when at least two subjects are in both (a within-subject design), else Welch's.

    Returns {"mean", "lower", "upper", "df", "n_subjects", "design"}.

    >>> r = compare_groups({"S1": 1.0, "S2": 2.0, "S3": 4.0}, {"S1": 2.0, "S2": 3.5, "S3": 4.5})
    >>> r["design"], r["mean"], round(r["lower"], 3), round(r["upper"], 3)
    ('paired (3 subjects)', 1.0, -0.242, 2.242)
    """
    both = [s for s in ref if s in other]
    if len(both) >= 2:
        m, lo, hi, _, n = t_interval([other[s] - ref[s] for s in both], level)
        alone = len(ref) + len(other) - 2 * len(both)
        return {"mean": m, "lower": lo, "upper": hi, "df": n - 1, "n_subjects": f"{n} pairs",
                "design": f"paired ({n} subjects)" + (f"; {alone} in one group only left out" if alone else "")}
    a, b = list(ref.values()), list(other.values())
    d, lo, hi, df = welch_interval(a, b, level)
    return {"mean": d, "lower": lo, "upper": hi, "df": df, "n_subjects": f"{len(b)}+{len(a)}",
            "design": "independent groups (Welch)"}


def common_grid(results) -> list:
    """Grid indices k (positions k * GRID_STEP rad) inside every successful record's
    identified range: the range all records share (empty when they share none)."""
    ok = [r for r in results if r["status"] == "ok"]
    if not ok:
        return []
    k0 = max(min(r["grid_index"]) for r in ok)
    k1 = min(max(r["grid_index"]) for r in ok)
    return list(range(k0, k1 + 1))


def _at(r, name, k):
    i = k - r["grid_index"][0]
    return r[name][i]


def _fmt(x) -> str:
    if x is None:
        return ""
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, float):
        return "" if math.isnan(x) else repr(x)
    return str(x)


RECORD_COLUMNS = ["record", "subject", "group", "status", "reason", "theta", "stiffness", "stiffness_lower",
                  "stiffness_upper", "viscosity", "viscosity_lower", "viscosity_upper", "reflex_gain",
                  "reflex_gain_lower", "reflex_gain_upper", "reflex_gain_status", "reflex_threshold",
                  "reflex_threshold_lower", "reflex_threshold_upper", "reflex_threshold_status", "vaf_heldout",
                  "vaf_identification", "structure", "range_lower", "range_upper", "missing_effect", "cached"]


def records_rows(results, rows, grid) -> list:
    """One dict per record and common-grid position (RECORD_COLUMNS; a failed record: one
    row with its reason). A reflex value not determined by the data has empty value and
    interval cells and ``*_status`` "not determined". ``missing_effect``: the diagnosis'
    first significant effect, "none", "not diagnosed" (the diagnosis refused the held-out part:
    the reason is in the report and summary.json), or empty when not asked."""
    out = []
    for row, r in zip(rows, results):
        base = {"record": row.record, "subject": row.subject, "group": row.group, "status": r["status"],
                "reason": r.get("reason", ""), "cached": r.get("cached", False)}
        if r["status"] != "ok":
            out.append(base)
            continue
        base.update(vaf_heldout=r["vaf_heldout"], vaf_identification=r["vaf_identification"],
                    structure=r["structure"], range_lower=r["range"][0], range_upper=r["range"][1],
                    missing_effect=_missing(r))
        for k in grid:
            line = dict(base, theta=round(k * GRID_STEP, 10))
            for q in QUANTITIES:
                vals = [_at(r, n, k) for n in (q, f"{q}_lower", f"{q}_upper")]
                if q.startswith("reflex"):
                    det = _at(r, f"{q}_determined", k)
                    line[f"{q}_status"] = "determined" if det else NOT_DETERMINED
                    if not det:
                        vals = [None] * 3
                line.update(zip((q, f"{q}_lower", f"{q}_upper"), vals))
            out.append(line)
    return out


def _missing(r) -> str:
    d = r.get("diagnosis")
    if d is None:
        return ""
    return "not diagnosed" if d.get("error") else (d["missing"] or "none")


def subject_values(results, rows, quantity, k) -> dict:
    """{group: {subject: mean over its sessions}} of ``quantity`` at grid index ``k``
    (``quantity`` "vaf_heldout": position-free, ``k`` ignored)."""
    per = {}
    for row, r in zip(rows, results):
        if r["status"] != "ok":
            continue
        if quantity == "vaf_heldout":
            v = r["vaf_heldout"]
        else:
            if quantity.startswith("reflex") and not _at(r, f"{quantity}_determined", k):
                continue
            v = _at(r, quantity, k)
        per.setdefault(row.group, {}).setdefault(row.subject, []).append(v)
    return {g: {s: float(np.mean(v)) for s, v in subj.items()} for g, subj in per.items()}


GROUP_COLUMNS = ["quantity", "unit", "theta", "group", "n_subjects", "mean", "lower", "upper", "sd", "df", "design"]


def group_rows(results, rows, grid, comparisons, level: float = 0.95) -> list:
    """groups.csv's rows (GROUP_COLUMNS): per quantity and grid position, each group's mean
    over subjects with its t interval, then each comparison ``(reference, other)`` as group
    "other - reference" with :func:`compare_groups`' interval (paired for subjects in both
    groups, Welch's otherwise; ``design`` says which)."""
    groups = list(dict.fromkeys(row.group for row in rows))
    out = []
    plan = [(q, k) for q in QUANTITIES for k in grid] + [("vaf_heldout", None)]
    for q, k in plan:
        vals = subject_values(results, rows, q, k)
        theta = "" if k is None else round(k * GRID_STEP, 10)
        unit = QUANTITIES.get(q, "%")
        for g in groups:
            m, lo, hi, sd, n = t_interval(list(vals.get(g, {}).values()), level)
            out.append({"quantity": q, "unit": unit, "theta": theta, "group": g, "n_subjects": n, "mean": m,
                        "lower": lo, "upper": hi, "sd": sd, "df": n - 1 if n else ""})
        for ref, other in comparisons:
            c = compare_groups(vals.get(ref, {}), vals.get(other, {}), level)
            out.append(dict(c, quantity=q, unit=unit, theta=theta, group=f"{other} - {ref}", sd=""))
    return out


def csv_text(rows, columns) -> str:
    """The rows as CSV text (floats written exactly, empty cells for NaN and None)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_fmt(r.get(c)) for c in columns])
    return buf.getvalue()


def write_csv(path, rows, columns):
    """Write the rows as CSV atomically; returns the path."""
    from ..io.outputs import write_text

    return write_text(path, csv_text(rows, columns))
