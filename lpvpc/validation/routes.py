"""The offline prediction routes of one held-out record (torque in N m, model rate):

- ``numpy``: :meth:`lpvpc.models.model.LPVPCModel.predict`, two-sided IRF (the identified model);
- ``numpy_causal``: the same with the causal IRF the default FMU runs;
- ``casadi`` / ``casadi_exact``: the exported CasADi step run over the record with
  :func:`lpvpc.export.exporter.trajectory_function` (causal; exact two-sided, output shifted back
  by its latency of L samples so that it lines up with ``numpy``, see ``_held_tail``);
- ``fmu``: the model FMU replaying the measured perturbation position, scheduling (and,
  for the causal variant, their central-difference velocity and acceleration), no
  actuator; an exact-variant FMU's outputs are shifted back by its latency.

An extended model (identified with effects, :mod:`lpvpc.models.effects`) takes extra signals
(``trial_time``, ``scheduling_velocity``, ``emg``, ``emg_ut``): every route receives the
record's (``signals``, name -> array at the model rate, e.g. from
:func:`lpvpc.models.effects.signals_from_data`) and the FMU gets them on its extra inputs.
"""

from __future__ import annotations

import time
import warnings
from math import isfinite

import numpy as np

from lpvpc.export import exporter as ex
from lpvpc.errors import FMUError, OutOfRangeWarning

from .cosim import MODEL_OUTPUTS, hold_tail, model_fmu_sampled, model_fmu_variant, model_variant_inputs
from .fmu import FMUInfo, FMUInstance

__all__ = ["offline_routes", "casadi_routes", "fmu_replay", "model_fmu_inputs"]


def model_fmu_inputs(model, variant: str = "causal") -> tuple:
    """Inputs of the model FMU in the order the routes set them: the variant's base inputs
    (:func:`~lpvpc.validation.cosim.model_variant_inputs`), then the extra signals of an
    extended model (none for the base model)."""
    return tuple(model_variant_inputs(variant)) + tuple(ex._effect_signals(model))


def offline_routes(model, position, scheduling, signals=None, data=None) -> dict:
    """numpy predictions (torques in N m) of a record (``position``, ``scheduling`` in rad).

    Returns {"numpy": Prediction (two-sided IRF), "numpy_causal": Prediction (causal IRF),
    "identified": Prediction}. The first two are computed from the model-rate arrays, as the
    FMU and CasADi compute them. "identified" is the record's torque as ``model.predict(data)``
    gives it from every other door: for a model whose reflex runs on the file's own rate
    (``model.high_rate``) and a ``data`` record that carries that rate's signals, the reflex
    on the file's velocity; otherwise the same Prediction as "numpy"."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        out = {"numpy": model.predict(position, scheduling, signals=signals),
               "numpy_causal": model.predict(position, scheduling, causal=True, signals=signals)}
        high = data is not None and model.high_rate is not None and getattr(data, "high_rate", None) is not None
        out["identified"] = model.predict(data, warn=False, signals=signals) if high else out["numpy"]
    return out


def _held_tail(position, scheduling, signals, latency):
    """The record run ``latency`` samples past its end with the last sample held (the
    record-edge convention of :mod:`lpvpc.models.equations`): a model with an output latency of L
    then gives the torque of every sample, output k + L being that of sample k."""
    held = {k: hold_tail(v, latency) for k, v in signals.items()} if signals else signals
    return hold_tail(np.asarray(position, dtype=float), latency), hold_tail(np.asarray(scheduling, dtype=float), latency), held


def casadi_routes(model, position, scheduling, signals=None) -> dict:
    """CasADi predictions: {"torque": {"casadi": causal total, "casadi_exact": two-sided total}
    (N m), "seconds": {the same keys: build and run time in s}}."""
    out, timing = {}, {}
    for name, variant in (("casadi", "causal"), ("casadi_exact", "exact")):
        t0 = time.perf_counter()
        lat = ex.latency_samples(model, variant)
        pos, sched, sig = _held_tail(position, scheduling, signals, lat)
        step = ex.step_function(model, variant)
        traj = ex.trajectory_function(step, len(pos))
        args = ex.replay_inputs(model, pos, sched, variant, signals=sig)
        res = traj(state=np.zeros(step.size1_in("state")), **args)
        out[name] = np.asarray(res["torque"]).ravel()[lat:]
        timing[name] = time.perf_counter() - t0
    return {"torque": out, "seconds": timing}


def fmu_replay(model_fmu: FMUInfo, model, position, scheduling, signals=None) -> dict:
    """Replay a record through the model FMU (either variant) at its sample period; every
    output checked finite. An exact FMU's outputs are shifted back by its latency
    (``_held_tail``), so that every route covers every sample.
    Returns {"torque", "torque_intrinsic", "torque_reflex", "seconds"}."""
    variant = model_fmu_variant(model_fmu)
    lat = ex.latency_samples(model, variant)
    position, scheduling, signals = _held_tail(position, scheduling, signals, lat)
    rows = ex.replay_inputs(model, position, scheduling, variant, signals=signals)
    inputs = model_fmu_inputs(model, variant)
    U = np.column_stack([np.ravel(rows[name]) for name in inputs])
    h = 1.0 / model.fs
    Y = np.empty((len(U), 3))
    sampled = model_fmu_sampled(model_fmu)  # outputs read after the step (held samples)
    with FMUInstance(model_fmu, "model_replay") as inst:
        inst.initialize(0.0)
        pin, pout = inst.port(inputs, "input"), inst.port(MODEL_OUTPUTS, "output")
        t0 = time.perf_counter()
        for k in range(len(U)):
            pin.set(U[k])
            if sampled:
                inst.do_step(k * h, h)
            y = Y[k] = pout.get()
            if not (isfinite(y[0]) and isfinite(y[1]) and isfinite(y[2])):
                raise FMUError(f"model_replay ({model_fmu.path.name}): output {MODEL_OUTPUTS} = {y} (not finite) at "
                               f"t = {k * h:.6g} s although the FMU reported OK")
            if not sampled:
                inst.do_step(k * h, h)
        elapsed = time.perf_counter() - t0
    Y = Y[lat:]
    return {"torque": Y[:, 0], "torque_intrinsic": Y[:, 1], "torque_reflex": Y[:, 2], "seconds": elapsed}
