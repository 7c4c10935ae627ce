"""``lpvpc improve``: fit, diagnose, add the top significant effect, refit, until none is left."""

from __future__ import annotations

import json

from ..io.outputs import write_text
from ._common import (
    MODEL_HOLD_OUT, _UsageError, _add_convention_args, _add_data_args, _add_hold_out_arg, _add_quiet_arg,
    _channel_skew, _check_effect_names, _effect_names, _hold_out_text, _hold_out_value, _load_data, _rate,
    _record_files, _second_record, _second_record_flags, check_report_folder, write_report_folder)


def run(args) -> int:
    """Run the improve loop (lpvpc.diagnosis.improve.improve) on an identification record
    and a held-out record, print each step, write the report and optionally the final model;
    returns 0."""
    from ..diagnosis.improve import improve, write_report

    effects = _check_effect_names(args.effect)
    target_fs = None if args.fs == 0 else args.fs
    check_report_folder(args.report, ("improve.md",), args.force)
    held_out = None
    if args.hold_out is not None:  # a later stretch of the one record given
        if args.hold_out == MODEL_HOLD_OUT:
            raise _UsageError("improve --hold-out needs FRACTION or START:STOP (without a value it takes a saved "
                              "model's stretch, in validate and diagnose)")
        if _second_record_flags(args, "heldout"):
            raise _UsageError("give either --hold-out (a later stretch of the record held out) or a held-out record "
                              "(--heldout, --heldout-pt/--heldout-ut), not both")
        held_out = _hold_out_value(args.hold_out)
        if len(_record_files(args)) > (1 if args.data or args.stationary else 2):
            raise _UsageError("improve --hold-out splits one record: give one DATA file or one --pt/--ut pair")
    # or the held-out record as the identification record is given: a PT - UT file, a PT/UT pair or a stationary trial
    held_args = _second_record(args, "heldout", "held-out", 2, required=held_out is None)
    units = dict(position_unit=args.position_unit, torque_sign=args.torque_sign, time_unit="s")
    # a late torque channel lined up in both records as identify does (the rig's: found on the identification record)
    ident = _load_data(args, target_fs=target_fs, channel_skew=_channel_skew(args.channel_skew_ms), **units)
    skew = ident.meta.get("channel_skew_s", 0.0)
    if held_out is not None:  # (with --hold-out the skew is found on the whole record, then split)
        from ..io import hold_out

        ident, held = hold_out(ident, held_out)
        a, b = held.meta["part"]["start_s"], held.meta["part"]["stop_s"]
        print(f"held out:  {a:.1f}..{b:.1f} s of the {held.meta['part']['record_s']:.1f} s record (--hold-out "
              f"{_hold_out_text(held_out)}); identified on 0.0..{a:.1f} s", flush=True)
    else:
        held = _load_data(held_args, target_fs=ident.fs, channel_skew=skew, **units)
    if skew:
        print(f"skew:      torque channel {skew * 1e3:+.2f} ms behind position, lined up in both records", flush=True)

    def show(r):
        head = "step  model" if r.index == 0 else None
        if head:
            print(f"{'step':>4}  {'model':44} {'held-out VAF':>12} {'RMSE (N m)':>11}   fit + diagnosis")
        times = f"{r.fit_time:.1f} s + {r.diagnosis_time:.1f} s" if r.diagnosis is not None else f"{r.fit_time:.1f} s"
        note = "" if r.kept else "   (not kept: no held-out gain)"
        print(f"{r.index:>4}  {r.label[:44]:44} {r.heldout_vaf:>10.2f} % {r.heldout_rmse:>11.4f}   {times}{note}",
              flush=True)
        if r.kept and r.diagnosis is not None:
            top = r.diagnosis.top
            print(f"      diagnosis: {r.diagnosis.answer() if top is None else top.effect + ' significant, +' + format(top.vaf_gain, '.2f') + ' pp held-out'}",
                  flush=True)

    steps = {} if args.max_steps is None else {"max_steps": args.max_steps}  # else the library's MAX_STEPS
    ladder = improve(ident, held, settings={"effects": effects} if effects else None, progress=show, **steps)
    first, last = ladder.rungs[0], ladder.final
    changed = {k: v for k, v in last.settings.items() if first.settings.get(k) != v}  # from the base's structure
    print(f"stopped:   {ladder.stopped}")
    print(f"result:    held-out VAF {first.heldout_vaf:.2f} % -> {last.heldout_vaf:.2f} %, RMSE "
          f"{first.heldout_rmse:.4f} -> {last.heldout_rmse:.4f} N m; final model: "
          f"{', '.join(fe.name for fe in last.model.effects or ()) or 'no effects'}"
          + (f"; settings changed: {', '.join(f'{k}={v}' for k, v in changed.items())}" if changed else ""))
    if args.output:
        model = last.model
        model.conventions.setdefault("position_unit", args.position_unit)
        model.conventions.setdefault("torque_sign", args.torque_sign)
        if args.time_unit != "s":
            model.conventions.setdefault("time_unit", args.time_unit)
        if held_out is not None:  # as identify records it: validate and diagnose --hold-out use the same stretch
            part = held.meta["part"]
            model.fit["hold_out"] = {"value": list(held_out) if isinstance(held_out, tuple) else held_out,
                                     "identification_s": [0.0, part["start_s"]],
                                     "held_out_s": [part["start_s"], part["stop_s"]], "record_s": part["record_s"],
                                     "files": _record_files(args), "vaf": last.heldout_vaf}
        model.save(args.output)
        print(f"model:     {args.output} (hash {model.model_hash[:12]})")
    if args.json:
        write_text(args.json, json.dumps(ladder.to_dict(), indent=1) + "\n")
        print(f"ladder:    {args.json}")
    write_report_folder(args.report, "improve", lambda stage: write_report(ladder, held, stage))
    return 0


