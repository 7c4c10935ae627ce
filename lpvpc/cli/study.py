"""``lpvpc study``: identify a cohort of records, compare groups, write tables and a report."""

from __future__ import annotations

from ._common import _UsageError, _add_quiet_arg


def run(args) -> int:
    """Run the study of a manifest (lpvpc.study.run_study) and print its summary; returns 1
    when a record failed (the others are finished), else 0."""
    from ..study import run_study

    if args.jobs < 1:
        raise _UsageError(f"-j must be at least 1, got {args.jobs}")
    if not 0.0 < args.heldout < 1.0:
        raise _UsageError(f"--heldout {args.heldout:g}: give a fraction between 0 and 1 (e.g. 0.3)")
    result = run_study(args.manifest, args.out, jobs=args.jobs, scheduler=args.scheduler, heldout=args.heldout,
                       compare=tuple(args.compare) if args.compare else None, diagnose=args.diagnose)
    print("\n".join(result.summary_lines()))
    return result.exit_status


def add_parser(sub):
    """Register the ``study`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc study'
    """
    p = sub.add_parser("study", help="identify a cohort of records, compare groups, write tables and a report",
                       description="Identify every record of a manifest (in parallel, cached by content), "
                                   "validate each on its held-out later part, and compare the groups: "
                                   "records.csv, groups.csv and report.html in DIR (docs/guide/study.md).")
    p.add_argument("manifest", metavar="MANIFEST", help="CSV: record,subject,group,pt,ut (or data) and optional "
                                                        "torque_sign,position_unit,stationary,heldout")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="study folder (created; its cache is kept)")
    p.add_argument("-j", "--jobs", type=int, default=1, metavar="N", help="records identified at once (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask scheduler (e.g. tcp://host:8786; "
                                                          "needs pip install 'lpvpc[study]')")
    p.add_argument("--heldout", type=float, default=0.3, metavar="FRACTION",
                   help="later fraction of each record held out (default 0.3; a manifest row's heldout overrides)")
    p.add_argument("--compare", nargs=2, metavar=("REF", "OTHER"),
                   help="the two groups to compare (OTHER - REF; default: each group against the first)")
    p.add_argument("--diagnose", action="store_true",
                   help="also diagnose each record's model on its held-out part (records.csv's missing_effect names "
                        "the first significant effect; a manifest row's diagnose overrides)")
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
