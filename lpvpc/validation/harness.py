"""Validate a fitted model on a held-out PT/UT record: every prediction route, the
co-simulation with the actuator, the comparison, and the report.

Units: time s, angles rad, torque N m, rates Hz, VAF percent.

:func:`validate` checks its inputs first (model file, both records, sampling rates, the
FMUs) so that bad input fails in well under a second with one :class:`lpvpc.errors.LpvpcError`
(exit status 2 on the command line), then runs:

1. the offline routes (numpy two-sided and causal, CasADi causal and exact) and the model
   FMU replaying the measured positions (:mod:`lpvpc.validation.routes`);
2. the co-simulation of the lab experiment (:mod:`lpvpc.validation.cosim`): calibrated actuator
   runs driven by the record's commands, the model FMU closing the loop; once more
   without load to measure what the load changes;
3. the comparison (:mod:`lpvpc.validation.compare`) and the report (:mod:`lpvpc.validation.report`):
   ``report.html``, ``metrics.json``, the figures as PNG and the co-simulation set-up as an
   SSP archive (``cosimulation.ssp``, :mod:`lpvpc.validation.ssp`) in the report folder.
"""

from __future__ import annotations

import datetime as _dt
import inspect
import platform
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from lpvpc.models import equations as eq
from lpvpc.io import (Trial, check_model_rate, decimate_signal, load_trial, pair_trials, perturbation_file_trials,
                        split_variable, stationary_ut, to_multiple_rate)
from lpvpc.errors import DataError, FMUError, OutOfRangeWarning
from lpvpc.export.exporter import latency_samples
from lpvpc.models.model import LPVPCModel
from lpvpc.io.outputs import staged_folder
from lpvpc.progress import report as progress

from . import compare as cmp
from .cosim import (ACTUATOR_INPUTS, ACTUATOR_LINEAR_PARAMETERS, ACTUATOR_OUTPUTS, MODEL_OUTPUTS, ActuatorDrive,
                    CosimSettings, actuator_inverse, band_limit, calibrate_servo, feedforward_command, model_fmu_sampled,
                    model_fmu_variant, run_cosimulation, to_rate)
from .fmu import FMUInfo, file_sha256, fmu_model_hash, inspect_fmu
from .routes import casadi_routes, fmu_replay, model_fmu_inputs, offline_routes

__all__ = ["validate", "ValidationResult", "load_record", "Record", "DEFAULT_ROUTE_TOLERANCE"]

#: Largest max|a - b| / max|b| allowed between the numpy causal prediction and the CasADi
#: and FMU routes (they evaluate the same equations; measured ~1e-15).
DEFAULT_ROUTE_TOLERANCE = 1e-9
#: The co-simulation set-up as an SSP 1.0 archive, in the report folder (:mod:`lpvpc.validation.ssp`).
SSP_FILE = "cosimulation.ssp"
#: The same set-up for engines that only connect outputs to inputs (libcosim, ECOS): every
#: signal the master computes is done by a record-player FMU (:func:`lpvpc.validation.ssp.write_portable_ssp`).
PORTABLE_SSP_FILE = "cosimulation_portable.ssp"
#: Calibration of the servo is reported as poor below this VAF (percent) of the position fit.
CALIBRATION_WARN_VAF = 99.0
#: Iterative learning of a command rebuilt from a record's measured positions (no command
#: channel): at most this many passes, each one co-simulation; it stops when the perturbation
#: tracking error is below COMMAND_REFINEMENT_TOLERANCE of the perturbation's RMS, or when a
#: pass does not cut it by a tenth.
COMMAND_REFINEMENT_PASSES = 4
COMMAND_REFINEMENT_TOLERANCE = 1e-4


@dataclass
class Record:
    """The held-out record: the two trials in SI units and their pairing at the model rate."""

    pt: Trial
    ut: Trial
    measured: object  # lpvpc.io.PerturbationData at the model rate
    files: dict  # role ("pt", "ut"; or "data": one PT - UT file) -> {"path", "sha256"}
    fs_file: float | None = None  # the files' own rate when pt/ut were resampled from it

    @property
    def ut_torque_known(self) -> bool:
        """False for a PT - UT file: its UT trial is rebuilt from the scheduling, torque unknown."""
        return "data" not in self.files

    @property
    def fs(self) -> float:
        return self.pt.fs

    @property
    def has_command(self) -> bool:
        return "command" in self.pt.channels and "command" in self.ut.channels


@dataclass
class ValidationResult:
    """What :func:`validate` measured and wrote.

    Parameters
    ----------
    metrics : dict
        Every VAF (%), RMSE (N m), route agreement and check, as in ``metrics.json``;
        ``metrics["pass"]`` is False when a threshold failed.
    report_dir : pathlib.Path
        The report folder.
    files : dict, optional
        The files written, by role (report, metrics, FMUs, figures).

    Examples
    --------
    >>> result = ValidationResult({"pass": True, "vaf": 96.5, "vaf_fmu": 96.5}, Path("report"))
    >>> result.passed, result
    (True, ValidationResult(pass; vaf 96.50 %, vaf_fmu 96.50 %; report 'report'))
    """

    metrics: dict
    report_dir: Path
    files: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return bool(self.metrics["pass"])

    def __repr__(self):
        m = self.metrics
        vafs = ", ".join(f"{k} {m[k]:.2f} %" for k in ("vaf", "vaf_fmu", "vaf_cosim") if k in m)
        return f"ValidationResult({'pass' if m.get('pass') else 'FAIL'}; {vafs}; report {str(self.report_dir)!r})"


# --------------------------------------------------------------------------- inputs


