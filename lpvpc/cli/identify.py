"""``lpvpc identify``: identify an LPV-PC model from a record and save it."""

from __future__ import annotations

import inspect
import time
import warnings

from ..progress import report as progress
from ..report_html import command_line_syntax
from ._common import (
    MODEL_HOLD_OUT, _UsageError, _add_convention_args, _add_data_args, _add_hold_out_arg, _add_quiet_arg, _channel_skew,
    _check_effect_names, _effect_names, _hold_out_text, _hold_out_value, _load_data, _only_one_record,
    _positive_float, _rate, _record_files, _state_order)


def _estimator_defaults() -> dict:
    from ..identification.identify import LPVPCEstimator

    return {k: p.default for k, p in inspect.signature(LPVPCEstimator.__init__).parameters.items()
            if k != "self"}


def _check_allowed_effects(names) -> tuple:
    """--allow-effect names ("none": no effect is offered to the selection)."""
    from ..identification.selection import cv_effect_problem

    if list(names) == ["none"]:
        return ()
    names = _check_effect_names(names)
    for n in names:
        problem = cv_effect_problem(n)
        if problem:
            raise _UsageError(f"--allow-effect: {problem}")
    return names


def run(args) -> int:
    """Identify a model from the record the options name, save it to ``-o`` and print the
    data, the model's summary and the time; returns 0."""
    defaults = _estimator_defaults()
    settings = {k: getattr(args, k) for k in defaults if getattr(args, k, None) is not None}
    if "effects" in settings:
        settings["effects"] = _check_effect_names(settings["effects"])
    if "allow_effects" in settings:
        settings["allow_effects"] = _check_allowed_effects(settings["allow_effects"])
    if "relaxation_times" in settings:
        settings["relaxation_times"] = tuple(settings["relaxation_times"])
    if args.state_order == "auto":
        settings.pop("state_order")
    elif "state_order" in settings:
        settings["state_order"] = int(settings["state_order"])
    if settings.get("structure", "cv") == "cv":  # (the default) what the user wrote is not selected
        from ..identification.selection import REFLEX_PATH_SETTINGS, SEARCH

        settings["structure_fixed"] = tuple(k for k in settings if k in SEARCH or k == "irf_lags"
                                            or k in REFLEX_PATH_SETTINGS)
    from ..identification.identify import LPVPCEstimator

    try:  # a bad setting in one line, before any file is read
        LPVPCEstimator(**settings).check_settings()
    except ValueError as exc:
        raise _UsageError(str(exc)) from None
    held_out = None
    if args.hold_out is not None:
        if args.hold_out == MODEL_HOLD_OUT:
            raise _UsageError("identify --hold-out needs FRACTION or START:STOP (without a value it takes a saved "
                              "model's stretch, in validate and diagnose)")
        held_out = _hold_out_value(args.hold_out)
        _only_one_record(args, "identify")
    target_fs = None if args.fs == 0 else args.fs
    skew = _channel_skew(args.channel_skew_ms)
    load = dict(target_fs=target_fs, position_unit=args.position_unit, torque_sign=args.torque_sign)
    # "auto" (the default): the loader is not given a skew, and the fit lines up a late torque
    # channel itself (lpvpc.identification.identify, as Python's identify does)
    data = _load_data(args, **load, channel_skew=None if skew == "auto" else skew)
    if held_out is not None:  # identified on the earlier part (lpvpc.hold_out, as in Python)
        from ..io import hold_out

        data, held = hold_out(data, held_out)
    t0 = time.perf_counter()
    est = _identified(data, settings)
    elapsed = time.perf_counter() - t0
    model = est.model_
    if held_out is not None:
        model.fit["hold_out"] = _hold_out_entry(model, held, held_out, _record_files(args))
    model.save(args.output)

    lo, hi = model.scheduling_range
    q = data.meta.get("decimation", 1)
    via = f" via {data.meta['resampled_to']:g} Hz" if "resampled_to" in data.meta else ""
    rate = f"{data.fs:g} Hz" + (f" (decimated from {data.meta['fs_original']:g} Hz{via})" if q > 1 else "")
    trials = f"{len(data.segments)} trials, " if data.segments else ""
    print(f"data:        {trials}{data.n} samples at {rate}, {data.n / data.fs:.1f} s, "
          f"position range {lo:+.3f}..{hi:+.3f} rad")
    if data.meta.get("stationary"):
        ops = data.meta.get("operating_points", [data.meta.get("operating_point")])
        print(f"stationary:  no UT trial; operating point {', '.join(f'{x:+.4f}' for x in ops)} rad "
              f"(the trial's mean position; its mean torque removed)")
    for line in model.summary().lines:
        print(command_line_syntax(line))
    if held_out is not None:
        h = model.fit["hold_out"]
        print(f"held out:    {h['held_out_s'][0]:.1f}..{h['held_out_s'][1]:.1f} s of the {h['record_s']:.1f} s record "
              f"(--hold-out {_hold_out_text(held_out)}): VAF {h['vaf']:.2f} % (identified on 0.0.."
              f"{h['identification_s'][1]:.1f} s)")
    if model.effects:
        print(f"effects:     {', '.join(fe.name for fe in model.effects)} (extra inputs: "
              f"{', '.join(model.signals) or 'none'})")
    print(f"time:        {elapsed:.2f} s")
    print(f"model:       {args.output} (hash {model.model_hash[:12]})")
    return 0