def add_parser(sub):
    """Register the ``improve`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc improve'
    """
    p = sub.add_parser("improve", help="fit, diagnose, add the top significant effect, refit, until none is left",
                       description="The improve loop on an identification record and a held-out record; writes "
                                   "DIR/report.html (and improve.md) with the ladder of models (held-out VAF and RMSE), residual "
                                   "plots before and after each step, and each step's diagnosis.")
    _add_data_args(p, "identification record", time_unit="s")
    p.add_argument("--heldout", metavar="DATA2", help="held-out record as a PT - UT file with a scheduling column "
                                                        "(or, with --stationary, the held-out stationary trial)")
    p.add_argument("--heldout-pt", metavar="PT2", help="held-out perturbed trial")
    p.add_argument("--heldout-ut", metavar="UT2", help="held-out unperturbed trial")
    _add_hold_out_arg(p)
    p.add_argument("--report", required=True, metavar="DIR", help="report folder (created)")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report, and "
                        "-o even if it is not a model file")
    p.add_argument("--json", metavar="LADDER.json", help="write the ladder as JSON")
    p.add_argument("-o", "--output", metavar="MODEL.json", help="save the final model")
    p.add_argument("--max-steps", type=int, metavar="N", help="at most N refits (default 6)")
    p.add_argument("--effect", action="extend", nargs="+", default=[], metavar="NAME",
                   help="effects the starting model already has (repeatable): " + ", ".join(_effect_names()))
    _add_convention_args(p, from_model=False)
    p.add_argument("--fs", type=_rate, default=100.0, metavar="HZ",
                   help="rate to identify at (default 100; 0 keeps the file's rate)")
    p.add_argument("--channel-skew-ms", metavar="MS|auto",
                   help="the torque channel's lag behind the position channel in ms, undone in both records at the "
                        "files' rate; auto (default): found as identify finds it, on the identification record "
                        "(one extra fit); 0: none")
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
