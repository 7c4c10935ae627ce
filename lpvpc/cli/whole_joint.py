"""``lpvpc whole-joint``: joint angle in, total torque out (and its closed-loop form)."""

from __future__ import annotations

import math
import time

from ._common import (
    _UsageError, _add_convention_args, _add_file_choice_args, _add_quiet_arg, _add_time_unit_arg, _channel_options,
    _positive_float)


def run(args) -> int:
    """Fit the whole-joint model (or, with ``--closed-loop``, its closed-loop form) of a
    saved model to the UT trial, save it and optionally export it; returns 0."""
    from ..export import whole_joint as W
    from ..models.model import LPVPCModel

    if args.pt and not args.closed_loop:
        raise _UsageError("--pt is used by --closed-loop only (the whole-joint curve is fitted to the UT trial)")
    if args.position_delay_ms is not None and not args.closed_loop:
        raise _UsageError("--position-delay-ms is used by --closed-loop only")
    model = LPVPCModel.load(args.model)
    conv = model.conventions or {}
    ut = _trial_with_conventions(args.ut, args, conv)
    try:
        wj = W.fit_whole_joint(model, ut, cutoff=args.cutoff, order=args.order)
    except ValueError as exc:  # a cutoff outside (0, fs/2)
        raise _UsageError(str(exc)) from None
    if args.closed_loop:
        return _closed_loop(args, wj, ut, conv)
    wj.save(args.out)
    print(f"whole-joint model: {args.out} (quasi-static curve VAF {wj.fit['quasi_static_vaf']:.2f} % on the UT "
          f"trial; low-pass {wj.cutoff:g} Hz; step/FMU latency {W.latency_samples(wj)} samples)")
    if args.casadi:
        print(f"CasADi step function (angle -> torque): {W.export_whole_joint_casadi(wj, args.casadi)}")
    if args.fmu:
        t0 = time.perf_counter()
        path = W.export_whole_joint_fmu(wj, args.fmu, fmi_version=args.fmi, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange"
        print(f"FMU (FMI {args.fmi}.0 {kind}, angle -> torque): {path}  [{time.perf_counter() - t0:.2f} s]")
    return 0


def _trial_with_conventions(path, args, conv):
    """One trial read with the command line's units and torque sign, else the model's own
    (whole-joint's UT trial and --closed-loop's PT trial alike)."""
    from ..io import load_trial

    return load_trial(path, position_unit=args.position_unit or conv.get("position_unit", "rad"),
                      time_unit=args.time_unit or conv.get("time_unit", "s"),
                      torque_sign=float(args.torque_sign if args.torque_sign is not None else conv.get("torque_sign", 1)),
                      variable=args.variable, channels=_channel_options(args),
                      degrees="refuse")  # a model is fitted to it


def _closed_loop(args, wj, ut, conv) -> int:
    """lpvpc whole-joint --closed-loop: the causal closed-loop form (lpvpc.export.closed_loop)."""
    from ..export import closed_loop as CL

    if args.pt:
        pt = _trial_with_conventions(args.pt, args, conv)
        trials, source = [pt, ut], "the PT and UT trials"
    else:
        trials, source = [CL.distillation_trial(wj, ut)], "the two-sided model's torque (no --pt given)"
    delay = _position_delay(args, wj, conv)
    cl = CL.fit_closed_loop(wj, trials, position_delay=delay)
    cl.save(args.out)
    if delay:
        print(f"position channel delayed by {delay * 1e3:.2f} ms to meet the torque channel's (fit only; the model "
              "answers the plant's angle without delay)")
    print(f"closed-loop model: {args.out} (fitted to {source}: VAF {cl.fit['vaf_with_inertia']:.2f} %; inertia "
          f"{cl.inertia:.5g} kg m^2, for the plant; no latency)")
    if args.casadi:
        print(f"CasADi tick function (angle, angular_velocity -> torque): {CL.export_closed_loop_casadi(cl, args.casadi)}")
    if args.fmu:
        t0 = time.perf_counter()
        path = CL.export_closed_loop_fmu(cl, args.fmu, fmi_version=args.fmi, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange"
        print(f"FMU (FMI {args.fmi}.0 {kind}, angle and angular_velocity -> torque, constant output inertia): "
              f"{path}  [{time.perf_counter() - t0:.2f} s]")
    return 0


def _position_delay(args, wj, conv) -> float:
    """--position-delay-ms: a number (ms), or 'auto' (estimated from the PT/UT files)."""
    from ..export import closed_loop as CL
    from ..io import load_identification_data

    text = args.position_delay_ms
    if text is None:
        return 0.0
    if text != "auto":
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value) or abs(value) > 20.0:
            raise _UsageError(f"--position-delay-ms {text!r}: give milliseconds within +-20, or auto")
        return value * 1e-3
    if not args.pt:
        raise _UsageError("--position-delay-ms auto estimates the delay from the PT and UT trials: give --pt")
    data = load_identification_data(
        pt=args.pt, ut=args.ut, target_fs=wj.fs, position_unit=args.position_unit or conv.get("position_unit", "rad"),
        time_unit=args.time_unit or conv.get("time_unit", "s"), variable=args.variable, channels=_channel_options(args),
        torque_sign=float(args.torque_sign if args.torque_sign is not None else conv.get("torque_sign", 1)))
    return CL.estimate_channel_skew(data).delay


def add_parser(sub):
    """Register the ``whole-joint`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc whole-joint'
    """
    p = sub.add_parser("whole-joint", help="joint angle in, total torque out: fit the quasi-static curve, export",
                       description="Build the whole-joint model of a saved LPV-PC model: the quasi-static "
                                   "torque-angle curve fitted to the UT trial at the operating angle (a causal "
                                   "low-pass of the joint angle) plus the LPV-PC model of the angle minus it. "
                                   "Save it as JSON; optionally export it as a CasADi step and an FMU (input "
                                   "angle in rad, output torque in N m, latency L samples).")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("--ut", required=True, metavar="UT", help="the unperturbed trial the model was identified with")
    p.add_argument("-o", "--out", required=True, metavar="WHOLE.json", help="write the whole-joint model here")
    p.add_argument("--force", action="store_true",
                   help="write -o even over an existing file that is not a model file (refused otherwise)")
    p.add_argument("--cutoff", type=_positive_float, default=0.5, metavar="HZ",
                   help="cutoff of the operating-angle low-pass (default 0.5 Hz)")
    p.add_argument("--order", type=int, default=5, metavar="N", help="order of the quasi-static curve (default 5)")
    p.add_argument("--fmu", metavar="FILE.fmu", help="write the whole-joint FMU")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the FMU (default 2)")
    p.add_argument("--fmi-type", choices=("cs", "me"), default="cs",
                   help="cs: co-simulation (default); me: Model Exchange, a time event per sample")
    p.add_argument("--casadi", metavar="FILE.casadi", help="write the whole-joint CasADi step function")
    p.add_argument("--closed-loop", action="store_true",
                   help="the closed-loop form instead (for a plant that the torque moves): inputs angle (rad) and "
                        "angular_velocity (rad/s), no latency, inertia declared apart (docs/guide/closed_loop.md)")
    p.add_argument("--pt", metavar="PT", help="with --closed-loop: fit it to the PT and UT trials (default: to the "
                                              "two-sided model's torque)")
    p.add_argument("--position-delay-ms", metavar="MS|auto",
                   help="with --closed-loop: the torque channel's lag behind the position channel in the recording "
                        "(a measurement artefact, undone for the fit only); auto: estimated from --pt and --ut")
    _add_convention_args(p, from_model=True)
    _add_time_unit_arg(p, default=None)
    _add_file_choice_args(p)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)
    p.set_defaults(func=run)
    return p