def _hold_out_entry(model, held, value, files) -> dict:
    """``model.fit["hold_out"]``: the --hold-out value, the two parts (s from the record's
    start), the record's files (validate and diagnose match them) and the held-out VAF (%),
    the held-out part predicted as ``lpvpc predict`` predicts a record."""
    from ..models.model import vaf

    held = model.conform(held)  # lined up as the model's conventions say, as predict does
    signals = {}
    if model.effects:  # an extended model's extra channels from the record, as predict takes them
        from ..models.effects import signals_from_data

        signals = signals_from_data(held, model)
    part = held.meta["part"]
    return {"value": list(value) if isinstance(value, tuple) else value,
            "identification_s": [0.0, part["start_s"]], "held_out_s": [part["start_s"], part["stop_s"]],
            "record_s": part["record_s"], "files": files, "vaf": vaf(held.torque, model.predict(held, signals=signals).total)}


def _identified(data, settings):
    """The fitted estimator (identify's fit, with its progress line when it takes long)."""
    from ..identification.identify import LPVPCEstimator, with_base_model_activation

    data = with_base_model_activation(data, settings)  # activation as predict estimates it (one extra fit)
    est = LPVPCEstimator(**settings)
    # most fits take a second or two: a line only when this one takes longer
    with _progress_after(IDENTIFY_QUIET_S, f"identify: fitting {data.n} samples at {data.fs:g} Hz"
                         + (f" (reflex state order chosen among {est.min_state_order}..{est.max_state_order})"
                            if est.state_order is None else "") + " ..."), warnings.catch_warnings():
        # a skew found where --channel-skew-ms was given gets identify's own 'skew:' line instead
        warnings.filterwarnings("ignore", message="the torque channel lags the position channel")
        est.fit(data)
    return est


#: s: identify shows its progress line only when the fit has not finished by then
IDENTIFY_QUIET_S = 3.0


class _progress_after:
    """Report ``message`` as progress if the block is still running after ``seconds``."""

    def __init__(self, seconds, message):
        import threading

        self.timer = threading.Timer(seconds, progress, (message,))
        self.timer.daemon = True

    def __enter__(self):
        self.timer.start()

    def __exit__(self, *exc):
        self.timer.cancel()
        return False