def load_record(model: LPVPCModel, pt, ut, *, position_unit=None, torque_sign=None, time_unit=None, variable=None,
                channels=None, data=None, stationary: bool = False, hold_out=None) -> Record:
    """Load the held-out PT and UT trials (with the model's file conventions unless given;
    ``variable`` and ``channels`` for .mat variables and other column names, as in
    :func:`lpvpc.io.load_trial`) and pair them at the model's rate. ``data`` instead of
    ``pt`` and ``ut``: one PT - UT file with a scheduling column, its two trials rebuilt
    (:func:`lpvpc.io.perturbation_file_trials`: the UT torque unknown, zero). ``stationary``:
    ``pt`` recorded around one fixed position without a UT trial, which stands for the PT
    trial's mean position and torque (:func:`lpvpc.io.stationary_ut`).
    ``hold_out`` (a fraction or ``(start, stop)`` in s, as :func:`lpvpc.io.hold_out` takes it):
    only that later stretch of the record is the held-out record, split at the model's rate
    as ``hold_out`` splits it, the trials cut to the same span at their own rate. A rate that
    is not a multiple of the model's (1024 Hz) is first resampled to the largest multiple
    below it (lpvpc.io.to_multiple_rate), as identification does. DataError for unequal
    lengths, a rate below the model's, and any bad sample."""
    conv = model.conventions or {}
    position_unit = position_unit or conv.get("position_unit", "rad")
    torque_sign = float(torque_sign if torque_sign is not None else conv.get("torque_sign", 1.0))
    time_unit = time_unit or conv.get("time_unit", "s")
    if stationary and (ut is not None or data is not None):
        raise DataError("a stationary trial is validated alone: give it as the PT trial, without a UT trial or a PT - UT "
                        "file", source=str(pt))
    if data is not None and (pt is not None or ut is not None):
        raise DataError("give either the PT and UT trials or one PT - UT file, not both", source=str(data))
    files = {}
    trials = []
    if data is not None:
        trials = list(perturbation_file_trials(data, position_unit=position_unit, torque_sign=torque_sign,
                                               time_unit=time_unit, variable=variable, channels=channels,
                                               degrees="refuse"))
        files["data"] = {"path": str(data), "sha256": file_sha256(split_variable(data)[0])}
    for role, src in () if data is not None else (("pt", pt),) if stationary else (("pt", pt), ("ut", ut)):
        if isinstance(src, Trial):
            trials.append(src)
            files[role] = {"path": src.name or role, "sha256": None}
        else:
            # degrees read as rad would make every figure of the report meaningless: refused
            trials.append(load_trial(src, position_unit=position_unit, torque_sign=torque_sign, time_unit=time_unit,
                                     variable=variable, channels=channels, degrees="refuse"))
            files[role] = {"path": str(src), "sha256": file_sha256(split_variable(src)[0])}
    if stationary:
        trials.append(stationary_ut(trials[0]))
        files["ut"] = {"path": "none: stationary, the PT trial's mean position and torque", "sha256": None}
    fs_file = trials[0].fs
    # e.g. 1024 Hz: the record at 1000 Hz, as identification reads it
    pt_t, ut_t = (to_multiple_rate(tr, model.fs) for tr in trials)
    # the recording's channel skew, undone as at identification (lpvpc.identification.channel_skew)
    measured = pair_trials(pt_t, ut_t, target_fs=model.fs, channel_skew=conv.get("channel_skew_s", 0.0))
    check_model_rate(measured.fs, model.fs, what="record", source=measured.source)
    measured.meta.update(position_unit=position_unit, torque_sign=torque_sign)
    if hold_out is not None:
        from lpvpc.io import hold_out as split_record

        measured = split_record(measured, hold_out)[1]
        part = measured.meta["part"]
        pt_t, ut_t = (_trial_part(t, part["start_s"], part["stop_s"]) for t in (pt_t, ut_t))
    return Record(pt_t, ut_t, measured, files, fs_file=None if pt_t.fs == fs_file else float(fs_file))


def _trial_part(trial: Trial, start_s: float, stop_s: float) -> Trial:
    """The samples of ``trial`` from ``start_s`` to ``stop_s`` after its first sample (s)."""
    n = len(trial.time)
    a, b = int(round(start_s * trial.fs)), min(n, int(round(stop_s * trial.fs)))
    channels = {k: (np.asarray(v)[a:b] if np.ndim(v) == 1 and len(v) == n else v) for k, v in trial.channels.items()}
    return Trial(trial.time[a:b], trial.position[a:b], trial.torque[a:b], channels, trial.name)


def check_model_fmu(info: FMUInfo, model: LPVPCModel) -> None:
    """The model FMU must be an lpvpc export of this model (exact or causal variant) at its
    sample period (with the extra inputs of an extended model)."""
    inputs = model_fmu_inputs(model, model_fmu_variant(info))
    missing_in = [n for n in inputs if info.variables.get(n, (None, None))[1] != "input"]
    missing_out = [n for n in MODEL_OUTPUTS if info.variables.get(n, (None, None))[1] != "output"]
    if missing_in or missing_out:
        what = ", ".join([f"input '{n}'" for n in missing_in] + [f"output '{n}'" for n in missing_out])
        raise FMUError(f"model FMU {info.path}: lacks {what}")
    declared = fmu_model_hash(info)
    if declared is not None and declared != model.model_hash:
        raise FMUError(f"model FMU {info.path}: exported from model {declared[:12]}, not from this model "
                       f"({model.model_hash[:12]}); export it again or pass the matching model file")
    h = 1.0 / model.fs
    if model_fmu_sampled(info):  # steps at a base tick that divides the sample period
        period = next(float(v.start) for v in info.model_description.modelVariables if v.name == "sample_period")
        ratio = h / info.step_size
        if abs(period - h) > 1e-9 * h or abs(ratio - round(ratio)) > 1e-6:
            raise FMUError(f"model FMU {info.path}: sample period {period:g} s (tick {info.step_size:g} s) does not "
                           f"match the model's sample period {h:g} s")
    elif info.step_size is not None and abs(info.step_size - h) > 1e-9 * h:
        raise FMUError(f"model FMU {info.path}: step size {info.step_size:g} s differs from the model's sample "
                       f"period {h:g} s")


