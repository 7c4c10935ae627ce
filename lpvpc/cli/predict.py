"""``lpvpc predict``: predict the torque of a record with a saved model and report the VAF."""

from __future__ import annotations

import json

from .. import __version__
from ..io.outputs import atomic_path, write_text
from ._common import _add_convention_args, _add_data_args, _add_quiet_arg, _load_data


def run(args) -> int:
    """Predict a record's perturbation torque with a saved model (its conventions unless
    given) and print the VAF and RMSE; optionally write them (``--json``) and the prediction
    (``--out``); returns 0."""
    import numpy as np

    from ..io import check_model_rate
    from ..models.model import LPVPCModel, vaf

    model = LPVPCModel.load(args.model)
    conv = model.conventions or {}
    position_unit = args.position_unit or conv.get("position_unit", "rad")
    torque_sign = args.torque_sign if args.torque_sign is not None else float(conv.get("torque_sign", 1.0))
    data = _load_data(args, target_fs=model.fs, position_unit=position_unit, torque_sign=torque_sign,
                      time_unit=conv.get("time_unit"), channel_skew=conv.get("channel_skew_s", 0.0))
    check_model_rate(data.fs, model.fs, source=data.source)
    signals = {}
    if model.effects:  # an extended model takes its extra channels from the data
        from ..models.effects import signals_from_data

        signals = signals_from_data(data, model)  # activation with the model's reflex drive, as improve fits it
    pred = model.predict(data, causal=args.causal, signals=signals)  # a 1 kHz reflex model: its 1 kHz path
    measured = data.torque
    metrics = {
        "vaf": vaf(measured, pred.total),
        "rmse": float(np.sqrt(np.mean((measured - pred.total) ** 2))),
        "n_samples": int(data.n),
        "fs": float(data.fs),
        "out_of_range_fraction": float(pred.out_of_range_fraction),
        "causal": bool(args.causal),
        "model_hash": model.model_hash,
        "data_hash": data.data_hash,
        "model": str(args.model),
        "data": data.source,
        "data_files": {"data": str(args.data)} if args.data is not None else {
            k: str(v) for k, v in (("pt", args.pt), ("ut", args.ut)) if v is not None},
        "units": {"vaf": "%", "rmse": "N m", "fs": "Hz"},
        "lpvpc_version": __version__,
    }
    form = "causal" if args.causal else "two-sided"
    print(f"VAF {metrics['vaf']:.2f} %  RMSE {metrics['rmse']:.3g} N m  ({data.n} samples at {data.fs:g} Hz, "
          f"{form} intrinsic IRF)")
    if args.json:
        write_text(args.json, json.dumps(metrics, indent=1) + "\n")
        print(f"metrics:   {args.json}")
    if args.out:
        cols = [data.time, measured, pred.total, pred.intrinsic, pred.reflex, data.position, data.scheduling]
        with atomic_path(args.out) as tmp:
            np.savetxt(tmp, np.column_stack(cols), delimiter=",", fmt="%.10g", comments="",
                       header="time,measured,predicted,intrinsic,reflex,position,scheduling")
        print(f"predicted: {args.out} (time s; torques N m; position, scheduling rad)")
    return 0


def add_parser(sub):
    """Register the ``predict`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc predict'
    """
    p = sub.add_parser("predict", help="predict torque with a saved model and report the VAF",
                       description="Predict the perturbation torque of a record with a saved model. Data are "
                                   "decimated to the model's rate; units and sign default to the model's.")
    p.add_argument("model", metavar="MODEL.json")
    _add_data_args(p, "instead of --pt/--ut")
    p.add_argument("--json", metavar="METRICS.json",
                   help="write vaf (%%), rmse (N m), n_samples, out_of_range_fraction, model_hash, data_hash")
    p.add_argument("--out", metavar="PREDICTED.csv",
                   help="write time, measured, predicted, intrinsic, reflex torques (and position, scheduling)")
    p.add_argument("--causal", action="store_true",
                   help="use the causal intrinsic IRF (what the default FMU runs)")
    _add_convention_args(p, from_model=True)
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)
    p.set_defaults(func=run)
    return p
