"""The whole-joint model: joint angle in, total joint torque out.

Prosthesis and controller designers have the joint angle, not a perturbation split into a
"perturbation position" and an "operating position". This model makes that split itself,
causally, and adds the quasi-static torque that the identification's PT minus UT removed:

    operating angle   rho(k) = lowpass(theta)(k)       first-order, cutoff f_c (Hz), at rest
                                                        at the first sample: rho(0) = theta(0)
    perturbation      p(k)   = theta(k) - rho(k)
    total torque      tq(k)  = T_qs(rho(k)) + LPVPC(p, rho)(k)

with ``T_qs`` the quasi-static torque-angle curve fitted to the UT trial (torque against
angle, a basis expansion extended linearly beyond the identified range) and ``LPVPC`` the
identified parallel-cascade model (two-sided intrinsic IRF, reflex pathway). Every equation
comes from :mod:`lpvpc.models.equations` (``lowpass_step``, ``quasi_static_torque``) and the LPV-PC
step of :mod:`lpvpc.export.exporter`; the numpy prediction, the CasADi function and the FMU share it.

Timing: the two-sided IRF needs L future angles, so the CasADi step and the FMU that
receive theta(k) return the torque of sample k - L (``latency_samples``; L/fs s, 0 N m
before that), exactly like the ``exact`` export variant. ``predict`` is the offline
(non-delayed) prediction. For a plant that the torque moves (a controller or prosthesis
simulation) that latency and the inertia inside the torque destabilise the loop: use the
closed-loop form of :mod:`lpvpc.export.closed_loop` (``lpvpc whole-joint --closed-loop``) there.

The low-pass is a compromise: a slow cutoff lets the operating-angle estimate lag behind
voluntary movement (the elastic torque of that lag then comes from the perturbation
pathway's stiffness instead of the quasi-static curve); a fast one removes part of the
perturbation from p. Measured on the virtual subject (benchmarks/bench_whole_joint.py):
0.5 Hz, first order, is near the best perturbation-part VAF over 0.3-3 Hz.

Units: angle rad, torque N m, cutoff Hz, time s.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..models import equations as eq
from ..models.basis import Basis, CasadiOps, basis_from_data
from ..errors import DataError, ModelFileError, non_finite_problem

__all__ = ["WholeJointModel", "WholeJointPrediction", "fit_quasi_static", "fit_whole_joint",
           "whole_joint_step", "export_whole_joint_casadi", "export_whole_joint_fmu", "latency_samples",
           "DEFAULT_CUTOFF", "OUTPUT_NAMES"]

FORMAT = "lpvpc-whole-joint"
FORMAT_VERSION = 1
DEFAULT_CUTOFF = 0.5  # Hz (module notes)
DEFAULT_ORDER = 5
OUTPUT_NAMES = ("torque", "torque_quasi_static", "torque_perturbation", "torque_intrinsic", "torque_reflex",
                "operating_angle")
_OUTPUT_INFO = {
    "torque": ("N.m", "total joint torque: quasi-static + perturbation (of sample k - L)"),
    "torque_quasi_static": ("N.m", "quasi-static torque-angle curve at the operating angle"),
    "torque_perturbation": ("N.m", "LPV parallel-cascade torque of the perturbation (intrinsic + reflex)"),
    "torque_intrinsic": ("N.m", "intrinsic pathway torque"),
    "torque_reflex": ("N.m", "reflex pathway torque"),
    "operating_angle": ("rad", "causally low-passed joint angle (the scheduling variable)"),
}


@dataclass
class WholeJointPrediction:
    """Offline prediction (N m, rad), one value per sample of the angle record.

    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.models.model import vaf
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> wj = fit_whole_joint(identify(pair_trials(sim.pt, sim.ut)), sim.ut)
    >>> p = wj.predict(sim.pt.position, warn=False)  # the joint angle of the perturbed trial, rad
    >>> bool(np.allclose(p.total, p.quasi_static + p.perturbation_torque))  # N m
    True
    >>> bool(vaf(sim.pt.torque, p.total) > 95.0)  # percent
    True
    """

    total: np.ndarray
    quasi_static: np.ndarray
    perturbation_torque: np.ndarray
    intrinsic: np.ndarray
    reflex: np.ndarray
    operating_angle: np.ndarray
    perturbation: np.ndarray


@dataclass
class WholeJointModel:
    """An identified LPV-PC model plus the quasi-static curve and the operating-angle low-pass.

    ``model``: :class:`lpvpc.models.model.LPVPCModel`; ``curve_basis``/``curve``: the quasi-static
    torque-angle curve (basis in rad, coefficients in N m); ``cutoff``: low-pass cutoff (Hz).
    """

    model: object
    curve_basis: Basis
    curve: np.ndarray
    cutoff: float = DEFAULT_CUTOFF
    fit: dict = field(default_factory=dict)

    def __post_init__(self):
        self.curve = np.asarray(self.curve, dtype=float).reshape(-1)
        if self.curve.size != self.curve_basis.size:
            raise ValueError(f"quasi-static curve has {self.curve.size} coefficients, its basis "
                             f"{self.curve_basis.size} functions")
        if not (np.isfinite(self.cutoff) and 0.0 < self.cutoff < 0.5 * self.fs):
            raise ValueError(f"low-pass cutoff {self.cutoff!r} Hz must lie in (0, fs/2 = {0.5 * self.fs}) Hz")

    @property
    def fs(self) -> float:
        return float(self.model.fs)

    @property
    def alpha(self) -> float:
        return float(eq.lowpass_alpha(self.cutoff, self.fs))

    def quasi_static(self, angle) -> np.ndarray:
        """Quasi-static torque (N m) at ``angle`` (rad)."""
        return eq.quasi_static_torque(self.curve_basis.evaluate(angle), self.curve)

    def split(self, angle):
        """(operating angle, perturbation) of an angle record (rad)."""
        angle = _checked_angle(angle)
        rho = eq.lowpass(angle, self.alpha)
        return rho, angle - rho

    def predict(self, angle, *, warn: bool = True) -> WholeJointPrediction:
        """Offline total torque (N m) for a joint-angle record (rad) sampled at ``fs``."""
        rho, p = self.split(angle)
        lp = self.model.predict(p, rho, warn=warn)
        qs = self.quasi_static(rho)
        return WholeJointPrediction(total=qs + lp.total, quasi_static=qs, perturbation_torque=lp.total,
                                    intrinsic=lp.intrinsic, reflex=lp.reflex, operating_angle=rho, perturbation=p)

    # -- persistence ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "cutoff": float(self.cutoff),
                "quasi_static": {"basis": self.curve_basis.to_dict(), "coefficients": self.curve.tolist()},
                "units": {"angle": "rad", "torque": "N m", "cutoff": "Hz"}, "fit": self.fit,
                "model": self.model.to_dict()}

    @classmethod
    def from_dict(cls, d: dict, source: str = "whole-joint model") -> "WholeJointModel":
        from ..models.model import LPVPCModel

        if not isinstance(d, dict) or d.get("format") != FORMAT or d.get("format_version") != FORMAT_VERSION:
            raise ModelFileError(f"{source}: not an lpvpc whole-joint model file (format {FORMAT!r} version "
                                 f"{FORMAT_VERSION})")
        from ..models.modelfile import check_whole_joint_dict

        check_whole_joint_dict(d, source)  # its own fields; the embedded model: LPVPCModel.from_dict
        try:
            qs = d["quasi_static"]
            return cls(model=LPVPCModel.from_dict(d["model"], source), curve_basis=Basis.from_dict(qs["basis"]),
                       curve=np.array(qs["coefficients"], dtype=float), cutoff=float(d["cutoff"]),
                       fit=d.get("fit", {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{source}: corrupt whole-joint model file ({type(exc).__name__}: {exc})") from None

    def save(self, path) -> None:
        from ..io.outputs import write_text

        write_text(path, json.dumps(self.to_dict(), indent=1))  # temporary file + rename

    @classmethod
    def load(cls, path) -> "WholeJointModel":
        from ..models.modelfile import read_model_file

        return cls.from_dict(read_model_file(path), str(path))  # a regular file, size, nesting, JSON


def _checked_angle(angle) -> np.ndarray:
    angle = np.asarray(angle, dtype=float)
    if angle.ndim != 1 or len(angle) < 1:
        raise DataError([f"channel angle: expected a 1-D record of at least one sample, got shape {angle.shape}"])
    if problem := non_finite_problem("angle", angle):
        raise DataError([problem])
    return angle


def fit_quasi_static(angle, torque, order: int = DEFAULT_ORDER, family: str = "chebyshev"):
    """Least-squares torque-angle curve of an unperturbed trial: (basis, coefficients, VAF %).

    ``angle`` rad, ``torque`` N m, same length. The basis spans the trial's angles and
    continues linearly beyond them (a tangent, not a polynomial blowing up).

    >>> angle = np.linspace(-0.4, 0.2, 200)  # rad
    >>> basis, coef, fit_vaf = fit_quasi_static(angle, 30.0 * angle + 40.0 * angle**2, order=3)
    >>> round(fit_vaf, 6), bool(np.allclose(basis.evaluate(angle) @ coef, 30.0 * angle + 40.0 * angle**2))
    (100.0, True)
    """
    from ..models.model import vaf

    angle = _checked_angle(angle)
    torque = np.asarray(torque, dtype=float)
    if torque.shape != angle.shape:
        raise DataError([f"angle and torque differ in length: {angle.shape} and {torque.shape}"])
    if problem := non_finite_problem("torque", torque):
        raise DataError([problem])
    if len(angle) < 4 * (order + 1):
        raise DataError([f"{len(angle)} samples are too few for a quasi-static curve of order {order}"])
    basis = basis_from_data(angle, family, order, extrapolation="linear")
    G = basis.evaluate(angle)
    coef, *_ = np.linalg.lstsq(G, torque, rcond=None)
    return basis, coef, vaf(torque, G @ coef)


def fit_whole_joint(model, ut, *, cutoff: float = DEFAULT_CUTOFF, order: int = DEFAULT_ORDER) -> WholeJointModel:
    """Whole-joint model from an identified LPV-PC ``model`` and the UT trial it came from.

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel
        The identified perturbation model.
    ut : lpvpc.io.trial.Trial or tuple of numpy.ndarray
        The unperturbed trial (any rate above ``model.fs``; it is resampled and decimated
        with the package's anti-alias filter, as the identification data), or an
        ``(angle, torque)`` pair (rad, N m) at ``model.fs``.
    cutoff : float, default 0.5
        Cutoff (Hz) of the first-order low-pass that estimates the operating angle (module
        notes).
    order : int, default 5
        Polynomial order of the quasi-static torque curve of the operating angle.

    Returns
    -------
    WholeJointModel
        The model of the total joint torque: the quasi-static curve plus ``model``.
    """
    from ..io import Trial, decimate_trial, to_multiple_rate

    if isinstance(ut, Trial):
        ut = to_multiple_rate(ut, model.fs)  # as the identification data (lpvpc.io.pair_trials)
        q = ut.fs / model.fs
        low = ut if abs(q - 1.0) < 1e-9 else decimate_trial(ut, model.fs)
        angle, torque = low.position, low.torque
    else:
        angle, torque = ut
    basis, coef, fit_vaf = fit_quasi_static(angle, torque, order)
    return WholeJointModel(model=model, curve_basis=basis, curve=coef, cutoff=float(cutoff),
                           fit={"quasi_static_vaf": fit_vaf, "quasi_static_order": int(order)})


# ---------------------------------------------------------------------------------------
# CasADi step and FMU
def latency_samples(wj: WholeJointModel) -> int:
    """Output delay of the step and the FMU in samples (L of the two-sided IRF)."""
    from .exporter import latency_samples as lpvpc_latency

    return lpvpc_latency(wj.model, "exact")


def _parameter_blocks(wj):
    """(names, values, (description, unit)) of the parametric step's ``params``."""
    from .exporter import parameter_info, parameter_names, parameter_vector

    names = list(parameter_names(wj.model, "exact"))
    values = list(parameter_vector(wj.model, "exact"))
    info = list(parameter_info(wj.model, "exact"))
    names += [f"curve[{i}]" for i in range(wj.curve.size)] + ["cutoff"]
    values += list(wj.curve) + [wj.cutoff]
    info += [(f"quasi-static torque-angle curve coefficient {i} ({wj.curve_basis.family} basis on "
              f"[{wj.curve_basis.lo!r}, {wj.curve_basis.hi!r}] rad)", "N.m") for i in range(wj.curve.size)]
    info += [("cutoff frequency of the operating-angle low-pass", "Hz")]
    return names, np.array(values, dtype=float), info


def whole_joint_step(wj: WholeJointModel, parametric: bool = False, name: str = "lpvpc_whole_joint_step"):
    """The whole-joint model's step as a ``casadi.Function``.

    Inputs: ``state`` (zeros at the start of a record), ``angle`` (rad)[, ``params``].
    Outputs: ``next_state`` and ``OUTPUT_NAMES`` of sample k - L (0 for k < L).

    The CasADi step reproduces the offline prediction, L samples later:

    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> wj = fit_whole_joint(identify(pair_trials(sim.pt, sim.ut)), sim.ut)
    >>> step = whole_joint_step(wj)
    >>> angle = sim.pt.position[:300]
    >>> out = step.mapaccum(len(angle))(np.zeros(step.size1_in(0)), angle[None, :])
    >>> L = latency_samples(wj)
    >>> torque = np.asarray(out[1]).ravel()
    >>> bool(np.allclose(torque[L:], wj.predict(angle, warn=False).total[:-L], atol=1e-9))
    True
    """
    import casadi as ca

    from .exporter import state_layout, step_function

    ops = CasadiOps()
    L = latency_samples(wj)
    inner = step_function(wj.model, "exact", parametric=True)
    n_inner = state_layout(wj.model, "exact").size
    names, values, _ = _parameter_blocks(wj)
    n_model = len(names) - wj.curve.size - 1
    n_state = 2 + L + n_inner  # [samples seen (saturating), rho(k-1), rho(k-1)..rho(k-L), inner state]

    state = ca.SX.sym("state", n_state)
    angle = ca.SX.sym("angle")
    p = ca.SX.sym("params", len(names)) if parametric else ca.DM(values)
    count, rho_prev, rho_hist, inner_state = state[0], state[1], state[2: 2 + L], state[2 + L:]
    alpha = eq.lowpass_alpha(p[len(names) - 1], wj.fs, ops)
    curve = p[n_model: n_model + wj.curve.size]

    rho = ca.if_else(count > 0, eq.lowpass_step(rho_prev, angle, alpha), angle)
    inner_next, tq_p, tq_i, tq_r = inner(inner_state, angle - rho, rho, p[:n_model])
    rho_j = rho if L == 0 else rho_hist[L - 1]  # operating angle of sample k - L
    started = count >= L
    tq_qs = ca.if_else(started, eq.quasi_static_torque(wj.curve_basis.evaluate(rho_j, ops), curve, ops), 0.0)
    rho_out = ca.if_else(started, rho_j, 0.0)
    next_state = ca.vertcat(ca.fmin(count + 1.0, float(L + 1)), rho, *([rho, rho_hist[: L - 1]] if L else []),
                            inner_next)
    inputs, in_names = [state, angle], ["state", "angle"]
    if parametric:
        inputs.append(p)
        in_names.append("params")
    return ca.Function(name, inputs, [next_state, tq_qs + tq_p, tq_qs, tq_p, tq_i, tq_r, rho_out], in_names,
                       ["next_state", *OUTPUT_NAMES])


def export_whole_joint_casadi(wj: WholeJointModel, path) -> Path:
    """Save the (non-parametric) step with ``Function.save`` and its metadata in
    ``<path>.json`` (:func:`lpvpc.export.exporter.save_casadi`: tick, latency, units, names, initial
    state); run a record with ``lpvpc.export.exporter.trajectory_function`` (inputs ``state`` = zeros,
    ``angle`` = 1 x n row), or load both with :func:`lpvpc.export.exporter.load_casadi`."""
    from .exporter import save_casadi

    L, T = latency_samples(wj), 1.0 / wj.fs
    meta = {"kind": "whole-joint", "variant": "exact", "fs": wj.fs, "tick_s": T, "sample_period_s": T,
            "latency_samples": L, "latency_s": L * T,
            "units": {"state": "the previous call's next_state", "angle": "rad", "next_state": "(state)",
                      **{n: u.replace("N.m", "N m") for n, (u, _) in _OUTPUT_INFO.items()}},
            "inertia": {"kg_m2": None, "in_torque": True,
                        "note": "the intrinsic impulse response contains the foot's inertia: do not add it again"},
            "cutoff_hz": wj.cutoff, "model_hash": wj.model.model_hash}
    return save_casadi(whole_joint_step(wj), path, meta)


def replay(wj: WholeJointModel, angle) -> dict:
    """Run the CasADi step over an angle record plus L held samples: numpy arrays of the
    outputs aligned with the record (sample k is the torque of angle sample k)."""
    import casadi as ca

    from .exporter import trajectory_function

    angle = _checked_angle(angle)
    L = latency_samples(wj)
    step = whole_joint_step(wj)
    x = np.concatenate([angle, np.full(L, angle[-1])])
    out = trajectory_function(step, len(x))(state=np.zeros(step.size1_in(0)), angle=x[None, :])
    return {k: np.asarray(ca.DM(out[k])).ravel()[L:] for k in OUTPUT_NAMES}


def export_whole_joint_fmu(wj: WholeJointModel, path, fmi_version: int = 2, *, reuse_existing: bool = False,
                           fmi_type: str = "cs") -> Path:
    """The whole-joint model as an FMI 2.0 or 3.0 co-simulation FMU (input ``angle`` rad,
    outputs ``OUTPUT_NAMES``, step 1/fs, outputs of sample k - L; parameters: the
    LPV-PC coefficients, the curve coefficients ``curve_i`` and ``cutoff`` Hz);
    ``fmi_type="me"``: Model Exchange, a time event per sample (see :func:`lpvpc.export.exporter.export_fmu`)."""
    from .. import __version__
    from .exporter import build_step_fmu, fmu_parameter_name, step_system_functions
    from .fmu_build import FmuVariable

    step = whole_joint_step(wj, parametric=True)
    deps = step_system_functions(step)[3]
    names, values, info = _parameter_blocks(wj)
    outputs = [FmuVariable(n, "output", _OUTPUT_INFO[n][0], _OUTPUT_INFO[n][1], dependencies=deps[n])
               for n in OUTPUT_NAMES]
    inputs = [FmuVariable("angle", "input", "rad", "joint angle", 0.0)]
    parameters = [FmuVariable(fmu_parameter_name(n), "parameter", unit, f"{n}: {text}", float(v))
                  for n, v, (text, unit) in zip(names, values, info)]
    L = latency_samples(wj)
    lo, hi = wj.model.scheduling_range
    description = (f"Whole-joint ankle model exported by lpvpc {__version__} (LPV-PC model sha256 "
                   f"{wj.model.model_hash}): joint angle in, total torque out = quasi-static torque-angle curve at "
                   f"the operating angle (first-order low-pass, cutoff {wj.cutoff!r} Hz) + LPV parallel cascade of "
                   f"the angle minus it. Outputs are those of {L} samples earlier (latency {L / wj.fs!r} s; 0 before "
                   f"that). Sample rate {wj.fs!r} Hz. Operating angle outside [{lo!r}, {hi!r}] rad: the cascade is "
                   f"{wj.model.beyond_range}, the curve continues linearly.")
    return build_step_fmu(path, step, model_identifier="lpvpc_whole_joint", fmi_type=fmi_type,
                          prefix="lpvpc-whole-joint-", step_size=1.0 / wj.fs, outputs=outputs, inputs=inputs,
                          parameters=parameters, fmi_version=fmi_version, description=description,
                          version=f"lpvpc {__version__} model {wj.model.model_hash[:12]}", latency=L / wj.fs,
                          reuse_existing=reuse_existing)