def check_actuator_fmu(info: FMUInfo, model: LPVPCModel, parameters: dict) -> int:
    """Variables, parameters and step of the actuator FMU; returns actuator steps per model step."""
    missing = [n for n in ACTUATOR_INPUTS if info.variables.get(n, (None, None))[1] != "input"]
    missing += [n for n in ACTUATOR_OUTPUTS if info.variables.get(n, (None, None))[1] != "output"]
    if missing:
        raise FMUError(f"actuator FMU {info.path}: lacks variable(s) {', '.join(missing)}")
    params = info.names("parameter")
    unknown = [n for n in parameters if n not in params]
    if unknown:
        raise FMUError(f"actuator FMU {info.path}: no parameter named {', '.join(map(repr, unknown))} "
                       f"(parameters: {', '.join(params)})")
    if info.step_size is None or not info.step_size > 0:
        raise FMUError(f"actuator FMU {info.path}: no DefaultExperiment stepSize (its fixed internal step)")
    ratio = (1.0 / model.fs) / info.step_size
    if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
        raise FMUError(f"actuator FMU {info.path}: its step {info.step_size:g} s does not divide the model's "
                       f"sample period {1.0 / model.fs:g} s")
    return int(round(ratio))


def _start_values(info: FMUInfo) -> dict:
    out = {}
    for v in info.model_description.modelVariables:
        if v.causality == "parameter" and v.start is not None:
            try:
                out[v.name] = float(v.start)
            except (TypeError, ValueError):
                pass
    return out


def _pad(x, n):
    x = np.asarray(x, dtype=float)
    if len(x) >= n:
        return x[:n].copy()
    return np.concatenate([x, np.full(n - len(x), x[-1])])


def _tracking_error(cos, targets) -> float:
    """RMS (rad) of the perturbation position (PT - UT) the model FMU received in ``cos`` (the
    actuators sampled at the model rate) against that of ``targets`` (UT, PT at the model rate)."""
    k = len(targets[0])
    return float(np.sqrt(np.mean((cos.model_inputs["position"][:k] - (targets[1] - targets[0])) ** 2)))


def refined_drive(drive: ActuatorDrive, targets, run, parameters: dict):
    """Iterative learning of a command rebuilt from measured positions (a record without a
    command channel). The feedforward inverts the servo loop alone; the footplate's lag and the
    load leave the co-simulated actuators ~0.4 mrad off the measured positions, and the model's
    velocity and acceleration inputs turn that into ~1 VAF point (the lab's pilot trial).
    Each pass takes the UT and PT position errors where the model sees them (the actuators
    sampled at the model rate, against ``targets``: the measured UT and PT positions at the model
    rate, as identification reads them), brings them to the actuator rate by the commands'
    band-limited interpolation, adds their :func:`~lpvpc.validation.cosim.actuator_inverse` and runs
    again (``run(drive) -> CosimResult``; ``parameters``: the actuator's). Returns (drive, its
    co-simulation, {"passes", "tracking_rms_mrad" per pass}).

    On the lab's pilot trial (22 s held out): 0.40 -> 0.010 -> 0.0005 mrad in two passes, and the
    co-simulation's VAF from 1.3 points below the FMU replay to equal to it."""
    import dataclasses

    K, r = drive.n_model, drive.ratio
    fs_model, fs_a = 1.0 / (drive.step * r), 1.0 / drive.step
    enough = COMMAND_REFINEMENT_TOLERANCE * float(np.sqrt(np.mean((targets[1] - targets[0]) ** 2)))
    cos = run(drive)
    rms = [_tracking_error(cos, targets)]
    while len(rms) <= COMMAND_REFINEMENT_PASSES and rms[-1] > enough:
        commands = []
        for target, y, cmd in ((targets[0], cos.ut, drive.command_ut), (targets[1], cos.pt, drive.command_pt)):
            error = to_rate(target[:K] - y[: K * r: r, 0], fs_model, fs_a, "position error")[: K * r]
            d = actuator_inverse(error, drive.step, parameters)
            commands.append(np.concatenate([cmd[: K * r] + d, cmd[K * r:] + d[-1]]))
        trial = dataclasses.replace(drive, command_ut=commands[0], command_pt=commands[1])
        trial_cos = run(trial)
        e = _tracking_error(trial_cos, targets)
        if not e < 0.9 * rms[-1]:
            break
        drive, cos = trial, trial_cos
        rms.append(e)
    drive = dataclasses.replace(drive, source=f"{drive.source}; refined by {len(rms) - 1} pass(es) of iterative "
                                f"learning (perturbation tracking {1e3 * rms[0]:.3g} -> {1e3 * rms[-1]:.2g} mrad RMS)")
    return drive, cos, {"passes": len(rms) - 1, "tracking_rms_mrad": [1e3 * x for x in rms]}


