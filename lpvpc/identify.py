"""The subspace LPV parallel-cascade identification (Sobhani Tehrani et al., EMBC 2014).

Steps (equation numbers of the seed paper):

1. regressors: intrinsic Psi_i (9-11) and reflex inputs U_r (17) from the bases;
2. MOESP on the MISO form (21)-(23) gives A_r, C_r; the state order is chosen from the
   singular values (the orders at the two largest gaps, plus order 2) and settled by BIC
   of the complete fit, unless ``state_order`` is given; the MOESP poles are then refined
   by variable projection on the complete fit (``PoleRefinement``; MOESP with ~70 inputs
   leaves a bias in the poles that leaks reflex torque into the intrinsic estimate);
3. reflex regressor Psi_r (25) by filtering U_r through C_r (zI - A_r)^-1;
4. orthogonal projection (27)-(28): the intrinsic parameters by least squares after
   projecting out range(Psi_r) (Frisch-Waugh: identical to C^+ Psi_i^+ (I - Psi_r Psi_r^+) Y
   without N x N matrices);
5. reflex torque (29) and separable least squares for B, d and Omega;
6. a causal intrinsic IRF (lags 0..Lc, plus velocity and acceleration terms) fitted to the
   two-sided intrinsic torque, for closed loop (the default FMU's form).
"""

from __future__ import annotations

import functools
import inspect
import math
import time
import warnings
from typing import TYPE_CHECKING

import numpy as np

from . import __version__
from . import equations as eq
from .basis import basis_from_data
from .errors import (DataError, IdentificationError, InsufficientExcitationError, LpvpcError, PhysiologyWarning,
                     StationaryWarning)
from .intrinsic import curvature_from_irf, curvature_regressor, intrinsic_regressor, two_sided_lags
from .segments import Segments

# why the selection skips a record whose reflex nonlinearity the caller put on the high-rate velocity
HIGH_RATE_GIVEN = "reflex nonlinearity on the high-rate velocity"

if TYPE_CHECKING:  # annotations only: lpvpc.model imports scipy.signal, kept out of import time (above)
    from .model import LPVPCModel

# scipy-based modules are imported where they are used, so that `lpvpc identify --help`
# (which reads the estimator's defaults) starts without scipy.signal.

# Defaults that a stationary trial's delay search replaces (see ``stationary_delays``).
DEFAULT_REFLEX_DELAY = 0.040  # s
DEFAULT_IRF_LENGTH = 0.040  # s
DEFAULT_MAX_REFLEX_TIME_CONSTANT = 1.0  # s (see max_reflex_time_constant)
STATIONARY_DELAYS = (0.04, 0.05, 0.06, 0.07, 0.08)  # s
#: structure="cv" is skipped (the settings as given, the reason recorded) when its largest
#: regressor would take more than this: a 30-minute 100 Hz record's takes 260 MB; a 1 kHz
#: record's IRF has 10x the lags.
DESIGN_BUDGET_BYTES = 400e6
#: s: structure="cv" is skipped on shorter records (the settings as given, the reason recorded).
#: Virtual subject, seeds 0-5, worst K(theta) error over the central 80 % of the range: 30-s
#: records 2.5-28 % with the selection (small structures: IRF 20 ms, intrinsic order 2-3)
#: against 3.7-6.9 % at the fixed settings; 45-s records 2.2-5.4 % against 2.7-4.9 %;
#: 60-s records (seeds 0-3, five positions) within 2.5 %, as good or better.
MIN_SELECTION_S = 45.0
#: Effects structure="cv" may switch on (``allow_effects``): stress relaxation, on every
#: record (docs/guide/structure_selection.md, "Effects chosen by cross-validation").
DEFAULT_ALLOWED_EFFECTS = ("stress_relaxation",)
#: An allowed effect is kept only if, beyond the one-standard-error rule, it lowers the
#: cross-validated squared error by at least this fraction. Why: with 5-10 folds a tiny but
#: consistent gain passes the paired rule (stationary virtual subject without relaxation, seed 0:
#: +0.002 points of CV VAF, chosen), and an effect costs more than its parameters (an extended
#: model's K interval is about twice as wide, lpvpc.uncertainty; the FMU gets its states). 5 %: on
#: clean 1 kHz records of the standard and sum-of-exponentials stiffness (seed 3) relaxation was
#: chosen at 1.5 and 2.2 % (absorbing what the position basis misses), while relaxation
#: present gave 16-35 % (benchmarks/results/effect_selection.txt).
MIN_EFFECT_GAIN = 0.05
#: Why structure="cv" fits forced effects as given (then only stress relaxation's term is chosen).
EXTENDED_GIVEN = "extended model (effects)"
#: Fits of the effects' dynamics at most (each with the best terms under the previous one's).
MAX_EFFECT_PASSES = 3
#: The first look (the first fit's dynamics, which take part of a relaxation) screens at a
#: lower bar: it showed 4-10 % on records with relaxation.
FIRST_LOOK_GAIN = 0.01

#: rad: a trial whose scheduling variable spans less than this is at one operating position
#: (stationary): identified as the position-independent cascade.
STATIONARY_RANGE = 0.010


