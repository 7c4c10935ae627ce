"""``lpvpc diagnose``: where a model fails on held-out data, and which effect is missing."""

from __future__ import annotations


from ..io.outputs import atomic_path
from ..progress import report as progress
from ._common import (
    _add_convention_args, _add_data_args, _add_hold_out_arg, _add_quiet_arg, _held_out_for_model, _hold_out_text,
    _load_for_model, check_report_folder, write_report_folder)


def run(args) -> int:
    """Diagnose a saved model on a record (lpvpc.diagnosis.diagnose.diagnose): print the
    candidates' table, the answer and where the residual is largest; optionally write the
    diagnosis (``--json``) and a report; returns 0."""
    from ..diagnosis.diagnose import diagnose, format_table, write_report
    from ..models.model import LPVPCModel

    if args.report:
        check_report_folder(args.report, ("diagnosis.md", "diagnosis.json"), args.force)
    model = LPVPCModel.load(args.model)
    held_out = None if args.hold_out is None else _held_out_for_model(args, model)
    data = _load_for_model(args, model)
    reference = None
    if held_out is not None:  # the held-out record: a later stretch of the one record given
        from ..io import hold_out

        earlier, data = hold_out(data, held_out)
        if earlier.data_hash == (model.provenance or {}).get("data_hash"):
            # the stretch the model was identified on (its hash): the effects whose signal can
            # differ between the two stretches are tried between them too, as improve does
            reference = earlier
    progress(f"diagnose: fitting and scoring every candidate of the catalog by cross-validation on {data.n} "
             f"samples")
    diag = diagnose(model, data, reference=reference)
    print(f"data:      {data.n} samples at {data.fs:g} Hz ({data.source})")
    if held_out is not None:
        part = data.meta["part"]
        print(f"held out:  {part['start_s']:.1f}..{part['stop_s']:.1f} s of the {part['record_s']:.1f} s record "
              f"(--hold-out {_hold_out_text(held_out)})")
        if reference is not None:
            print("reference: the rest of the record, which the model was identified on (its data hash): effects "
                  "whose signal can differ between the two stretches are tried between them too")
    print(f"model:     VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m on these data; {diag.base_description()}")
    print(format_table(diag))
    print(f"answer:    {diag.answer()}")
    for note in diag.notes():
        print(f"note:      {note}")
    pos = diag.where["position"]["bins"]
    worst = max(pos, key=lambda b: b["residual_rms"]) if pos else None
    if worst:
        print(f"where:     largest residual at positions {worst['bin']} rad (RMS {worst['residual_rms']:.3g} N m, "
              f"{worst['relative_rms']:.2f} x the mean)")
    cc = [f"{k} (lag {c['at_lag_s']:+.2f} s)" for k, c in diag.where["cross_correlation"].items() if c["outside_band"]]
    if cc:
        print(f"           residual correlated with {', '.join(cc)} beyond the 99 % band")
    print(f"time:      {diag.timings['total']:.2f} s")
    if args.json:
        with atomic_path(args.json) as tmp:
            diag.save(tmp)
        print(f"diagnosis: {args.json}")
    if args.report:
        write_report_folder(args.report, "diagnose", lambda stage: write_report(diag, data, stage))
    return 0


def add_parser(sub):
    """Register the ``diagnose`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc diagnose'
    """
    p = sub.add_parser("diagnose", help="where does a model fail on held-out data, and which effect is missing",
                       description="Analyse the residual of a saved model on a record it was not fitted to, and "
                                   "fit and score every candidate effect of the catalog by cross-validated "
                                   "held-out VAF gain with a significance test.")
    p.add_argument("model", metavar="MODEL.json")
    _add_data_args(p, "instead of --pt/--ut")
    p.add_argument("--json", metavar="DIAGNOSIS.json", help="write the diagnosis (candidates in rank order)")
    p.add_argument("--report", metavar="DIR", help="write DIR/report.html (self-contained), diagnosis.json, "
                                                   "diagnosis.md and the figures")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report")
    _add_hold_out_arg(p)
    _add_convention_args(p, from_model=True)
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
