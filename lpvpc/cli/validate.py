"""``lpvpc validate``: a model on a held-out record through every route, co-simulation and report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import LpvpcError
from ._common import (
    PROG, _UsageError, _add_convention_args, _add_file_choice_args, _add_hold_out_arg, _add_quiet_arg,
    _add_time_unit_arg, _channel_options, _held_out_for_model, _hold_out_text, _positive_float, check_report_folder)


def _actuator_param(text):
    name, sep, value = text.partition("=")
    try:
        x = float(value)
    except ValueError:
        x = None
    if not sep or not name.strip() or x is None:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a number, got {text!r}")
    return name.strip(), x


def run(args) -> int:
    """Validate a saved model on a held-out record (lpvpc.validation.validate): print the
    VAF of each route, the checks and the report's paths; returns 1 when a threshold fails, else 0."""
    try:
        from lpvpc.validation import CosimSettings, validate
        from lpvpc.validation.compare import worst_route_difference
    except ModuleNotFoundError as exc:
        if exc.name != "validation":
            raise
        raise LpvpcError("the validation harness is not available in this installation (package 'validation' "
                         "missing)") from None
    if args.stationary:
        if args.data and not (args.pt or args.ut):  # DATA --stationary: the stationary trial's file itself
            args.data, args.pt = None, args.data
        if args.data or args.ut or not args.pt:
            raise _UsageError("--stationary validates one perturbed trial, DATA or --pt, recorded without UT")
    elif args.data and (args.pt or args.ut):
        raise _UsageError("give either DATA or --pt and --ut, not both")
    elif not args.data and not (args.pt and args.ut):
        raise _UsageError("missing --ut: give the held-out unperturbed trial with --ut UT, or --stationary if the PT "
                          "trial was recorded around one fixed position without a UT trial" if args.pt else
                          "missing --pt: give the held-out perturbed trial with --pt PT" if args.ut else
                          "missing DATA or --pt and --ut: give the held-out perturbed and unperturbed trials as "
                          "--pt PT --ut UT (or a PT - UT file with a scheduling column as DATA)")
    check_report_folder(args.report, ("metrics.json", "report.html"), args.force)
    held_out = None
    if args.hold_out is not None:  # the held-out record: a later stretch of the one record given
        from ..models.model import LPVPCModel

        held_out = _held_out_for_model(args, LPVPCModel.load(args.model))
    channels = _channel_options(args)
    settings = CosimSettings(coupling=args.coupling)
    result = validate(args.model, args.pt, args.ut, args.report, fmu=args.fmu, fmi_version=args.fmi,
                      actuator_fmu=args.actuator_fmu, actuator_parameters=dict(args.actuator_param),
                      calibrate=not args.no_calibrate, settings=settings, min_vaf=args.min_vaf,
                      band_limit_command=args.band_limit_command, fmu_variant=args.fmu_variant,
                      route_tolerance=args.route_tolerance, position_unit=args.position_unit,
                      torque_sign=args.torque_sign, time_unit=args.time_unit,
                      command_line=" ".join([PROG, *sys.argv[1:]]),
                      whole_joint=args.whole_joint, variable=args.variable, channels=channels, data=args.data,
                      stationary=args.stationary, hold_out=held_out)
    m = result.metrics
    part = m["provenance"].get("record_part")
    if part:
        print(f"held out:    {part['start_s']:.1f}..{part['stop_s']:.1f} s of the {part['record_s']:.1f} s record "
              f"(--hold-out {_hold_out_text(held_out)})")
    ag = m["route_agreement"]
    sched = m["scheduling"]
    cos = m["cosim"]
    print(f"VAF offline {m['vaf']:.2f} %, FMU replay {m['vaf_fmu']:.2f} %, co-simulation {m['vaf_cosim']:.2f} %  "
          f"(RMSE {m['rmse']:.3g} / {m['rmse_fmu']:.3g} / {m['rmse_cosim']:.3g} N m; {m['n_samples']} samples at "
          f"{m['fs']:g} Hz)")
    worst = worst_route_difference(ag)
    print(f"routes:      CasADi and FMU vs numpy agree to {worst:.1e} (tolerance {ag['tolerance']:.0e}); "
          f"co-simulation {m['vaf_cosim'] - m['vaf_fmu']:+.2f} VAF points vs FMU replay")
    if cos["model_fmu_variant"] == "exact":
        print(f"model FMU:   exact variant, latency {cos['model_fmu_latency_samples']} samples removed; the causal "
              f"(closed-loop) form reaches {m['vaf_causal']:.2f} % offline")
    print(f"co-sim:      {cos['real_time_factor']:.0f}x real time; perturbation tracking VAF "
          f"{cos['tracking']['perturbation_position_vaf']:.3f} %")
    if sched["flagged"]:
        o = sched["out_of_range"]["numpy"]
        if sched["one_position"]:  # "outside [op, op]" says nothing: how far from the one position
            print(f"range:       identified at one operating position, {sched['identified_range'][0]:+.3f} rad; the "
                  f"record lies up to {1e3 * sched['max_excursion']:.1f} mrad from it (offline RMSE {o['rmse']:.3g} N m)")
        else:
            print(f"range:       {100 * sched['out_of_range_fraction']:.2f} % of the record outside the identified "
                  f"scheduling range [{sched['identified_range'][0]:+.3f}, {sched['identified_range'][1]:+.3f}] rad "
                  f"(offline RMSE there {o['rmse']:.3g} N m)")
    for check in m["checks"]:
        if not check["pass"]:
            print(f"FAILED:      {check['name']}: {check['value']:.4g} (threshold {check['threshold']:.4g})")
    print(f"report:      {Path(result.files['report']).resolve()}")
    print(f"metrics:     {Path(result.files['metrics']).resolve()}")
    if "whole_joint" in m:
        w = m["whole_joint"]
        print(f"whole joint: total-torque VAF {w['vaf_total']:.2f} % (FMU {w['vaf_total_fmu']:.2f} %), perturbation "
              f"part {w['vaf_perturbation']:.2f} % (two-input model {w['vaf_two_input']:.2f} %)")
    if result.files.get("ssp"):
        print(f"ssp:         {Path(result.files['ssp']).resolve()}")
    if result.files.get("portable_ssp"):
        print(f"ssp:         {Path(result.files['portable_ssp']).resolve()} (libcosim, ECOS)")
    print(f"result:      {'pass' if result.passed else 'FAIL'}")
    return 0 if result.passed else 1