def add_parser(sub):
    """Register the ``identify`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc identify'
    """
    d = _estimator_defaults()
    _given = ", unless given here"
    p = sub.add_parser("identify", help="identify an LPV-PC model and save it as JSON",
                       description="Identify an LPV-PC model (subspace method) and save it as JSON.")
    _add_data_args(p, "instead of --pt/--ut", several=True)
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--force", action="store_true",
                   help="write -o even over an existing file that is not a model file (refused otherwise)")
    p.add_argument("--irf-length", type=_positive_float, metavar="S",
                   help=f"half-width of the intrinsic IRF in s (default {d['irf_length']:g} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--irf-lags", type=int, dest="irf_lags", metavar="L",
                   help="intrinsic IRF spans lags -L..L samples (overrides --irf-length)")
    p.add_argument("--basis", choices=("chebyshev", "legendre", "gaussian"),
                   help=f"basis family in the scheduling variable (default {d['basis']})")
    p.add_argument("--intrinsic-order", type=int, metavar="N",
                   help=f"basis order of the IRF weights (default {d['intrinsic_order']} with --structure fixed; with "
                        f"--structure cv, the default, cross-validation chooses it among 2 to 7 unless given here)")
    p.add_argument("--reflex-order", type=int, metavar="N",
                   help=f"basis order of the reflex nonlinearity in position (default {d['reflex_order']} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--velocity-order", type=int, metavar="N",
                   help=f"polynomial order of the reflex nonlinearity in velocity (default {d['velocity_order']} with --structure fixed; "
                        f"chosen by cross-validation otherwise{_given})")
    p.add_argument("--reflex-delay", type=_positive_float, metavar="S",
                   help=f"reflex delay in s (default {d['reflex_delay']} with --structure fixed; chosen by "
                        f"cross-validation otherwise{_given}; a stationary trial's by BIC among 40-80 ms)")
    p.add_argument("--high-rate-reflex", dest="high_rate_reflex", action="store_const", const=True, default=None,
                   help="identify the reflex nonlinearity on the file's own rate (e.g. 1 kHz) delayed velocity "
                        "instead of the model rate's (better reflex trends on the virtual subject, worse held-out "
                        "prediction on the lab's pilot trial; default: chosen per record by the structure selection)")
    p.add_argument("--model-rate-reflex", dest="high_rate_reflex", action="store_const", const=False,
                   help="identify the reflex nonlinearity on the model rate's delayed velocity (not selected)")
    p.add_argument("--high-rate-velocity-basis", choices=("chebyshev", "legendre", "hinge"),
                   help="velocity basis of the high-rate reflex nonlinearity (default: chosen between chebyshev 4 "
                        "and hinge 8)")
    p.add_argument("--high-rate-velocity-order", type=int, choices=range(1, 13), metavar="N",
                   help="its order, 1-12")
    p.add_argument("--state-order", type=_state_order, metavar="M|auto",
                   help="order of the reflex dynamics (default auto: from the singular values and BIC)")
    p.add_argument("--max-state-order", type=int, metavar="M",
                   help=f"largest order tried by auto (default {d['max_state_order']})")
    p.add_argument("--horizon", type=int, metavar="S",
                   help=f"block rows of the MOESP Hankel matrices (default {d['horizon']})")
    p.add_argument("--causal-lags", type=int, metavar="LC",
                   help="lags 0..LC of the causal intrinsic IRF used by the FMU (default L + 2)")
    p.add_argument("--tol", type=_positive_float, help=f"separable least-squares tolerance (default {d['tol']:g})")
    p.add_argument("--max-iter", type=int, metavar="N",
                   help=f"separable least-squares iterations (default {d['max_iter']})")
    _add_hold_out_arg(p)
    _add_convention_args(p, from_model=False)
    p.add_argument("--fs", type=_rate, default=100.0, metavar="HZ",
                   help="rate to identify at: data are decimated to it (default 100; 0 keeps the file's rate)")
    p.add_argument("--channel-skew-ms", metavar="MS|auto",
                   help="the torque channel's lag behind the position channel in ms (a recording artefact), "
                        "undone at the file's rate before decimation; auto (default): found by the fit's scan of "
                        "its own record (one least-squares solve), the files reloaded and refitted when lining the "
                        "channels up removes at least 2 %% of the residual variance; 0: none (docs: data guide, "
                        "channel skew)")
    p.add_argument("--structure", choices=("fixed", "cv"),
                   help="cv (default): choose IRF half-width, basis orders, reflex delay, curvature term and "
                        "extrapolation rule by leave-one-level-out cross-validation (options given here stay fixed); "
                        "fixed: the settings as given")
    p.add_argument("--extrapolation", dest="scheduling_extrapolation", choices=("clip", "linear"),
                   help="beyond the identified position range the bases are held (clip) or continued linearly; "
                        "default: chosen by the structure selection (--structure cv), clip with --structure fixed")
    p.add_argument("--effect", dest="effects", action="extend", nargs="+", default=None, metavar="NAME",
                   help="add an effect of the catalog (repeatable): " + ", ".join(_effect_names()))
    p.add_argument("--allow-effect", dest="allow_effects", action="extend", nargs="+", default=None, metavar="NAME",
                   help="an effect the cross-validation may switch on (repeatable; default stress_relaxation; "
                        "'none': no effect)")
    p.add_argument("--relaxation-times", dest="relaxation_times", type=_positive_float, nargs="+", default=None,
                   metavar="S", help="stress relaxation's averaging times in s (default: chosen per record by the "
                                     "cross-validation among single times of 0.3-3 s and the catalog's 0.3 1 3)")
    p.add_argument("--relaxation-order", dest="relaxation_order", type=int, default=None, metavar="N",
                   help="order in position of stress relaxation's weights (default: with the times)")
    _add_quiet_arg(p)
    p.set_defaults(func=run)
    return p
