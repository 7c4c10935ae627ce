"""Export a fitted LPV-PC model as a CasADi step function and as an FMU.

Units: position and scheduling in rad, velocity rad/s, acceleration rad/s^2, torque N m,
time s.

One symbolic definition
-----------------------
:func:`step_function` builds the model's discrete-time step symbolically from the same
code as the numpy prediction (:mod:`lpvpc.models.equations` and :meth:`lpvpc.models.basis.Basis.evaluate`
with :class:`lpvpc.models.basis.CasadiOps`). The ``.casadi`` export saves that step; the FMU's C
code is generated from it by CasADi's ``CodeGenerator``. Nothing here re-writes an equation.

Step, at sample k (period T = 1/fs)::

    (next_state, torque, torque_intrinsic, torque_reflex) =
        step(state, position(k), scheduling(k)[, velocity(k), acceleration(k)][, params])

Outputs have direct feedthrough: they use the inputs of the same sample.

Extended models (:mod:`lpvpc.models.effects`) take the extra signals their effects need as
further inputs after these, in the order of :data:`lpvpc.models.effects.SIGNAL_ORDER`
(``trial_time`` s, ``scheduling_velocity`` rad/s, ``emg``, ``emg_ut``), and keep the
effects' own states (slow-movement direction memory, stress-relaxation averages, reflex cascade, the reflex re-run at
neighbouring delays) in the state; the
effect terms are evaluated by :func:`lpvpc.models.effects.effect_term`, the same code as the
numpy prediction, and added to the pathway they belong to.

Variants
--------
``"causal"`` (default of the building blocks; meant for closed loop with an actuator that supplies the derivatives)
    tq_i(k) = sum_{l=0..Lc} h_l(rho(k)) pos(k-l) + h_v(rho(k)) vel(k) + h_a(rho(k)) acc(k)
    with the model's causal IRF ``H_causal``. ``velocity``/``acceleration`` are the
    current perturbation velocity (rad/s) and acceleration (rad/s^2): the actuator's
    outputs in closed loop, central differences (:func:`lpvpc.models.equations.velocity`,
    :func:`lpvpc.models.equations.acceleration`) when replaying a record. Equals
    ``model.predict(..., causal=True, velocity=v, acceleration=a)`` sample by sample.
``"exact"``
    The identified two-sided IRF (lags -L..L) needs L future positions, so the step
    that receives position(k) returns the torque of sample k - L: the output is delayed
    by exactly ``latency_samples(model, "exact")`` = L samples (L/fs s; with the
    direct-feedthrough I/O above it is L, not L + 1). For k < L the outputs are 0 (no
    torque is defined before the record starts). Equals ``model.predict(...)`` shifted
    by L samples.

The building blocks here (:func:`step_function`, :func:`export_fmu`, ...) default to
``"causal"``; the files ``lpvpc export``, :func:`export_casadi` and the model's export methods
write default to :data:`DEFAULT_VARIANT` (``"sampled"``).

Reflex pathway (both variants): dvel(k) = vel(k - d) with vel the central difference of
position and d = ``model.delay`` >= 1 samples; the velocity is zero outside the record
(as in :func:`lpvpc.models.equations.delayed_velocity`), then z = f(dvel, rho) and the reflex
state x(k+1) = A x + B z, tq_r = C x + D z, x(0) = 0.

State layout (a column vector, initial value all zeros)::

    [ pos(k-1), ..., pos(k-P)            position history, P samples
      rho(k-1), ..., rho(k-L)            scheduling history (exact variant only)
      x_1, ..., x_m                      reflex state
      n ]                                samples seen, saturating at L + d: marks the
                                         start of the record (velocity before it is 0)

Scheduling outside the identified range follows the scheduling bases' extrapolation rule
(held at the boundary, or continued linearly: ``model.beyond_range``); velocities beyond the identified range continue the reflex
nonlinearity linearly. The CasADi function and the FMU inherit this from the basis code.

Closed loop
-----------
The causal FMU's torque depends directly (same sample) on its ``acceleration`` input (the
inertial term), and the actuator FMU's ``acceleration`` output depends directly on its
``load_torque`` input: connected both ways they form an algebraic loop. The model
description declares these dependencies exactly (computed from the CasADi expressions),
so a master can see the loop and either iterate or break it with a one-step delay.

Parameters
----------
``parametric=True`` takes every identified coefficient the variant uses as one input
vector ``params`` (:func:`parameter_vector`, :func:`parameter_names`): the intrinsic IRF
(``H_causal`` or ``H``), ``Omega``, ``A``, ``B``, ``C``, ``D``, each flattened row-major.
Structure (lags, delay, basis families, orders and ranges, fs) is fixed at export.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..models import equations as eq
from ..models.basis import CasadiOps
from ..errors import ExportError
from ..io.outputs import atomic_path, write_text

__all__ = [
    "VARIANTS",
    "OUTPUT_NAMES",
    "StateLayout",
    "step_function",
    "input_names",
    "state_layout",
    "latency_samples",
    "parameter_vector",
    "parameter_names",
    "parameter_info",
    "export_casadi",
    "trajectory_function",
    "replay_inputs",
    "export_fmu",
    "DEFAULT_VARIANT",
    "DEFAULT_FMU_VARIANT",
    "save_casadi",
    "load_casadi",
    "CasadiExport",
    "ticks_per_sample",
    "fmu_constants",
    "derivative_points",
    "fmu_variables",
    "fmu_parameter_name",
    "fmu_description",
    "system_functions",
    "generate_c",
    "write_system_c",
    "step_system_functions",
    "build_step_fmu",
    "model_source_dir",
]

VARIANTS = ("sampled", "causal", "exact")
#: The variant written when none is named, by ``lpvpc export`` (``--casadi`` and ``--fmu``),
#: :meth:`lpvpc.LPVPCModel.export_casadi <lpvpc.models.model.LPVPCModel.export_casadi>`, :meth:`lpvpc.LPVPCModel.export_fmu <lpvpc.models.model.LPVPCModel.export_fmu>` and
#: :func:`export_casadi`: positions in, velocity and acceleration by central differences
#: inside, a declared latency of half the difference stencil.
DEFAULT_VARIANT = "sampled"
#: The FMU ``lpvpc export --fmu`` makes (the same as :data:`DEFAULT_VARIANT`).
DEFAULT_FMU_VARIANT = DEFAULT_VARIANT
#: ``format`` of the sidecar ``<file>.casadi.json`` beside every exported step function.
CASADI_FORMAT = "lpvpc-casadi-step"
#: Version 2 adds ``tick_s``, ``sample_period_s``, ``inertia``, the initial state as numbers
#: and ``kind``; :func:`load_casadi` reads version 1 files too.
CASADI_FORMAT_VERSION = 2
#: Relative tolerance of :meth:`CasadiExport.check_step` on a host's time step.
STEP_TOLERANCE = 1e-6

STATE_INPUT = "state"
OUTPUT_NAMES = ("next_state", "torque", "torque_intrinsic", "torque_reflex")


def _check_variant(variant):
    if variant not in VARIANTS:
        raise ExportError(f"unknown export variant {variant!r}; choose one of {VARIANTS}")


def _irf(variant) -> str:
    """The intrinsic IRF a variant runs: "causal" (H_causal with velocity and acceleration
    terms; causal and sampled) or "exact" (the two-sided H)."""
    return "exact" if variant == "exact" else "causal"


def input_names(variant="causal", parametric=False, model=None):
    """Names of the step function's inputs, in order (with ``model``: including the extra
    signals of an extended model).

    Parameters
    ----------
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form.
    parametric : bool, default False
        Include the ``params`` input.
    model : lpvpc.models.model.LPVPCModel, optional
        With it, the extra signals of an extended model too.

    Returns
    -------
    list of str
        The input names, in order.

    Examples
    --------
    >>> input_names("causal")
    ['state', 'position', 'scheduling', 'velocity', 'acceleration']
    >>> input_names("sampled", parametric=True)  # positions only; the coefficients as an input
    ['state', 'position', 'scheduling', 'params']
    """
    _check_variant(variant)
    names = [STATE_INPUT, "position", "scheduling"]
    if variant == "causal":
        names += ["velocity", "acceleration"]
    names += list(_effect_signals(model))
    if parametric:
        names.append("params")
    return names


def _effect_signals(model) -> tuple:
    if model is None or not getattr(model, "effects", None):
        return ()
    from ..models.effects import model_signals

    return model_signals(model)


def _effect_states(model) -> list:
    """Names of the effect states of an extended model (direction memory, stress-relaxation
    averages, reflex cascade, the reflex re-run at neighbouring delays)."""
    if model is None or not getattr(model, "effects", None):
        return []
    from ..models.effects import model_derived, model_reflex_delay_steps

    derived = model_derived(model)
    names = []
    if "direction" in derived:
        names += ["direction_latched", "direction_smoothed"]
    if "relaxation" in derived:
        from ..models.effects import model_relaxation_times

        names += [f"relaxation_average[{tau:g} s]" for tau in model_relaxation_times(model)]
    if "reflex" in derived:
        names += [f"reflex_cascade[{i}]" for i in range(int(model.A.shape[0]))]
    for j in model_reflex_delay_steps(model):  # the reflex re-run at the delay d + j
        names += [f"reflex_delay{j:+d}_state[{i}]" for i in range(int(model.A.shape[0]))]
    return names


# ---------------------------------------------------------------------------------------
# Layout of the state
@dataclass(frozen=True)
class StateLayout:
    """Where things live in the step's state vector (see the module docstring).

    Parameters
    ----------
    latency : int
        Output delay in samples (0 for causal).
    n_pos, n_sched : int
        Position and scheduling history lengths.
    m : int
        Reflex state order.
    start : int
        Saturation value of the sample counter (latency + delay, + the largest effect
        delay step).
    signals : tuple of str, default ``()``
        Extra input signals of an extended model (history kept for latency > 0).
    effect_states : tuple of str, default ``()``
        Names of the effect states.
    """

    latency: int  # output delay in samples (0 for causal)
    n_pos: int  # position history length P
    n_sched: int  # scheduling history length
    m: int  # reflex state order
    start: int  # saturation value of the sample counter (latency + delay, + the largest effect delay step)
    signals: tuple = ()  # extra input signals of an extended model (history kept for latency > 0)
    effect_states: tuple = ()  # names of the effect states

    @property
    def size(self) -> int:
        return self.n_pos + self.n_sched + self.m + self.latency * len(self.signals) + len(self.effect_states) + 1

    def describe(self) -> list:
        names = [f"position(k-{i + 1})" for i in range(self.n_pos)]
        names += [f"scheduling(k-{i + 1})" for i in range(self.n_sched)]
        names += [f"reflex_state[{i}]" for i in range(self.m)]
        names += [f"{s}(k-{i + 1})" for s in self.signals for i in range(self.latency)]
        names += list(self.effect_states)
        names.append(f"samples_seen (saturates at {self.start})")
        return names


def latency_samples(model, variant="causal") -> int:
    """Output delay of the exported step in samples: 0 for causal, L for exact.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    int
        The delay in samples.
    """
    _check_variant(variant)
    if variant == "sampled":  # the differences of sample k need position k + 1 (5-point: k + 2)
        return derivative_points(model) // 2
    return 0 if variant == "causal" else max(0, -min(model.lags))


def state_layout(model, variant="causal") -> StateLayout:
    """Where things live in the exported step's state vector for ``variant``.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    StateLayout
        The layout.
    """
    _check_variant(variant)
    d = int(model.delay)
    lat = latency_samples(model, variant)
    lags = model.causal_lags if _irf(variant) == "causal" else model.lags
    # history index i means pos(k - i); i = 0 is the current input.
    needed = [lat + int(l) for l in lags] + [lat + d - 1, lat + d + 1]
    if variant == "sampled":
        needed += [2 * lat]  # differences at j = k - lat reach back to j - lat
    from ..models.effects import model_reflex_delay_steps

    steps = model_reflex_delay_steps(model)
    if getattr(model, "effects", None):
        needed += [lat + 1]  # perturbation velocity at j for effects (central difference)
        needed += [lat + d + j + 1 for j in steps]  # the reflex re-run at the delay d + j
    return StateLayout(latency=lat, n_pos=max(needed), n_sched=lat, m=int(model.A.shape[0]),
                       start=lat + d + max([0] + steps),
                       signals=_effect_signals(model), effect_states=tuple(_effect_states(model)))


# ---------------------------------------------------------------------------------------
# Parameters
def _coefficient_blocks(model, variant):
    """(name, array) for each identified coefficient block the variant uses."""
    _check_variant(variant)
    H_name = "H_causal" if _irf(variant) == "causal" else "H"
    H = model.H_causal if _irf(variant) == "causal" else model.H
    return [
        (H_name, np.atleast_2d(np.asarray(H, dtype=float))),
        ("Omega", np.atleast_2d(np.asarray(model.Omega, dtype=float))),
        ("A", np.atleast_2d(np.asarray(model.A, dtype=float))),
        ("B", np.asarray(model.B, dtype=float).reshape(-1)),
        ("C", np.asarray(model.C, dtype=float).reshape(-1)),
        ("D", np.array([float(model.D)])),
    ] + ([("curvature", np.asarray(model.curvature, dtype=float).reshape(-1))]
         if getattr(model, "curvature", None) is not None else []) + [blk for fe in getattr(model, "effects", ()) for blk in fe.coefficient_blocks(_irf(variant))]


def parameter_vector(model, variant="causal") -> np.ndarray:
    """The identified coefficients the variant uses, as one vector (row-major blocks
    H_causal or H, Omega, A, B, C, D), the ``params`` input of the parametric step.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    numpy.ndarray
        The coefficients.
    """
    return np.concatenate([a.ravel() for _, a in _coefficient_blocks(model, variant)])


def parameter_names(model, variant="causal") -> list:
    """Names matching :func:`parameter_vector`: ``"H_causal[2,1]"``, ``"Omega[0,3]"``,
    ``"A[0,1]"``, ``"B[0]"``, ``"C[0]"``, ``"D"``.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    list of str
        One name per coefficient.
    """
    names = []
    for name, a in _coefficient_blocks(model, variant):
        if name == "D":
            names.append("D")
        elif a.ndim == 1:
            names += [f"{name}[{i}]" for i in range(a.shape[0])]
        else:
            names += [f"{name}[{i},{j}]" for i in range(a.shape[0]) for j in range(a.shape[1])]
    return names


def parameter_info(model, variant="causal") -> list:
    """(description, unit) of each parameter, matching :func:`parameter_names`. Units are
    FMI unit names ("" where a coefficient has no physical unit of its own, e.g. the
    reflex nonlinearity scale, which is shared between Omega and B, C, D).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    list of tuple
        ``(description, unit)`` per parameter.
    """
    out = []
    lags = model.causal_lags if _irf(variant) == "causal" else model.lags
    for name, a in _coefficient_blocks(model, variant):
        if name in ("H", "H_causal"):
            rows = [f"lag {l}" for l in lags]
            units = ["N.m/rad"] * len(lags)
            if name == "H_causal":
                rows += ["velocity", "acceleration"]
                units += ["N.m.s/rad", "N.m.s2/rad"]
            out += [(f"intrinsic IRF coefficient ({rows[i]}, scheduling basis function {j})", units[i])
                    for i in range(a.shape[0]) for j in range(a.shape[1])]
        elif name == "Omega":
            out += [(f"reflex nonlinearity coefficient (velocity basis function {i}, scheduling basis "
                     f"function {j})", "") for i in range(a.shape[0]) for j in range(a.shape[1])]
        elif name == "A":
            out += [(f"reflex dynamics A[{i},{j}] (state matrix, per sample)", "")
                    for i in range(a.shape[0]) for j in range(a.shape[1])]
        elif name in ("B", "C"):
            out += [(f"reflex dynamics {name}[{i}]", "") for i in range(a.shape[0])]
        elif name == "curvature":
            out += [(f"elastic curvature coefficient (scheduling basis function {i})", "N.m/rad2")
                    for i in range(a.shape[0])]
        elif name != "D":  # an effect term of an extended model (lpvpc.models.effects)
            effect, kind = name.rsplit("_", 1) if not name.endswith("H_causal") else (name[:-9], "H_causal")
            what = {"H": "two-sided IRF", "H_causal": "causal IRF", "Theta": "static term"}[kind]
            out += [(f"effect {effect}: {what} coefficient [{i},{j}]", "")
                    for i in range(a.shape[0]) for j in range(a.shape[1])]
            continue
        else:
            out.append(("reflex dynamics feedthrough D", ""))
    return out


def _split_parameters(model, variant, p):
    """Coefficient blocks as CasADi matrices: from the symbol ``p`` or baked-in values."""
    import casadi as ca

    blocks = {}
    offset = 0
    for name, a in _coefficient_blocks(model, variant):
        if p is None:
            value = ca.DM(a)
        else:
            flat = p[offset: offset + a.size]
            # p is row-major; casadi.reshape is column-major.
            value = ca.reshape(flat, a.shape[1], a.shape[0]).T if a.ndim == 2 else flat
        offset += a.size
        blocks[name] = value
    return blocks


# ---------------------------------------------------------------------------------------
# The step
def step_function(model, variant="causal", parametric=False, name=None):
    """The model's discrete-time step as a ``casadi.Function`` (SX).

    Inputs (all column vectors, in this order): ``state`` (``state_layout(model,
    variant).size``), ``position`` (rad), ``scheduling`` (rad), and for ``"causal"``
    ``velocity`` (rad/s) and ``acceleration`` (rad/s^2); ``params`` when ``parametric``.
    Outputs: ``next_state``, ``torque``, ``torque_intrinsic``, ``torque_reflex`` (N m) of
    sample k (causal), k - 1 (sampled: its central differences need position k) or k - L
    (exact). Start from ``state = 0``.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).
    parametric : bool, default False
        Take the coefficients as a ``params`` input instead of constants.
    name : str, optional
        The function's name.

    Returns
    -------
    casadi.Function
        The step.
    """
    import casadi as ca

    _check_variant(variant)
    ops = CasadiOps()
    lay = state_layout(model, variant)
    fs = float(model.fs)

    state = ca.SX.sym("state", lay.size)
    pos = ca.SX.sym("position")
    rho_in = ca.SX.sym("scheduling")
    inputs = [state, pos, rho_in]
    if variant == "causal":
        vel = ca.SX.sym("velocity")
        acc = ca.SX.sym("acceleration")
        inputs += [vel, acc]
    sig_in = {name: ca.SX.sym(name) for name in lay.signals}  # extended models' extra inputs
    inputs += list(sig_in.values())
    p = None
    if parametric:
        p = ca.SX.sym("params", len(parameter_vector(model, variant)))
        inputs.append(p)
    c = _split_parameters(model, variant, p)

    lat_ = lay.latency
    i0 = 0
    pos_hist = state[i0: i0 + lay.n_pos]
    i0 += lay.n_pos
    rho_hist = state[i0: i0 + lay.n_sched]
    i0 += lay.n_sched
    x = state[i0: i0 + lay.m]
    i0 += lay.m
    sig_hist = {}
    for name in lay.signals:
        sig_hist[name] = state[i0: i0 + lat_]
        i0 += lat_
    eff_state = state[i0: i0 + len(lay.effect_states)]
    i0 += len(lay.effect_states)
    seen = state[i0]

    def p_at(i):  # pos(k - i)
        return pos if i == 0 else pos_hist[i - 1]

    lat = lay.latency
    rho = rho_in if lat == 0 else rho_hist[lat - 1]  # rho(j), j = k - latency
    sig = {n: (v if lat == 0 else sig_hist[n][lat - 1]) for n, v in sig_in.items()}  # signals at j

    # Intrinsic pathway at sample j.
    if variant == "sampled" and lat == 2:  # the model's 5-point stencil, positions j-2..j+2
        vel, acc = eq.five_point_derivatives(p_at(4), p_at(3), p_at(2), p_at(1), p_at(0), fs)
    elif variant == "sampled":  # velocity and acceleration at j from positions j+1, j, j-1
        vel = eq.central_velocity(p_at(lat - 1), p_at(lat + 1), fs)
        acc = eq.central_acceleration(p_at(lat - 1), p_at(lat), p_at(lat + 1), fs)
    if _irf(variant) == "causal":
        signals = ops.hcat([p_at(lat + int(l)) for l in model.causal_lags] + [vel, acc])
        H = c["H_causal"]
    else:
        signals = ops.hcat([p_at(lat + int(l)) for l in model.lags])
        H = c["H"]
    Gi = model.intrinsic_basis.evaluate(rho, ops)
    tq_i = eq.intrinsic_torque(signals, Gi, H, ops)
    if "curvature" in c:  # the elastic curvature term at sample j
        tq_i = tq_i + eq.elastic_curvature_torque(p_at(lat), Gi, c["curvature"], ops)

    # Reflex pathway at sample j: dvel(j) = vel(j - d), zero before the record starts.
    d = int(model.delay)
    dvel = eq.central_velocity(p_at(lat + d - 1), p_at(lat + d + 1), fs)
    dvel = ca.if_else(seen >= lat + d, dvel, 0.0)
    z = eq.reflex_drive(model.velocity_basis.evaluate(dvel, ops), model.reflex_rho_basis.evaluate(rho, ops),
                        c["Omega"], ops)
    x_next, tq_r = eq.reflex_step(c["A"], c["B"], c["C"].T, c["D"], x, z)

    eff_next = eff_state
    if getattr(model, "effects", None):  # extended model: effect terms (lpvpc.models.effects)
        v_j = vel if _irf(variant) == "causal" else eq.central_velocity(p_at(lat - 1), p_at(lat + 1), fs)
        tq_ei, tq_er, eff_next = _effect_torques(model, variant, c, lay, ops, signals, rho, v_j, sig, x, z,
                                                 eff_state, p_at(lat), p_at, seen)
        tq_i, tq_r = tq_i + tq_ei, tq_r + tq_er

    if lat > 0:  # nothing is defined before the record starts: hold x = 0, output 0
        started = seen >= lat
        x_next = ca.if_else(started, x_next, x)
        if lay.effect_states:
            eff_next = ca.if_else(started, eff_next, eff_state)
        tq_i = ca.if_else(started, tq_i, 0.0)
        tq_r = ca.if_else(started, tq_r, 0.0)

    next_state = ca.vertcat(
        pos,
        *([pos_hist[: lay.n_pos - 1]] if lay.n_pos > 1 else []),  # (an empty SX slice is 1x1, not 0x1)
        *([rho_in] if lay.n_sched else []),
        *([rho_hist[: lay.n_sched - 1]] if lay.n_sched > 1 else []),
        x_next,
        *[v for n in lay.signals for v in ([sig_in[n]] + ([sig_hist[n][: lat - 1]] if lat > 1 else []) if lat else [])],
        eff_next,
        ca.fmin(seen + 1.0, float(lay.start)),
    )
    if name is None:
        name = f"lpvpc_step_{variant}" + (f"_latency{lat}" if lat else "")
    return ca.Function(
        name,
        inputs,
        [next_state, tq_i + tq_r, tq_i, tq_r],
        input_names(variant, parametric, model),
        list(OUTPUT_NAMES),
    )


def _effect_torques(model, variant, c, lay, ops, position_signals, rho, v_j, sig, x, z, eff_state, p_j, p_at, seen):
    """Effect torques of an extended model at sample j (intrinsic, reflex) and the next
    effect states; the terms come from :func:`lpvpc.models.effects.effect_term`."""
    import casadi as ca

    from ..models import effects as fx

    ctx = {"rho": rho, "velocity": v_j, "position": p_j, **sig}
    nxt = []
    k = 0
    states = list(lay.effect_states)
    if "direction_latched" in states:
        latched, smoothed = fx.eq.direction_memory_step(
            eff_state[k], eff_state[k + 1], sig["scheduling_velocity"], fx.DIRECTION_V_MIN, fx.DIRECTION_V_WIDTH,
            fx.direction_alpha(model.fs), ops)
        ctx["direction"] = smoothed
        nxt += [latched, smoothed]
        k += 2
    if any(s.startswith("relaxation_average") for s in states):
        ctx["relaxation"] = []
        for tau in fx.model_relaxation_times(model):
            average = fx.eq.relaxation_step(eff_state[k], p_j, fx.smoothing_alpha(tau, model.fs))
            ctx["relaxation"].append(average)
            nxt.append(average)
            k += 1
    if any(s.startswith("reflex_cascade") for s in states):
        m = lay.m
        w = eff_state[k: k + m]
        C = c["C"].T
        w_next, _ = eq.reflex_step(c["A"], c["B"], C, 0.0, w, ca.mtimes(C, x))
        ctx.update(x=[x[i] for i in range(m)], z=z, w=[w[i] for i in range(m)])
        nxt += [w_next[i] for i in range(m)]
        k += m
    steps = fx.model_reflex_delay_steps(model)
    if steps:  # the model's reflex re-run at the delay d + j (as lpvpc.models.effects.shifted_reflex_torques)
        m, d, lat, fs = lay.m, int(model.delay), lay.latency, float(model.fs)
        C = c["C"].T
        _, tq0 = eq.reflex_step(c["A"], c["B"], C, c["D"], x, z)
        shift = {}
        G_r = model.reflex_rho_basis.evaluate(rho, ops)
        for j in steps:
            dv = eq.central_velocity(p_at(lat + d + j - 1), p_at(lat + d + j + 1), fs)
            dv = ca.if_else(seen >= lat + d + j, dv, 0.0)
            zj = eq.reflex_drive(model.velocity_basis.evaluate(dv, ops), G_r, c["Omega"], ops)
            xj = eff_state[k: k + m]
            xj_next, tqj = eq.reflex_step(c["A"], c["B"], C, c["D"], xj, zj)
            shift[j] = tqj - tq0
            nxt += [xj_next[i] for i in range(m)]
            k += m
        ctx["reflex_shift"] = shift
    context = fx.Context(**ctx)
    Gi = model.intrinsic_basis.evaluate(rho, ops)
    tq_i = tq_r = 0.0
    for fe in model.effects:
        coef = {}
        for name, _ in fe.coefficient_blocks(_irf(variant)):
            coef["Theta" if name.endswith("_Theta") else "H"] = c[name]
        tq = fx.effect_term(fe, context, position_signals, Gi, "causal" if _irf(variant) == "causal" else "two_sided",
                            ops, coef)
        if fe.effect.pathway == "reflex":
            tq_r = tq_r + tq
        else:
            tq_i = tq_i + tq
    return tq_i, tq_r, (ca.vertcat(*nxt) if nxt else eff_state)


# ---------------------------------------------------------------------------------------
# CasADi export
def save_casadi(step, path, metadata: dict) -> Path:
    """Save a step function with ``casadi.Function.save`` and its sidecar ``<path>.json``:
    the one writer of every CasADi export (the model's, whole-joint, closed-loop).

    Parameters
    ----------
    step : casadi.Function
        A non-parametric step (inputs ``state`` then the signals; outputs ``next_state``
        then the torques).
    path : str or Path
        The ``.casadi`` file to write.
    metadata : dict
        What the exporter knows (``kind``, ``variant``, ``tick_s``, ``sample_period_s``,
        ``latency_samples``, ``units``, ``inertia``, ...). The names of the inputs and
        outputs, the state size, the initial state (zeros), the format and the lpvpc
        version are added from the function.

    Returns
    -------
    Path
        ``path``. The sidecar is ``<path>.json``; :func:`load_casadi` reads both.

    Raises
    ------
    ExportError
        The function or its sidecar could not be written.
    """
    from .. import __version__

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:  # temporary file + rename
            step.save(str(tmp))
    except (OSError, RuntimeError) as exc:
        raise ExportError(f"{path}: could not save the CasADi function ({exc})") from None
    meta = {
        "format": CASADI_FORMAT,
        "format_version": CASADI_FORMAT_VERSION,
        "function": step.name(),
        **metadata,
        "inputs": list(step.name_in()),
        "outputs": list(step.name_out()),
        "state_size": int(step.size1_in(0)),
        "initial_state": [0.0] * int(step.size1_in(0)),  # every exported step starts from rest
        "lpvpc_version": __version__,
    }
    try:
        write_text(str(path) + ".json", json.dumps(meta, indent=1))
    except OSError as exc:
        raise ExportError(f"{path}.json: could not write the CasADi function's metadata ({exc})") from None
    return path


def casadi_metadata(model, variant=DEFAULT_VARIANT) -> dict:
    """The sidecar metadata of the model's step function (:func:`save_casadi` adds the names,
    sizes and initial state): variant, tick and sample period (s), latency, units, state
    layout, inertia, identified ranges, model hash."""
    _check_variant(variant)
    lay = state_layout(model, variant)
    T = 1.0 / float(model.fs)
    return {
        "kind": "lpvpc model",
        "variant": variant,
        "fs": model.fs,
        "tick_s": T,  # one call advances the model by one sample
        "sample_period_s": T,
        "latency_samples": lay.latency,
        "latency_s": lay.latency * T,
        "units": {"state": "the previous call's next_state", "position": "rad", "scheduling": "rad",
                  "velocity": "rad/s", "acceleration": "rad/s^2", "next_state": "(state)", "torque": "N m",
                  "torque_intrinsic": "N m", "torque_reflex": "N m", **_signal_units(model)},
        "inertia": {"kg_m2": None, "in_torque": True,
                    "note": "the intrinsic impulse response contains the foot's inertia: do not add it again"},
        "state_layout": lay.describe(),
        **({"effects": [fe.name for fe in model.effects]} if getattr(model, "effects", None) else {}),
        "identified_ranges": {"scheduling": list(model.scheduling_range), "velocity": list(model.velocity_range)},
        "model_hash": model.model_hash,
    }


def export_casadi(model, path, variant=DEFAULT_VARIANT) -> Path:
    """Save the (non-parametric) step function to ``path`` with ``Function.save``, and its
    metadata beside it (:func:`save_casadi`).

    ``variant`` defaults to :data:`DEFAULT_VARIANT` (what ``lpvpc export --casadi`` writes).
    A user with only casadi installed runs a whole record of the default variant with::

        import casadi, numpy as np
        step = casadi.Function.load("model.casadi")
        traj = step.mapaccum(len(position))  # or lpvpc.export.exporter.trajectory_function(step, n)
        out = traj(state=np.zeros(step.size1_in("state")), position=position[None, :],
                   scheduling=scheduling[None, :])
        torque = np.asarray(out["torque"]).ravel()  # sample k - latency_samples at row k

    The sidecar ``<path>.json`` (``casadi_metadata``) records the variant, tick and
    sample period, latency (samples and s), units, input and output names, initial state,
    state layout, inertia, model hash and lpvpc version; :func:`load_casadi` returns the
    function with it and refuses host steps that are not the tick.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model to export.
    path : str or pathlib.Path
        The ``.casadi`` file to write.
    variant : {"sampled", "causal", "exact"}, default "sampled"
        The form exported (:data:`DEFAULT_VARIANT`).

    Returns
    -------
    pathlib.Path
        The function's path.

    Raises
    ------
    lpvpc.errors.ExportError
        An unknown variant.
    """
    _check_variant(variant)
    return save_casadi(step_function(model, variant), path, casadi_metadata(model, variant))


class CasadiExport(NamedTuple):
    """An exported step function with its metadata (:func:`load_casadi`).

    Unpacks as ``function, metadata``. The step is a fixed-step model: one call advances
    its model time by ``tick`` seconds, whatever the host's clock. :meth:`step` and
    :meth:`trajectory` take the host's time step and refuse one that is not the tick
    (:class:`lpvpc.errors.StepSizeError`): a simulator stepping at half the tick would
    otherwise run the model's time twice as fast, silently.

    Parameters
    ----------
    function : casadi.Function
        The step function.
    metadata : dict
        Its sidecar's metadata (variant, tick, latency, units, names, initial state).
    """

    function: Any
    metadata: dict

    @property
    def tick(self) -> float:
        """Seconds of model time one call advances (s)."""
        m = self.metadata
        return float(m["tick_s"]) if "tick_s" in m else 1.0 / float(m["fs"])  # format 1: one sample per call

    def check_step(self, dt) -> None:
        """Raise :class:`lpvpc.errors.StepSizeError` unless ``dt`` (s) is the tick within
        ``STEP_TOLERANCE`` (relative)."""
        from ..errors import StepSizeError

        tick = self.tick
        if not (np.isfinite(dt) and abs(float(dt) - tick) <= STEP_TOLERANCE * tick):
            raise StepSizeError(f"time step {float(dt):g} s is not the exported function's tick {tick:g} s: call it "
                                f"once per tick (step your host at {tick:g} s, or call the function every {tick:g} s "
                                "of host time)")

    def initial_state(self) -> np.ndarray:
        """The state to start a record from (zeros: the model at rest)."""
        m = self.metadata
        x0 = m.get("initial_state")
        return np.array(x0, dtype=float) if isinstance(x0, list) else np.zeros(int(m["state_size"]))

    def step(self, dt, state, **inputs) -> dict:
        """One call of the function after checking the host's step ``dt`` (s): ``state``
        (the previous call's ``next_state``, :meth:`initial_state` first) and the inputs by
        name (the sidecar's ``inputs`` after ``state``). Returns every output as a numpy array
        (``next_state`` a vector, the torques floats)."""
        self.check_step(dt)
        out = self.function(state=state, **inputs)
        return {k: (np.asarray(v, dtype=float).ravel() if k == "next_state" else float(v)) for k, v in out.items()}

    def trajectory(self, n: int, dt):
        """The whole-record function (:func:`trajectory_function`) for ``n`` calls, after
        checking that the record's sample spacing ``dt`` (s) is the tick."""
        self.check_step(dt)
        return trajectory_function(self.function, n)


def load_casadi(path) -> CasadiExport:
    """Load an exported step function and its sidecar metadata.

    Parameters
    ----------
    path : str or Path
        A ``.casadi`` file written by ``lpvpc export --casadi``, ``lpvpc whole-joint
        --casadi``, :func:`export_casadi` or their whole-joint and closed-loop
        counterparts; its metadata is ``<path>.json``.

    Returns
    -------
    CasadiExport
        ``(function, metadata)``, with :meth:`CasadiExport.step` and
        :meth:`CasadiExport.trajectory` that check the host's time step against the tick.

    Raises
    ------
    ExportError
        A file is missing or unreadable, the sidecar is not lpvpc's, or it describes
        another function.
    """
    import casadi as ca

    path = Path(path)
    side = Path(str(path) + ".json")
    for f in (path, side):
        if not f.is_file():
            raise ExportError(f"{f}: no such file" + (" (the metadata lpvpc writes beside the .casadi file)"
                                                      if f is side else ""))
    try:
        meta = json.loads(side.read_text())
    except (OSError, ValueError) as exc:
        raise ExportError(f"{side}: not readable as JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != CASADI_FORMAT:
        raise ExportError(f"{side}: not the metadata of an lpvpc CasADi export (missing 'format': '{CASADI_FORMAT}')")
    try:
        function = ca.Function.load(str(path))
    except RuntimeError as exc:
        raise ExportError(f"{path}: not a CasADi function ({' '.join(str(exc).split())[:200]})") from None
    if meta.get("function") not in (None, function.name()) or meta.get("inputs") not in (None, function.name_in()):
        raise ExportError(f"{side} describes function {meta.get('function')!r} with inputs {meta.get('inputs')}, "
                          f"but {path} holds {function.name()!r} with inputs {function.name_in()}")
    return CasadiExport(function, meta)


def trajectory_function(step_or_path, n: int):
    """Whole-record function: ``step.mapaccum(n)``.

    ``step_or_path`` is a step ``casadi.Function`` or the path of a ``.casadi`` file.
    Call it with named arguments: ``state`` = the initial state (column, zeros at the
    start of a record), every other input as a 1 x n row (``params`` may be given once,
    as a column, and is repeated). Outputs: ``next_state`` (state_size x n, column k is
    the state after sample k; the last column continues a record), ``torque``,
    ``torque_intrinsic``, ``torque_reflex`` (1 x n rows, N m; for the exact variant
    column k is the torque of sample k - L).

    Parameters
    ----------
    step_or_path : casadi.Function or str or pathlib.Path
        A step function, or the path of a ``.casadi`` file.
    n : int
        Samples of the record (at least 1).

    Returns
    -------
    casadi.Function
        The whole-record function.

    Raises
    ------
    lpvpc.errors.ExportError
        ``n`` below 1.
    """
    import casadi as ca

    step = ca.Function.load(str(step_or_path)) if isinstance(step_or_path, (str, Path)) else step_or_path
    n = int(n)
    if n < 1:
        raise ExportError(f"trajectory length must be at least 1, got {n}")
    return step.mapaccum(f"{step.name()}_trajectory", n)


def replay_inputs(model, position, scheduling, variant="causal", signals=None) -> dict:
    """Named rows for :func:`trajectory_function` from a record (velocity/acceleration by
    the model's difference stencil for the causal variant, as in ``model.predict(causal=True)``).
    ``signals``: the extra channels of an extended model (as for ``model.predict``;

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    position, scheduling : array_like
        The record (rad), one value per sample.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).
    signals : dict, optional
        The extra channels of an extended model.

    Returns
    -------
    dict
        Input name -> 1 x n row.
    """
    position = np.asarray(position, dtype=float)
    scheduling = np.asarray(scheduling, dtype=float)
    args = {"position": position[None, :], "scheduling": scheduling[None, :]}
    if variant == "causal":
        vel, acc = eq.derivatives(position, model.fs, model.causal_derivatives)
        args["velocity"], args["acceleration"] = vel[None, :], acc[None, :]
    names = _effect_signals(model)
    if names:
        from ..models.effects import check_signals, default_signals

        sig = default_signals(scheduling, model.fs, signals)
        check_signals(sig, names, len(position))
        args.update({n: np.asarray(sig[n], dtype=float)[None, :] for n in names})
    return args


def _signal_units(model) -> dict:
    from ..models.effects import SIGNALS

    return {n: SIGNALS[n][0] for n in _effect_signals(model)}


# ---------------------------------------------------------------------------------------
# FMU export
CASADI_C_NAME = "lpvpc_model_casadi"  # generated C file (name fixed: the adapter includes it)

_INPUT_INFO = {
    "position": ("rad", "perturbation position (joint angle minus the operating position)"),
    "scheduling": ("rad", "operating position: the scheduling variable rho (beyond the identified range as the model's extrapolation rule says)"),
    "velocity": ("rad/s", "current perturbation velocity (from the actuator in closed loop; central "
                          "difference when replaying a record)"),
    "acceleration": ("rad/s2", "current perturbation acceleration (from the actuator in closed loop; central "
                               "second difference when replaying a record)"),
}
_OUTPUT_INFO = {
    "torque": "joint torque: intrinsic + reflex",
    "torque_intrinsic": "intrinsic pathway torque",
    "torque_reflex": "reflex pathway torque",
}


def model_source_dir() -> Path:
    """Folder with the generic C adapter ``model_system.c`` (next to the FMU wrapper).

    Returns
    -------
    pathlib.Path
        The folder.

    Examples
    --------
    >>> (model_source_dir() / "model_system.c").is_file()
    True
    """
    from .fmu_build import wrapper_dir

    return wrapper_dir().parent / "model"


def fmu_parameter_name(name: str) -> str:
    """FMU variable name of a parameter (C identifier): ``"H_causal[2,1]"`` -> ``"H_causal_2_1"``.

    Parameters
    ----------
    name : str
        The parameter's name in :func:`parameter_names`.

    Returns
    -------
    str
        A C identifier.
    """
    return name.replace("[", "_").replace("]", "").replace(",", "_")


def step_system_functions(step):
    """The three CasADi functions an FMU's C code is generated from, made from a parametric
    step function.

    Parameters
    ----------
    step : casadi.Function
        A step whose inputs are ``(state, u_1, ..., u_m, params)`` (scalar u_i) and whose
        outputs are ``(next_state, y_1, ..., y_r)`` (scalar y_j), as :func:`step_function`,
        :func:`lpvpc.export.whole_joint.whole_joint_step` and
        :func:`lpvpc.export.closed_loop.closed_loop_step` make them with ``parametric=True``.

    Returns
    -------
    initial, output, update : casadi.Function
        ``lpvpc_model_initial(p) -> x0`` (zeros: every exported step starts from rest),
        ``lpvpc_model_output(x, u, p) -> y`` and ``lpvpc_model_update(x, u, p) -> x_next``,
        with u and y the step's inputs and outputs stacked in order: the names the
        adapter ``model_system.c`` calls.
    output_dependencies : dict
        For each output name, the input names it depends on directly (the FMU's declared
        dependencies; an algebraic loop in a master is seen from them).

    Raises
    ------
    ExportError
        The step's last input is not ``params``.

    Examples
    --------
    A gain with a one-sample memory: ``y = p u + x``, ``x_next = u``.

    >>> import casadi as ca
    >>> x, u, p = ca.SX.sym("state"), ca.SX.sym("u"), ca.SX.sym("params")
    >>> step = ca.Function("gain", [x, u, p], [u, p * u + x], ["state", "u", "params"], ["next_state", "y"])
    >>> init, output, update, deps = step_system_functions(step)
    >>> float(output(2.0, 3.0, 0.5)), float(update(2.0, 3.0, 0.5)), deps
    (3.5, 3.0, {'y': ['u']})
    """
    import casadi as ca

    u_names, y_names = step.name_in()[1:-1], step.name_out()[1:]
    if step.name_in()[-1] != "params":
        raise ExportError(f"step function {step.name()!r} is not parametric: its last input is "
                          f"{step.name_in()[-1]!r}, not 'params'")
    x = ca.SX.sym("x", step.size1_in(0))
    u = ca.SX.sym("u", len(u_names))
    p = ca.SX.sym("p", step.size1_in(step.n_in() - 1))
    res = step(x, *[u[i] for i in range(len(u_names))], p)
    init = ca.Function("lpvpc_model_initial", [p], [ca.SX.zeros(x.shape[0])], ["p"], ["x0"])
    output = ca.Function("lpvpc_model_output", [x, u, p], [ca.vertcat(*res[1:])], ["x", "u", "p"], ["y"])
    update = ca.Function("lpvpc_model_update", [x, u, p], [res[0]], ["x", "u", "p"], ["x_next"])
    deps = {name: [u_names[i] for i in range(len(u_names)) if ca.depends_on(res[1 + k], u[i])]
            for k, name in enumerate(y_names)}
    return init, output, update, deps


def system_functions(model, variant="causal"):
    """The three CasADi functions the FMU's C code is generated from, all of (x, u, p):
    ``lpvpc_model_initial(p) -> x0``, ``lpvpc_model_output(x, u, p) -> y``,
    ``lpvpc_model_update(x, u, p) -> x_next``, with u = (position, scheduling[, velocity,
    acceleration]) and y = (torque, torque_intrinsic, torque_reflex). They call the
    parametric :func:`step_function` (:func:`step_system_functions`). Returns (initial,
    output, update, output_dependencies) where ``output_dependencies[name]`` lists the
    inputs an output depends on directly.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    tuple
        ``(initial, output, update, dependencies)``: the three ``casadi.Function`` objects
        and, per output, the inputs it depends on.
    """
    return step_system_functions(step_function(model, variant, parametric=True))


def generate_c(model, folder, variant="causal") -> list:
    """Write the CasADi-generated C code (``lpvpc_model_casadi.c`` and ``.h``) into
    ``folder``; returns the paths.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    folder : str or pathlib.Path
        Where to write (created).
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    list of pathlib.Path
        The C source and header.
    """
    init, output, update, _ = system_functions(model, variant)
    return write_system_c((init, output, update), folder)


def write_system_c(functions, folder) -> list:
    """Generate C for the three system functions (initial, output, update, named as in
    :func:`system_functions`) into ``folder`` as ``lpvpc_model_casadi.c`` and ``.h``, the
    files the adapter ``model_system.c`` includes; returns the paths.

    Parameters
    ----------
    functions : tuple of casadi.Function
        ``(initial, output, update)`` as :func:`system_functions` returns them.
    folder : str or pathlib.Path
        Where to write (created).

    Returns
    -------
    list of pathlib.Path
        The C source and header.

    Raises
    ------
    lpvpc.errors.ExportError
        CasADi's code generation did not write the files.
    """
    import casadi as ca

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{CASADI_C_NAME}.c", {"with_header": True, "casadi_real": "double"})
    for f in functions:
        cg.add(f)
    cg.generate(str(folder) + "/")
    paths = [folder / f"{CASADI_C_NAME}.c", folder / f"{CASADI_C_NAME}.h"]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ExportError(f"CasADi code generation did not write {', '.join(missing)}")
    # CasADi's generic entry points leave work arguments unused: keep the build log for
    # real warnings.
    paths[0].write_text('#if defined(__GNUC__)\n#pragma GCC diagnostic ignored "-Wunused-parameter"\n#endif\n'
                        + paths[0].read_text())
    return paths


def build_step_fmu(path, step, *, model_identifier: str, fmi_type: str = "cs", prefix: str = "lpvpc-export-",
                   **build_options) -> Path:
    """Build an FMU from a parametric CasADi step: the one build path of every model FMU.

    The step becomes the three system functions (:func:`step_system_functions`), CasADi
    writes their C (:func:`write_system_c`) into a temporary folder, and
    :func:`lpvpc.export.fmu_build.build_fmu` compiles it with the generic adapter ``model_system.c``
    (:func:`model_source_dir`) and the FMI wrapper.

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` to write.
    step : casadi.Function
        The parametric step (inputs ``state``, the FMU's inputs in value-reference order,
        ``params``).
    model_identifier : str
        The co-simulation identifier; a Model Exchange FMU gets it suffixed ``_me``.
    fmi_type : {"cs", "me"}
        Co-simulation (default) or Model Exchange.
    prefix : str
        Prefix of the temporary folder of the generated C (shows which export made it).
    **build_options
        The rest of :func:`lpvpc.export.fmu_build.build_fmu`'s keywords (variables, step size,
        FMI version, description, ...), passed on unchanged; ``nx`` defaults to the step's
        state size.

    Returns
    -------
    Path
        The FMU written.

    Raises
    ------
    ExportError
        Code generation or compilation failed, or the FMU could not be written.
    """
    import tempfile

    from .fmu_build import build_fmu

    init, output, update, _ = step_system_functions(step)
    build_options.setdefault("nx", step.size1_in(0))
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        generated = write_system_c((init, output, update), tmp)
        try:
            out = build_fmu(path, model_identifier=model_identifier + ("_me" if fmi_type == "me" else ""),
                            system_sources=[model_source_dir() / "model_system.c", *generated],
                            interface=fmi_type, **build_options)
        except ExportError:
            raise
        except OSError as exc:
            raise ExportError(f"{path}: could not write the FMU ({exc})") from None
    return Path(out)


def ticks_per_sample(model) -> int:
    """Base ticks per sample period of the sampled FMU: the tick closest to 1 ms that
    divides the period (10 at 100 Hz), so that masters can step at about 1 ms.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.

    Returns
    -------
    int
        Ticks per sample period.
    """
    return max(1, int(round(1.0 / (float(model.fs) * 1e-3))))


def fmu_constants(model, variant="causal"):
    """Constant outputs that state the timing contract in the FMU itself: ``latency`` (s,
    the delay of a sample's torque in sample periods times the period) and
    ``sample_period`` (s); the causal variant adds ``derivative_points`` (3 or 5: the central
    differences its velocity and acceleration inputs must be).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    list of lpvpc.export.fmu_build.FmuVariable
        The constant outputs.
    """
    from .fmu_build import FmuVariable

    T = 1.0 / float(model.fs)
    lat = latency_samples(model, variant)
    when = ("the torque of sample k is the output from the end of the communication step that starts at sample "
            "time k + 1 (inputs taken at sample times)" if variant == "sampled" else
            "outputs have direct feedthrough of the inputs set at the same communication point")
    constants = [FmuVariable("latency", "output", "s", f"output latency: {lat} sample(s) of {T!r} s; {when}",
                             lat * T, dependencies=[]),
                 FmuVariable("sample_period", "output", "s", "model sample period 1/fs", T, dependencies=[])]
    if variant == "causal":  # a master must supply the derivatives the coefficients were identified with
        points = derivative_points(model)
        constants.append(FmuVariable(
            "derivative_points", "output", "", f"the velocity and acceleration inputs are {points}-point central "
            f"differences of the position at the sample period (they need position k + {points // 2})",
            float(points), dependencies=[]))
    return constants


def derivative_points(model) -> int:
    """Points of the central differences (velocity rad/s, acceleration rad/s^2) the model's
    causal form was identified with: 3 or 5 (files without the key: 3).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.

    Returns
    -------
    int
        3 or 5.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> derivative_points(SimpleNamespace(causal_derivatives="central5")), derivative_points(SimpleNamespace())
    (5, 3)
    """
    return 5 if getattr(model, "causal_derivatives", "central3") == "central5" else 3


def fmu_variables(model, variant="causal"):
    """(outputs, inputs, parameters) as :class:`lpvpc.export.fmu_build.FmuVariable` lists.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    tuple of list
        ``(outputs, inputs, parameters)``.
    """
    from .fmu_build import FmuVariable

    _, _, _, deps = system_functions(model, variant)
    if variant == "sampled":  # sampled mode: outputs are held samples, none depends on the current inputs
        deps = {name: [] for name in deps}
    outputs = [FmuVariable(name, "output", "N.m", text, dependencies=deps[name])
               for name, text in _OUTPUT_INFO.items()]
    info = dict(_INPUT_INFO)
    if getattr(model, "effects", None):
        from ..models.effects import SIGNALS

        info.update({n: (u, f"{text} (an input of the model's effects)") for n, (u, text) in SIGNALS.items()})
    inputs = [FmuVariable(name, "input", info[name][0], info[name][1], 0.0)
              for name in input_names(variant, model=model)[1:]]
    parameters = [FmuVariable(fmu_parameter_name(n), "parameter", unit, f"{n}: {text}", float(v))
                  for n, v, (text, unit) in zip(parameter_names(model, variant), parameter_vector(model, variant),
                                                parameter_info(model, variant))]
    return outputs, inputs, parameters


def fmu_description(model, variant="causal") -> str:
    """The FMU's description text: what the model is, its variant and timing contract, its range.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The exported form (:func:`export_fmu`).

    Returns
    -------
    str
        The FMU's description text.
    """
    from .. import __version__

    lo, hi = model.scheduling_range
    lat = latency_samples(model, variant)
    text = (f"LPV parallel-cascade ankle stiffness model exported by lpvpc {__version__}; "
            f"model sha256 {model.model_hash}; variant {variant}; sample rate {model.fs!r} Hz. ")
    if variant == "sampled":
        T = 1.0 / float(model.fs)
        text += (f"Inputs are positions only; velocity and acceleration are computed inside ({derivative_points(model)}"
                 f"-point central differences, as identified), so the torque of sample k needs position k + {lat}: "
                 f"latency {lat} sample(s) ({lat * T!r} s). "
                 f"Timing contract: the model is sampled at t_start + k*{T!r} s; a communication step that starts "
                 f"at a sample time takes the inputs set at its start, and from its end the outputs are the torque "
                 f"of sample k - {lat} (held; no direct feedthrough, the same in every master). Step at the "
                 f"DefaultExperiment step ({T / ticks_per_sample(model)!r} s) or any divisor of the sample period "
                 f"that is a multiple of it. ")
    elif variant == "causal":
        text += ("Causal intrinsic IRF with current velocity and acceleration inputs: no added latency when the "
                 "master sets the inputs before reading the outputs. ")
    else:
        text += (f"Exact two-sided intrinsic IRF: outputs are the torque of {lat} samples earlier "
                 f"(latency {lat / model.fs!r} s) with direct feedthrough of the current inputs; 0 before that. ")
    text += (f"Scheduling outside the identified range [{lo!r}, {hi!r}] rad: the model is {model.beyond_range}. "
             "Parameters: identified coefficients (row-major, see variable descriptions).")
    if getattr(model, "effects", None):
        text += (f" Extended model with effects {', '.join(fe.name for fe in model.effects)}; extra inputs "
                 f"{', '.join(_effect_signals(model)) or 'none'}.")
    return text


def export_fmu(model, path, fmi_version: int = 2, variant: str = "causal", *, timings: dict | None = None,
               reuse_existing: bool = False, fmi_type: str = "cs") -> Path:
    """Export the model as an FMI 2.0 (default) or 3.0 co-simulation FMU; returns its path.

    C code is generated by CasADi from the parametric :func:`step_function`, joined to
    the generic adapter ``lpvpc/export/c/model/model_system.c`` and the project's FMI wrapper,
    and compiled with the system C compiler (:func:`lpvpc.export.fmu_build.build_fmu`).

    Variables: inputs ``position``, ``scheduling`` (rad) and, for ``"causal"``,
    ``velocity`` (rad/s), ``acceleration`` (rad/s2); outputs ``torque``,
    ``torque_intrinsic``, ``torque_reflex`` (N.m); constant outputs ``latency`` and
    ``sample_period`` (s, :func:`fmu_constants`); the identified coefficients as fixed
    parameters (:func:`fmu_parameter_name` of :func:`parameter_names`).

    ``"sampled"`` (what ``lpvpc export --fmu`` makes): sampled every 1/fs s, communication
    steps are multiples of the base tick 1/(fs * :func:`ticks_per_sample`) (1 ms at 100 Hz,
    the DefaultExperiment step); outputs are the torque of the previous sample from the end
    of the step that starts at a sample time (see ``fmu_description``). ``"causal"`` and
    ``"exact"``: step size 1/fs, communication steps multiples of it, outputs with direct
    feedthrough of the current inputs (for masters that set inputs before reading outputs,
    such as :mod:`lpvpc.validation`).
    ``timings`` (a dict) receives ``codegen``, ``compile`` and ``total`` seconds.
    ``fmi_type="me"``: a Model Exchange FMU of the same model instead, sampled with a time
    event every 1/fs s (inputs sampled there; outputs at t_k equal the co-simulation FMU's at
    sample k; model identifier suffixed ``_me``).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The model to export.
    path : str or pathlib.Path
        The ``.fmu`` file to write.
    fmi_version : {2, 3}, default 2
        The FMI version.
    variant : {"causal", "sampled", "exact"}, default "causal"
        The form exported (above); :meth:`LPVPCModel.export_fmu
        <lpvpc.models.model.LPVPCModel.export_fmu>` defaults to
        :data:`DEFAULT_VARIANT` instead.
    timings : dict, optional
        Receives ``codegen``, ``compile`` and ``total`` seconds.
    reuse_existing : bool, default False
        Return an existing FMU at ``path`` built from the same sources and settings
        without rebuilding it.
    fmi_type : {"cs", "me"}, default "cs"
        Co-simulation, or Model Exchange (above).

    Returns
    -------
    pathlib.Path
        The FMU's path.

    Raises
    ------
    lpvpc.errors.ExportError
        An unknown variant, no C compiler, or a compiler error.
    """
    import time

    from .. import __version__

    _check_variant(variant)
    t0 = time.perf_counter()
    outputs, inputs, parameters = fmu_variables(model, variant)
    lat = latency_samples(model, variant)
    step = step_function(model, variant, parametric=True)
    build_timings = {}
    out = build_step_fmu(
        path, step,
        model_identifier={"sampled": "lpvpc_model", "causal": "lpvpc_model_causal",
                          "exact": "lpvpc_model_exact"}[variant],
        fmi_type=fmi_type,
        nx=state_layout(model, variant).size,
        step_size=1.0 / float(model.fs),
        outputs=outputs,
        inputs=inputs,
        parameters=parameters,
        fmi_version=fmi_version,
        description=fmu_description(model, variant),
        version=f"lpvpc {__version__} model {model.model_hash[:12]}",
        latency=lat / float(model.fs),
        reuse_existing=reuse_existing,
        timings=build_timings,
        # co-simulation: the wrapper's sampled mode (base tick ~1 ms) for the default variant
        ticks_per_sample=ticks_per_sample(model) if variant == "sampled" and fmi_type == "cs" else 0,
        constants=fmu_constants(model, variant),
    )
    t2 = time.perf_counter()
    if timings is not None:  # codegen: the variables and the C code, everything but build_fmu
        timings.update(codegen=t2 - t0 - build_timings.get("total", 0.0), compile=build_timings.get("compile", 0.0),
                       total=t2 - t0, build=build_timings)
    return Path(out)