def add_parser(sub):
    """Register the ``validate`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc validate'
    """
    p = sub.add_parser("validate", help="validate a model on a held-out record: routes, co-simulation, report",
                       description="Validate a saved model on a held-out PT/UT record: predict it offline, through "
                                   "CasADi and the model FMU, co-simulate the model FMU with the actuator FMU, and "
                                   "write DIR/report.html, DIR/metrics.json, DIR/figures and the co-simulation "
                                   "set-up as DIR/cosimulation.ssp (SSP 1.0). Exit status 1 when a "
                                   "threshold fails, 2 for bad input.")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("data", nargs="?", metavar="DATA",
                   help="instead of --pt/--ut: one PT - UT file with perturbation position, torque and a scheduling "
                        "column; the co-simulation drives the scheduling as UT and the scheduling plus the "
                        "perturbation as PT, and loads the PT actuator with the model's torque only (the file has "
                        "no UT torque)")
    p.add_argument("--pt", metavar="PT", help="held-out perturbed trial (CSV or .mat)")
    p.add_argument("--ut", metavar="UT", help="held-out unperturbed trial on the same trajectory")
    p.add_argument("--stationary", action="store_true",
                   help="DATA or --pt alone: a perturbed trial around one fixed operating position recorded "
                        "without UT; the UT actuator holds its mean position, loaded by its mean torque")
    p.add_argument("--report", required=True, metavar="DIR", help="folder for report.html, metrics.json, figures/")
    p.add_argument("--force", action="store_true",
                   help="replace the report folder even if it holds files that are not a previous report")
    p.add_argument("--min-vaf", type=float, metavar="X",
                   help="fail (exit 1) when vaf, vaf_fmu or vaf_cosim is below X percent")
    p.add_argument("--fmu", metavar="F.fmu", help="validate this model FMU, either variant (default: export one, "
                                                  "see --fmu-variant)")
    p.add_argument("--fmu-variant", choices=("exact", "causal", "sampled"), default="exact",
                   help="model FMU to export and validate: exact (the identified two-sided model; its declared "
                        "latency is removed when comparing; default) or causal (velocity and acceleration inputs, for closed loop)")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the exported FMUs (default 2)")
    p.add_argument("--actuator-fmu", metavar="F.fmu", help="actuator FMU (default: the project's actuator)")
    p.add_argument("--actuator-param", type=_actuator_param, action="append", default=[], metavar="NAME=VALUE",
                   help="fix an actuator parameter (repeatable); fixed servo parameters are not calibrated")
    p.add_argument("--no-calibrate", action="store_true",
                   help="do not fit the servo bandwidth and damping to the record's command and position")
    p.add_argument("--band-limit-command", action=argparse.BooleanOptionalAction, default=True,
                   help="low-pass the record's command (zero-phase) to the model's band before it drives the "
                        "actuators (default: on; --no-band-limit-command drives them with the full-band command)")
    p.add_argument("--coupling", choices=("iterate", "delay"), default="iterate",
                   help="load-torque coupling: iterate to convergence (default) or a one-step delay")
    p.add_argument("--route-tolerance", type=_positive_float, default=1e-9, metavar="TOL",
                   help="largest max|a-b|/max|b| of the CasADi and FMU routes vs numpy (default 1e-9)")
    p.add_argument("--whole-joint", metavar="WHOLE.json",
                   help="also validate this whole-joint model (lpvpc whole-joint) on the PT trial's total torque")
    _add_hold_out_arg(p)
    _add_convention_args(p, from_model=True)
    _add_time_unit_arg(p, default=None)
    _add_file_choice_args(p)
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