def actuator_drive(record: Record, info: FMUInfo, ratio: int, n_model: int, parameters: dict,
                   calibrate: bool, band_limit_to: float | None = None) -> tuple[ActuatorDrive, dict, dict]:
    """Commands and UT load at the actuator rate, the servo calibration and the actuator
    parameters to use. ``band_limit_to`` (Hz): low-pass the commands (zero-phase) to the band
    of that sampling rate after calibrating. Returns (drive, parameters, calibration info)."""
    h = info.step_size
    fs_a = 1.0 / h
    n_a = n_model * ratio
    defaults = _start_values(info)
    params = dict(parameters)
    servo_params = {"servo_bandwidth", "servo_damping"} <= set(defaults)
    cal = {"done": False}
    if record.has_command:
        cmd_u = to_rate(record.ut.channels["command"], record.fs, fs_a, "UT command")
        cmd_p = to_rate(record.pt.channels["command"], record.fs, fs_a, "PT command")
        source = "the record's command channel"
        if calibrate and servo_params and not ({"servo_bandwidth", "servo_damping"} & set(params)):
            t0 = time.perf_counter()
            fit = calibrate_servo(cmd_p - cmd_u, record.pt.position - record.ut.position, h, record.fs,
                                  start=(defaults["servo_bandwidth"], defaults["servo_damping"]))
            params.update(servo_bandwidth=fit["servo_bandwidth"], servo_damping=fit["servo_damping"])
            cal = {"done": True, **fit, "seconds": time.perf_counter() - t0,
                   "what": "servo_bandwidth and servo_damping fitted by least squares to the record's perturbation "
                           "command (PT - UT) and measured perturbation position",
                   "defaults": {k: defaults[k] for k in ("servo_bandwidth", "servo_damping")},
                   "poor": bool(fit["vaf"] < CALIBRATION_WARN_VAF)}
        elif not calibrate:
            cal["reason"] = "calibration switched off"
        elif not servo_params:
            cal["reason"] = "the actuator FMU has no servo_bandwidth/servo_damping parameters"
        else:
            cal["reason"] = "servo parameters given by the user"
    else:
        pos_u = to_rate(record.ut.position, record.fs, fs_a, "UT position")
        pos_p = to_rate(record.pt.position, record.fs, fs_a, "PT position")
        if servo_params:
            bw = params.get("servo_bandwidth", defaults["servo_bandwidth"])
            zeta = params.get("servo_damping", defaults["servo_damping"])
            cmd_u = feedforward_command(pos_u, h, bw, zeta)
            cmd_p = feedforward_command(pos_p, h, bw, zeta)
            source = (f"the record's measured positions through the inverse servo loop (feedforward, "
                      f"{bw:g} Hz, damping {zeta:g}); the record has no command channel")
        else:
            cmd_u, cmd_p = pos_u, pos_p
            source = "the record's measured positions (no command channel)"
        cal["reason"] = "the record has no command channel"
    if band_limit_to is not None:
        cmd_u, cmd_p = band_limit(cmd_u, fs_a, band_limit_to), band_limit(cmd_p, fs_a, band_limit_to)
        source += f", band-limited (zero-phase) to the band of {band_limit_to:g} Hz sampling"
    load = to_rate(record.ut.torque, record.fs, fs_a, "UT torque")
    drive = ActuatorDrive(_pad(cmd_u, n_a), _pad(cmd_p, n_a), _pad(load, n_a), h, ratio, n_model, source)
    return drive, params, cal


# --------------------------------------------------------------------------- provenance