def _records_given_settings(init):
    """Wrap ``__init__`` to record the names of the settings passed (structure="cv" leaves them as given)."""
    signature = inspect.signature(init)

    @functools.wraps(init)
    def wrapper(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self._given = set(signature.bind(self, *args, **kwargs).arguments) - {"self"}

    return wrapper


class LPVPCEstimator:
    """Estimator of an LPV-PC ankle stiffness model (scikit-learn style).

    Parameters (defaults suit 100 Hz ankle data)
    ----------
    irf_length : half-width of the intrinsic IRF in s: lags -L..L with L = round(irf_length
        * fs) (0.04 s: L = 4 at 100 Hz; on the lab's pilot trial L = 3 lost 0.3 VAF points
        held out, L = 2 1.3 points; the virtual subject is indifferent).
    irf_lags : L in samples, overriding ``irf_length`` when given. Keep L at most the
        reflex delay, otherwise intrinsic and reflex regressors overlap.
    basis : basis family in the scheduling variable ("chebyshev", "legendre", "gaussian").
    intrinsic_order : basis order in rho of each IRF weight (order 5 follows an
        exponential K(theta); 3 does not).
    reflex_order : basis order in rho of the reflex nonlinearity coefficients.
    velocity_order : basis order in delayed velocity of the reflex nonlinearity.
    velocity_basis : its family ("chebyshev" polynomials or "hinge" piecewise-linear);
        both continue linearly beyond the identified velocity range.
    high_rate_reflex : identify the reflex nonlinearity on the high-rate delayed velocity of
        data that keep their file's higher rate (below). With ``structure="cv"`` (the default)
        and the setting not given, it is chosen per record by the same cross-validation
        (:func:`lpvpc.selection.compare_reflex_paths`; the model rate unless the high rate
        predicts the left-out levels better by more than a standard error), together with the
        high-rate velocity basis (Chebyshev 4 or hinge 8) unless one is given. Why per record:
        on the lab's pilot trial (1 kHz file, split 70/30) the high rate predicted the held-out
        part worse than the model-rate velocity (93.49 % against 94.06 %:
        benchmarks/results/real_pilot.txt), while on the virtual subject it recovers the reflex
        gain trend (and, on long or clean records, the threshold's) better
        (benchmarks/results/reflex_1k.txt) and its gain intervals cover the truth
        (benchmarks/results/uncertainty.txt). Given (True or False), or with
        ``structure="fixed"`` (then False unless given), it stays as given; given True, the
        rest of the structure is not selected (its candidates are model-rate columns).
    high_rate_velocity_basis, high_rate_velocity_order : family and order in delayed
        velocity of the reflex nonlinearity when ``high_rate_reflex`` and the data keep their file's higher rate
        (1 kHz files loaded at the 100 Hz model rate: :class:`lpvpc.data.HighRate`). The
        nonlinearity then acts on the high-rate delayed velocity, where the 20 ms
        reflex-evoking pulses are resolved, and its output is decimated to the model rate
        (:func:`lpvpc.reflex.high_rate_input`); a piecewise-linear basis can place the
        rectifier's kink (virtual subject, 10 seeds, slope ratios to the truth, medians: hinge
        order 8 gain 0.99, threshold 1.15; from 100 Hz files 1.12 and 0.31:
        benchmarks/results/reflex_1k.txt). Under the lab's perturbation design (every step
        large) the hinge basis is left free and Chebyshev order 4 holds up (virtual subject
        and pilot trial: benchmarks/results/lab_perturbation.txt, real_pilot.txt).
    reflex_delay : reflex delay in s (rounded to samples).
    state_order : order m of the reflex dynamics; None chooses it from the data.
    min_state_order, max_state_order : range of orders considered when choosing.
    horizon : block rows s of the MOESP Hankel matrices.
    causal_lags : Lc, the causal intrinsic IRF spans lags 0..Lc (default L + 2).
    causal_derivatives : offline velocity/acceleration estimate of the causal form,
        "central5" (default: 5-point differences; on the lab's pilot trial the causal form
        loses 1.2 points to the two-sided IRF, with "central3" 4.7; they need p(k+2), so the
        default FMU's latency is 2 samples) or "central3" (3-point, latency 1): see
        :data:`lpvpc.equations.DERIVATIVE_STENCILS`.
    refine : refine the MOESP poles by variable projection (see module docstring).
    max_reflex_time_constant : longest time constant (s) the refined reflex poles may have
        (None: up to the stability limit). The reflex's activation dynamics are a 2-4 Hz
        low-pass (time constants ~0.1-0.3 s: 0.18 s on the lab's pilot trial, 0.10-0.29 s on
        its five stationary trials). Where the record holds slow torque the model lacks (a
        background activation that changes over the trial), the poles otherwise ran to
        0.999 per sample, an integrator that followed that torque on the identification
        record and drifted on any other (virtual subject with a hidden activation, seed 4:
        novel VAF 40 %; capped at 1 s, 69 %; clean seeds unchanged). The lab's stationary
        trial z_df2 would take a 2.5-s pole uncapped (held-out VAF 96.45 %; capped 96.43 %).
    tol, max_iter : stopping rule of the separable least squares.
    stationary_range : when the scheduling variable spans less than this (rad), the trial is
        stationary (one operating position) and the LTI parallel cascade is identified
        (basis orders 0 in rho) with a :class:`~lpvpc.errors.StationaryWarning`.
    stationary_delays : on a stationary trial, the reflex delays (s) among which the delay
        is chosen by BIC of the complete fit, with the IRF half-width equal to it (the
        longest IRF whose regressors stay independent of the reflex's); used while
        ``reflex_delay``, ``irf_length`` and ``irf_lags`` keep their defaults (``()``: off;
        given ``effects`` stay in every candidate).
        On the lab's five stationary trials BIC chose 60-80 ms and the held-out VAF rose on
        every trial (benchmarks/bench_real_stationary.py); on the virtual subject (40 ms) it
        chose 40-50 ms and K moved by < 0.3 %. Up to 80 ms: a longer intrinsic IRF starts
        to take reflex torque (K fell from 44 to 17 N m/rad on one lab trial at 120 ms).
    elastic_curvature : include the elastic torque's second-order term in the perturbation,
        0.5 K'(theta) p^2 (:func:`lpvpc.equations.elastic_curvature_torque`), tied to the
        IRF's own stiffness K(theta) (no extra parameters; not in the paper). The IRF is
        linear in p; without the term the reflex nonlinearity takes up part of it (a stretch
        step raises velocity and p^2 together) and the 1 kHz path's reflex gain came out
        +14 % high on the virtual subject (+1 % with it; K unchanged). Lab pilot trial:
        held-out VAF 94.06 % with it, 94.10 % without; free coefficients instead of tied
        ones lost 0.13 points there (and 6 points on the 1 kHz path).
    structure : "cv" (default) or "fixed". "cv": the IRF half-width, basis orders, reflex
        delay, curvature term and scheduling extrapolation the caller did not set are
        chosen by leave-one-level-out cross-validation with the one-standard-error rule
        (:mod:`lpvpc.selection`), starting from the settings given; the choice and a CV
        table are recorded in ``model.fit["structure_selection"]``. On the lab's pilot
        trial (first 70 %, leave-one-level-out) it predicted left-out levels at 90.9 %
        VAF against 81.1 % for the fixed settings (benchmarks/results/selection.txt).
        On data that keep their file's higher rate, the velocity of the reflex nonlinearity
        (model or high rate, see ``high_rate_reflex``) is a candidate too.
        Selection is skipped, with the reason recorded, on stationary trials, extended
        models (effects), non-polynomial bases, ``high_rate_reflex=True`` given and records whose
        selection design would exceed ``DESIGN_BUDGET_BYTES``. "fixed": the settings as given.
    structure_fixed : with ``structure="cv"``, names of settings the selection leaves as
        given. None (default): every selected setting named in the call (to the constructor,
        :meth:`set_params` or :func:`identify`), whatever its value; an ``irf_lags`` given
        fixes ``irf_length``. The command line likewise fixes every option the user wrote.
    scheduling_extrapolation : beyond the identified range of the scheduling variable the
        position bases are held at the boundary ("clip", default) or continued along their
        tangent ("linear"; :class:`lpvpc.basis.Basis`).
    allow_effects : effects of the catalog that structure="cv" may switch on: each is an
        on/off candidate of the same cross-validation (its columns join the largest
        regressor; :mod:`lpvpc.selection`), on stationary trials scored on contiguous blocks
        at the delay BIC chose. Default ``("stress_relaxation",)``; ``()``: none. Only
        intrinsic effects with static features of the position qualify (ValueError
        otherwise). Not used with structure="fixed", nor when ``effects`` are given (then
        the structure is as given), nor on several trials joined. Stress relaxation's
        averaging time and position-weight order are chosen with it
        (:data:`lpvpc.selection.RELAXATION_VARIANTS`).
    relaxation_times, relaxation_order : a stress-relaxation term's averaging times (s) and
        the order of its position weights. None (default): chosen by the cross-validation
        when it switches the effect on, else :data:`lpvpc.effects.RELAXATION_TIMES` and the
        catalog's order (1). The model stores its times (its effect's options).
    effects : names of effects from :data:`lpvpc.effects.CATALOG` to include (an extended
        model; default none), always on. Intrinsic-pathway effects are estimated jointly with the
        intrinsic part (extra columns of Psi_i); reflex-pathway effects jointly with it
        after the reflex is identified. The data must carry the signals the effects need.

    Examples
    --------
    Fit a 30-s record of the virtual subject (100 Hz) and score a trial of another seed
    (VAF in percent; it leaves the identified range a quarter of the time, where the model
    is held at the range's edge): it comes within 2 points of that trial's noise ceiling.

    >>> import warnings
    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.errors import OutOfRangeWarning
    >>> from lpvpc.model import vaf
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> est = LPVPCEstimator(intrinsic_order=5).fit(pair_trials(sim.pt, sim.ut))
    >>> est.get_params()["intrinsic_order"], est.model_.fs
    (5, 100.0)
    >>> other = simulate_pair("multilevel", seed=1, duration=30.0, fs_out=100.0)
    >>> test, clean = pair_trials(other.pt, other.ut), pair_trials(other.pt_clean, other.ut_clean)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", OutOfRangeWarning)
    ...     score, torque = est.score(test), est.predict(test)
    >>> bool(score > vaf(test.torque, clean.torque) - 2.0), torque.shape  # torque in N m per sample
    (True, (3000,))
    >>> est.set_params(intrinsic_order=4).intrinsic_order
    4
    """

    @_records_given_settings
    def __init__(
        self,
        irf_lags: int | None = None,
        basis: str = "chebyshev",
        intrinsic_order: int = 5,
        reflex_order: int = 2,
        velocity_order: int = 4,
        velocity_basis: str = "chebyshev",
        reflex_delay: float = DEFAULT_REFLEX_DELAY,
        state_order: int | None = None,
        min_state_order: int = 1,
        max_state_order: int = 4,
        horizon: int = 6,
        causal_lags: int | None = None,
        tol: float = 1e-6,
        max_iter: int = 100,
        refine: bool = True,
        effects: tuple = (),
        irf_length: float = DEFAULT_IRF_LENGTH,
        stationary_range: float = STATIONARY_RANGE,
        causal_derivatives: str = "central5",
        stationary_delays: tuple = STATIONARY_DELAYS,
        high_rate_velocity_basis: str = "hinge",
        high_rate_velocity_order: int = 8,
        high_rate_reflex: bool = False,
        elastic_curvature: bool = True,
        max_reflex_time_constant: float | None = DEFAULT_MAX_REFLEX_TIME_CONSTANT,
        structure: str = "cv",
        structure_fixed: tuple | None = None,
        scheduling_extrapolation: str = "clip",
        allow_effects: tuple = DEFAULT_ALLOWED_EFFECTS,
        relaxation_times: tuple | None = None,
        relaxation_order: int | None = None,
    ):
        self.allow_effects = allow_effects
        self.relaxation_times = relaxation_times
        self.relaxation_order = relaxation_order
        self.structure = structure
        self.structure_fixed = structure_fixed
        self.scheduling_extrapolation = scheduling_extrapolation
        self.elastic_curvature = elastic_curvature
        self.max_reflex_time_constant = max_reflex_time_constant
        self.high_rate_reflex = high_rate_reflex
        self.high_rate_velocity_basis = high_rate_velocity_basis
        self.high_rate_velocity_order = high_rate_velocity_order
        self.irf_lags = irf_lags
        self.irf_length = irf_length
        self.stationary_range = stationary_range
        self.causal_derivatives = causal_derivatives
        self.stationary_delays = stationary_delays
        self.basis = basis
        self.intrinsic_order = intrinsic_order
        self.reflex_order = reflex_order
        self.velocity_order = velocity_order
        self.velocity_basis = velocity_basis
        self.reflex_delay = reflex_delay
        self.state_order = state_order
        self.min_state_order = min_state_order
        self.max_state_order = max_state_order
        self.horizon = horizon
        self.causal_lags = causal_lags
        self.tol = tol
        self.max_iter = max_iter
        self.refine = refine
        self.effects = effects

    def get_params(self, deep: bool = True) -> dict:
        """The estimator's settings as a dict (scikit-learn convention; ``deep`` is ignored:
        no nested estimators)."""
        return {k: getattr(self, k) for k in (
            "irf_lags", "basis", "intrinsic_order", "reflex_order", "velocity_order", "velocity_basis", "reflex_delay",
            "state_order", "min_state_order", "max_state_order", "horizon", "causal_lags", "tol", "max_iter", "refine",
            "effects", "irf_length", "stationary_range", "causal_derivatives", "stationary_delays",
            "high_rate_velocity_basis", "high_rate_velocity_order", "high_rate_reflex", "elastic_curvature",
            "max_reflex_time_constant", "structure", "structure_fixed", "scheduling_extrapolation", "allow_effects",
            "relaxation_times", "relaxation_order")
            } | {"structure_fixed": self._given_settings()}  # (a clone keeps what was given)

    def resolved_lags(self, fs: float) -> int:
        """L in samples at rate ``fs`` (Hz): ``irf_lags`` if given, else round(irf_length * fs)."""
        if self.irf_lags is not None:
            return int(self.irf_lags)
        return max(1, int(round(self.irf_length * fs)))

    def set_params(self, **params) -> "LPVPCEstimator":
        """Change settings (names as in ``__init__``); returns self. Unknown names raise
        ValueError naming them; the fitted model, if any, is kept until the next fit."""
        unknown = sorted(set(params) - set(self.get_params()))
        if unknown:
            raise ValueError(f"unknown estimator setting(s) {unknown}; valid: {sorted(self.get_params())}")
        for k, v in params.items():
            setattr(self, k, v)
        self._given = getattr(self, "_given", set()) | set(params)
        return self

    def predict(self, data):
        """Predicted torque (N m) of the fitted model for a data object (or any object with
        ``position`` and ``scheduling`` in rad and ``fs`` in Hz)."""
        return self._fitted().predict(data).total

    def score(self, data) -> float:
        """VAF (%) of the fitted model's prediction of ``data.torque`` (N m)."""
        from .model import vaf

        return vaf(np.asarray(data.torque, dtype=float), self.predict(data))

    def _fitted(self):
        if not hasattr(self, "model_"):
            raise IdentificationError("this LPVPCEstimator is not fitted yet: call fit(data) first")
        return self.model_

    # ------------------------------------------------------------------------------------
    def fit(self, data) -> "LPVPCEstimator":
        """Identify the model from :class:`lpvpc.data.PerturbationData` (or any object with
        ``position``, ``torque``, ``scheduling`` arrays and ``fs``), or from a list of them:
        several trials fitted jointly (:func:`lpvpc.data.join_trials`).

        With ``high_rate_reflex``, data that keep their file's higher rate (``high_rate``) get
        the reflex nonlinearity identified on the high-rate velocity; when that fit is not determined (too few
        stretch velocities for its basis: InsufficientExcitationError) it is identified on
        the model-rate velocity instead, with an :class:`~lpvpc.errors.LpvpcWarning`."""
        from .linalg import one_blas_thread

        with one_blas_thread(), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            self._fit_any(data)
        _physiology_of_final(self.model_, caught)
        return self

    def _fit_any(self, data) -> None:
        """fit's work (its warnings are sorted by :func:`_physiology_of_final`)."""
        if True:  # (the body of fit, unchanged)
            if isinstance(data, (list, tuple)):
                from .data import join_trials

                data = join_trials(data)
            self.check_settings()
            if self.structure == "cv":
                self._fit_selected(data)
            else:
                try:
                    self._fit(data)
                except InsufficientExcitationError as exc:
                    if getattr(data, "high_rate", None) is None or self.effects or not self.high_rate_reflex:
                        raise
                    from dataclasses import replace

                    from .errors import LpvpcWarning

                    warnings.warn(f"the reflex nonlinearity could not be identified on the {data.high_rate.fs:g} Hz "
                                  f"velocity ({exc}); identified on the {data.fs:g} Hz velocity instead (its threshold "
                                  f"is biased)", LpvpcWarning, stacklevel=2)
                    self._fit(replace(data, high_rate=None))
            self._record_channel_skew(data)

    def _record_channel_skew(self, data) -> None:
        """The channel skew the fitted model sees in its data (lpvpc.skew_scan.scan_channel_skew,
        about one least-squares solve), in ``model.fit["channel_skew"]``, with a warning naming
        the fix when lining the channels up would remove at least MIN_RESIDUAL_REDUCTION of the
        residual variance. Not for the fits inside identify, nor for data already aligned."""
        meta = getattr(data, "meta", {}) or {}
        if getattr(self, "_reuse", {}).get("bare") or not getattr(self, "_scan_skew", True) \
                or "channel_skew_s" in meta or "position_delay_s" in meta or not hasattr(data, "meta"):
            return
        # Only where the scan's regressor is the model's own: a moving record without effects.
        # On stationary virtual trials and on models with an effect the scan took the misfit for
        # a skew (2.6-6.9 % of the residual removed by -1.4..+0.6 ms, where there is none).
        if self.model_.effects or float(np.ptp(np.asarray(data.scheduling, dtype=float))) < self.stationary_range:
            return
        from .errors import LpvpcWarning
        from .skew_scan import scan_channel_skew

        found = scan_channel_skew(self.model_, data)
        self.model_.fit["channel_skew"] = found.to_dict()
        if found.chosen:
            warnings.warn(f"the torque channel lags the position channel by about {found.chosen * 1e3:.2f} ms (a "
                          f"recording artefact: lining them up removes {100 * found.residual_reduction:.1f} % of the "
                          f"residual variance); load the files with channel_skew={found.chosen:.5f} "
                          f"(lpvpc.channel_skew.load_aligned; the CLI's identify does it by default) and identify again",
                          LpvpcWarning, stacklevel=3)

    def check_settings(self) -> None:
        """ValueError naming the first bad setting, before any data are read (fit calls it;
        the CLI calls it before loading files, to answer in one line).

        >>> LPVPCEstimator(intrinsic_order=-1).check_settings()
        Traceback (most recent call last):
        ...
        ValueError: intrinsic_order must be an integer in 0..12, got -1
        """
        if self.structure not in ("fixed", "cv"):
            raise ValueError(f"structure must be 'fixed' or 'cv', got {self.structure!r}")
        for name in ("intrinsic_order", "reflex_order", "velocity_order"):
            _check_basis_order(name, getattr(self, name))
        _check_reflex_path_settings(self)
        self._allowed_effects()  # a bad allow_effects is an error whatever the structure

    def _selection_unavailable(self, data) -> str | None:
        """Why the structure cannot be selected on these data (None: it can)."""
        rho = np.asarray(data.scheduling, dtype=float)
        if rho.size == 0 or not np.all(np.isfinite(rho)) or float(np.ptp(rho)) < self.stationary_range:
            return "stationary trial (its delay is chosen by BIC: stationary_delays)"
        if len(rho) < MIN_SELECTION_S * float(data.fs):
            return (f"record of {len(rho) / float(data.fs):.0f} s, shorter than {MIN_SELECTION_S:.0f} s: too short for "
                    f"the cross-validation to choose reliably")
        if self.effects:
            return EXTENDED_GIVEN
        if self.basis not in ("chebyshev", "legendre") or self.velocity_basis not in ("chebyshev", "legendre"):
            return "non-polynomial basis (the candidates' columns do not nest)"
        if self.high_rate_reflex and getattr(data, "high_rate", None) is not None:
            return HIGH_RATE_GIVEN
        return None

    def _fit_selected(self, data) -> "LPVPCEstimator":
        """structure="cv": a fit at the given settings gives the reflex dynamics; the
        structure is chosen by cross-validation with them held (lpvpc.selection); the
        chosen structure is fitted (its state order the first fit's)."""
        from .selection import (REFLEX_PATH_SETTINGS, SEARCH, StructureSearch, compare_state_orders, design_columns,
                                search_space)

        t0 = time.perf_counter()
        given = self._given_settings()
        unknown = sorted(set(given) - set(SEARCH) - {"irf_lags", "state_order"} - set(REFLEX_PATH_SETTINGS))
        if unknown:
            raise ValueError(f"structure_fixed names settings that are not selected: {unknown}; selected: "
                             f"{sorted(SEARCH)} (and irf_lags, state_order, {', '.join(REFLEX_PATH_SETTINGS)})")
        fixed = {"irf_length" if k == "irf_lags" else k for k in given}
        base = {**self.get_params(), "structure": "fixed", "structure_fixed": tuple(sorted(fixed))}
        reason = self._selection_unavailable(data)
        offered = self._offered_effects(data)
        if reason is not None:
            self._fit_unselected(data, base, reason)
            if reason == HIGH_RATE_GIVEN and self.model_.uncertainty:  # nothing selected, but the intervals
                # still include the structures CV cannot tell apart and the model-rate reflex path
                # (benchmarks/results/uncertainty.txt: viscosity covered 87.8 % without them)
                from .structural_uncertainty import add_structural_uncertainty

                add_structural_uncertainty(self.model_, data)
            if offered and reason.startswith("stationary") and not self.effects:  # (forced effects: as given)
                self._choose_stationary_effects(data, base, offered)
            if reason == EXTENDED_GIVEN and tuple(self.effects) == ("stress_relaxation",) \
                    and self.relaxation_times is None and self.relaxation_order is None:
                self._choose_forced_relaxation_term(data, base)
            return self
        first = LPVPCEstimator(**base)
        first._reuse = {"bare": True}  # no intervals, causal form or scores: computed once, for the model kept
        with warnings.catch_warnings():  # the model kept gives its own warnings
            warnings.simplefilter("ignore")
            first._fit(data)
        m = first.model_
        fs = m.fs
        start = {"irf_length": m.settings["irf_lags"] / fs, "intrinsic_order": self.intrinsic_order,
                 "reflex_order": self.reflex_order, "velocity_order": self.velocity_order,
                 "reflex_delay": m.delay / fs, "elastic_curvature": bool(self.elastic_curvature),
                 "scheduling_extrapolation": self.scheduling_extrapolation}
        p, y, rho = (np.asarray(x, dtype=float) for x in (data.position, data.torque, data.scheduling))
        search = search_space(start, fixed)
        n_cols = design_columns(search, fs)
        if 8.0 * len(y) * n_cols > DESIGN_BUDGET_BYTES:
            return self._fit_unselected(data, base, f"the selection's design ({len(y)} x {n_cols}) would exceed "
                                                    f"{DESIGN_BUDGET_BYTES / 1e6:.0f} MB")
        if int(round(start["irf_length"] * fs)) > int(round(start["reflex_delay"] * fs)):
            return self._fit_unselected(data, base, "IRF half-width longer than the reflex delay")
        t = time.perf_counter()
        try:
            structures = StructureSearch(p, y, rho, fs, (m.A, m.C[None, :], np.append(m.B, m.D)), self.basis,
                                         self.velocity_basis, search, Segments.of(data, len(y)))
            sel = structures.run(start, fixed)
        except np.linalg.LinAlgError as exc:  # e.g. a fold's normal equations singular on a very short record
            return self._fit_unselected(data, base, f"cross-validation failed: {exc}")
        # The state order: BIC's at the starting structure, against one lower and one higher
        # (those the first fit tried) scored by CV at the chosen structure, unless it is given.
        order, bic_order, order_cv = m.fit["state_order"], m.fit["state_order"], {}
        chosen_score = next(sc for sc in sel.scored if sc.settings == sel.chosen)
        if self.state_order is None and "state_order" not in fixed:
            neighbours = {k: v for k, v in first._order_dynamics.items() if abs(k - bic_order) <= 1}
            order, order_cv = compare_state_orders(p, y, rho, fs, sel.chosen, neighbours, bic_order, chosen_score,
                                                   self.basis, self.velocity_basis, Segments.of(data, len(y)))
        path = self._select_reflex_path(data, first, sel.chosen, order, bic_order, chosen_score, fixed)
        effects_cv, effect_poles, effect_structures = None, None, None
        if offered:
            # Cheap first look (the first fit's dynamics, same folds): an effect that does not lower
            # the CV error by FIRST_LOOK_GAIN even there is not given the extra fit (its cost was
            # 2.2x the rest of the selection on a clean 2-minute record). Those dynamics took part of
            # the relaxation, so they understate its gain; the extra fit then decides.
            look, look_terms = _effect_gains(p, y, rho, fs, (m.A, m.C[None, :], np.append(m.B, m.D)), self.basis,
                                             self.velocity_basis, Segments.of(data, len(y)), sel.chosen, offered)
            worth = tuple(n for n in offered if look[n] >= FIRST_LOOK_GAIN)
            if worth:
                fit_settings = {**base, **sel.chosen, "irf_lags": None, "state_order": order}
                effects_cv, effect_poles, effect_structures = self._choose_effects(data, fit_settings, sel.chosen,
                                                                                   worth, look_terms)
            if effects_cv is None:
                effects_cv = {"allowed": sorted(offered), "chosen": [], "cv": {},
                              "first_look_gain": {n: float(g) for n, g in look.items()},
                              "rule": f"not tried further: less than {100 * FIRST_LOOK_GAIN:g} % less CV squared "
                                      f"error with the first fit's reflex dynamics"}
            else:
                effects_cv["first_look_gain"] = {n: float(g) for n, g in look.items()}
        t_select = time.perf_counter() - t
        # The chosen structure is fitted at that order, its poles refined from the first fit's
        # subspace step (the poles do not depend on the structure's columns; MOESP is a quarter
        # of a fit). The starting structure chosen: the same fit, with intervals.
        if path is not None and path.chosen["high_rate_reflex"] and effects_cv and effects_cv["chosen"]:
            # an extended model's reflex nonlinearity is fitted at the model rate (_high_rate_input)
            path.chosen = {"high_rate_reflex": False}
            path.fallback = (f"an extended model ({', '.join(effects_cv['chosen'])}) keeps the model-rate "
                             "velocity")
        chosen = {**sel.chosen, "irf_lags": None, "state_order": order, **(path.chosen if path else {})}
        if effects_cv and effects_cv["chosen"]:
            chosen["effects"] = tuple(effects_cv["chosen"])
            chosen.update(effects_cv["settings"])  # e.g. the relaxation's times and order
            if self.state_order is None and "state_order" not in fixed:  # BIC again, with the effects' columns:
                # the order chosen without them can hold a slow pole that took the relaxation (virtual
                # subject seed 1, 100 Hz: order 3, K +19 %; BIC with them: order 2, K within 3 %)
                chosen["state_order"] = None
        est = LPVPCEstimator(**{**base, **chosen})
        est._reuse = {"subspace": first.subspace_}
        if effect_poles is not None and "effects" in chosen:  # the effects' own subspace step
            # (the first fit's poles take part of a relaxation), unless their terms changed since
            A_e = effect_poles[0]
            est._reuse = ({"subspace": effect_poles[1], "poles": {A_e.shape[0]: A_e}}
                          if effects_cv["settings"] == effect_poles[2] else {})
        elif sel.chosen != {k: start[k] for k in sel.chosen} or order != bic_order:  # another structure: its
            # refinement starts at the first fit's poles of that order (fewer steps than from MOESP's)
            est._reuse["poles"] = {order: first._order_dynamics[order][0]}
        if path is not None and path.chosen["high_rate_reflex"]:
            est = self._fit_high_rate_chosen(data, est, path, first, order)
        else:  # effects chosen: joined in the subspace step, as in the fit whose dynamics the CV held
            # (fitted both ways, the fit after the reflex was kept on seed 10 of the virtual subject
            # that relaxes, 100 Hz: in-sample VAF alike, its reflex had taken the relaxing torque, K -16 %)
            est._fit(data, late=False if "effects" in chosen else None)
        est.model_.settings["state_order"] = self.state_order  # chosen (BIC, then CV)
        est.model_.fit["singular_values"] = m.fit["singular_values"]
        est.model_.fit["state_order_candidates"] = m.fit["state_order_candidates"]  # BIC at the starting structure
        model = est.model_
        model.settings.update({"structure": "cv", "structure_fixed": sorted(fixed)})
        model.fit["structure_selection"] = {**sel.to_dict(), "seconds": t_select,
                                            "state_order": {"bic": int(bic_order), "chosen": int(order),
                                                            "cv_vaf": {str(k): v for k, v in order_cv.items()}},
                                            **({"reflex_path": path.to_dict()} if path is not None else {}),
                                            "state_order_from": "BIC at the starting structure" if not order_cv else
                                            "BIC at the starting structure, against one lower and one higher by CV "
                                            "at the chosen structure (one-standard-error rule toward BIC's)"}
        if model.uncertainty:  # the intervals include the spread over the structures CV cannot tell apart
            # (lpvpc.structural_uncertainty): the search continued from the chosen structure, so its
            # neighbours are scored too (cached scores reused), and the near-equivalent ones refitted
            from .structural_uncertainty import add_structural_uncertainty

            add_structural_uncertainty(model, data, structures, structures.run(sel.chosen, fixed),
                                       effect_structures if "effects" in chosen else None)
        if effects_cv:
            model.fit["structure_selection"]["effects"] = effects_cv
            if "effects" in chosen and chosen["state_order"] is None:  # BIC's order again, with the effects
                model.fit["structure_selection"]["state_order"]["with_effects"] = int(model.state_order)
        model.fit["timings_s"]["selection"] = t_select
        model.fit["timings_s"]["total"] = time.perf_counter() - t0
        self.model_, self.subspace_, self.n_features_ = model, est.subspace_, est.n_features_
        return self

    def _choose_effects(self, data, fit_settings, chosen, offered, terms=None, forced=False):
        """The allowed effects on or off at the chosen structure (``chosen``, fitted with
        ``fit_settings``), scored on the same folds (their columns joined to the structure's in
        one design: column subsets), the one-standard-error rule and ``MIN_EFFECT_GAIN``. The
        reflex dynamics held come from a fit of that structure with the effects' columns in
        the subspace step's intrinsic regressor: held from the first fit, a slow reflex pole
        had taken part of the relaxation and the effect looked useless (virtual subject seed 100:
        CV gain +0.19 points, not chosen; +0.95 with these dynamics, chosen). Scored after the
        structure, not inside its search, so a record without the effect gets exactly the model
        it got before effects were allowed. The effects' fit uses ``terms`` (the first look's
        best variants; the catalog's when None); when the best variant under its dynamics is
        another (another relaxation time), the dynamics are refitted with that one, until the
        best was already fitted (at most ``MAX_EFFECT_PASSES`` fits). Returns (record of the
        choice, (the last effects' fit's A, its subspace step, the terms it was fitted with),
        for the structural term: {"gain", "variants"} or None when no effect is chosen), or
        (None, None, None) when a fit fails (the effects' columns not independent here)."""
        from .selection import SEARCH, chosen_effects, effect_key

        t = time.perf_counter()
        p, y, rho = (np.asarray(x, dtype=float) for x in (data.position, data.torque, data.scheduling))
        # the effects' terms of the fit whose dynamics are held: first the first look's best (else the
        # catalog's). The catalog's three times there left the effect off on a record that relaxes
        # (virtual subject seed 18, 100 Hz: first look 9.4 %, then 1.1 % with those dynamics)
        terms, tried = dict(terms or {}), []
        while True:
            fit = LPVPCEstimator(**{**fit_settings, "effects": tuple(offered), **terms})
            if terms and self.state_order is None:  # BIC's order with the chosen terms (_fit_selected)
                fit.state_order = None
            # its own subspace step: started from the first fit's (no effect columns) the pole refinement
            # stayed near poles that take the relaxation (seed 102: CV VAF with the effect 93.80 %, without
            # 95.25; from its own, 97.19 and 96.13)
            fit._reuse = {"bare": True}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fit._fit(data, late=False)
            except (LpvpcError, np.linalg.LinAlgError):
                return None, None, None
            e = fit.model_
            search, off, cands = _effect_search(p, y, rho, e.fs, (e.A, e.C[None, :], np.append(e.B, e.D)),
                                                self.basis, self.velocity_basis, Segments.of(data, len(y)), chosen,
                                                offered, e.intrinsic_basis.order, on_only=forced)
            if not terms:  # the catalog's term: named as the candidate with its columns (the loop compares them)
                terms = _catalog_terms(cands, e.intrinsic_basis)
            # forced: the search starts at the fitted terms and never scores the effects off
            start = {**off, **{effect_key(n): v for n, by in cands.items() for v, c in by.items()
                               if c[3] == terms}} if forced else off
            pick = search.run(start, fixed=set(SEARCH)).chosen
            sse_on, sse_off = (float(search.score(x).fold_sse.sum()) for x in (pick, off))
            if not forced and sse_on > (1.0 - MIN_EFFECT_GAIN) * sse_off:  # a consistent but negligible gain
                pick = off
            tried.append(terms)
            # The best term under these dynamics (the chosen one, else the best-scoring), if not
            # the fitted one (another relaxation time), is scored again under dynamics fitted with
            # it: the held dynamics had taken part of the other term's misfit (relaxing virtual
            # subject, 100 Hz, seed 5: the first look's 3 s, then off; the catalog's term there
            # left seed 18 off)
            best_terms = {}
            for n, by_value in cands.items():
                v = pick[effect_key(n)] or max(by_value, key=lambda u: search.score({**pick, effect_key(n): u}).cv_vaf)
                best_terms.update(by_value[v][3])
            if best_terms in tried or len(tried) == MAX_EFFECT_PASSES:
                break
            terms = best_terms
        entry = _effects_cv(search, pick, cands)
        entry["rule"] += f", and at least {100 * MIN_EFFECT_GAIN:g} % less held-out squared error"
        entry["passes"] = [{k: (list(v) if isinstance(v, tuple) else v) for k, v in x.items()} for x in tried]
        effects = None
        if chosen_effects(pick):  # for the structural term of the intervals
            from .structural_uncertainty import effect_variant_shifts

            effects = {"gain": 1.0 - sse_on / sse_off, "variants": effect_variant_shifts(search, pick, cands)}
        entry["seconds"] = time.perf_counter() - t
        return entry, (e.A, fit.subspace_, terms), effects

    def _allowed_effects(self) -> tuple:
        """``allow_effects`` as a tuple of names, checked (ValueError naming a bad one)."""
        from .selection import cv_effect_problem

        names = (self.allow_effects,) if isinstance(self.allow_effects, str) else tuple(self.allow_effects or ())
        for n in names:
            problem = cv_effect_problem(n)
            if problem:
                raise ValueError(f"allow_effects: {problem}")
        if len(set(names)) != len(names):
            raise ValueError(f"allow_effects lists an effect twice: {list(names)}")
        return names

    def _offered_effects(self, data) -> tuple:
        """The allowed effects the selection offers on these data: those not forced on; none
        for several trials joined (effects are identified from one trial)."""
        names = self._allowed_effects()
        if len(Segments.of(data, len(np.asarray(data.torque)))) > 1:
            return ()
        return tuple(n for n in names if n not in tuple(self.effects or ()))

    def _choose_stationary_effects(self, data, base, offered) -> None:
        """A stationary trial (one position, no level folds): the allowed effects on or off by
        the same cross-validation on contiguous blocks (:meth:`_choose_effects`), at the
        structure BIC chose (delay and IRF half-width, state order); an effect chosen: the
        trial refitted with it at that structure."""
        m = self.model_
        from .selection import fitted_structure  # (here: the CLI's --help imports identify, not scipy)

        chosen = fitted_structure(m, self.scheduling_extrapolation)
        settings = {**base, "reflex_delay": chosen["reflex_delay"], "irf_length": chosen["irf_length"],
                    "stationary_delays": (), "state_order": m.state_order}
        with warnings.catch_warnings():  # (the stationary warning was given by the first fit)
            warnings.simplefilter("ignore", StationaryWarning)
            entry, dyn, _ = self._choose_effects(data, settings, chosen, offered)
            if entry is None:
                return
            if entry["chosen"]:
                est = _inner(LPVPCEstimator(**{**settings, "effects": tuple(entry["chosen"]), **entry["settings"]}))
                if entry["settings"] and self.state_order is None:  # BIC's order with them (_fit_selected)
                    est.state_order = None
                if entry["settings"] == dyn[2]:
                    est._reuse = {"subspace": dyn[1], "poles": {dyn[0].shape[0]: dyn[0]}}
                est.fit(data)
                est.model_.settings["stationary_delays"] = m.settings["stationary_delays"]  # the delay: BIC's
                est.model_.settings["state_order"] = self.state_order  # (chosen by BIC)
                if "stationary_delay_bic" in m.fit:
                    est.model_.fit["stationary_delay_bic"] = m.fit["stationary_delay_bic"]
                est.model_.settings["structure"] = "cv"
                est.model_.fit["structure_selection"] = dict(m.fit["structure_selection"])
                self.model_, self.subspace_, self.n_features_ = est.model_, est.subspace_, est.n_features_
        self.model_.fit["structure_selection"]["effects"] = entry

    def _given_settings(self) -> tuple:
        """Names of the selected settings the caller set: structure_fixed, or those named in the call."""
        if self.structure_fixed is not None:
            return tuple(self.structure_fixed)
        from .selection import REFLEX_PATH_SETTINGS, SEARCH

        return tuple(k for k in (*SEARCH, "irf_lags", "state_order", *REFLEX_PATH_SETTINGS)
                     if k in getattr(self, "_given", ()))

    def _select_reflex_path(self, data, first, chosen, order, bic_order, chosen_score, fixed):
        """structure="cv" on data that keep their file's higher rate: model-rate or high-rate reflex
        nonlinearity (and the high-rate velocity basis) by the same folds and rule
        (:func:`lpvpc.selection.compare_reflex_paths`); None when it is not a candidate (no
        high-rate signals, or ``high_rate_reflex`` given by the caller)."""
        from .selection import HIGH_RATE_BASES, SEARCH, StructureSearch, compare_reflex_paths

        high = getattr(data, "high_rate", None)
        if high is None or "high_rate_reflex" in fixed:
            return None
        p, y, rho = (np.asarray(x, dtype=float) for x in (data.position, data.torque, data.scheduling))
        seg = Segments.of(data, len(y))
        dynamics = first._order_dynamics[order]
        if order != bic_order:  # the model-rate score under the chosen order's dynamics
            chosen_score = StructureSearch(p, y, rho, data.fs, dynamics, self.basis, self.velocity_basis,
                                           {k: (chosen[k],) for k in SEARCH}, seg).score(chosen)
        candidates = HIGH_RATE_BASES
        if {"high_rate_velocity_basis", "high_rate_velocity_order"} & set(fixed):  # the caller's basis only
            candidates = ((self.high_rate_velocity_basis, int(self.high_rate_velocity_order)),)
        try:
            return compare_reflex_paths(p, y, rho, data.fs, chosen, dynamics, chosen_score, high, candidates,
                                        self.basis, seg)
        except np.linalg.LinAlgError:  # a high-rate design singular (a very short record): the model rate
            return None

    def _fit_high_rate_chosen(self, data, est, path, first, order):
        """The chosen structure on the high-rate path, its pole refinement from the first fit's
        poles of that order (the reflex dynamics the comparison held). The first fit's subspace
        step is reused: with the order given and a start, only its record (singular values)
        is read, not its poles. Not determined (InsufficientExcitationError): the model-rate
        fit, the reason recorded."""
        reuse = {"subspace": first.subspace_, "poles": {order: first._order_dynamics[order][0]}}
        est._reuse = dict(reuse)
        try:
            est._fit(data)
        except InsufficientExcitationError as exc:
            fallback = LPVPCEstimator(**{**est.get_params(), "high_rate_reflex": False})
            fallback._reuse = dict(reuse)
            fallback._fit(data)
            path.chosen = {"high_rate_reflex": False}
            path.fallback = f"the high-rate fit was not determined ({exc}): model-rate velocity"
            return fallback
        return est

    def _choose_forced_relaxation_term(self, data, base) -> None:
        """Stress relaxation forced (``effects=("stress_relaxation",)``, its term not given),
        the structure as given: its term (lpvpc.selection.RELAXATION_VARIANTS) chosen as when
        the selection switches the effect on (:meth:`_choose_effects`, the effect held on),
        the model refitted with it (as forced: both ways), its intervals counting the terms the
        data could not exclude. Why: with the catalog's three times a relaxing virtual subject's
        K was 8.5 % off (median) and its interval covered it at 30.6 %
        (benchmarks/results/relaxed_stiffness.txt)."""
        m = self.model_
        if not {self.basis, self.velocity_basis} <= {"chebyshev", "legendre"}:
            return  # (the candidates' columns nest only in polynomial bases)
        from .selection import fitted_structure  # (here: the CLI's --help imports identify, not scipy)

        chosen = fitted_structure(m, self.scheduling_extrapolation)
        settings = {**base, "reflex_delay": chosen["reflex_delay"], "irf_length": chosen["irf_length"], "irf_lags": None}
        entry, _, structures = self._choose_effects(data, settings, chosen, tuple(self.effects), forced=True)
        if entry is None or not entry["chosen"]:
            return
        entry["rule"] = ("the effect forced on: its term among the variants by the same cross-validation, "
                         "one-standard-error rule toward fewer parameters")
        if entry["settings"] != _relaxation_term_of(m):
            est = _inner(LPVPCEstimator(**{**base, **entry["settings"]})).fit(data)
            est.model_.settings["structure"] = "cv"
            est.model_.fit["structure_selection"] = dict(m.fit["structure_selection"])
            self.model_, self.subspace_, self.n_features_ = est.model_, est.subspace_, est.n_features_
        self.model_.fit["structure_selection"]["relaxation_term"] = entry
        if self.model_.uncertainty:  # the terms the data could not exclude count in K's interval
            from .structural_uncertainty import add_structural_uncertainty

            # (forced: the structure without the effect is no alternative, as for an effect that won clearly)
            add_structural_uncertainty(self.model_, data, effects={**structures, "gain": 1.0})

    def _fit_unselected(self, data, base, reason) -> "LPVPCEstimator":
        """structure="cv" where the structure cannot be selected: the settings as given, the reason recorded."""
        est = _inner(LPVPCEstimator(**base)).fit(data)
        est.model_.settings["structure"] = "cv"
        est.model_.fit["structure_selection"] = {"skipped": reason}
        self.model_, self.subspace_, self.n_features_ = est.model_, est.subspace_, est.n_features_
        return self

    def _fit_both_ways(self, data) -> "LPVPCEstimator":
        """Effects that may be fitted ``after_reflex`` (lpvpc.effects.Effect): the fit with
        them in the subspace step's intrinsic regressor and the fit with them joining only
        the final solve, the identified reflex held; the better in-sample fit is kept (same
        parameter count). Why both: on the virtual subject with stress relaxation the first
        predicts better (novel VAF 97.7-97.9 against 97.1-97.6 %); on the lab's stationary
        trial z_pf the slow columns took the reflex's slow response there (fit VAF 86.2 %
        against 87.0 %)."""
        def fit(late):  # its warnings, told only for the fit kept (each fit warns alike, in other numbers)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self._fit(data, late=late)
            return caught

        told_early = fit(False)
        early = (self.model_, self.subspace_, self.n_features_)
        told = fit(True)
        total = early[0].fit["timings_s"]["total"] + self.model_.fit["timings_s"]["total"]
        if early[0].fit["vaf"] > self.model_.fit["vaf"]:
            self.model_, self.subspace_, self.n_features_ = early
            told = told_early
        for w in told:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        self.model_.fit["effects_after_reflex"] = self.model_ is not early[0]
        self.model_.fit["timings_s"]["total"] = total  # both fits
        return self

    def _fit(self, data, late=None) -> "LPVPCEstimator":
        from .effects import CATALOG
        from .model import LPVPCModel, vaf
        from .reflex import reflex_input_regressor
        from .subspace import STABLE_POLE_RADIUS, PoleRefinement, candidate_orders, po_moesp

        t0 = time.perf_counter()
        timings = {}
        if self._searches_delay(data):  # (fit joined a list of trials)
            return self._fit_stationary_delays(data)
        if late is None and any(CATALOG[n].after_reflex for n in self.effects if n in CATALOG):
            return self._fit_both_ways(data)
        p, y, rho, fs = self._checked(data)
        seg = Segments.of(data, len(y))  # several trials: nothing crosses a seam (lpvpc.segments)
        delay = int(round(self.reflex_delay * fs))
        if delay < 1:
            raise DataError(f"reflex delay {self.reflex_delay} s is less than one sample at {fs} Hz")
        L = self.resolved_lags(fs)
        lags = two_sided_lags(L)
        dvel = seg.map(eq.delayed_velocity, p, fs=fs, delay=delay)

        rho_orders = self._scheduling_orders(rho, declared=bool((getattr(data, "meta", None) or {}).get("stationary")))
        G_i = basis_from_data(rho, self.basis, rho_orders["intrinsic_order"], self.scheduling_extrapolation)
        G_r = basis_from_data(rho, self.basis, rho_orders["reflex_order"], self.scheduling_extrapolation)
        V_b = basis_from_data(dvel, self.velocity_basis, self.velocity_order, extrapolation="linear")
        Gi_val, Gr_val = G_i.evaluate(rho), G_r.evaluate(rho)
        Psi_irf = seg.map(intrinsic_regressor, p, Gi_val, lags=lags)
        Psi_i = Psi_irf
        if self.elastic_curvature:  # tied to the IRF's stiffness: each lag's column gains 0.5 K' p^2's share
            Psi_i = Psi_irf + np.tile(curvature_regressor(p, Gi_val, G_i), len(lags))
        n_base = Psi_i.shape[1]  # columns beyond belong to effects
        U_r = reflex_input_regressor(V_b.evaluate(dvel), Gr_val)
        high = _high_rate_input(self, data, G_r)  # None unless the file's rate exceeds the model's
        if high is not None:  # the rectifier acts on the high-rate velocity (lpvpc.reflex.high_rate_input)
            U_r_model, U_r = U_r, high.U_r
        design = None
        if self.effects and len(seg) > 1:
            raise DataError(f"effects are identified from one trial; got {len(seg)} trials")
        if self.effects:  # extended model: the effects' columns join the intrinsic regressor
            from .effects import RELAXATION_TIMES, EffectDesign, default_signals, signals_from_data

            # the data's extra signals only when an effect reads them (the EMG's background
            # activation costs as much as a fit; stress relaxation reads the position alone)
            reads = {s for n in self.effects for s in CATALOG[n].signals + CATALOG[n].optional_signals}
            design = EffectDesign(self.effects, p, rho, fs, lags, G_i,
                                  signals_from_data(data) if reads else default_signals(rho, fs),
                                  source=getattr(data, "source", "") or "data", late=bool(late),
                                  relaxation=(tuple(self.relaxation_times or RELAXATION_TIMES),
                                              self.relaxation_order))
            Psi_i = np.hstack([Psi_i, design.columns])
        self._check_counts(len(y), Psi_i.shape[1], U_r.shape[1])
        # Fail before the expensive subspace step. The pivoted QR runs on the regressors'
        # triangular factors (the same column norms, pivots and rank as the N-row matrices,
        # at 4x less cost: blocked QR, then pivoting on n x n).
        from .linalg import check_full_rank, triangular_factor

        check_full_rank(triangular_factor(Psi_i), "intrinsic")
        check_full_rank(triangular_factor(U_r), "reflex input")
        timings["regressors"] = time.perf_counter() - t0

        t = time.perf_counter()
        reuse = getattr(self, "_reuse", {})  # structure selection's refit: the first fit's subspace step
        sub = reuse["subspace"] if "subspace" in reuse else po_moesp(U_r, Psi_i, y, self.horizon, segments=seg)
        timings["moesp"] = time.perf_counter() - t

        t = time.perf_counter()
        if self.state_order is not None:
            orders = [int(self.state_order)]
        else:
            # The gaps alone are not enough: a well-damped reflex pole pair often shows as one
            # gap at order 1. Orders 2 and 3 are therefore always tried; BIC of the complete
            # fit decides (which needs each order's Hammerstein fit at its best minimum:
            # lpvpc.reflex.fit_hammerstein).
            orders = sorted(set(candidate_orders(sub.singular_values, self.max_state_order)) | {2, 3})
            orders = [m for m in orders if self.min_state_order <= m <= self.max_state_order]
        orientation = np.sign(dvel) @ U_r  # makes Omega's output grow with stretch velocity
        max_radius = (np.exp(-1.0 / (self.max_reflex_time_constant * fs)) if self.max_reflex_time_constant
                      else STABLE_POLE_RADIUS)
        refinement = PoleRefinement(U_r, Psi_i, y, segments=seg, max_radius=max_radius) if self.refine else None
        fits, failed = {}, {}
        for m in orders:
            try:
                fits[m] = self._fit_given_order(sub, m, refinement, U_r, Psi_i, y, orientation, seg,
                                                start=reuse.get("poles", {}).get(m), joint=high is not None)
            except InsufficientExcitationError as err:  # a candidate order the data cannot support
                failed[m] = err
        if not fits:  # every order failed: report the first
            raise failed[orders[0]]
        n = len(y)
        # An unstable reflex (MOESP can return a pole on or outside the unit circle, which the
        # pole refinement cannot leave: it refuses unstable points) fits the identification
        # record yet diverges on any later one (a lab trial: held-out VAF -1e6 %), and the
        # model file refuses it: such orders compete only when no order is stable.
        stable = {m for m, f in fits.items() if np.max(np.abs(np.linalg.eigvals(f["A"]))) < 1.0}
        bic = {m: n * np.log(f["rss"] / n) + f["n_params"] * np.log(n) for m, f in fits.items()
               if m in stable or not stable}
        m_best = min(bic, key=bic.get)
        best = fits[m_best]
        self._order_dynamics = {m: (f["A"], np.reshape(f["C"], (1, -1)), np.append(f["hammerstein"].b, f["hammerstein"].d))
                                for m, f in fits.items() if m in bic}  # (structure selection compares them)
        del refinement  # its N-row factors (a third of a 30-minute record's peak memory)
        timings["projection_and_reflex"] = time.perf_counter() - t

        H = best["theta_i"][:n_base].reshape(len(lags), G_i.size)
        curvature = curvature_from_irf(H, G_i) if self.elastic_curvature else None
        causal = list(range(0, (self.causal_lags if self.causal_lags is not None else L + 2) + 1))
        bare = bool(reuse.get("bare"))  # structure selection's first fit: only its dynamics and order are used
        if bare:
            H_causal = np.zeros((len(causal) + 2, G_i.size))  # (no causal form)
        else:
            S_c = seg.map(eq.causal_signals, p, fs=fs, lags=causal, stencil=self.causal_derivatives)
            Psi_c = (S_c[:, :, None] * Gi_val[:, None, :]).reshape(len(p), -1)
            # the causal form is fitted to the IRF's torque; the curvature term, static in pos(k), is shared
            H_causal = np.linalg.lstsq(Psi_c, Psi_irf @ best["theta_i"][:n_base],
                                       rcond=None)[0].reshape(S_c.shape[1], G_i.size)
            del Psi_c, S_c

        hf = best["hammerstein"]
        Omega = hf.omega.reshape(-1, G_r.size)
        high_nl = None
        if high is not None:
            from .model import HighRateNonlinearity

            high_nl = HighRateNonlinearity(fs=high.fs, delay=high.delay, velocity_basis=high.velocity_basis, Omega=Omega)
            Omega = _model_rate_stand_in(U_r_model, U_r, best, seg, G_r.size)
        model = LPVPCModel(
            fs=fs, lags=lags, H=H, intrinsic_basis=G_i, causal_lags=causal, H_causal=H_causal, delay=delay,
            velocity_basis=V_b, reflex_rho_basis=G_r, Omega=Omega, high_rate=high_nl,
            A=best["A"], B=hf.b, C=best["C"].ravel(), D=hf.d, causal_derivatives=self.causal_derivatives,
            curvature=curvature,
            settings={**self.get_params(), "irf_lags": L, **rho_orders,  # as used at this rate and range
                      "stationary_delays": [float(c) for c in self.stationary_delays],  # JSON: lists
                      "structure_fixed": list(self.structure_fixed or ()),
                      "allow_effects": ([self.allow_effects] if isinstance(self.allow_effects, str)
                                        else list(self.allow_effects or ()))},
            provenance=_provenance(data),
            conventions=_conventions(data),
        )
        sig = {}
        if design is not None:
            from .effects import finish_extended_fit

            finish_extended_fit(design, model, best["theta_i"][n_base:], Psi_i[:, :n_base], y, Psi_irf=Psi_irf)
            sig = {"signals": design.signals}
        def predicted(causal):  # trial by trial
            if high is not None:  # the high-rate path, as identified
                return model.predict(data, causal=causal, warn=False).total
            return seg.map(lambda pp, rr: model.predict(pp, rr, causal=causal, warn=False, **sig).total, p, rho)

        if not bare:  # intervals (lpvpc.uncertainty)
            from .reflex import reflex_regressor
            from .uncertainty import fit_uncertainty

            t = time.perf_counter()
            Psi_u, theta_u, omega_u = Psi_i, best["theta_i"], hf.omega
            if design is not None:  # extended: the effects' columns as the final fit has them, fitted with
                # the base ones (whose block of the full covariance is then marginal); the model-rate
                # nonlinearity as refitted there (lpvpc.effects.finish_extended_fit)
                X_e, theta_e = design.extension
                Psi_u = np.hstack([Psi_i[:, :n_base], X_e])
                theta_u, omega_u = np.concatenate([model.H.ravel(), theta_e]), model.Omega.ravel()
            # the model's reflex dynamics: the base fit's, or as an effect refitted them
            A_u, C_u = model.A, np.reshape(model.C, (1, -1))
            try:
                model.uncertainty = fit_uncertainty(
                    model, Psi_u, reflex_regressor(U_r, A_u, C_u, seg), y, np.append(model.B, model.D),
                    omega_u, theta_u, U_r, A_u, truncated_irf(p, Gi_val, L, seg), segments=seg,
                    richer=richer_basis_irf(p, rho, G_i, lags, seg),
                    curvature_torque=(None if model.curvature is None
                                      else eq.elastic_curvature_torque(p, Gi_val, model.curvature)),
                    # the elastic torque's second-order term, free (not tied to the IRF's K')
                    free_curvature=(p ** 2)[:, None] * Gi_val, n_base=n_base)
            except np.linalg.LinAlgError as exc:  # the model stands; only its intervals are missing
                from .errors import LpvpcWarning

                warnings.warn(f"no confidence intervals for this model: {exc}", LpvpcWarning, stacklevel=3)
            timings["uncertainty"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - t0
        model.fit = {
            "vaf": float("nan") if bare else vaf(y, predicted(False)),
            "vaf_causal": float("nan") if bare else vaf(y, predicted(True)),
            "n_samples": int(n),
            "n_trials": len(seg),
            # the top of the rectifier fit (model.reflex_gain_threshold). High rate: the top of the
            # basis's range (99.5th percentile of the 1 kHz velocities); a percentile of the positive
            # ones is fragile there (~90 % of the samples are holds whose 1e-7 rad/s velocities, or a
            # file's rounding, fall on either side of zero: 2.6 or 4.5 rad/s for one recording), and
            # beyond the range the curve is only the basis's linear continuation.
            "velocity_p99": _velocity_p99(dvel, V_b) if high is None else high.velocity_basis.hi,
            "data_density": {} if bare else data_density(rho, dvel, G_i, V_b) if high is None else
            data_density(high.rho, high.dvel, G_i, high.velocity_basis),
            "state_order": int(m_best),
            "state_order_candidates": {str(m): float(b) for m, b in bic.items()},
            "state_orders_failed": {str(m): str(err) for m, err in failed.items()},
            "singular_values": sub.singular_values.tolist(),
            "moesp_poles": [[float(z.real), float(z.imag)] for z in best["moesp_poles"]],
            # the model's own: the reflex dynamics effect refits them (lpvpc.effects.finish_extended_fit)
            "poles": [[float(z.real), float(z.imag)] for z in np.linalg.eigvals(model.A)],
            "stationary": bool(np.ptp(rho) < self.stationary_range),
            "hammerstein_iterations": int(hf.iterations),
            "hammerstein_converged": bool(hf.converged),
            "timings_s": timings,
        }
        if design is not None and any(fe.name == "stress_relaxation" for fe in model.effects):
            from .effects import relaxation_stiffness_entry

            model.fit["stiffness"] = relaxation_stiffness_entry(model)  # short-range and relaxed, labelled
        if not bare:
            check_physiology(model)
        self.model_ = model
        self.subspace_ = sub
        self.n_features_ = Psi_i.shape[1] + U_r.shape[1]
        return self

    # ------------------------------------------------------------------------------------
    def _searches_delay(self, data) -> bool:
        """True for a stationary trial whose reflex delay and IRF length are left to the
        data (``stationary_delays``; with or without effects, which each candidate keeps)."""
        rho = np.asarray(data.scheduling, dtype=float)
        return (bool(self.stationary_delays) and self.irf_lags is None
                and self.reflex_delay == DEFAULT_REFLEX_DELAY and self.irf_length == DEFAULT_IRF_LENGTH
                and rho.size > 0 and np.all(np.isfinite(rho)) and float(np.ptp(rho)) < self.stationary_range)

    def _fit_stationary_delays(self, data) -> "LPVPCEstimator":
        """A stationary trial: the complete fit at each delay of ``stationary_delays`` (IRF
        half-width = delay), the one of least BIC kept. Why: on the lab's stationary trials
        the fixed 40 ms left the intrinsic IRF too short and the reflex onset too early
        (benchmarks/bench_real_stationary.py); the choice uses the identification data only."""
        fs = float(data.fs)
        delays = {}  # samples -> s: candidates that round to the same sample count are one
        for c in self.stationary_delays:
            delays.setdefault(max(1, int(round(float(c) * fs))), float(c))
        fits, failed = {}, {}
        for c in delays.values():
            est = _inner(LPVPCEstimator(**{**self.get_params(), "reflex_delay": c, "irf_length": c,
                                           "stationary_delays": ()}))
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    est.fit(data)
                except (LpvpcError, np.linalg.LinAlgError) as e:  # that candidate is out; the others stand
                    failed[c] = e
                    continue
            fits[c] = (min(est.model_.fit["state_order_candidates"].values()), est, caught)
        if not fits:  # no delay works: the error at the candidate nearest the moving trials' 40 ms
            raise failed[min(failed, key=lambda c: abs(c - DEFAULT_REFLEX_DELAY))]
        best = min(fits, key=lambda c: fits[c][0])
        _, est, caught = fits[best]
        chosen = (f"; reflex delay and IRF half-width {1e3 * best:g} ms, chosen by BIC among "
                  f"{', '.join(f'{1e3 * c:g}' for c in delays.values())} ms")
        for w in caught:  # the chosen fit's warnings, once
            text = str(w.message) + (chosen if issubclass(w.category, StationaryWarning) else "")
            warnings.warn(text, w.category, stacklevel=3)
        model = est.model_
        model.settings["stationary_delays"] = [float(c) for c in self.stationary_delays]
        model.fit["stationary_delay_bic"] = {f"{c:g}": float(b) for c, (b, _, _) in fits.items()}
        if failed:
            model.fit["stationary_delay_failed"] = {f"{c:g}": f"{type(e).__name__}: {e}" for c, e in failed.items()}
        model.fit["timings_s"]["total"] = float(sum(f[1].model_.fit["timings_s"]["total"] for f in fits.values()))
        self.model_, self.subspace_, self.n_features_ = model, est.subspace_, est.n_features_
        return self

    def _fit_given_order(self, sub, m, refinement, U_r, Psi_i, y, orientation, segments=None, start=None,
                         joint=False):
        from .linalg import project_out_and_solve, triangular_factor
        from .reflex import fit_hammerstein, refit_jointly, reflex_regressor

        A, C = sub.system(m)
        moesp_poles = np.linalg.eigvals(A)
        if refinement is not None:  # from ``start`` (A of the fit at a neighbouring structure) when given
            A, C, _ = refinement.refine(A if start is None else start)
        blocks = reflex_regressor(U_r, A, C, segments)
        # Every fit below is a least-squares problem in the columns of [Psi_r, Psi_i, y]:
        # solved on their triangular factor, at ~100 rows instead of N, with the same
        # solutions and residual norms.
        k_r = sum(blk.shape[1] for blk in blocks)
        R = triangular_factor(blocks + [Psi_i, y])  # (stacked a block of rows at a time)
        blocks_c, Psi_i_c, y_c = np.hsplit(R[:, :k_r], len(blocks)), R[:, k_r:-1], R[:, -1]
        theta_i = project_out_and_solve(R[:, :k_r], Psi_i_c, y_c)
        tq_r = y_c - Psi_i_c @ theta_i
        hf = fit_hammerstein(blocks_c, tq_r, orientation, tol=self.tol, max_iter=self.max_iter)
        # On the high-rate path, then intrinsic and rank-1 reflex together: the projection's
        # unstructured reflex space can take up elastic torque there (lpvpc.reflex.refit_jointly;
        # at the model rate it cost the lab pilot's leave-one-level-out 0.15 points, so not there)
        if joint:
            theta_i, hf = refit_jointly(blocks_c, Psi_i_c, y_c, hf, orientation)
        resid = y_c - Psi_i_c @ theta_i - sum(c * (blk @ hf.omega) for c, blk in zip(np.append(hf.b, hf.d), blocks_c))
        n_params = Psi_i.shape[1] + U_r.shape[1] + m + 1 + 2 * m
        return {"A": A, "C": C, "moesp_poles": moesp_poles, "theta_i": theta_i, "hammerstein": hf, "rss": float(resid @ resid), "n_params": n_params}

    def _scheduling_orders(self, rho, declared: bool = False) -> dict:
        """Basis orders in rho; both 0 (the LTI parallel cascade) when rho spans less than
        ``stationary_range`` rad: a trial at one operating position cannot determine position
        dependence (its bases would be rank-deficient). A StationaryWarning tells it, unless
        the data were ``declared`` stationary (``stationary=True``, ``--stationary``): the
        user said so, and the warning would only repeat it."""
        span = float(np.ptp(rho))
        if span >= self.stationary_range or self.intrinsic_order == self.reflex_order == 0:
            return {"intrinsic_order": self.intrinsic_order, "reflex_order": self.reflex_order}
        if declared:
            return {"intrinsic_order": 0, "reflex_order": 0}
        warnings.warn(
            f"the scheduling variable spans only {span * 1e3:.2f} mrad (< {self.stationary_range * 1e3:g} mrad): "
            f"stationary trial, identified the position-independent (LTI) parallel cascade",
            StationaryWarning, stacklevel=3)
        return {"intrinsic_order": 0, "reflex_order": 0}

    def _checked(self, data):
        p = np.asarray(data.position, dtype=float)
        y = np.asarray(data.torque, dtype=float)
        rho = np.asarray(data.scheduling, dtype=float)
        fs = float(data.fs)
        problems = []
        if not (p.shape == y.shape == rho.shape) or p.ndim != 1:
            problems.append(f"position, torque and scheduling must be 1-D of equal length, got {p.shape}, {y.shape}, {rho.shape}")
        else:
            for name, x in (("position", p), ("torque", y), ("scheduling", rho)):
                bad = ~np.isfinite(x)
                if bad.any():
                    problems.append(f"channel {name}: {int(bad.sum())} non-finite values, first at index {int(np.argmax(bad))}")
        if not np.isfinite(fs) or fs <= 0:
            problems.append(f"sampling rate must be positive, got {fs}")
        if problems:
            raise DataError(problems)
        if np.var(p) < 1e-12:
            raise InsufficientExcitationError("no perturbation: the perturbation position has zero variance")
        if np.var(y) <= 0:
            raise InsufficientExcitationError("no response: the perturbation torque has zero variance")
        return p, y, rho, fs

    def _check_counts(self, n, n_intrinsic, n_reflex):
        s = self.horizon
        need_moesp = s * (n_intrinsic + 2 * n_reflex + 2) + 2 * s - 1
        n_params = n_intrinsic + n_reflex + 2 * self.max_state_order + 1
        need = max(need_moesp, 10 * n_params)
        if n < need:
            raise InsufficientExcitationError(
                f"too few samples for the parameter count: {n} samples for {n_params} parameters "
                f"({n_intrinsic} intrinsic, {n_reflex} reflex nonlinearity); need at least {need} "
                f"(reduce basis orders, IRF lags or MOESP horizon, or record longer)"
            )


def _inner(est):
    """``est`` as a fit inside another (no channel-skew scan: the outer fit scans its own model)."""
    est._scan_skew = False
    return est


def _check_reflex_path_settings(est) -> None:
    """ValueError naming a bad high-rate setting (before any fit)."""
    from .basis import FAMILIES
    from .modelfile import MAX_BASIS_ORDER

    if not isinstance(est.high_rate_reflex, (bool, np.bool_)):
        raise ValueError(f"high_rate_reflex must be True or False, got {est.high_rate_reflex!r}")
    if est.high_rate_velocity_basis not in FAMILIES:
        raise ValueError(f"high_rate_velocity_basis must be one of {FAMILIES}, got {est.high_rate_velocity_basis!r}")
    order = est.high_rate_velocity_order
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 1 <= order <= MAX_BASIS_ORDER:
        raise ValueError(f"high_rate_velocity_order must be an integer in 1..{MAX_BASIS_ORDER}, got {order!r}")
    _check_relaxation_settings(est)


def _check_relaxation_settings(est) -> None:
    """ValueError naming a bad stress-relaxation term (before any fit): the times must be what a
    model file can hold (a saved model is loaded again), the order a basis order."""
    from .modelfile import MAX_RELAXATION_S

    times = est.relaxation_times
    if times is not None:
        try:
            values = [float(t) for t in times]
        except (TypeError, ValueError):
            values = None
        if not values or not all(math.isfinite(t) and 0.0 < t <= MAX_RELAXATION_S for t in values) \
                or len(set(values)) != len(values):
            raise ValueError(f"relaxation_times must be one or more different averaging times in s, each in "
                             f"(0, {MAX_RELAXATION_S:g}], got {times!r}")
    if est.relaxation_order is not None:
        _check_basis_order("relaxation_order", est.relaxation_order)


def _check_basis_order(name, order) -> None:
    """ValueError unless ``order`` is an integer basis order a model file can hold."""
    from .modelfile import MAX_BASIS_ORDER

    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 0 <= order <= MAX_BASIS_ORDER:
        raise ValueError(f"{name} must be an integer in 0..{MAX_BASIS_ORDER}, got {order!r}")


def _high_rate_input(est, data, rho_basis):
    """The reflex regressor from the data's high-rate signals (:class:`lpvpc.data.HighRate`),
    or None when the data have none (100 Hz files, or loaded with ``target_fs=None``)."""
    hr = getattr(data, "high_rate", None)
    if hr is None or est.effects or not est.high_rate_reflex:  # extended models keep the model-rate one
        return None
    from .reflex import high_rate_input

    q = int(round(hr.fs / float(data.fs)))
    return high_rate_input(hr, q, est.reflex_delay, rho_basis, est.high_rate_velocity_basis,
                           est.high_rate_velocity_order)


def _model_rate_stand_in(U_r_model, U_r_high, best, segments, n_r):
    """Omega of the model-rate nonlinearity (exports, predictions from model-rate records):
    least squares of the high-rate path's reflex drive through the identified dynamics, as
    seen from the model-rate velocity basis (the dynamics and rho basis are shared)."""
    from .reflex import reflex_regressor

    hf = best["hammerstein"]
    bd = np.append(hf.b, hf.d)
    blocks_h = reflex_regressor(U_r_high, best["A"], best["C"], segments)
    blocks_m = reflex_regressor(U_r_model, best["A"], best["C"], segments)
    target = sum(c * (blk @ hf.omega) for c, blk in zip(bd, blocks_h))
    X = sum(c * blk for c, blk in zip(bd, blocks_m))
    return np.linalg.lstsq(X, target, rcond=None)[0].reshape(-1, n_r)


def _velocity_p99(dvel, velocity_basis) -> float:
    """99th percentile of the positive delayed velocities (rad/s): the top of the rectifier fit."""
    return float(np.percentile(dvel[dvel > 0], 99)) if np.any(dvel > 0) else velocity_basis.hi


def data_density(rho, dvel, rho_basis, velocity_basis, n_rho: int = 16, n_vel: int = 48) -> dict:
    """Joint histogram of scheduling (rad) and delayed velocity (rad/s) over the identified
    ranges: where the data determine the model (figures draw only there).

    >>> from lpvpc.basis import Basis
    >>> rho, dvel = np.array([-0.3, -0.3, 0.1]), np.array([-0.5, 0.5, -0.5])  # rad, rad/s
    >>> d = data_density(rho, dvel, Basis("chebyshev", 3, -0.4, 0.2), Basis("chebyshev", 3, -1.0, 1.0), 2, 2)
    >>> d["counts"]  # rows: rho in [-0.4, -0.1), [-0.1, 0.2]; columns: dvel below / above 0
    [[1, 1], [1, 0]]
    """
    counts, e_r, e_v = np.histogram2d(rho, dvel, bins=[np.linspace(rho_basis.lo, rho_basis.hi, n_rho + 1),
                                                       np.linspace(velocity_basis.lo, velocity_basis.hi, n_vel + 1)])
    return {"scheduling_edges": e_r.tolist(), "velocity_edges": e_v.tolist(), "counts": counts.astype(int).tolist()}


def truncated_irf(position, rho_basis_values, L, segments=None):
    """(lags, Psi_i) of the IRF one lag shorter on each side (None for L = 0), built trial
    by trial: the structural term of the intrinsic intervals (lpvpc.uncertainty).

    >>> pos = np.linspace(0.0, 0.01, 50)  # rad
    >>> lags, Psi = truncated_irf(pos, np.ones((50, 2)), 3)  # two scheduling functions
    >>> list(lags), Psi.shape  # lags -2..2, one column per lag and function
    ([-2, -1, 0, 1, 2], (50, 10))
    >>> truncated_irf(pos, np.ones((50, 2)), 0) is None
    True
    """
    if L < 1:
        return None
    lags = two_sided_lags(L - 1)
    if segments is None:
        return lags, intrinsic_regressor(position, rho_basis_values, lags)
    return lags, segments.map(intrinsic_regressor, position, rho_basis_values, lags=lags)


def richer_basis_irf(position, rho, rho_basis, lags, segments=None):
    """(basis, Psi_i) of the IRF with the scheduling basis one order higher (same family and
    range), built trial by trial: the second structural term of the intrinsic intervals
    (lpvpc.uncertainty). None for a position-independent fit (order 0) and at the file
    format's largest order.

    >>> from lpvpc.basis import basis_from_data
    >>> rho = np.linspace(-0.4, 0.2, 500)  # rad
    >>> p = np.random.default_rng(0).uniform(-0.04, 0.04, 500)  # rad
    >>> basis, Psi = richer_basis_irf(p, rho, basis_from_data(rho, "chebyshev", 5), [-1, 0, 1])
    >>> basis.order, Psi.shape
    (6, (500, 21))
    """
    from .basis import Basis

    from .modelfile import MAX_BASIS_ORDER

    if not 0 < rho_basis.order < MAX_BASIS_ORDER:  # stationary (LTI) fit, or no room in the file format
        return None
    richer = Basis(rho_basis.family, rho_basis.order + 1, rho_basis.lo, rho_basis.hi, rho_basis.extrapolation)
    G = richer.evaluate(rho)
    if segments is None:
        return richer, intrinsic_regressor(position, G, lags)
    return richer, segments.map(intrinsic_regressor, position, G, lags=lags)


def check_physiology(model, stacklevel: int = 3, sign_seen: bool = False) -> None:
    """PhysiologyWarning when the elastic stiffness K(rho) is negative over most of the
    identified range: joint tissue is never negative-stiff there, and the usual cause is a
    torque sign convention opposite to the position's.

    In a model extended by effects, K(rho) is the stiffness at zero displacement with the
    effects' inputs at zero (trial start, rest, no direction): negative there, the effect
    terms have traded with the linear stiffness (seen on a lab stationary trial: the
    amplitude term p|p|, p^3 left K = -41 N m/rad with a positive slope at the trial's
    displacements), and the warning names them instead of the torque sign.

    ``sign_seen``: the effect-free fit of the same data was negative too (the estimator's
    fit knows it): one line naming the torque sign, in the extended model's numbers.

    Also told, each as one PhysiologyWarning: a negative viscosity B(rho) where K is
    positive; a relaxed stiffness (stress relaxation) above the short-range one or below
    zero; a time base that is probably wrong (:func:`_check_time_base`); a reflex gain whose
    interval lies below zero (:func:`_check_reflex_gain`).

    A torque recorded with the opposite sign gives a negative stiffness, and a warning:

    >>> import warnings
    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> data.torque = -data.torque
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     model = identify(data)
    >>> [type(w.message).__name__ for w in caught]
    ['PhysiologyWarning']
    """
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, 51)
    K = model.elastic_stiffness(rho)
    negative = float(np.mean(K < 0))
    if negative <= 0.5:  # (a reversed torque sign turns the reflex gain too: one warning)
        _check_viscosity(model, rho, stacklevel + 1)
        _check_relaxed_stiffness(model, stacklevel + 1)
        _check_time_base(model, stacklevel + 1)
        _check_reflex_gain(model, stacklevel + 1)
        return
    where = f"negative over {100 * negative:.0f} % of the identified position range (median {np.median(K):.1f} N m/rad)"
    if len(rho) and float(np.ptp(rho)) < 1e-6:  # one operating position: its value, as the summary prints it
        where = f"negative ({K[0]:.1f} N m/rad at {rho[0]:+.3f} rad)"
    sign = float((model.conventions or {}).get("torque_sign", 1.0))
    flip = "-1" if sign > 0 else "1"
    if model.effects and not sign_seen:
        names = ", ".join(fe.name for fe in model.effects)
        warnings.warn(
            f"elastic stiffness K(theta) at zero displacement is {where} in the model extended by {names}: the "
            f"effect terms have traded with the linear stiffness, which is not physical; prefer the model without "
            f"them (if that one is negative too, the torque sign convention is reversed)", PhysiologyWarning,
            stacklevel=stacklevel)
        return
    B = model.viscosity(rho)
    also = " (viscosity too)" if np.mean(B < 0) > 0.5 else ""
    both = " with and without the effects" if model.effects else ""
    warnings.warn(
        f"elastic stiffness K(theta) is {where}{both}{also}: the torque sign convention is probably reversed; "
        f"identify again with --torque-sign {flip} (torque_sign={flip})", PhysiologyWarning, stacklevel=stacklevel)


#: The sign warning's words (what :func:`_physiology_of_final` looks for in a candidate fit's warnings).
SIGN_WORDS = "the torque sign convention is probably reversed"


def _physiology_of_final(model, caught) -> None:
    """Re-emit the warnings ``caught`` during a fit, the physiology ones replaced by those of
    the final ``model``: candidate fits (the effect-free model, other delays) warned in their
    own numbers, which the user never sees printed. A candidate's sign warning is kept as
    knowledge: the extended model negative too then names the torque sign (one line)."""
    physiology = [w for w in caught if issubclass(w.category, PhysiologyWarning)]
    for w in caught:
        if not issubclass(w.category, PhysiologyWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if physiology and model is not None:
        check_physiology(model, stacklevel=4, sign_seen=any(SIGN_WORDS in str(w.message) for w in physiology))


def _check_viscosity(model, rho, stacklevel: int) -> None:
    """PhysiologyWarning when the intrinsic viscosity B(rho) is negative over most of the
    range while K is positive: tissue does not push along with a movement. Its usual cause
    is the reflex pathway and the intrinsic IRF sharing the velocity response (their sum is
    determined, the split is not)."""
    B = model.viscosity(rho)
    share = float(np.mean(B < 0))
    if share <= 0.5:
        return
    at = (f"{B[0]:.2f} N m s/rad at {rho[0]:+.3f} rad" if float(np.ptp(rho)) < 1e-6
          else f"median {np.median(B):.2f} N m s/rad over {100 * share:.0f} % of the range")
    warnings.warn(
        f"viscosity B is negative ({at}): not physical. These data cannot tell the intrinsic viscosity from the "
        f"reflex pathway's velocity response (their sum is what the fit determines); do not read B alone",
        PhysiologyWarning, stacklevel=stacklevel)


def _check_relaxed_stiffness(model, stacklevel: int) -> None:
    """PhysiologyWarning when a model with stress relaxation has a relaxed stiffness above
    its short-range stiffness, or below zero: the slow term then does not describe a
    relaxing tissue (it rises, or overshoots), and the relaxed value is an extrapolation of
    the slow averages beyond the holds the record contains, not a property of the joint."""
    entry = (model.fit or {}).get("stiffness")
    if not entry:
        return
    short, relaxed = entry["short_range"]["values"], entry["relaxed"]["values"]
    bad = [i for i, (sr, r) in enumerate(zip(short, relaxed)) if sr > 0 and not 0.0 < r <= sr]
    if not bad:  # (a negative short-range K has its own warning)
        return
    s_k, r_k, p_k = short[bad[0]], relaxed[bad[0]], entry["scheduling"][bad[0]]
    how = ("above the short-range stiffness: the slow term adds torque to a held displacement instead of "
           "relaxing it (a slow drift of tone or of the trial's mean, not stress relaxation)" if r_k > s_k else
           "below zero: the slow term takes away more torque than the displacement gives")
    warnings.warn(
        f"relaxed stiffness {r_k:.1f} N m/rad at {p_k:+.3f} rad is {how}; it extrapolates the slow averages beyond "
        f"the holds in this record, so these data cannot tell the relaxed stiffness (the short-range "
        f"{s_k:.1f} N m/rad stands)", PhysiologyWarning, stacklevel=stacklevel)


def _check_time_base(model, stacklevel: int) -> None:
    """PhysiologyWarning when the identified dynamics say the time axis is probably scaled
    wrong (a time column in other units, a sampling rate given wrong): see
    :func:`time_base_problem`."""
    problem = time_base_problem(model)
    if problem:
        warnings.warn(problem, PhysiologyWarning, stacklevel=stacklevel)


# Share of the identified range over which a negative reflex gain is reported. A stretch
# reflex adds torque against the stretch: a negative rectifier slope is a nonlinearity the
# model could not get right. Seen: the lab's pilot trial with the 1 kHz hinge basis (-1.8 and
# -8.8 N m s/rad at the range's ends), and the virtual subject with a hidden background
# activation, default path (-12.9 at the plantarflexed end; with the effect, 2.2 there); the
# virtual subject without a hidden effect: never.
NEGATIVE_GAIN_SHARE = 0.1


def _check_reflex_gain(model, stacklevel: int) -> None:
    """PhysiologyWarning when the reflex rectifier gain is negative, with its confidence
    interval below zero, over more than NEGATIVE_GAIN_SHARE of the identified range. Where
    the interval reaches zero the data do not determine the gain (the summary says so):
    no warning, since no setting was seen to fix it there (on the lab's pilot neither a
    lower velocity order nor diagnose did). A model without intervals is judged by the
    estimate alone."""
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, 51)
    gain, _ = model.reflex_gain_threshold(rho)
    upper = gain
    judged = bool(getattr(model, "has_intervals", False))
    if judged:
        try:
            _, upper = model.reflex_gain_interval(rho)
        except (LpvpcError, ValueError, KeyError):  # (no stored reflex interval: the estimate alone)
            judged = False
    below = (gain < 0) & (np.asarray(upper) < 0)
    share = float(np.mean(below))
    if share <= NEGATIVE_GAIN_SHARE:
        return
    k = int(np.argmin(np.where(below, gain, np.inf)))
    interval = f", interval up to {float(np.asarray(upper)[k]):.1f}" if judged else " (no interval to judge by)"
    warnings.warn(
        f"reflex gain is negative over {100 * share:.0f} % of the identified position range ({gain[k]:.1f} N m s/rad "
        f"at {rho[k]:+.2f} rad{interval}): a stretch reflex that lowers the torque is not physiological, and these "
        f"data cannot tell why; read the reflex there as not determined (an effect the model lacks would show in "
        f"lpvpc diagnose on held-out data)", PhysiologyWarning, stacklevel=stacklevel)


def _conventions(data) -> dict:
    """Units and torque sign the data were loaded with (recorded so predict can reuse them)."""
    meta = dict(getattr(data, "meta", {}) or {})
    return {"position_unit": meta.get("position_unit", "rad"), "torque_sign": float(meta.get("torque_sign", 1.0)),
            "fs_original": meta.get("fs_original"), "decimation": meta.get("decimation"),
            **({"channel_skew_s": float(meta["channel_skew_s"])} if meta.get("channel_skew_s") else {})}


def _provenance(data) -> dict:
    import casadi
    import scipy

    h = getattr(data, "data_hash", None)
    if callable(h):
        h = h()
    return {
        "data_hash": h,
        "data_source": getattr(data, "source", ""),
        "lpvpc_version": __version__,
        "numpy_version": np.__version__,
        "scipy_version": scipy.__version__,
        "casadi_version": casadi.__version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def _relaxation_term_of(model) -> dict:
    """The estimator settings of a model's stress-relaxation term as the selection names them
    (lpvpc.selection.effect_candidates): its times and its weights' order in position."""
    from .effects import model_relaxation_times

    fe = next(f for f in model.effects if f.name == "stress_relaxation")
    return {"relaxation_times": model_relaxation_times(model), "relaxation_order": fe.basis.order}


def _catalog_terms(cands: dict, intrinsic_basis) -> dict:
    """The estimator settings of the candidates (lpvpc.selection.effect_candidates) whose
    columns are the catalog's own terms (stress relaxation: lpvpc.effects.RELAXATION_TIMES at
    the catalog's order in position), {} when none is."""
    from .effects import CATALOG, RELAXATION_TIMES, effect_basis

    out = {}
    for name, by_value in cands.items():
        order = effect_basis(CATALOG[name], intrinsic_basis).order
        out.update(next((c[3] for c in by_value.values() if c[3].get("relaxation_times") == tuple(RELAXATION_TIMES)
                         and c[1].order == order), {}))
    return out


def _effects_cv(search, chosen: dict, cands: dict) -> dict:
    """The record of the allowed effects' choice: which were allowed and chosen, the chosen
    variants' estimator settings, and the CV VAF (%) of the chosen structure with each effect
    off and on (its chosen variant, else its best; every variant's under ``variants``), same
    folds."""
    from .selection import chosen_effects, effect_key, effect_settings

    on = chosen_effects(chosen)
    table = {}
    for n in cands:
        without = search.score({**chosen, effect_key(n): False})
        scores = {v: search.score({**chosen, effect_key(n): v}) for v in cands[n]}
        v_on = chosen[effect_key(n)] if n in on else max(scores, key=lambda v: scores[v].cv_vaf)
        table[n] = {"cv_vaf_on": float(scores[v_on].cv_vaf), "cv_vaf_off": float(without.cv_vaf),
                    "n_params": int(scores[v_on].n_params - without.n_params)}
        if len(scores) > 1:
            table[n].update(variant=v_on, variants={str(v): float(sc.cv_vaf) for v, sc in scores.items()})
    return {"allowed": sorted(cands), "chosen": on, "settings": effect_settings(chosen, cands), "cv": table,
            "rule": "off or one of its variants, candidates of the same cross-validation, one-standard-error rule "
                    "toward fewer parameters"}


def _effect_search(p, y, rho, fs, dynamics, family, velocity_family, segments, chosen, offered, intrinsic_order,
                   on_only=False):
    """(search, the structure ``chosen`` with every effect off, the effects' columns): a
    :class:`lpvpc.selection.StructureSearch` held at ``chosen`` with the ``offered`` effects'
    columns (off or one of their variants; ``on_only``: their variants only), under the reflex
    ``dynamics`` (same folds as the selection)."""
    from .selection import SEARCH, StructureSearch, effect_candidates, effect_key

    cands = effect_candidates(offered, p, rho, fs, family, intrinsic_order)
    space = {k: (chosen[k],) for k in SEARCH}
    if on_only:
        space.update({effect_key(n): tuple(cands[n]) for n in cands})
    search = StructureSearch(p, y, rho, fs, dynamics, family, velocity_family, space, segments, effects=cands)
    return search, {**chosen, **{effect_key(n): False for n in cands}}, cands


def _effect_gains(p, y, rho, fs, dynamics, family, velocity_family, segments, chosen, offered):
    """({effect: fraction by which its best variant lowers the cross-validated squared error of
    the structure ``chosen``}, the estimator settings of those variants) with the given reflex
    dynamics (same folds as the selection)."""
    from .selection import effect_key

    search, off, cands = _effect_search(p, y, rho, fs, dynamics, family, velocity_family, segments, chosen, offered,
                                        chosen["intrinsic_order"])
    sse_off = float(search.score(off).fold_sse.sum())
    gains, terms = {}, {}
    for n in cands:
        sse = {v: float(search.score({**off, effect_key(n): v}).fold_sse.sum()) for v in cands[n]}
        best = min(sse, key=sse.get)
        gains[n] = 1.0 - sse[best] / sse_off
        terms.update(cands[n][best][3])
    return gains, terms


def with_base_model_activation(data, settings):
    """``data`` ready for identifying a model with ``settings`` (estimator settings): when its
    effects read the background activation, the estimates computed with the reflex drive of
    a base model (the same settings without effects; one extra fit) and stored
    (:func:`with_model_activation`), as predict, diagnose and improve estimate them.
    Without it the extended model was fitted on the velocity-hinge estimate and
    evaluated on the drive's. Unchanged otherwise (no such effect, no EMG, estimates stored).

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> with_base_model_activation(data, {"effects": ("stress_relaxation",)}) is data  # reads no activation
    True
    """
    from .effects import _has_backgrounds, reads_activation, with_model_activation

    extra = getattr(data, "extra", None) or {}
    if (not reads_activation(settings.get("effects") or ()) or not ({"emg", "emg_ut"} & set(extra))
            or _has_backgrounds(extra)):
        return data
    base = _inner(LPVPCEstimator(**{**settings, "effects": ()})).fit(data).model_
    return with_model_activation(data, base)


def identify(data, **settings) -> LPVPCModel:
    """Identify an LPV-PC model with the given estimator settings; returns the model.

    >>> from lpvpc.data import pair_trials
    >>> from lpvpc.simulate import SubjectParams, simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> model = identify(pair_trials(sim.pt, sim.ut), intrinsic_order=5)
    >>> K = model.elastic_stiffness([-0.2, 0.0])  # N m/rad, against the subject's truth:
    >>> bool(np.all(np.abs(K / SubjectParams().K(np.array([-0.2, 0.0])) - 1) < 0.15))
    True
    """
    return LPVPCEstimator(**settings).fit(with_base_model_activation(data, settings)).model_


def __getattr__(name):
    # project_out_and_solve and check_full_rank moved to lpvpc.linalg; still importable from
    # here, on first use (lpvpc.linalg imports scipy.linalg, which the CLI's help must not load)
    if name in ("check_full_rank", "project_out_and_solve"):
        from . import linalg

        return getattr(linalg, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: (inertia kg m^2, viscosity N m s/rad) both below which, or both above which (the
#: second pair), the identified intrinsic dynamics are outside an ankle's by a factor of
#: several: an ankle (with its foot plate) has about 0.005-0.09 kg m^2 and 0.5-3 N m s/rad
#: (the lab's stationary trials and pilot, the virtual subject). A time axis k times too
#: fast divides the viscosity by k and the inertia by k^2; the fast pair keeps clear of the
#: lab's trials, whose inertia estimate is noisy (-0.012 to 0.09) but whose viscosity is not.
TIME_BASE_TOO_FAST = (3e-3, 0.3)
TIME_BASE_TOO_SLOW = (0.5, 5.0)


def time_base_problem(model) -> str | None:
    """The one-line reason when the identified inertia and viscosity (median over the
    identified range) are both far below, or both far above, an ankle's: the time axis is
    then probably scaled wrong (a time column in other units, a sampling rate given wrong),
    which leaves the stiffness and the fit's VAF plausible; None otherwise."""
    lo, hi = model.scheduling_range
    rho = np.linspace(lo, hi, 11)
    inertia = float(np.median(np.abs(model.inertia(rho))))
    viscosity = float(np.median(model.viscosity(rho)))
    fs0 = (model.conventions or {}).get("fs_original") or model.fs
    seen = (f"identified inertia {inertia:.2g} kg m^2 and viscosity {viscosity:.2g} N m s/rad are far "
            f"{{}} an ankle's (about 0.005-0.09 kg m^2 and 0.5-3 N m s/rad)")
    if inertia < TIME_BASE_TOO_FAST[0] and viscosity < TIME_BASE_TOO_FAST[1]:
        return (seen.format("below") + f": the time axis is probably too fast (the file was read as {fs0:g} Hz): "
                "check the time column's unit (--time-unit) or --fs; the stiffness and the VAF do not show it")
    if inertia > TIME_BASE_TOO_SLOW[0] and viscosity > TIME_BASE_TOO_SLOW[1]:
        return (seen.format("above") + f": the time axis is probably too slow (the file was read as {fs0:g} Hz): "
                "check the time column's unit (--time-unit) or --fs")
    return None
