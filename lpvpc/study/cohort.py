"""A virtual cohort for a study: subjects of the population of virtual subjects
(:mod:`lpvpc.simulation.population`) in two groups, with a known difference between the
groups (or none: a null cohort), written as files with their manifest and truth.

Each subject is the population's subject of its seed with an exponential K(theta) (its
dorsiflexion exponential is what the stiffness effect scales) and no extra effect. In the
second group ("patient") the dorsiflexion part of K(theta) is multiplied by
``stiffness_factor`` (K x1.5 toward dorsiflexion by default: the constant part is unchanged)
and the reflex gain by ``reflex_factor`` (x2) at every position. In the default
between-subject design, subjects alternate between the groups, so both groups draw from the
same population; in a within-subject design (``design="within"``) every subject is recorded
in both conditions (two sessions with independent noise), as in a before/after study.

The true difference of the group means (``truth.json``, "difference") is that of the
population means, from the population's ranges (:data:`lpvpc.simulation.population.RANGES`),
in closed form: the ranges are independent uniform draws, so for the stiffness
``(f - 1) E[k_df_end - k_min] E[exp(r (theta - 0.2))]`` with ``r`` uniform on its range, and
for the reflex gain ``(g - 1) E[g_pf] E[ratio^s(theta)]``. This is what a study's 95 %
interval for the difference should cover; ``truth.json`` also holds each subject's curves.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["write_cohort", "true_difference", "GROUPS"]

#: The cohort's groups: the reference and the one with the difference.
GROUPS = ("control", "patient")


def _mean_uniform(name):
    from ..simulation.population import RANGES

    lo, hi, _, how = RANGES[name]
    assert how == "uniform"
    return 0.5 * (lo + hi)


def true_difference(theta, stiffness_factor: float = 1.5, reflex_factor: float = 2.0) -> dict:
    """Population-mean difference patient - control of K (N m/rad) and reflex gain
    (N m s/rad) at ``theta`` (rad) (module docstring).

    >>> d = true_difference([0.2, -0.4])
    >>> [round(x, 2) for x in d["stiffness"]], [round(x, 3) for x in d["reflex_gain"]]
    ([61.25, 0.51], [7.75, 2.5])
    """
    from ..simulation.population import RANGES
    from ..simulation.subject import THETA_DF, THETA_PF

    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    a, b = RANGES["k_df_rate"][:2]
    d = theta - THETA_DF
    with np.errstate(divide="ignore", invalid="ignore"):
        e_exp = np.where(np.abs(d) < 1e-12, 1.0, (np.exp(b * d) - np.exp(a * d)) / ((b - a) * d))
    k = (stiffness_factor - 1.0) * (_mean_uniform("k_df_end") - _mean_uniform("k_min")) * e_exp
    s = np.clip((theta - THETA_PF) / (THETA_DF - THETA_PF), 0.0, 1.0)
    lo, hi = RANGES["reflex_gain_ratio"][:2]
    e_ratio = (hi ** (s + 1) - lo ** (s + 1)) / ((s + 1) * (hi - lo))
    g = (reflex_factor - 1.0) * _mean_uniform("reflex_gain_pf") * e_ratio
    return {"theta": theta.tolist(), "stiffness": k.tolist(), "reflex_gain": g.tolist()}


def cohort_subject(seed: int, patient: bool, stiffness_factor: float = 1.5, reflex_factor: float = 2.0):
    """The population subject of ``seed`` (exponential K), with the group's difference
    applied when ``patient``."""
    from ..simulation.population import draw_subject

    s = draw_subject(int(seed), stiffness="exponential")
    if not patient:
        return s
    p = s.params
    return replace(s, params=replace(p, k_df=p.k_df * stiffness_factor, reflex_gain_pf=p.reflex_gain_pf * reflex_factor,
                                     reflex_gain_df=p.reflex_gain_df * reflex_factor))


#: Seed offset of a subject's second session in a within-subject cohort (its own noise).
SESSION_SEED_OFFSET = 100_000
#: Cohort designs: subjects in one group each, or every subject in both conditions.
DESIGNS = ("between", "within")


def write_cohort(out, n_subjects: int = 24, *, first_seed: int = 0, null: bool = False, duration: float = 120.0,
                 fs: float = 100.0, stiffness_factor: float = 1.5, reflex_factor: float = 2.0,
                 design: str = "between") -> dict:
    """Write a virtual cohort to ``out``: ``SUBJECT/PT.csv`` and ``SUBJECT/UT.csv`` per
    subject (the population's identification trajectory, ``duration`` s at ``fs`` Hz),
    ``manifest.csv`` (:mod:`lpvpc.study.manifest`) and ``truth.json`` (groups, factors, each
    record's subject, seed, group and curves, the true difference of the group means; all zero for a
    ``null`` cohort). Subjects take seeds ``first_seed``, ``first_seed + 1``, ... and
    alternate between :data:`GROUPS` (``design="between"``), or each subject has a record in
    both (``design="within"``: records ``SUBJECT-GROUP``, the second session's noise seeded
    apart by ``SESSION_SEED_OFFSET``). Returns {"manifest": path, "truth": path}.
    """
    from ..io.outputs import write_text
    from ..io.trial import write_trial_csv
    from ..simulation.population import simulate_subject
    from ..simulation.subject import THETA_DF, THETA_PF

    if design not in DESIGNS:
        raise ValueError(f"design must be one of {', '.join(DESIGNS)}, not {design!r}")
    if n_subjects < 2:
        raise ValueError(f"a cohort needs at least 2 subjects, got {n_subjects}")
    sf, rf = (1.0, 1.0) if null else (float(stiffness_factor), float(reflex_factor))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    theta = np.round(np.arange(THETA_PF, THETA_DF + 1e-9, 0.01), 10)
    width = max(2, len(str(n_subjects)))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["record", "subject", "group", "pt", "ut"])
    records = []
    for i in range(n_subjects):
        name = f"S{i + 1:0{width}d}"
        sessions = (GROUPS[i % 2],) if design == "between" else GROUPS
        for j, group in enumerate(sessions):
            subject = cohort_subject(first_seed + i, group == GROUPS[1], sf, rf)
            if j:  # the same subject again: its own measurement noise
                subject = replace(subject, seed=subject.seed + SESSION_SEED_OFFSET)
            record = name if design == "between" else f"{name}-{group}"
            pair = simulate_subject(subject, duration=duration, fs_out=fs)
            folder = out / record
            folder.mkdir(exist_ok=True)
            write_trial_csv(pair.pt, folder / "PT.csv")
            write_trial_csv(pair.ut, folder / "UT.csv")
            w.writerow([record, name, group, f"{record}/PT.csv", f"{record}/UT.csv"])
            records.append({"record": record, "subject": name, "group": group, "seed": subject.seed,
                             "design": subject.design, "stiffness": subject.params.K(theta).tolist(),
                             "reflex_gain": subject.params.reflex_gain(theta).tolist()})
    diff = true_difference(theta, sf, rf)
    truth = {"groups": list(GROUPS), "design": design, "null": bool(null), "stiffness_factor": sf, "reflex_factor": rf,
             "duration_s": duration, "fs_hz": fs, "theta": theta.tolist(), "difference": diff,
             "difference_note": "population-mean difference patient - control (lpvpc.study.cohort)",
             "records": records}
    manifest = write_text(out / "manifest.csv", buf.getvalue())
    truth_path = write_text(out / "truth.json", json.dumps(truth, indent=1))
    return {"manifest": manifest, "truth": truth_path}
