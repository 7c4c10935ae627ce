"""The fitted LPV parallel-cascade model: prediction, physical summaries, save/load.

Units: position and scheduling in rad, velocity in rad/s, torque in N m, stiffness in
N m/rad, frequency in Hz.

Saved-model JSON format (``format: "lpvpc-model"``, ``format_version: 1``)::

    fs                  sampling rate (Hz) the model runs at
    intrinsic           {"lags": [-L..L], "H": n_lags x n_i (N m/rad), "basis": Basis,
                         "causal_lags": [0..Lc], "H_causal": (Lc + 3) x n_i: lags 0..Lc,
                         then velocity and acceleration at k, "derivatives": their
                         offline estimate, "central3" or "central5" (absent: central3),
                         "curvature" (format 3): n_i elastic curvature coefficients,
                         N m/rad^2 (:func:`lpvpc.models.equations.elastic_curvature_torque`;
                         absent: none)}
    reflex              {"delay": samples, "velocity_basis": Basis, "rho_basis": Basis,
                         "Omega": n_v x n_r, "A": m x m, "B": m, "C": m, "D": scalar,
                         "high_rate" (optional): {"fs": Hz, "delay": samples at fs,
                         "velocity_basis": Basis, "Omega": n_v' x n_r}}
    identified_ranges   {"scheduling": [lo, hi] (rad), "velocity": [lo, hi] (rad/s)}
    settings            estimator settings used
    provenance          {"data_hash", "lpvpc_version", "numpy_version", ...}
    units, conventions  {"position": "rad", "torque": "N m", "torque_sign": +1|-1, ...}
    fit                 identification diagnostics (VAF, singular values, order, iterations)
    format_version      1; 2 with effects; 3 when the model has the elastic curvature term
                        (older readers refuse files they would predict wrongly)
    effects             (extended models only) list of effect terms
                        {"name", "options", "H", "H_causal", "Theta", "basis"}: see
                        :mod:`lpvpc.models.effects`; they need the extra input signals named there

The reflex nonlinearity identified from files recorded faster than the model rate (1 kHz)
acts on the delayed velocity at the file's rate: ``reflex.high_rate`` holds it
(:class:`HighRateNonlinearity`), and the reflex gain, threshold and figures come from it.
``reflex.Omega`` is then its model-rate stand-in: the same dynamics, the nonlinearity of
the model-rate velocity refitted by least squares; exports (CasADi, FMUs) and predictions
from model-rate records use it, predictions from records carrying high-rate signals use
the high-rate one. Files without ``high_rate`` (and 100 Hz identifications) have one
nonlinearity, at the model rate, whose threshold is biased (the 20 ms reflex-evoking
velocity pulses are smoothed at 100 Hz).

Floats are written with Python's shortest round-trip representation, so save/load is exact.
A file is checked against this format and its limits (:mod:`lpvpc.models.modelfile`) before
anything is built from it.

Out-of-range behaviour: scheduling values outside the identified range follow the
scheduling bases' extrapolation rule (:attr:`LPVPCModel.beyond_range`: "clip" holds the
boundary dynamics, "linear" continues them along the boundary tangent) and an
:class:`~lpvpc.errors.OutOfRangeWarning` names the fraction affected. Velocities outside
the identified range continue the reflex nonlinearity along its boundary tangent, so a
fast outlier produces a proportionate torque, never a polynomial spike.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from . import equations as eq
from .basis import Basis
from ..errors import DataError, ModelFileError, OutOfRangeWarning, non_finite_problem
from .modelfile import FORMAT, FORMAT_VERSION, FORMAT_VERSION_CURVATURE, FORMAT_VERSION_EFFECTS  # noqa: F401 (re-exported)
from .reflex import rectifier_fit  # noqa: F401 (re-exported)
from .modelfile import check_model_dict, read_model_file

#: Lowest velocity rate (Hz) at which the reflex rectifier's threshold is observable.
RECTIFIER_MIN_FS = 500.0
#: An extra input (EMG) whose RMS differs from its level at identification by more than this
#: factor is in another unit (mV for V: 1000): predict warns (UnitWarning).
SIGNAL_LEVEL_FACTOR = 30.0


@dataclass
class Prediction:
    """Predicted torques (N m): total = intrinsic + reflex. In an extended model the
    effect terms are included in the pathway they belong to and listed in ``effects``.

    Parameters
    ----------
    total, intrinsic, reflex : numpy.ndarray
        The predicted torque and its two pathways (N m), one value per sample.
    out_of_range_fraction : float, default 0.0
        Fraction of the samples whose scheduling lies outside the identified range.
    effects : dict, optional
        Each effect's torque (N m) by name; empty for a model without effects.

    Examples
    --------
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> p = identify(data).predict(data)
    >>> bool(np.allclose(p.total, p.intrinsic + p.reflex)), p.out_of_range_fraction
    (True, 0.0)
    """

    total: np.ndarray
    intrinsic: np.ndarray
    reflex: np.ndarray
    out_of_range_fraction: float = 0.0
    effects: dict = field(default_factory=dict)

    def __repr__(self):
        rms = lambda x: float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0  # noqa: E731
        effects = f", effects: {', '.join(self.effects)}" if self.effects else ""
        return (f"Prediction({len(self.total)} samples; RMS total {rms(self.total):.3g}, intrinsic "
                f"{rms(self.intrinsic):.3g}, reflex {rms(self.reflex):.3g} N m; "
                f"{100 * self.out_of_range_fraction:.1f} % out of range{effects})")


@dataclass
class HighRateNonlinearity:
    """The reflex static nonlinearity identified on the delayed velocity at ``fs`` (Hz,
    the file's rate, a multiple of the model's): velocity basis (rad/s), coefficients
    Omega (n_v x n_r, with the model's rho basis) and the delay in samples at ``fs``.

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0)  # 1 kHz trials
    >>> model = identify(pair_trials(sim.pt, sim.ut), high_rate_reflex=True)  # runs at 100 Hz
    >>> model.fs, model.high_rate.fs, model.high_rate.delay, model.high_rate.Omega.shape
    (100.0, 1000.0, 40, (9, 3))
    """

    fs: float
    delay: int
    velocity_basis: Basis
    Omega: np.ndarray

    def to_dict(self) -> dict:
        return {"fs": self.fs, "delay": int(self.delay), "velocity_basis": self.velocity_basis.to_dict(),
                "Omega": self.Omega.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "HighRateNonlinearity":
        return cls(fs=float(d["fs"]), delay=int(d["delay"]), velocity_basis=Basis.from_dict(d["velocity_basis"]),
                   Omega=np.array(d["Omega"], dtype=float))


@dataclass
class LPVPCModel:
    """An identified LPV parallel-cascade model of ankle stiffness at sampling rate ``fs``
    (Hz): the intrinsic IRF ``H`` (N m/rad, lags ``lags`` in samples, scheduled by
    ``intrinsic_basis`` of rho in rad), the reflex nonlinearity ``Omega`` of the velocity
    (rad/s) delayed by ``delay`` samples, and the reflex dynamics ``A, B, C, D``. Predicts
    torque (N m), reports the physical quantities with confidence intervals, saves, loads
    and exports without the estimator that made it. Made by :func:`lpvpc.identify
    <lpvpc.identification.identify.identify>` or read by :meth:`LPVPCModel.load <lpvpc.models.model.LPVPCModel.load>`, not built by hand.

    Attributes
    ----------
    fs : float
        The model's sampling rate (Hz).
    lags, H : list of int, numpy.ndarray
        The two-sided intrinsic IRF's lags (samples) and weights (N m/rad per sample), one
        column per ``intrinsic_basis`` function.
    intrinsic_basis : lpvpc.models.basis.Basis
        The basis in the scheduling variable (rad) that schedules the intrinsic IRF.
    causal_lags, H_causal : list of int, numpy.ndarray
        The causal form's lags and weights (lags 0..Lc plus velocity and acceleration).
    delay : int
        The reflex delay (samples).
    velocity_basis, reflex_rho_basis : lpvpc.models.basis.Basis
        The bases of the reflex nonlinearity in velocity (rad/s) and in the scheduling
        variable (rad).
    Omega : numpy.ndarray
        The reflex nonlinearity's coefficients on those bases.
    A, B, C, D : numpy.ndarray, numpy.ndarray, numpy.ndarray, float
        The reflex dynamics' state-space matrices (one sample per step).
    settings, provenance, conventions, fit : dict
        The estimator's settings, where the record came from, the record's conventions
        (units, torque sign, channel skew, original rate), and how the fit went (VAF, orders,
        selection, timings).
    effects : list
        The fitted effect terms of an extended model (:mod:`lpvpc.models.effects`); empty
        otherwise.
    causal_derivatives : {"central3", "central5"}
        The stencil of the causal form's velocity and acceleration.
    uncertainty : dict
        What the confidence intervals need (:mod:`lpvpc.models.uncertainty`); empty: no
        intervals.
    high_rate : HighRateNonlinearity or None
        The reflex nonlinearity identified at the file's rate (module notes).
    curvature : numpy.ndarray or None
        The elastic curvature coefficients (N m/rad^2), one per intrinsic basis function;
        None: no such term.

    Examples
    --------
    >>> import tempfile
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.identification.identify import identify
    >>> from lpvpc.simulation.simulate import SubjectParams, simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> model = identify(data)
    >>> pred = model.predict(data)  # or model.predict(position, scheduling)
    >>> bool(vaf(data.torque, pred.total) > 95.0)  # percent
    True
    >>> theta = np.array([-0.2, 0.0])  # rad
    >>> lower, upper = model.elastic_stiffness_interval(theta)  # N m/rad, 95 %
    >>> bool(np.all(lower < model.elastic_stiffness(theta)) and np.all(model.elastic_stiffness(theta) < upper))
    True
    >>> bool(np.all(np.abs(model.elastic_stiffness(theta) / SubjectParams().K(theta) - 1) < 0.15))
    True
    >>> gain, threshold = model.reflex_gain_threshold(theta)  # N m s/rad, rad/s
    >>> bool(np.all(gain > 0))
    True
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     model.save(f"{tmp}/model.json")
    ...     again = LPVPCModel.load(f"{tmp}/model.json")
    >>> again.model_hash == model.model_hash
    True
    """

    fs: float
    lags: list
    H: np.ndarray
    intrinsic_basis: Basis
    causal_lags: list
    H_causal: np.ndarray
    delay: int
    velocity_basis: Basis
    reflex_rho_basis: Basis
    Omega: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: float
    settings: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)
    conventions: dict = field(default_factory=dict)
    fit: dict = field(default_factory=dict)
    effects: list = field(default_factory=list)  # lpvpc.models.effects.FittedEffect terms (extended models)
    causal_derivatives: str = "central3"  # stencil of the causal form's velocity/acceleration
    uncertainty: dict = field(default_factory=dict)  # lpvpc.models.uncertainty.fit_uncertainty (empty: no intervals)
    high_rate: HighRateNonlinearity | None = None  # the nonlinearity identified at the file's rate (module notes)
    curvature: np.ndarray | None = None  # (n_i,) elastic curvature coefficients, N m/rad^2 (None: no such term)

    def __repr__(self):
        # what a user checks first, in one line (the arrays are in the attributes)
        lo, hi = self.scheduling_range
        parts = [f"{self.fs:g} Hz", f"IRF lags {self.lags[0]}..{self.lags[-1]}",
                 f"reflex order {self.state_order}, delay {1000 * self.delay / self.fs:.0f} ms",
                 f"scheduling {lo:+.3f}..{hi:+.3f} rad"]
        if self.effects:
            parts.append("effects: " + ", ".join(fe.name for fe in self.effects))
        if "vaf" in self.fit:
            parts.append(f"VAF {self.fit['vaf']:.2f} %")
        parts.append(f"hash {self.model_hash[:12]}")
        return f"LPVPCModel({'; '.join(parts)})"

    @property
    def nonlinearity_fs(self) -> float:
        """Rate (Hz) of the delayed velocity the identified reflex nonlinearity acts on."""
        return self.fs if self.high_rate is None else self.high_rate.fs

    @property
    def reflex_threshold_biased(self) -> bool:
        """True when the nonlinearity saw velocity below :data:`RECTIFIER_MIN_FS`: the ~20 ms
        reflex-evoking velocity pulses are smoothed there, so the rectifier looks softer and
        its threshold is biased (benchmarks/results/reflex_observability.txt). Said wherever
        the threshold is shown (identify summary, Fig. 5A, validation report)."""
        return self.nonlinearity_fs < RECTIFIER_MIN_FS

    def nonlinearity(self):
        """(velocity basis, Omega) of the identified reflex nonlinearity: the high-rate one
        when the model has it (gain, threshold, figures and intervals describe it), else the
        model-rate one."""
        if self.high_rate is not None:
            return self.high_rate.velocity_basis, self.high_rate.Omega
        return self.velocity_basis, self.Omega

    # -- prediction ---------------------------------------------------------------------
    @property
    def scheduling_range(self):
        return (self.intrinsic_basis.lo, self.intrinsic_basis.hi)

    @property
    def one_position(self) -> bool:
        """Whether the identified range is one operating position (narrower than 1 urad: a
        stationary trial's model). Nothing varies with position there: tables and figures show
        that one position."""
        lo, hi = self.scheduling_range
        return hi - lo < 1e-6

    @property
    def beyond_range(self) -> str:
        """What the model does with scheduling outside its identified range, in words (its
        scheduling bases' extrapolation rule, chosen by cross-validation by default)."""
        return ("continued linearly from the boundary (extrapolation rule 'linear')"
                if self.intrinsic_basis.extrapolation == "linear" else "held at the boundary")

    @property
    def velocity_range(self):
        return (self.velocity_basis.lo, self.velocity_basis.hi)

    @property
    def state_order(self) -> int:
        return self.A.shape[0]

    @property
    def signals(self) -> tuple:
        """Extra input signals the model's effects need (see :data:`lpvpc.models.effects.SIGNALS`)."""
        if not self.effects:
            return ()
        from .effects import model_signals

        return model_signals(self)

    def summary(self):
        """What the model says about the ankle: lines to read and the same figures as numbers.

        Returns
        -------
        lpvpc.models.summary.ModelSummary
            ``lines`` (the text ``lpvpc identify`` prints) and ``values`` (the same figures
            in SI units, None where the data do not determine them).

        Examples
        --------
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.identification.identify import identify
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> data = pair_trials(sim.pt, sim.ut)
        >>> model = identify(data)
        >>> summary = model.summary()
        >>> summary.lines[1].startswith("VAF:"), sorted(summary.values)[:3]
        (True, ['channel_skew_s', 'effects', 'reflex_delay_s'])
        """
        from .summary import summarize

        return summarize(self)

    def record_conventions(self) -> dict:
        """The conventions this model's records are read with (its input contract): the
        file conventions of the record it was identified from, and its rate.

        Returns
        -------
        dict
            ``position_unit`` ("rad" or "deg"), ``torque_sign`` (+1 or -1), ``time_unit``
            ("s" or "ms"), ``channel_skew`` (s: the torque channel's lag behind position,
            undone at the file's rate) and ``fs`` (Hz).
        """
        from ..io.identification_data import CONVENTION_DEFAULTS as d  # the loader's defaults, one place

        c = self.conventions or {}
        return {"position_unit": c.get("position_unit", d["position_unit"]),
                "torque_sign": float(c.get("torque_sign", d["torque_sign"])),
                "time_unit": c.get("time_unit", d["time_unit"]),
                "channel_skew": float(c.get("channel_skew_s", d["channel_skew"]) or 0.0), "fs": float(self.fs)}

    def load_record(self, pt=None, ut=None, data=None, **settings):
        """A record read the way this model's own record was: its torque sign, units,
        channel skew and rate (:meth:`record_conventions`).

        Parameters
        ----------
        pt, ut, data
            As :func:`lpvpc.io.load_identification_data` takes them: the perturbed and the
            unperturbed trial (paths or Trials), or one perturbation file. A stationary
            model's record may be a perturbed trial alone.
        **settings
            Other loader settings (``variable``, ``channels``, ``stationary``); a convention
            given here must agree with the model's.

        Returns
        -------
        lpvpc.io.PerturbationData

        Raises
        ------
        lpvpc.errors.DataError
            A convention given that contradicts the model's (both named), or bad data.
        """
        from ..io import load_identification_data

        want = self.record_conventions()
        contract = {"position_unit": want["position_unit"], "torque_sign": want["torque_sign"],
                    "time_unit": want["time_unit"], "channel_skew": want["channel_skew"], "target_fs": want["fs"]}
        _refuse_contradictions(want, {("fs" if k == "target_fs" else k): v for k, v in settings.items()
                                      if k in contract and v is not None}, source=str(data or pt))
        if pt is not None and ut is None and data is None and self.one_position:
            settings.setdefault("stationary", True)
        settings = {k: v for k, v in settings.items() if k not in contract}
        return load_identification_data(pt, ut, data, **contract, **settings)

    def conform(self, data):
        """``data`` as this model reads a record: with the model's channel skew undone, and
        with its torque sign and units.

        A model identified from a lab's files carries how they were read
        (:meth:`record_conventions`). A record loaded without a channel skew is loaded again
        from its files with the model's, so that every door (the command line,
        ``model.predict(data)``, the FMU recipes) predicts from the same positions; the
        torque the caller holds is unchanged by it. A record read with another torque sign
        or unit is refused, naming both: reading it again would change the torque the
        caller compares with (:meth:`load_record` reads a record the model's way).

        Parameters
        ----------
        data : lpvpc.io.PerturbationData or object
            Anything else (arrays, other records) is returned unchanged.

        Returns
        -------
        lpvpc.io.PerturbationData

        Raises
        ------
        lpvpc.errors.DataError
            A torque sign or unit that differs from the model's, or a channel skew given
            explicitly that does.
        """
        from ..io import PerturbationData

        if not isinstance(data, PerturbationData):
            return data
        want, have = self.record_conventions(), data.conventions
        meta = data.meta or {}
        recorded = {"position_unit", "torque_sign", "time_unit"} & set(meta)
        if data.origin is not None:
            recorded |= {"position_unit", "torque_sign", "time_unit"}
        _refuse_contradictions(want, {k: have[k] for k in recorded}, source=data.source)
        if _same_convention(want["channel_skew"], have["channel_skew"]) or "position_delay_s" in meta \
                or data.origin is None:  # (built in memory: predict warns when it was not lined up)
            return data
        if "channel_skew" in data.origin.given:
            _refuse_contradictions(want, {"channel_skew": have["channel_skew"]}, source=data.source)
        return data.reload(channel_skew=want["channel_skew"])

    def _check_alignment(self, data) -> None:
        """Warn when the model was identified on records lined up for a late torque channel
        (``conventions["channel_skew_s"]``, lpvpc.identification.channel_skew) and ``data`` were not lined up
        the same: the prediction would be compared with a torque that lags it."""
        from ..errors import LpvpcWarning

        skew = float(self.conventions.get("channel_skew_s", 0.0) or 0.0)
        meta = getattr(data, "meta", {}) or {}
        done = float(meta.get("channel_skew_s", 0.0) or 0.0) + float(meta.get("position_delay_s", 0.0) or 0.0)
        if skew and abs(done - skew) > 1e-7:
            warnings.warn(f"this model was identified on records whose position was delayed by {skew * 1e3:.2f} ms to "
                          f"line up a late torque channel; these data were lined up by {done * 1e3:.2f} ms: load them "
                          f"with channel_skew={skew:.5f} to compare with the torque the rig records (lpvpc predict and "
                          f"validate do)", LpvpcWarning, stacklevel=3)

    def predict(self, position, scheduling=None, *, causal: bool = False, velocity=None, acceleration=None,
                warn: bool = True, signals: dict | None = None) -> Prediction:
        """Torque (N m) for a perturbation position record and its scheduling record, or for
        a loaded record.

        Parameters
        ----------
        position : array_like or lpvpc.io.PerturbationData
            The perturbation position (rad), N samples at the model's rate; or a record as
            :func:`lpvpc.load_identification_data <lpvpc.io.identification_data.load_identification_data>`
            returns it (its ``position``, ``scheduling`` and extra signals; its ``fs`` must be
            the model's; joined trials are predicted trial by trial, each from rest).
        scheduling : array_like, optional
            The scheduling variable (rad, the slow joint position), N samples; omitted when
            ``position`` is a record.
        causal : bool, default False
            Use the causal intrinsic IRF (lags 0..Lc plus the current velocity and
            acceleration) that the default FMU runs; False: the identified two-sided IRF.
        velocity, acceleration : array_like, optional
            With ``causal``: rad/s and rad/s^2; by default the model's difference stencil of
            ``position`` (``causal_derivatives``: 5-point central for new models).
        warn : bool, default True
            Warn when the scheduling leaves the identified range
            (:class:`~lpvpc.errors.OutOfRangeWarning`) or a record was lined up differently
            from the model's.
        signals : dict, optional
            The extra channels an extended model needs (``self.signals``; e.g.
            ``{"emg": ...}``), N samples each; ``trial_time`` defaults to k / fs and
            ``scheduling_velocity`` to the gradient of ``scheduling``.

        Returns
        -------
        Prediction
            ``total``, ``intrinsic`` and ``reflex`` torque (N m), the fraction of samples
            outside the identified range, and each effect's torque.

        Raises
        ------
        lpvpc.errors.DataError
            Arrays of different lengths, NaN or inf values, a record at another rate, or a
            record whose conventions contradict the model's.

        Examples
        --------
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.identification.identify import identify
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> data = pair_trials(sim.pt, sim.ut)
        >>> model = identify(data)
        >>> prediction = model.predict(data)  # the record as loaded
        >>> prediction.total.shape, bool(vaf(data.torque, prediction.total) > 95.0)
        ((3000,), True)
        >>> same = model.predict(data.position, data.scheduling)  # or its arrays
        >>> bool(np.allclose(same.total, prediction.total))
        True
        """
        if scheduling is None:
            position = self.conform(position)
            segments = list(getattr(position, "segments", ()) or ())
            if len(segments) > 1:  # joined trials: each predicted on its own, from rest
                data = position
                self._unpack_data(data, signals)  # the checks
                high = self._high_rate_of(data) is not None  # then each trial's high-rate signals too
                parts = [self.predict(*((data.segment(a, b), None) if high else (data.position[a:b], data.scheduling[a:b])),
                                      causal=causal, warn=warn,
                                      velocity=None if velocity is None else velocity[a:b],
                                      acceleration=None if acceleration is None else acceleration[a:b])
                         for a, b in segments]
                n = np.array([b - a for a, b in segments], dtype=float)
                return Prediction(total=np.concatenate([q.total for q in parts]),
                                  intrinsic=np.concatenate([q.intrinsic for q in parts]),
                                  reflex=np.concatenate([q.reflex for q in parts]),
                                  out_of_range_fraction=float(np.dot(n, [q.out_of_range_fraction for q in parts]) / n.sum()))
            high = self._high_rate_of(position)
            if warn:
                self._check_alignment(position)
            position, scheduling, signals = self._unpack_data(position, signals)
        else:
            high = None
        extra_signals = signals  # (the name ``signals`` is reused below for the IRF inputs)
        position = np.asarray(position, dtype=float)
        scheduling = np.asarray(scheduling, dtype=float)
        problems = []
        if position.ndim != 1 or scheduling.shape != position.shape:
            problems.append(f"position and scheduling must be 1-D of equal length, got {position.shape} and {scheduling.shape}")
        else:
            problems += [m for name, x in (("position", position), ("scheduling", scheduling))
                         if (m := non_finite_problem(name, x))]
        if problems:
            raise DataError(problems)
        lo, hi = self.scheduling_range
        outside = float(np.mean((scheduling < lo) | (scheduling > hi))) if len(scheduling) else 0.0
        if outside > 0 and warn:
            if self.one_position:  # "outside [op, op]" says nothing: say how far, and that the model cannot follow
                away = 1e3 * float(np.max(np.abs(scheduling - lo)))
                text = (f"the model was identified at one operating position ({lo:+.4f} rad) and does not vary "
                        f"with position; this record's scheduling lies up to {away:.1f} mrad from it, where the "
                        f"ankle may differ")
            else:
                text = (f"{100 * outside:.2f} % of scheduling values lie outside the identified range "
                        f"[{lo:.4f}, {hi:.4f}] rad; the model is {self.beyond_range} there")
            warnings.warn(text, OutOfRangeWarning, stacklevel=2)
        lags, H = (self.causal_lags, self.H_causal) if causal else (self.lags, self.H)
        if causal:  # whole-record differences by the model's stencil, unless given
            v_est, a_est = (eq.derivatives(position, self.fs, self.causal_derivatives)
                            if velocity is None or acceleration is None else (None, None))
            velocity = v_est if velocity is None else np.asarray(velocity, dtype=float)
            acceleration = a_est if acceleration is None else np.asarray(acceleration, dtype=float)
        Gi = self.intrinsic_basis.evaluate(scheduling)
        tq_i = np.zeros(len(position))
        for a, b in eq.blocks(len(position), H.shape[0]):  # bounded memory for any record length
            signals = eq.position_signals(position, self.fs, lags, a, b, causal=causal, vel=velocity, acc=acceleration)
            tq_i[a:b] = eq.intrinsic_torque(signals, Gi[a:b], H)
        if self.curvature is not None:  # static in pos(k): the same term in both IRF forms
            tq_i = tq_i + eq.elastic_curvature_torque(position, Gi, self.curvature)
        z = self.reflex_drive(position, scheduling, high_rate=high)
        tq_r = self._reflex_filter(z)
        parts = {}
        if self.effects:
            from .effects import predict_effects

            parts = predict_effects(self, position, scheduling, extra_signals, causal=causal, velocity=velocity,
                                    acceleration=acceleration, z=z)
            if warn:
                self._warn_if_signal_levels(extra_signals)
            for pathway, tq in parts.values():
                if pathway == "reflex":
                    tq_r = tq_r + tq
                else:
                    tq_i = tq_i + tq
        return Prediction(total=tq_i + tq_r, intrinsic=tq_i, reflex=tq_r, out_of_range_fraction=outside,
                          effects={k: v[1] for k, v in parts.items()})

    def _warn_if_signal_levels(self, signals) -> None:
        """UnitWarning when an extra input (EMG) is far from its level at identification
        (``provenance["signal_levels"]``, RMS in the files' unit): the effect terms scale with it."""
        from ..errors import UnitWarning

        levels = self.provenance.get("signal_levels") or {}
        off = []
        for name, level in levels.items():
            x = (signals or {}).get(name)
            if x is None or not level > 0 or len(x) == 0:
                continue
            rms = float(np.sqrt(np.mean(np.square(np.asarray(x, dtype=float)))))
            ratio = rms / level
            if not (1 / SIGNAL_LEVEL_FACTOR <= ratio <= SIGNAL_LEVEL_FACTOR):
                off.append(f"'{name}' {ratio:.3g} times as large (RMS {rms:.3g}, at identification {level:.3g})")
        if off:
            warnings.warn(f"extra inputs far from their level at identification: {', '.join(off)}: another unit "
                          f"(EMG in mV for V is 1000 times)? The effect terms scale with them, the prediction is "
                          f"meaningless: give them in the unit of the identification data", UnitWarning, stacklevel=3)

    def _unpack_data(self, data, signals):
        if not (hasattr(data, "position") and hasattr(data, "scheduling")):
            raise DataError("predict needs position and scheduling arrays (rad), or a data object with "
                            f"'position' and 'scheduling' (got {type(data).__name__} without a scheduling record)")
        fs = getattr(data, "fs", None)
        if fs is not None and abs(float(fs) - self.fs) > 1e-9 * self.fs:
            raise DataError(f"data sampled at {float(fs):g} Hz, the model runs at {self.fs:g} Hz: load the data "
                            f"with target_fs={self.fs:g}")
        if signals is None and self.effects:
            from .effects import signals_from_data

            signals = signals_from_data(data, self)  # activation with this model's reflex drive, as improve fits it
        return data.position, data.scheduling, signals

    def export_fmu(self, path, fmi_version: int = 2, variant: str | None = None, **options):
        """Export as an FMI 2.0 (default) or 3.0 co-simulation FMU.

        A thin method over :func:`lpvpc.export.exporter.export_fmu`, which documents the
        variables, units and variants.

        Parameters
        ----------
        path : str or pathlib.Path
            The ``.fmu`` file to write (its folder is created).
        fmi_version : {2, 3}, default 2
            The FMI version.
        variant : {"sampled", "causal", "exact"}, optional
            Default :data:`lpvpc.export.exporter.DEFAULT_VARIANT` (``"sampled"``, what
            ``lpvpc export --fmu`` makes): inputs position and scheduling only, derivatives
            computed inside, a declared latency (2 samples with the default 5-point
            differences), the same timing in every co-simulation master. ``"causal"`` takes
            velocity and acceleration inputs and has direct feedthrough; ``"exact"`` is the
            two-sided IRF delayed by L samples.
        **options
            Passed to :func:`lpvpc.export.exporter.export_fmu` (e.g. ``interface="me"``).

        Returns
        -------
        pathlib.Path
            The FMU's path.

        Raises
        ------
        lpvpc.errors.ExportError
            An unknown variant, no C compiler, or a compiler error.
        TypeError
            An option :func:`lpvpc.export.exporter.export_fmu` does not take.

        Examples
        --------
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.identification.identify import identify
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> data = pair_trials(sim.pt, sim.ut)
        >>> model = identify(data)
        >>> import tempfile, zipfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = model.export_fmu(f"{folder}/ankle.fmu")
        ...     "modelDescription.xml" in zipfile.ZipFile(path).namelist()
        True
        """
        from ..export.exporter import DEFAULT_VARIANT, export_fmu

        return export_fmu(self, path, fmi_version=fmi_version, variant=variant or DEFAULT_VARIANT, **options)

    def export_casadi(self, path, variant: str | None = None):
        """Save the model's CasADi step function with its metadata in ``<path>.json``.

        ``casadi.Function.load`` reads the function back, :func:`lpvpc.export.exporter.load_casadi`
        the function with its metadata. See :func:`lpvpc.export.exporter.export_casadi`.

        Parameters
        ----------
        path : str or pathlib.Path
            The ``.casadi`` file to write.
        variant : {"sampled", "causal", "exact"}, optional
            Default :data:`lpvpc.export.exporter.DEFAULT_VARIANT`, what
            ``lpvpc export --casadi`` writes.

        Returns
        -------
        pathlib.Path
            The function's path.

        Raises
        ------
        lpvpc.errors.ExportError
            An unknown variant.

        Examples
        --------
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.identification.identify import identify
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> data = pair_trials(sim.pt, sim.ut)
        >>> model = identify(data)
        >>> import casadi, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     step = casadi.Function.load(str(model.export_casadi(f"{folder}/ankle.casadi")))
        >>> step.name_in(), step.name_out()[:2]
        (['state', 'position', 'scheduling'], ['next_state', 'torque'])
        """
        from ..export.exporter import DEFAULT_VARIANT, export_casadi

        return export_casadi(self, path, variant=variant or DEFAULT_VARIANT)

    def _high_rate_of(self, data):
        """The data's high-rate signals if this model identified its nonlinearity at their rate."""
        high = getattr(data, "high_rate", None)
        if high is None or self.high_rate is None or abs(high.fs - self.high_rate.fs) > 1e-9 * high.fs:
            return None
        return high

    def reflex_drive(self, position, scheduling, high_rate=None, delay=None):
        """Output z(k) of the reflex static nonlinearity for a whole record (model rate).

        ``high_rate`` (:class:`lpvpc.io.HighRate` at the rate of ``self.high_rate``): the
        high-rate nonlinearity acts on its delayed velocity and its output is decimated
        (:func:`lpvpc.models.reflex.high_rate_drive`); otherwise the model-rate nonlinearity acts on
        the velocity of ``position`` delayed by ``delay`` samples (default the model's; the
        diagnosis and the delay effect re-run the same nonlinearity at other delays)."""
        if high_rate is not None and self.high_rate is not None:
            from .reflex import high_rate_drive

            hr = self.high_rate
            q = int(round(hr.fs / self.fs))
            return high_rate_drive(high_rate, q, hr.delay, hr.velocity_basis, self.reflex_rho_basis, hr.Omega)
        dvel = eq.delayed_velocity(position, self.fs, self.delay if delay is None else delay)
        return eq.reflex_drive(self.velocity_basis.evaluate(dvel), self.reflex_rho_basis.evaluate(scheduling), self.Omega)

    def reflex_input(self, position, scheduling, delay=None):
        """The model-rate reflex nonlinearity's regressor U_r (N, n_v * n_r) on a record
        (:func:`lpvpc.models.reflex.reflex_input_regressor` of the model's velocity and
        scheduling bases): ``U_r @ Omega.ravel()`` is :meth:`reflex_drive`'s z without
        high-rate signals. The fits that refit the nonlinearity with the model's bases and
        delay (``delay`` samples; default the model's) start from it.

        >>> from lpvpc.identification.identify import identify
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> data = pair_trials(sim.pt, sim.ut)
        >>> model = identify(data, structure="fixed")
        >>> U = model.reflex_input(data.position, data.scheduling)
        >>> U.shape == (data.n, model.Omega.size)
        True
        >>> bool(np.allclose(U @ model.Omega.ravel(), model.reflex_drive(data.position, data.scheduling)))
        True
        """
        from .reflex import reflex_input_regressor

        dvel = eq.delayed_velocity(position, self.fs, self.delay if delay is None else delay)
        return reflex_input_regressor(self.velocity_basis.evaluate(dvel), self.reflex_rho_basis.evaluate(scheduling))

    def _reflex_filter(self, z):
        num, den = scipy.signal.ss2tf(self.A, self.B[:, None], self.C[None, :], np.array([[self.D]]))
        return scipy.signal.lfilter(num[0], den, z)

    # -- physical summaries (the paper's figures) ---------------------------------------
    def irf_weights(self, rho):
        """IRF weights h_l(rho) (N m/rad), shape (len(rho), n_lags) for lags ``self.lags``."""
        return self.intrinsic_basis.evaluate(np.atleast_1d(rho)) @ self.H.T

    def elastic_stiffness(self, rho):
        """Low-frequency intrinsic gain K(rho) in N m/rad: the sum of the IRF weights."""
        return self.irf_weights(rho).sum(axis=1)

    def viscosity(self, rho):
        """Intrinsic viscosity B(rho) in N m s/rad: minus the first moment of the IRF
        (sum_l h_l e^{-s l T} = K + B s + I s^2 + ... for slow inputs)."""
        return -(self.irf_weights(rho) @ np.asarray(self.lags, dtype=float)) / self.fs

    def inertia(self, rho):
        """Intrinsic inertia I(rho) in kg m^2: half the second moment of the IRF times T^2."""
        return 0.5 * (self.irf_weights(rho) @ np.asarray(self.lags, dtype=float) ** 2) / self.fs**2

    def intrinsic_frequency_response(self, freqs, rho):
        """Complex intrinsic frequency response (N m/rad), shape (len(rho), len(freqs)) (Fig. 4)."""
        w = 2 * np.pi * np.asarray(freqs, dtype=float) / self.fs
        phasors = np.exp(-1j * np.outer(self.lags, w))  # lag l delays by l samples
        return self.irf_weights(rho) @ phasors

    def reflex_static_gain(self) -> float:
        """DC gain of the reflex linear dynamics C (I - A)^-1 B + D."""
        return eq.static_gain(self.A, self.B, self.C, self.D)

    def reflex_nonlinearity(self, velocity, rho):
        """Static nonlinearity f(v, rho) scaled by the reflex DC gain, in N m (Fig. 5A).

        Returns an array of shape (len(rho), len(velocity)): the steady reflex torque that
        a constant delayed velocity would evoke at each position.
        """
        basis, Omega = self.nonlinearity()
        Vb = basis.evaluate(np.atleast_1d(velocity))
        Rb = self.reflex_rho_basis.evaluate(np.atleast_1d(rho))
        return self.reflex_static_gain() * (Rb @ Omega.T @ Vb.T)

    def reflex_impulse_response(self, n: int | None = None):
        """Impulse response of the reflex linear dynamics, (time s, response) (Fig. 5B)."""
        n = n or int(round(0.6 * self.fs))
        impulse = np.zeros(n)
        impulse[0] = 1.0
        return np.arange(n) / self.fs, self._reflex_filter(impulse)

    def rectifier_velocity_grid(self, n_velocity: int = 200):
        """Velocities (rad/s) over which the rectifier is fitted, and the p99 top used."""
        v_top = self.fit.get("velocity_p99", self.nonlinearity()[0].hi)
        return np.linspace(0.0, v_top, n_velocity), v_top

    def reflex_gain_threshold(self, rho, n_velocity: int = 200, knee_corrected: bool = True):
        """Fit a half-wave rectifier G * max(v - th, 0) + c to the identified nonlinearity.

        Returns (gain in N m s/rad, threshold in rad/s) for each rho, fitted from zero to
        the 99th percentile of the positive delayed velocities seen at identification
        (where the data determine the curve; the sparse extreme tail bends polynomials).

        A polynomial velocity basis rounds the rectifier's knee: a low threshold is read
        high and its gain high, a high one's gain low (:func:`lpvpc.models.reflex_uncertainty.knee_rounding`).
        When the model file stores how this record's regressors round a true rectifier
        (``uncertainty["knee_rounding"]``, 1 kHz path), the reading is mapped back through it
        (``knee_corrected``; False gives the plain fit to the curve): the threshold whose
        rounded reading is the fit's, and the gain divided by that threshold's rounding factor
        (:func:`lpvpc.models.reflex_uncertainty.unrounded_rectifier`).
        """
        rho = np.atleast_1d(np.asarray(rho, dtype=float))
        v, _ = self.rectifier_velocity_grid(n_velocity)
        gain, threshold = rectifier_fit(v, self.reflex_nonlinearity(v, rho))
        if not knee_corrected:
            return gain, threshold
        from .reflex_uncertainty import unrounded_rectifier

        return unrounded_rectifier(self, gain, threshold)

    # -- confidence intervals (lpvpc.models.uncertainty; stored in the model file) -----------------
    @property
    def has_intervals(self) -> bool:
        """True when the model carries the covariance the ``*_interval`` methods need."""
        return bool(self.uncertainty)

    @property
    def interval_terms(self) -> list:
        """What the K, viscosity and inertia intervals include: the noise, the neighbouring
        specifications' bias bound and, when stored
        (:func:`lpvpc.identification.structural_uncertainty.add_structural_uncertainty`), the spread over
        the structures cross-validation cannot tell apart (those that differ in the intrinsic
        pathway only). Empty without intervals."""
        if not self.uncertainty:
            return []
        terms = ["noise (HAC sandwich)"]
        if self.uncertainty.get("truncation") or self.uncertainty.get("richer_basis"):
            terms.append("neighbouring specifications (IRF one lag shorter: K and inertia; basis one order higher)")
        if self.uncertainty.get("structural"):
            terms.append("near-equivalent structures of the cross-validation")
        return terms

    def elastic_stiffness_interval(self, theta, level: float = 0.95):
        """Interval (unpacks as lower, upper arrays) (N m/rad) of the ``level`` confidence interval of K(theta)
        at positions ``theta`` (rad). HAC covariance of the final least squares (correlated
        residuals respected), widened for the structural bias (:attr:`interval_terms`); see
        :mod:`lpvpc.models.uncertainty` for what it leaves out."""
        return _interval_pair(self, "stiffness", theta, level)

    def viscosity_interval(self, theta, level: float = 0.95):
        """Interval (unpacks as lower, upper arrays) (N m s/rad) of the confidence interval of the viscosity."""
        return _interval_pair(self, "viscosity", theta, level)

    def inertia_interval(self, theta, level: float = 0.95):
        """Interval (unpacks as lower, upper arrays) (kg m^2) of the confidence interval of the inertia."""
        return _interval_pair(self, "inertia", theta, level)

    def reflex_gain_interval(self, theta, level: float = 0.95):
        """(lower, upper) arrays (N m s/rad) of the confidence interval of the reflex
        rectifier gain at positions ``theta`` (rad): parametric bootstrap of the rectifier
        fit with bounds for structural bias (:func:`lpvpc.models.reflex_uncertainty.reflex_interval`); an
        :class:`lpvpc.models.uncertainty.Interval` whose ``biased`` is True for a model-rate
        nonlinearity (:attr:`reflex_threshold_biased`; the interval then includes a bound
        for the smoothed knee) and whose ``determined`` is False where it reaches zero."""
        from .reflex_uncertainty import reflex_interval

        return reflex_interval(self, theta, level)[0]

    def reflex_threshold_interval(self, theta, level: float = 0.95):
        """(lower, upper) arrays (rad/s) of the confidence interval of the reflex velocity
        threshold (an :class:`lpvpc.models.uncertainty.Interval`, ``biased`` as for the gain; a
        model-rate nonlinearity's spans the fitted velocity range, ``determined`` False)."""
        from .reflex_uncertainty import reflex_interval

        return reflex_interval(self, theta, level)[1]

    def reflex_determined(self, theta, level: float = 0.95):
        """(gain, threshold) bool arrays at positions ``theta`` (rad): False where the
        quantity's interval spans most of its plausible range, so the data do not determine
        it there ("not determined by these data"; rule: :func:`lpvpc.models.reflex_uncertainty.reflex_determination`).
        All True for a model without intervals (nothing to judge by)."""
        theta = np.atleast_1d(np.asarray(theta, dtype=float))
        if not self.has_intervals:
            return np.ones(len(theta), dtype=bool), np.ones(len(theta), dtype=bool)
        from .reflex_uncertainty import reflex_interval

        g, th = reflex_interval(self, theta, level)
        return g.determined, th.determined

    def vaf_interval(self, level: float = 0.95):
        """(lower, upper) VAF (%) on the identification record, moving-block bootstrap."""
        from .uncertainty import _stored

        v = _stored(self)["vaf"]
        if abs(level - v["level"]) < 1e-12:
            return v["lower"], v["upper"]
        raise ValueError(f"the model file stores the {v['level']:.0%} VAF interval only, not {level}")

    # -- persistence ---------------------------------------------------------------------
    def to_dict(self, derived: bool = True) -> dict:
        """The model file's content; ``derived``: with the entries computed from the model
        (``uncertainty.reflex_determined``), which loading recomputes rather than trusts."""
        d = {
            "format": FORMAT,
            "format_version": (FORMAT_VERSION_CURVATURE if self.curvature is not None
                               else FORMAT_VERSION_EFFECTS if self.effects else FORMAT_VERSION),
            "fs": self.fs,
            "intrinsic": {
                "lags": list(map(int, self.lags)),
                "H": self.H.tolist(),
                "basis": self.intrinsic_basis.to_dict(),
                "causal_lags": list(map(int, self.causal_lags)),
                "H_causal": self.H_causal.tolist(),
                "derivatives": self.causal_derivatives,
            },
            "reflex": {
                "delay": int(self.delay),
                "velocity_basis": self.velocity_basis.to_dict(),
                "rho_basis": self.reflex_rho_basis.to_dict(),
                "Omega": self.Omega.tolist(),
                "A": self.A.tolist(),
                "B": self.B.tolist(),
                "C": self.C.tolist(),
                "D": self.D,
            },
            "identified_ranges": {"scheduling": list(self.scheduling_range), "velocity": list(self.velocity_range)},
            "units": {"position": "rad", "scheduling": "rad", "velocity": "rad/s", "torque": "N m", "fs": "Hz"},
            "settings": self.settings,
            "provenance": self.provenance,
            "conventions": self.conventions,
            "fit": self.fit,
        }
        if self.curvature is not None:
            d["intrinsic"]["curvature"] = self.curvature.tolist()
        if self.high_rate is not None:
            d["reflex"]["high_rate"] = self.high_rate.to_dict()
        if self.effects:
            d["effects"] = [fe.to_dict() for fe in self.effects]
        if self.uncertainty:
            d["uncertainty"] = self.uncertainty
            if derived:  # where the data determine the reflex gain and threshold, recorded for readers of the file
                from .reflex_uncertainty import reflex_determination

                d["uncertainty"] = {**self.uncertainty, "reflex_determined": reflex_determination(self)}
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "model") -> "LPVPCModel":
        check_model_dict(d, source)  # the schema and its limits, before anything is built
        try:
            intr, refl = d["intrinsic"], d["reflex"]
            model = cls(
                fs=float(d["fs"]),
                lags=[int(x) for x in intr["lags"]],
                H=np.array(intr["H"], dtype=float),
                intrinsic_basis=Basis.from_dict(intr["basis"]),
                causal_lags=[int(x) for x in intr["causal_lags"]],
                H_causal=np.array(intr["H_causal"], dtype=float),
                causal_derivatives=intr.get("derivatives", "central3"),  # files before it: central3
                delay=int(refl["delay"]),
                velocity_basis=Basis.from_dict(refl["velocity_basis"]),
                reflex_rho_basis=Basis.from_dict(refl["rho_basis"]),
                Omega=np.array(refl["Omega"], dtype=float),
                A=np.array(refl["A"], dtype=float),
                B=np.array(refl["B"], dtype=float),
                C=np.array(refl["C"], dtype=float),
                D=float(refl["D"]),
                settings=d.get("settings", {}),
                provenance=d.get("provenance", {}),
                conventions=d.get("conventions", {}),
                fit=d.get("fit", {}),
                uncertainty={k: v for k, v in (d.get("uncertainty") or {}).items() if k != "reflex_determined"},
                high_rate=HighRateNonlinearity.from_dict(refl["high_rate"]) if refl.get("high_rate") else None,
                curvature=np.array(intr["curvature"], dtype=float) if intr.get("curvature") is not None else None,
            )
            if d.get("effects"):
                from .effects import FittedEffect

                model.effects = [FittedEffect.from_dict(e) for e in d["effects"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{source}: corrupt model file ({type(exc).__name__}: {exc})") from None
        model._check_shapes(source)
        return model

    def _check_shapes(self, source):
        n_i, n_v, n_r, m = self.intrinsic_basis.size, self.velocity_basis.size, self.reflex_rho_basis.size, self.A.shape[0] if self.A.ndim == 2 else -1
        problems = []
        if self.H.shape != (len(self.lags), n_i):
            problems.append(f"intrinsic H has shape {self.H.shape}, expected {(len(self.lags), n_i)}")
        if self.H_causal.shape != (len(self.causal_lags) + 2, n_i):
            problems.append(f"intrinsic H_causal has shape {self.H_causal.shape}, expected {(len(self.causal_lags) + 2, n_i)}")
        if self.curvature is not None and self.curvature.shape != (n_i,):
            problems.append(f"intrinsic curvature has shape {self.curvature.shape}, expected {(n_i,)}")
        if min(self.causal_lags, default=0) < 0:
            problems.append("causal_lags must be non-negative")
        if self.causal_derivatives not in eq.DERIVATIVE_STENCILS:
            problems.append(f"intrinsic derivatives {self.causal_derivatives!r} is not one of {eq.DERIVATIVE_STENCILS}")
        if self.Omega.shape != (n_v, n_r):
            problems.append(f"reflex Omega has shape {self.Omega.shape}, expected {(n_v, n_r)}")
        if self.high_rate is not None:
            hr = self.high_rate
            q = hr.fs / self.fs
            if hr.Omega.shape != (hr.velocity_basis.size, n_r):
                problems.append(f"reflex high_rate Omega has shape {hr.Omega.shape}, expected {(hr.velocity_basis.size, n_r)}")
            if not (q > 1.5 and abs(q - round(q)) < 1e-6 * q):
                problems.append(f"reflex high_rate fs {hr.fs:g} Hz is not an integer multiple (> 1) of the model's {self.fs:g} Hz")
            if hr.delay < 1:
                problems.append(f"reflex high_rate delay must be at least 1 sample, got {hr.delay}")
        if m < 1 or self.A.shape != (m, m) or self.B.shape != (m,) or self.C.shape != (m,):
            problems.append(f"reflex state-space shapes inconsistent: A {self.A.shape}, B {self.B.shape}, C {self.C.shape}")
        if self.delay < 1:
            problems.append(f"reflex delay must be at least 1 sample, got {self.delay}")
        arrays = [self.H, self.H_causal, self.Omega, self.A, self.B, self.C, np.array([self.D, self.fs])]
        if self.curvature is not None:
            arrays.append(self.curvature)
        if self.high_rate is not None:
            arrays.append(self.high_rate.Omega)
        for fe in self.effects:
            arrays += [a for a in (fe.H, fe.H_causal, fe.Theta) if a is not None]
            n_c = n_i if fe.channel_basis is None else fe.channel_basis.size
            if fe.H is not None and (fe.H.shape[0] != len(self.lags) or fe.H.shape[1] % n_c):
                problems.append(f"effect {fe.name}: H has shape {fe.H.shape}, expected ({len(self.lags)}, k * {n_c})")
            if fe.H_causal is not None and fe.H_causal.shape[0] != len(self.causal_lags) + 2:
                problems.append(f"effect {fe.name}: H_causal has {fe.H_causal.shape[0]} rows, expected {len(self.causal_lags) + 2}")
            if fe.Theta is not None and (fe.basis is None or fe.Theta.shape[1] != fe.basis.size - (not fe.effect.feature_constant)):
                problems.append(f"effect {fe.name}: Theta has shape {fe.Theta.shape}, inconsistent with its basis")
        if not problems and not all(np.all(np.isfinite(a)) for a in arrays):
            problems.append("non-finite coefficients")
        if problems:
            raise ModelFileError(f"{source}: corrupt model file: " + "; ".join(problems))

    def save(self, path) -> None:
        """Write the model as JSON (the model file format, docs/guide/model_format.md).

        Parameters
        ----------
        path : str or pathlib.Path
            The file to write (a temporary file renamed into place: never half written).
        """
        from ..io.outputs import write_text

        write_text(path, json.dumps(self.to_dict(), indent=1))  # temporary file + rename

    @classmethod
    def load(cls, path) -> "LPVPCModel":
        """Read a model file written by :meth:`save` (or ``lpvpc identify -o``).

        Parameters
        ----------
        path : str or pathlib.Path
            The model file.

        Returns
        -------
        LPVPCModel
            The model, as it was saved.

        Raises
        ------
        lpvpc.errors.ModelFileError
            A missing, unreadable or corrupt file, or an unknown format version.
        """
        return cls.from_dict(read_model_file(path), source=str(path))

    @property
    def model_hash(self) -> str:
        """sha256 of the canonical JSON of the model's equations and coefficients."""
        import hashlib

        d = self.to_dict(derived=False)
        core = {k: d[k] for k in ("fs", "intrinsic", "reflex", "effects") if k in d}
        return hashlib.sha256(json.dumps(core, sort_keys=True).encode()).hexdigest()


def _interval_pair(model, quantity, theta, level):
    from .uncertainty import Interval, intrinsic_interval

    _, lo, hi = intrinsic_interval(model, quantity, theta, level)
    return Interval(lo, hi)  # unpacks as (lower, upper), like every interval of the model


def vaf(measured, predicted) -> float:
    """Variance accounted for, in percent: 100 (1 - var(measured - predicted) / var(measured)).

    Parameters
    ----------
    measured, predicted : array_like
        The measured and the predicted signal, same length.

    Returns
    -------
    float
        The VAF (%): 100 for a perfect prediction, 0 for the mean, negative for worse.

    Examples
    --------
    >>> vaf([1.0, -1.0, 1.0, -1.0], [0.9, -0.9, 0.9, -0.9])
    99.0
    """
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    return float(100.0 * (1.0 - np.var(measured - predicted) / np.var(measured)))


def _same_convention(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return abs(float(a) - float(b)) <= 1e-9 * max(1.0, abs(float(a)))


_KEYWORD = {"position_unit": "position_unit", "torque_sign": "torque_sign", "time_unit": "time_unit",
            "channel_skew": "channel_skew", "fs": "target_fs"}
_CONVENTION_TEXT = {"position_unit": "position unit", "torque_sign": "torque sign", "time_unit": "time unit",
                    "channel_skew": "channel skew (s)", "fs": "rate (Hz)"}


def _refuse_contradictions(model_conventions: dict, given: dict, source=None) -> None:
    """DataError naming each convention given for a record that differs from the model's."""
    problems = [f"{_CONVENTION_TEXT[k]}: the record was read with {v!r}, the model's record with "
                f"{model_conventions[k]!r}; read it as the model's (model.load_record, or {_KEYWORD[k]}="
                f"{model_conventions[k]!r} when loading it)"
                for k, v in given.items() if not _same_convention(model_conventions[k], v)]
    if problems:
        raise DataError(problems, source=source or None)
