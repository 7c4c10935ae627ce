"""``lpvpc export``: a saved model as a CasADi step function and/or an FMU."""

from __future__ import annotations

import time

from ..errors import LpvpcError
from ._common import _UsageError, _add_quiet_arg


def run(args) -> int:
    """Export a saved model as a CasADi step function and/or an FMU and print their inputs,
    outputs and latency; returns 0."""
    from ..models.model import LPVPCModel

    if not (args.casadi or args.fmu):
        raise _UsageError("nothing to export: give --casadi FILE and/or --fmu FILE")
    model = LPVPCModel.load(args.model)
    try:
        from ..export import exporter as export
    except ModuleNotFoundError as exc:
        if exc.name != "lpvpc.export":
            raise
        raise LpvpcError("export is not available in this installation (module lpvpc.export.exporter missing)") from None
    variant = "exact" if args.exact else (args.variant or export.DEFAULT_VARIANT)
    if args.casadi:
        t0 = time.perf_counter()
        path = export.export_casadi(model, args.casadi, variant=variant)
        print(f"CasADi step function ({variant}): {path or args.casadi}  [{time.perf_counter() - t0:.2f} s]")
        import casadi

        from ..models.effects import SIGNALS

        units = {"position": "rad", "scheduling": "rad", "velocity": "rad/s", "acceleration": "rad/s^2",
                 "state": "the previous step's next_state", **{k: u for k, (u, _) in SIGNALS.items()}}
        step = casadi.Function.load(str(path or args.casadi))
        print(f"  inputs:  {', '.join(f'{n} ({units.get(n, chr(45))})' for n in step.name_in())}")
        print(f"  outputs: {', '.join(f'{n} (N m)' if n.startswith('torque') else n for n in step.name_out())}")
    if args.fmu:
        t0 = time.perf_counter()
        path = export.export_fmu(model, args.fmu, fmi_version=args.fmi, variant=variant, fmi_type=args.fmi_type)
        kind = "co-simulation" if args.fmi_type == "cs" else "Model Exchange, a time event per sample"
        print(f"FMU (FMI {args.fmi}.0 {kind}, {variant}): {path or args.fmu}  "
              f"[{time.perf_counter() - t0:.2f} s]")
        for line in _fmu_interface(path or args.fmu, model):
            print(line)
    if args.casadi or args.fmu:
        lat = export.latency_samples(model, variant)
        lo, hi = model.scheduling_range
        print(f"latency:     {lat} sample{'s' if lat != 1 else ''} ({lat / model.fs:g} s at {model.fs:g} Hz) for the "
              f"{variant} variant; scheduling outside [{lo:+.3f}, {hi:+.3f}] rad: {model.beyond_range}")
    return 0


def _fmu_interface(path, model) -> list:
    """Lines naming the FMU's inputs and outputs with their units, as its modelDescription
    declares them; an extra input (EMG) with its level at identification (the same unit)."""
    from fmpy import read_model_description

    md = read_model_description(str(path))
    levels = model.provenance.get("signal_levels") or {}

    def one(v):
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or "1"
        level = (f"; RMS {levels[v.name]:.3g} at identification: give it in that unit" if v.name in levels else "")
        return f"{v.name} ({unit}{level})"

    by = {c: [one(v) for v in md.modelVariables if v.causality == c and v.name not in ("latency", "sample_period")]
          for c in ("input", "output")}
    return [f"  inputs:  {', '.join(by['input'])}", f"  outputs: {', '.join(by['output'])}"]


def add_parser(sub):
    """Register the ``export`` subcommand and its options on ``sub``, the subparsers of
    :func:`lpvpc.cli.build_parser`; returns its parser.

    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="lpvpc").add_subparsers()
    >>> add_parser(sub).prog
    'lpvpc export'
    """
    p = sub.add_parser("export", help="export a saved model as a CasADi function and/or an FMU",
                       description="Export a saved model as a CasADi step function and/or an FMI "
                                   "co-simulation FMU.")
    p.add_argument("model", metavar="MODEL.json")
    p.add_argument("--casadi", metavar="FILE.casadi", help="write the CasADi step function")
    p.add_argument("--fmu", metavar="FILE.fmu", help="write an FMU")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the FMU (default 2)")
    p.add_argument("--variant", choices=("sampled", "causal", "exact"), default=None,
                   help="sampled (default): inputs position and scheduling only, velocity and acceleration by "
                        "central differences inside, so a latency of half the difference stencil: 2 samples for "
                        "models identified by this version (5 points), 1 for older files (3 points); the same timing "
                        "in every co-simulation master (the FMU's description states its timing contract); "
                        "causal: also velocity and acceleration inputs, no latency when the master sets inputs "
                        "before reading outputs (closed loop with an actuator that supplies them); exact: the "
                        "two-sided IRF, latency L samples (its lags -L..L). export prints the model's latency")
    p.add_argument("--exact", action="store_true", help="same as --variant exact")
    p.add_argument("--fmi-type", choices=("cs", "me"), default="cs",
                   help="cs: co-simulation (default); me: Model Exchange, sampled with a time event every 1/fs "
                        "(for tools that import Model Exchange only)")
    _add_quiet_arg(p)  # accepted by every command (a newcomer types it anywhere)
    p.set_defaults(func=run)
    return p
