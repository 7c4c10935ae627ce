"""The study report: one self-contained HTML file (figures as inlined PNGs) with K(theta)
and the reflex gain of every subject over its group's mean and interval, the group
difference along the joint angle with its interval, the held-out VAF of every record, each
record's own identified range, and the failed records with their reasons.
"""

from __future__ import annotations

import base64
import html
import io

import numpy as np

from .run import GRID_STEP
from .tables import QUANTITIES, subject_values

__all__ = ["report_html"]

_LABEL = {"stiffness": "elastic stiffness K", "viscosity": "viscosity B", "reflex_gain": "reflex gain",
          "reflex_threshold": "reflex threshold"}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return f'<img alt="figure" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def _by_quantity(group_rows, quantity, group):
    sel = [r for r in group_rows if r["quantity"] == quantity and r["group"] == group]
    return (np.array([r["theta"] for r in sel], dtype=float),
            *(np.array([r[c] for r in sel], dtype=float) for c in ("mean", "lower", "upper")))


def _subjects_figure(results, rows, grid, group_rows, quantity, groups):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    theta = np.array(grid, dtype=float) * GRID_STEP
    for gi, g in enumerate(groups):
        c = colours[gi % len(colours)]
        per = [subject_values(results, rows, quantity, k).get(g, {}) for k in grid]
        for s in sorted({s for p in per for s in p}):
            ax.plot(theta, [p.get(s, np.nan) for p in per], color=c, lw=0.7, alpha=0.45)
        t, m, lo, hi = _by_quantity(group_rows, quantity, g)
        ax.fill_between(t, lo, hi, color=c, alpha=0.25, lw=0)
        ax.plot(t, m, color=c, lw=2.2, label=f"{g}: mean and 95 % interval over subjects")
    ax.set_xlabel("joint angle (rad, + dorsiflexion)")
    ax.set_ylabel(f"{_LABEL[quantity]} ({QUANTITIES[quantity]})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _png(fig)


def _difference_figure(group_rows, comparisons):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, q in zip(axes, ("stiffness", "reflex_gain")):
        for ref, other in comparisons:
            t, m, lo, hi = _by_quantity(group_rows, q, f"{other} - {ref}")
            ax.fill_between(t, lo, hi, alpha=0.3, lw=0)
            ax.plot(t, m, lw=2, label=f"{other} - {ref} (95 % interval)")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel("joint angle (rad)")
        ax.set_ylabel(f"difference of {_LABEL[q]} ({QUANTITIES[q]})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _png(fig)


def _vaf_figure(results, rows):
    import matplotlib.pyplot as plt

    ok = [(row.record, r["vaf_heldout"]) for row, r in zip(rows, results) if r["status"] == "ok"]
    fig, ax = plt.subplots(figsize=(max(5, 0.28 * len(ok) + 2), 3.2))
    ax.bar(range(len(ok)), [v for _, v in ok])
    ax.set_xticks(range(len(ok)), [n for n, _ in ok], rotation=90, fontsize=7)
    ax.set_ylabel("held-out VAF (%)")
    ax.set_ylim(min([0.0] + [v for _, v in ok]), 100)
    ax.grid(axis="y", alpha=0.3)
    return _png(fig)


def _table(header, body) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in body)
    return f"<table><tr>{head}</tr>{rows}</table>"


def _missing_text(r) -> str:
    d = r.get("diagnosis")
    if d is None:
        return "not asked"
    if d.get("error"):
        return f"not diagnosed: {d['error']}"
    if d["missing"] is None:
        return "none found"
    return f"{d['missing']} ({d['pathway']} pathway, +{d['vaf_gain']:.2f} pp)"


def report_html(results, rows, grid, group_rows, comparisons, *, counts: dict, title: str = "lpvpc study") -> str:
    """The report as one HTML string (no external files)."""
    groups = list(dict.fromkeys(row.group for row in rows))
    ok = [r for r in results if r["status"] == "ok"]
    failed = [(row, r) for row, r in zip(rows, results) if r["status"] != "ok"]
    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>{len(rows)} records of {len({row.subject for row in rows})} subjects in {len(groups)} groups "
             f"({', '.join(map(html.escape, groups))}): {len(ok)} identified, {len(failed)} failed; "
             f"{counts.get('computed', 0)} computed in this run, {counts.get('cached', 0)} taken from the cache.</p>"]
    if failed:
        parts.append("<h2>Failed records</h2>" + _table(["record", "subject", "group", "reason"],
                                                      [(row.record, row.subject, row.group, r["reason"])
                                                       for row, r in failed]))
    if grid:
        lo, hi = grid[0] * GRID_STEP, grid[-1] * GRID_STEP
        parts.append(f"<h2>Positions compared</h2><p>The range every identified record shares: {lo:+.2f} to "
                     f"{hi:+.2f} rad ({len(grid)} positions, {GRID_STEP:g} rad apart). Each record's own "
                     "identified range is in the table of records below. Group means are over subjects (a "
                     "subject's sessions averaged first), 95 % t intervals; differences have a 95 % interval, "
                     "paired over the subjects recorded in both groups, else Welch's. Reflex values not "
                     "determined by a record's data are left out.</p>")
        for q in ("stiffness", "reflex_gain"):
            parts.append(f"<h2>{_LABEL[q].capitalize()} per subject</h2>"
                         + _subjects_figure(results, rows, grid, group_rows, q, groups))
        if comparisons:
            parts.append("<h2>Group difference along the joint angle</h2>" + _difference_figure(group_rows, comparisons))
    elif ok:
        parts.append("<h2>Positions compared</h2><p>The identified records share no position range: no "
                     "comparison along the angle is possible (see each record's range below).</p>")
    if ok:
        parts.append("<h2>Held-out VAF per record</h2>" + _vaf_figure(results, rows))
        diagnosed = any(r.get("diagnosis") is not None for r in ok)
        parts.append("<h2>Records</h2>" + _table(
            ["record", "subject", "group", "held-out VAF %", "identified range (rad)", "structure"]
            + (["missing effect (diagnosis)"] if diagnosed else []) + ["cached"],
            [(row.record, row.subject, row.group, f"{r['vaf_heldout']:.1f}",
              f"{r['range'][0]:+.3f} .. {r['range'][1]:+.3f}", r["structure"])
             + ((_missing_text(r),) if diagnosed else ()) + ("yes" if r.get("cached") else "no",)
             for row, r in zip(rows, results) if r["status"] == "ok"]))
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px;"
             "text-align:left}img{max-width:100%}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
