"""``lpvpc diagnose``: where a model fails on held-out data, and which effect is missing."""

from __future__ import annotations


from ..io.outputs import atomic_path
from ..progress import report as progress
from ._common import (
    _UsageError, _add_convention_args, _add_data_args, _add_hold_out_arg, _add_quiet_arg, _held_out_for_model,
    _hold_out_text, _load_for_model, _second_record, _second_record_flags, check_report_folder, write_report_folder)


def run(args) -> int:
    """Diagnose a saved model on a record (lpvpc.diagnosis.diagnose.diagnose): print the
    candidates' table, the answer and where the residual is largest; optionally write the
    diagnosis (``--json``) and a report; returns 0.

    The identification record, given as the reference (``--reference`` or ``--reference-pt``
    and ``--reference-ut``; with ``--hold-out`` the earlier stretch when the model was
    identified on it), is passed to the diagnosis as ``reference``."""
    from ..diagnosis.diagnose import diagnose, format_table, write_report
    from ..models.model import LPVPCModel

    given = _second_record_flags(args, "reference")
    if given and args.hold_out is not None:
        raise _UsageError(f"give either --hold-out (the earlier stretch of the record is then the reference) or "
                          f"{'/'.join(given)} (the record the model was identified on), not both")
    reference_args = _second_record(args, "reference", "reference", 0, required=False)
    if args.report:
        check_report_folder(args.report, ("diagnosis.md", "diagnosis.json"), args.force)
    model = LPVPCModel.load(args.model)
    identified_on = (model.provenance or {}).get("data_hash")  # the hash of the record the model was fitted to
    held_out = None if args.hold_out is None else _held_out_for_model(args, model)
    data = _load_for_model(args, model)
    reference = None
    if held_out is not None:  # the held-out record: a later stretch of the one record given
        from ..io import hold_out

        earlier, data = hold_out(data, held_out)
        if earlier.data_hash == identified_on:
            # the stretch the model was identified on (its hash): the effects whose signal can
            # differ between the two stretches are tried between them too, as improve does
            reference = earlier
    elif reference_args is not None:  # the identification record, read as the diagnosed one is
        reference = _load_for_model(reference_args, model)
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
    elif reference is not None:
        mine = reference.data_hash == identified_on
        print(f"reference: {reference.n} samples at {reference.fs:g} Hz ({reference.source}), "
              + ("the record the model was identified on (its data hash)" if mine else
                 "given as the record the model was identified on")
              + ": effects whose signal can differ between the two records are tried between them too")
        if identified_on and not mine:
            split = (model.fit or {}).get("hold_out")  # identified on a stretch of a record: --hold-out takes it
            print("note:      the model was not identified on this reference record (its data hash differs from the "
                  "one the model file records): the between-record candidates are fitted on it all the same"
                  + ("; the model was identified on part of a record, which diagnose --hold-out takes as the "
                     "reference" if split else ""))
    print(f"model:     VAF {diag.vaf:.2f} %, RMSE {diag.rmse:.4g} N m on these data; {diag.base_description()}")
    print(format_table(diag, syntax="cli"))
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
                                   "held-out VAF gain with a significance test. Given the record the model was "
                                   "identified on (--reference, or --hold-out's earlier stretch), the effects "
                                   "whose signal can differ between records are also fitted on it and scored on "
                                   "this one.")
    p.add_argument("model", metavar="MODEL.json")
    _add_data_args(p, "instead of --pt/--ut")
    p.add_argument("--json", metavar="DIAGNOSIS.json", help="write the diagnosis (candidates in rank order)")
    p.add_argument("--report", metavar="DIR", help="write DIR/report.html (self-contained), diagnosis.json, "
                                                   "diagnosis.md and the figures")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report")
    p.add_argument("--reference", metavar="DATA0",
                   help="the record the model was identified on, as a PT - UT file with a scheduling column (or, "
                        "with --stationary, the stationary trial): the effects whose signal can differ between "
                        "records (the background activation) are also fitted on it and scored on the diagnosed "
                        "record, as Python's diagnose(..., reference=) does; not with --hold-out, which takes "
                        "the earlier stretch of the record as the reference")
    p.add_argument("--reference-pt", metavar="PT0",
                   help="the record the model was identified on: its perturbed trial (with --reference-ut; "
                        "with --stationary alone)")
    p.add_argument("--reference-ut", metavar="UT0",
                   help="the record the model was identified on: its unperturbed trial")
    _add_hold_out_arg(p)
    _add_convention_args(p, from_model=True)
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