def _versions() -> dict:
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in ("lpvpc", "numpy", "scipy", "casadi", "fmpy", "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            mod = sys.modules.get(pkg)
            out[pkg] = getattr(mod, "__version__", "unknown") if mod else "not installed"
    return out


# --------------------------------------------------------------------------- validate


def record_signals(model: LPVPCModel, measured) -> dict | None:
    """The extra signals an extended model needs, from the record (name -> array at the
    model rate, :func:`lpvpc.models.effects.signals_from_data`); None for the base model.
    DataError when the record lacks one (e.g. ``emg_ut`` without EMG in the UT trial)."""
    from lpvpc.models.effects import check_signals, model_signals, signals_from_data

    names = model_signals(model)
    if not names:
        return None
    signals = signals_from_data(measured, model)  # activation with the model's reflex drive, as improve fits it
    check_signals(signals, names, measured.n, source=measured.source or "record")
    return {n: signals[n] for n in names}


def _report_path(path, report_dir) -> str:
    """A file in the report folder by its path relative to the folder (the folder is
    built beside its target and renamed); others as given."""
    try:
        return Path(path).resolve().relative_to(Path(report_dir).resolve()).as_posix()
    except ValueError:
        return str(path)


def validate(model, pt, ut, report_dir, **kwargs) -> "ValidationResult":
    final = Path(report_dir)
    with staged_folder(final) as stage:  # written as a whole or not at all: never two runs in one folder
        result = _validate(model, pt, ut, stage, **kwargs)
    result.report_dir = final
    result.files = {k: (final / Path(v).relative_to(stage) if isinstance(v, (str, Path)) and Path(v).is_relative_to(stage)
                        else v) for k, v in result.files.items()}
    return result


def _validate(model, pt, ut, report_dir, *, fmu=None, fmi_version: int = 2, actuator_fmu=None,
             actuator_parameters: dict | None = None, calibrate: bool = True, settings: CosimSettings | None = None,
             min_vaf: float | None = None, route_tolerance: float = DEFAULT_ROUTE_TOLERANCE,
             measure_load_effect: bool = True, band_limit_command: bool = True, fmu_variant: str = "exact",
             position_unit=None,
             torque_sign=None, time_unit=None, command_line=None, write_report: bool = True,
             whole_joint=None, variable=None, channels=None, data=None, stationary: bool = False,
             hold_out=None) -> ValidationResult:
    """Validate ``model`` on held-out trials: every prediction route (numpy, CasADi, the FMU
    replayed, the FMU co-simulated with the actuator FMU) against the record, with a report.

    The report folder is built beside ``report_dir`` and swapped in when the run has
    finished: a failed or interrupted run leaves the previous folder as it was, and a folder
    never mixes two runs (its previous content is replaced).

    Parameters
    ----------
    model : lpvpc.models.model.LPVPCModel or str or pathlib.Path
        The model, or its JSON file.
    pt, ut : str, pathlib.Path or lpvpc.io.trial.Trial
        The held-out perturbed and unperturbed trials, read with the model's conventions
        unless given (:meth:`LPVPCModel.load_record <lpvpc.models.model.LPVPCModel.load_record>`).
    report_dir : str or pathlib.Path
        The folder the report, metrics and FMUs are written to.
    fmu : str or pathlib.Path, optional
        An existing model FMU to validate, either variant; default: export the
        ``fmu_variant`` FMU, FMI ``fmi_version``, into ``report_dir/fmus``.
    fmi_version : {2, 3}, default 2
        FMI version of the FMUs built.
    actuator_fmu : str or pathlib.Path, optional
        Default the project's actuator FMU, built into the same folder.
    actuator_parameters : dict, optional
        Fixed actuator parameter values (servo parameters given here are not calibrated).
    calibrate : bool, default True
        Fit the actuator's servo bandwidth and damping to the record's perturbation command
        and position (when the record has a command channel and they are not given).
    settings : lpvpc.validation.cosim.CosimSettings, optional
        How the master couples the FMUs; default ``CosimSettings()``.
    min_vaf : float, optional
        Threshold (percent) for ``vaf``, ``vaf_fmu`` and ``vaf_cosim``; None: no threshold.
    route_tolerance : float, default 1e-9
        Relative tolerance of the CasADi and FMU routes against numpy.
    measure_load_effect : bool, default True
        Co-simulate once more without the model's torque loading the actuator, to measure
        the load effect.
    band_limit_command : bool, default True
        Low-pass the record's commands (zero-phase) to the model's band before they drive
        the actuators (:func:`lpvpc.validation.cosim.band_limit`): the measured record is the
        anti-aliased view of the experiment, and a model sampled at fs sees nothing above
        fs/2.
    fmu_variant : {"exact", "causal", "sampled"}, default "exact"
        "exact" runs the identified two-sided model with its declared latency of L samples,
        which the replay and the co-simulation remove (its torque loads the actuator L
        steps late: the load effect is measured and reported); "causal" validates the
        latency-free form meant for closed loop (``vaf_causal`` states its loss in every
        report).
    position_unit, torque_sign, time_unit : optional
        The record's conventions, as :func:`lpvpc.io.load_identification_data
        <lpvpc.io.identification_data.load_identification_data>` takes them; default the model's.
    command_line : str, optional
        The command that ran the validation, written into the report.
    write_report : bool, default True
        Write ``report.html`` (the metrics are written either way).
    whole_joint : lpvpc.export.whole_joint.WholeJointModel or str, optional
        A whole-joint model (or its JSON path) built on this model, validated on the PT
        trial's total torque as well (:mod:`lpvpc.validation.whole_joint`; a report section
        and ``metrics["whole_joint"]``).
    variable, channels : optional
        The .mat variable and the column or channel names of the record's files.
    data : str or pathlib.Path, optional
        Instead of ``pt`` and ``ut``: one PT - UT file with a scheduling column (the lab
        pilot's format); its UT torque is unknown, so the co-simulation loads the PT
        actuator with the model's torque only (``CosimSettings.load`` "model").
    stationary : bool, default False
        ``pt`` alone, recorded around one fixed position.
    hold_out : float or tuple of float, optional
        Validate on that later stretch of the record only (a fraction, or start and stop in
        s: :func:`lpvpc.io.hold_out`; :func:`load_record`).

    Returns
    -------
    ValidationResult
        ``metrics`` (every VAF, RMSE and check), ``report_dir`` and ``files``; ``passed`` is
        False when a threshold fails.

    Raises
    ------
    lpvpc.errors.DataError
        An unusable record, or a combination of arguments that does not go together (a
        whole-joint model with a PT - UT file or a stationary trial).
    lpvpc.errors.FMUError
        A given FMU that does not fit the model or the actuator, or that fails.
    lpvpc.errors.ExportError
        An FMU that cannot be built (no C compiler).

    Examples
    --------
    A model of the virtual subject validated on its novel (held-out) trajectory:

    >>> import tempfile
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.io import load_identification_data
    >>> from lpvpc.simulation.simulate import write_dataset
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     files = write_dataset(folder, duration=30.0, fs_out=100.0)
    ...     model = identify(load_identification_data(pt=files["ident_PT"], ut=files["ident_UT"]))
    ...     result = validate(model, files["novel_PT"], files["novel_UT"], f"{folder}/report",
    ...                       write_report=False)
    >>> result.passed, bool(result.metrics["vaf_fmu"] > 90.0), bool(result.metrics["vaf_cosim"] > 90.0)
    (True, True, True)
    """
    t_all = time.perf_counter()
    timing = {}
    settings = (settings or CosimSettings()).check()
    report_dir = Path(report_dir)
    actuator_parameters = dict(actuator_parameters or {})

    # -- inputs, checked before any work ------------------------------------------------
    t0 = time.perf_counter()
    model_path = None
    if not isinstance(model, LPVPCModel):
        model_path = Path(model)
        model = LPVPCModel.load(model_path)
    if data is not None and whole_joint is not None:
        raise DataError("a whole-joint model is validated on the PT trial's total torque, which a PT - UT file does "
                        "not have: give the PT and UT trials", source=str(data))
    if stationary and whole_joint is not None:
        raise DataError("a whole-joint model follows the UT trial's slow movement, which a stationary trial does not "
                        "have: validate it on a PT and UT pair", source=str(pt))
    record = load_record(model, pt, ut, position_unit=position_unit, torque_sign=torque_sign, time_unit=time_unit,
                         variable=variable, channels=channels, data=data, stationary=stationary, hold_out=hold_out)
    if not record.ut_torque_known and settings.load == "measured_ut+model":  # no UT torque to load the actuators with
        settings = replace(settings, load="model")
    meas = record.measured
    signals = record_signals(model, meas)  # extended model: the record's extra channels, for every route
    given_fmu = None
    if fmu is not None:
        given_fmu = inspect_fmu(fmu, "model FMU")
        check_model_fmu(given_fmu, model)
    given_act = inspect_fmu(actuator_fmu, "actuator FMU") if actuator_fmu is not None else None
    if given_act is not None:
        check_actuator_fmu(given_act, model, actuator_parameters)
    timing["load_and_check"] = time.perf_counter() - t0
    progress(f"validate: model and held-out record checked ({meas.n} samples at {meas.fs:g} Hz)")

    # -- FMUs ---------------------------------------------------------------------------
    t0 = time.perf_counter()
    fmu_dir = report_dir / "fmus"
    fmu_dir.mkdir(parents=True, exist_ok=True)
    if given_fmu is None:
        from lpvpc.export.exporter import export_fmu

        progress(f"validate: exporting the {fmu_variant} model FMU (FMI {fmi_version}, C compiler)")
        model_fmu = inspect_fmu(export_fmu(model, fmu_dir / f"model_{fmu_variant}_fmi{fmi_version}.fmu",
                                           fmi_version=fmi_version, variant=fmu_variant), "model FMU")
        check_model_fmu(model_fmu, model)
    else:
        model_fmu = given_fmu
    if given_act is None:
        from lpvpc.export.actuator import build_actuator_fmu

        progress("validate: building the actuator FMU")
        act_fmu = inspect_fmu(build_actuator_fmu(fmu_dir / f"actuator_fmi{model_fmu.fmi_version}.fmu",
                                                 fmi_version=model_fmu.fmi_version), "actuator FMU")
    else:
        act_fmu = given_act
    ratio = check_actuator_fmu(act_fmu, model, actuator_parameters)
    timing["fmus"] = time.perf_counter() - t0

    # -- offline routes -----------------------------------------------------------------
    t0 = time.perf_counter()
    progress(f"validate: predicting {meas.n} samples offline, through CasADi and the model FMU")
    off = offline_routes(model, meas.position, meas.scheduling, signals, data=meas)
    file_rate = off["identified"] is not off["numpy"]  # the reflex on the file's own velocity
    cas = casadi_routes(model, meas.position, meas.scheduling, signals)
    timing["offline_and_casadi"] = time.perf_counter() - t0
    rep = fmu_replay(model_fmu, model, meas.position, meas.scheduling, signals)
    timing["fmu_replay"] = rep["seconds"]

    # -- co-simulation ------------------------------------------------------------------
    t0 = time.perf_counter()
    progress("validate: " + ("calibrating the actuator, " if calibrate else "") + "co-simulating the model FMU "
             "with the actuator FMUs")
    drive, params, calibration = actuator_drive(record, act_fmu, ratio, meas.n, actuator_parameters, calibrate,
                                                band_limit_to=model.fs if band_limit_command else None)
    timing["calibration"] = calibration.get("seconds", 0.0)
    variant = model_fmu_variant(model_fmu)
    latency = latency_samples(model, variant)

    def cosimulate(d):
        return run_cosimulation(model_fmu, act_fmu, d, settings=settings, actuator_parameters=params,
                                signals=signals, latency=latency)

    refinement = None
    linear = {**_start_values(act_fmu), **params}
    if not record.has_command and all(k in linear for k in ACTUATOR_LINEAR_PARAMETERS):
        # commands rebuilt from the measured positions: refined until the actuators reproduce them
        drive, cos, refinement = refined_drive(drive, (meas.scheduling, meas.scheduling + meas.position),
                                               cosimulate, linear)
    else:
        cos = cosimulate(drive)
    timing["cosim"] = time.perf_counter() - t0
    unloaded = None
    if measure_load_effect and settings.load != "none":
        t0 = time.perf_counter()
        unloaded = run_cosimulation(model_fmu, act_fmu, drive, settings=CosimSettings(**{**asdict(settings),
                                                                                         "load": "none"}),
                                    actuator_parameters=params, signals=signals, latency=latency)
        timing["cosim_unloaded"] = time.perf_counter() - t0
    # the lab pipeline on the co-simulated actuator: its 1 kHz positions recorded,
    # decimated like the measured data, replayed through the model FMU
    q_a = int(round((1.0 / drive.step) / model.fs))
    rec_pos = decimate_signal(cos.pt[:, 0] - cos.ut[:, 0], q_a)[: meas.n]
    rec_rho = decimate_signal(cos.ut[:, 0], q_a)[: meas.n]
    rec = fmu_replay(model_fmu, model, rec_pos, rec_rho, signals)

    # -- comparison ---------------------------------------------------------------------
    y = meas.torque
    preds = {"numpy": off["identified"].total, "fmu": rep["torque"], "cosim": cos.torque}
    fmu_form = {"exact": f"exact two-sided, latency of {latency} samples removed",
                "sampled": f"sampled, positions in, latency of {latency} sample removed"}.get(variant,
                                                                                              "causal, no latency")
    routes = {
        "numpy": ("offline numpy prediction, two-sided intrinsic IRF (the identified model"
                  + (f", its reflex on the record's {model.high_rate.fs:g} Hz velocity)" if file_rate else ")"),
                  off["identified"].total),
        "numpy_causal": ("offline numpy prediction, causal intrinsic IRF (what the causal FMU runs)",
                         off["numpy_causal"].total),
        "casadi": ("CasADi step function (causal) over the record, trajectory_function", cas["torque"]["casadi"]),
        "casadi_exact": ("CasADi step function (exact two-sided, latency removed)", cas["torque"]["casadi_exact"]),
        "fmu": (f"model FMU replaying the measured positions ({fmu_form}; no actuator)", rep["torque"]),
        "actuator_replay": ("model FMU replaying the co-simulated actuator positions recorded at the actuator "
                            "rate and decimated like the measured data", rec["torque"]),
        "cosim": (f"co-simulation: actuator FMUs driven by the record's commands, model FMU ({fmu_form}) in the loop",
                  cos.torque),
    }
    if file_rate:
        routes["numpy_model_rate"] = (f"offline numpy prediction with the reflex on the {model.fs:g} Hz velocity "
                                      "(what CasADi and the FMU compute)", off["numpy"].total)
    if unloaded is not None:
        routes["cosim_unloaded"] = ("the same co-simulation without load torque on the actuators", unloaded.torque)
    route_table = {}
    for name, (desc, p) in routes.items():
        ok = np.isfinite(p)
        route_table[name] = {"description": desc, "vaf": cmp.vaf(y[ok], p[ok]), "rmse": cmp.rmse(y[ok], p[ok]),
                             "n": int(ok.sum())}
    fmu_key = "fmu_vs_numpy" if variant == "exact" else "fmu_vs_numpy_causal"
    agreement = cmp.route_agreement(off["numpy_causal"].total, {"casadi_vs_numpy_causal": cas["torque"]["casadi"]},
                                    route_tolerance)
    agreement.update(cmp.route_agreement(off["numpy" if variant == "exact" else "numpy_causal"].total,
                                         {fmu_key: rep["torque"]}, route_tolerance))
    agreement.update(cmp.route_agreement(off["numpy"].total, {
        "casadi_exact_vs_numpy": cas["torque"]["casadi_exact"]}, route_tolerance))
    agreement["tolerance"] = route_tolerance
    agreement["pass"] = all(v["pass"] for v in agreement.values() if isinstance(v, dict))
    vaf_fmu, vaf_cos = route_table["fmu"]["vaf"], route_table["cosim"]["vaf"]
    agreement["cosim_vs_fmu_replay"] = {
        "vaf_difference": vaf_fmu - vaf_cos,
        "max_relative_difference": cmp.relative_difference(cos.torque, rep["torque"]),
        "rmse_difference": cmp.rmse(cos.torque, rep["torque"]),
        "note": "physical difference (actuator dynamics, load, sampling), not a numerical tolerance"}
    agreement["numpy_causal_vs_numpy"] = {
        "vaf_difference": route_table["numpy"]["vaf"] - route_table["numpy_causal"]["vaf"],
        "max_relative_difference": cmp.relative_difference(off["numpy_causal"].total, off["numpy"].total),
        "note": "the causal form the FMU runs (on the model-rate velocity) against the identified two-sided model"}

    sched = cmp.scheduling_summary(meas.scheduling, model.scheduling_range, y, preds)
    sched["flagged"] = bool(sched["out_of_range_fraction"] > 0)
    sched["one_position"] = bool(model.one_position)  # a stationary trial's model: max_excursion is the distance from it

    pert_pos_meas = meas.position
    track = {
        "perturbation_position_vaf": cmp.vaf(pert_pos_meas, cos.model_inputs["position"]),
        "perturbation_position_rmse_mrad": 1e3 * cmp.rmse(pert_pos_meas, cos.model_inputs["position"]),
        "scheduling_rmse_mrad": 1e3 * cmp.rmse(meas.scheduling, cos.model_inputs["scheduling"]),
        "what": "co-simulated actuator (model rate, sampled) against the measured record (decimated)"}
    load_effect = None
    if unloaded is not None:
        dp = (cos.pt[:, 0] - cos.ut[:, 0]) - (unloaded.pt[:, 0] - unloaded.ut[:, 0])
        du = cos.ut[:, 0] - unloaded.ut[:, 0]
        load_effect = {
            "vaf_cosim_unloaded": route_table["cosim_unloaded"]["vaf"],
            "vaf_change": vaf_cos - route_table["cosim_unloaded"]["vaf"],
            "perturbation_position_max_mrad": float(1e3 * np.max(np.abs(dp))),
            "perturbation_position_rms_mrad": float(1e3 * np.sqrt(np.mean(dp ** 2))),
            "perturbation_position_rms_relative": float(np.sqrt(np.mean(dp ** 2)) / np.std(pert_pos_meas)),
            "ut_position_max_mrad": float(1e3 * np.max(np.abs(du))),
            "model_torque_rms": float(np.sqrt(np.mean(cos.load_pt_model ** 2))),
        }

    # -- where the model fails ----------------------------------------------------------
    lo, hi = model.scheduling_range
    inner = np.linspace(lo, hi, 9)
    edges = inner.copy()
    if meas.scheduling.min() < lo:
        edges = np.concatenate([[meas.scheduling.min()], edges])
    if meas.scheduling.max() > hi:
        edges = np.concatenate([edges, [meas.scheduling.max()]])
    ut_vel = np.asarray(meas.extra.get("ut_velocity", np.gradient(meas.scheduling) * meas.fs))
    pert_vel = eq.velocity(meas.position, meas.fs)
    t_rec = np.arange(meas.n) / meas.fs
    failure = {
        "by_position": cmp.binned_errors(meas.scheduling, y, preds, edges),
        "by_ut_velocity": cmp.binned_errors(ut_vel, y, preds, cmp.quantile_edges(ut_vel, 8)),
        "by_perturbation_velocity": cmp.binned_errors(pert_vel, y, preds, cmp.symmetric_edges(pert_vel)),
        "over_time": cmp.errors_over_time(t_rec, y, preds, window=5.0),
        "by_frequency": cmp.band_errors(y, preds, meas.fs),
        "worst_segments": cmp.worst_segments(t_rec, y, off["identified"].total, length=2.0, n=3),
    }

    # -- thresholds ---------------------------------------------------------------------
    checks = []
    if min_vaf is not None:
        for key, name in (("vaf", "numpy"), ("vaf_fmu", "fmu"), ("vaf_cosim", "cosim")):
            v = route_table[name]["vaf"]
            checks.append({"name": f"{key} >= min_vaf", "value": v, "threshold": float(min_vaf),
                           "pass": bool(v >= min_vaf)})
    for key in ("casadi_vs_numpy_causal", fmu_key, "casadi_exact_vs_numpy"):
        checks.append({"name": f"route agreement {key} <= tolerance",
                       "value": agreement[key]["max_relative_difference"], "threshold": route_tolerance,
                       "pass": agreement[key]["pass"]})

    metrics = {
        "format": "lpvpc-validation",
        "format_version": 1,
        "vaf": route_table["numpy"]["vaf"],
        "vaf_causal": route_table["numpy_causal"]["vaf"],
        "vaf_casadi": route_table["casadi"]["vaf"],
        "vaf_fmu": vaf_fmu,
        "vaf_cosim": vaf_cos,
        "vaf_actuator_replay": route_table["actuator_replay"]["vaf"],
        "rmse": route_table["numpy"]["rmse"],
        "rmse_fmu": route_table["fmu"]["rmse"],
        "rmse_cosim": route_table["cosim"]["rmse"],
        "n_samples": int(meas.n),
        "model_signals": list(signals or {}),  # extra inputs of an extended model, from the record
        "fs": float(model.fs),
        "duration_s": float(meas.n / meas.fs),
        "units": {"vaf": "%", "rmse": "N m", "fs": "Hz", "time": "s", "position": "rad", "torque": "N m"},
        "routes": route_table,
        "route_agreement": agreement,
        "scheduling": sched,
        "out_of_range_fraction": sched["out_of_range_fraction"],
        "cosim": {
            "settings": {**asdict(settings), "band_limit_command": bool(band_limit_command)},
            "model_fmu_variant": variant,
            "model_fmu_latency_samples": int(latency),
            "connections": [{"to": a, "from": b} for a, b in cos.connections],
            "command_source": drive.source,
            "actuator_parameters": params,
            "calibration": calibration,
            # a record without a command channel: the rebuilt command's iterative learning (None otherwise)
            "command_refinement": refinement,
            "tracking": track,
            "load_effect": load_effect,
            "iterations": {"mean": float(cos.iterations.mean()), "max": int(cos.iterations.max())},
            "step_model_s": cos.step_model,
            "step_actuator_s": cos.step_actuator,
            "communication_step_s": cos.step_model,
            "actuator_steps_per_model_step": ratio,
            "model_steps": int(meas.n),
            "actuator_steps_per_run": int(meas.n * ratio),
            "stepping_seconds": cos.elapsed,
            "real_time_factor": cos.real_time_factor,
        },
        "failure_analysis": failure,
        "thresholds": {"min_vaf": None if min_vaf is None else float(min_vaf), "route_tolerance": route_tolerance},
        "checks": checks,
        "pass": all(c["pass"] for c in checks),
        "provenance": {
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "model_file": None if model_path is None else str(model_path),
            "model_hash": model.model_hash,
            "model_data_hash": (model.provenance or {}).get("data_hash"),
            "data_files": record.files,
            "data_hash": meas.data_hash,
            "record_fs": float(record.fs),
            "record_fs_file": record.fs_file,
            "record_samples": int(len(record.pt.time)),
            "record_part": meas.meta.get("part"),  # the held-out stretch of the record (hold_out), or None
            "position_unit": meas.meta.get("position_unit"),
            "torque_sign": meas.meta.get("torque_sign"),
            "model_fmu": {"path": _report_path(model_fmu.path, report_dir), "sha256": model_fmu.sha256, "fmi_version": model_fmu.fmi_version,
                          "variant": variant, "latency_samples": int(latency),
                          "given": given_fmu is not None, "declared_model_hash": fmu_model_hash(model_fmu)},
            "actuator_fmu": {"path": _report_path(act_fmu.path, report_dir), "sha256": act_fmu.sha256, "fmi_version": act_fmu.fmi_version,
                             "given": given_act is not None},
            "step_sizes": {"model_s": 1.0 / model.fs, "actuator_s": act_fmu.step_size,
                           "communication_s": cos.step_model},
            "tolerances": {"route_agreement": route_tolerance, "iterate_tol_Nm": settings.iterate_tol,
                           "max_iterations": settings.max_iterations,
                           "calibration": "scipy least_squares xtol 1e-10, ftol 1e-12"},
            "versions": _versions(),
            "platform": platform.platform(),
            "command_line": command_line,
        },
        "timing_s": timing,
    }
    wj_traces = None
    if whole_joint is not None:  # the whole-joint model on the PT trial's total torque
        from lpvpc.export.whole_joint import WholeJointModel

        from .whole_joint import evaluate_whole_joint

        t0 = time.perf_counter()
        progress("validate: the whole-joint model")
        wj = whole_joint if isinstance(whole_joint, WholeJointModel) else WholeJointModel.load(whole_joint)
        metrics["whole_joint"], wj_traces = evaluate_whole_joint(wj, record, fmu_dir, model_fmu.fmi_version)
        timing["whole_joint"] = time.perf_counter() - t0
    ssp_path = portable = None
    if write_report:
        # the same set-up for other co-simulation tools (SSP 1.0, FMUs included)
        from .ssp import instance_parameters, write_ssp

        progress("validate: writing the co-simulation set-up (SSP)")
        ssp_path = write_ssp(report_dir / SSP_FILE, model_fmu, act_fmu, stop_time=meas.n * cos.step_model,
                             communication_step=cos.step_model, settings=settings,
                             parameters=instance_parameters(params, drive.command_ut[0], drive.command_pt[0]),
                             signals=tuple(signals or ()), wiring=cos.connections)
        metrics["cosim"]["ssp"] = SSP_FILE
        # the same set-up with every harness signal in an FMU, for libcosim and ECOS as they are
        from .ssp import portable_ssp_from_run

        t0 = time.perf_counter()
        portable = portable_ssp_from_run(report_dir / PORTABLE_SSP_FILE, model_fmu, act_fmu, drive,
                                         instance_parameters(params, drive.command_ut[0], drive.command_pt[0]),
                                         settings, latency, fmu_dir / "record_fmi2.fmu")
        metrics["cosim"]["portable_ssp"] = PORTABLE_SSP_FILE if portable else None
        timing["portable_ssp"] = time.perf_counter() - t0
    result = ValidationResult(metrics=metrics, report_dir=report_dir)
    if write_report:
        from .report import write_report as _write

        t0 = time.perf_counter()
        progress("validate: writing the report and its figures")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            result.files = _write(result, model=model, record=record, predictions={
                "numpy": off["identified"], "numpy_model_rate": off["numpy"], "numpy_causal": off["numpy_causal"],
                "fmu": rep, "cosim": cos,
                "unloaded": unloaded, "actuator_replay": rec, "whole_joint": wj_traces})
        timing["report"] = time.perf_counter() - t0
        result.files["ssp"] = ssp_path
        result.files["portable_ssp"] = portable
    timing["total"] = time.perf_counter() - t_all
    if write_report:
        from .report import write_metrics

        write_metrics(result)
    return result


validate.__doc__ = _validate.__doc__
validate.__signature__ = inspect.signature(_validate)
