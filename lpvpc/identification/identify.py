"""The subspace LPV parallel-cascade identification (Sobhani Tehrani et al., EMBC 2014).

Steps (equation numbers of the seed paper), each a method of :class:`LPVPCEstimator`
called in this order by ``_fit``:

1. ``_build_regressors``: intrinsic Psi_i (9-11) and reflex inputs U_r (17) from the bases;
2. ``_moesp``: MOESP on the MISO form (21)-(23), from which A_r, C_r are read;
3. ``_candidate_orders``: the state orders to fit, from the singular values (the orders at
   the two largest gaps, plus orders 2 and 3), unless ``state_order`` is given;
4. ``_fit_orders``, at each order (``_fit_given_order``): ``_reflex_dynamics``, the MOESP
   poles refined by variable projection on the complete fit (``PoleRefinement``; MOESP with
   ~70 inputs leaves a bias in the poles that leaks reflex torque into the intrinsic
   estimate); ``_orthogonal_projection`` (25, 27-28): the reflex regressor Psi_r by
   filtering U_r through C_r (zI - A_r)^-1, then the intrinsic parameters by least squares
   after projecting out range(Psi_r) (Frisch-Waugh: identical to C^+ Psi_i^+ (I - Psi_r
   Psi_r^+) Y without N x N matrices); ``_hammerstein``: the reflex torque (29) and
   separable least squares for B, d and Omega;
5. ``_choose_order``: the order of least BIC of the complete fit among the stable ones;
6. ``_intrinsic_irf``: the two-sided IRF and the elastic curvature tied to it;
7. ``_causal_form``: a causal intrinsic IRF (lags 0..Lc, plus velocity and acceleration
   terms) fitted to the two-sided intrinsic torque, for closed loop (the default FMU's form);
8. ``_reflex_nonlinearity`` and ``_new_model``: the model; ``_finish_effects``: an extended
   model's effect terms;
9. ``_intervals``: the confidence intervals; ``_scores`` and ``_fit_summary``: ``model.fit``.

Fits inside another (the structure selection's) start from a :class:`WarmStart`.
"""

from __future__ import annotations

import functools
import inspect
import math
import time
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import __version__
from ..models import equations as eq
from ..models.basis import basis_from_data
from ..errors import (DataError, IdentificationError, InsufficientExcitationError, LpvpcError, PhysiologyWarning,
                     StationaryWarning)
from ..models.intrinsic import curvature_from_irf, curvature_regressor, intrinsic_regressor, two_sided_lags
from ..io.segments import Segments

# why the selection skips a record whose reflex nonlinearity the caller put on the high-rate velocity
HIGH_RATE_GIVEN = "reflex nonlinearity on the high-rate velocity"

if TYPE_CHECKING:  # annotations only: lpvpc.models.model imports scipy.signal, kept out of import time (above)
    from ..models.model import LPVPCModel

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
#: s: structure="cv" is skipped on shorter records (the settings as given, the reason recorded):
#: there the selection picks structures too small to follow K(theta) (docs/design_notes.md,
#: "Shortest record for structure selection").
MIN_SELECTION_S = 45.0
#: Effects structure="cv" may switch on (``allow_effects``): stress relaxation, on every
#: record (docs/guide/structure_selection.md, "Effects chosen by cross-validation").
DEFAULT_ALLOWED_EFFECTS = ("stress_relaxation",)
#: An allowed effect is kept only if, beyond the one-standard-error rule, it lowers the
#: cross-validated squared error by at least this fraction: with 5-10 folds a tiny but
#: consistent gain passes the paired rule, and an effect costs more than its parameters (wider
#: K intervals, the FMU's states). Evidence for 5 %: docs/design_notes.md, "Effects' bar".
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


@dataclass(frozen=True)
class WarmStart:
    """Where one of the estimator's internal fits starts, and what it leaves out.

    The structure selection fits the same record several times; a later fit starts from what
    an earlier one found instead of repeating it. A fit from ``WarmStart()`` is the fit of
    the record alone (what :meth:`LPVPCEstimator.fit` does).

    Parameters
    ----------
    subspace : lpvpc.identification.subspace.SubspaceResult or None, default None
        The MOESP step of an earlier fit of the same record, used instead of computing it
        (the reflex poles do not depend on the structure's columns). None: computed.
    poles : dict of int to numpy.ndarray, or None, default None
        A reflex state matrix A_r by state order: the pole refinement at that order starts
        there (the poles of a fit at a neighbouring structure) instead of at MOESP's.
    bare : bool, default False
        Only the reflex dynamics, the state order and the parameters: no causal form,
        intervals, scores or physiology checks (a fit whose model is not kept).
    scan_skew : bool, default True
        Scan the fitted model's record for a channel skew; False for fits inside another,
        which scans its own model.

    Examples
    --------
    A fit whose model is not kept, and one whose pole refinement at order 2 starts from the
    poles of a fit at a neighbouring structure:

    >>> WarmStart(bare=True).scan_skew
    True
    >>> warm = WarmStart(poles={2: np.diag([0.9, 0.5])})
    >>> warm.bare, warm.subspace is None, sorted(warm.poles)
    (False, True, [2])
    """

    subspace: object = None
    poles: dict | None = None
    bare: bool = False
    scan_skew: bool = True


#: A fit inside another (no channel-skew scan: the outer fit scans its own model).
_INNER = WarmStart(scan_skew=False)


@dataclass
class _Regressors:
    """One record's regressors of both pathways and what built them (the first step of a fit)."""

    data: object
    p: np.ndarray  # perturbation position (rad)
    y: np.ndarray  # perturbation torque (N m)
    rho: np.ndarray  # scheduling variable (rad)
    fs: float  # Hz
    seg: Segments
    delay: int  # reflex delay, samples
    L: int  # IRF half-width, samples
    lags: np.ndarray
    dvel: np.ndarray  # delayed velocity (rad/s)
    rho_orders: dict  # basis orders in rho as used (0 on a stationary trial)
    G_i: object  # intrinsic basis in rho
    G_r: object  # reflex basis in rho
    V_b: object  # velocity basis
    Gi_val: np.ndarray
    Psi_irf: np.ndarray  # the IRF's columns
    Psi_i: np.ndarray  # with the curvature's share and the effects' columns
    n_base: int  # columns of Psi_i that are the IRF's
    U_r: np.ndarray  # reflex inputs, at the high rate on that path
    U_r_model: np.ndarray  # reflex inputs at the model rate
    high: object  # high-rate reflex input, or None
    design: object  # the effects' design, or None


class LPVPCEstimator:
    """Estimator of an LPV-PC ankle stiffness model, in the scikit-learn manner.

    ``fit(data)`` follows the paper's steps: the regressors of both pathways, MOESP for the
    reflex dynamics, the orthogonal projection that separates the intrinsic IRF, the
    Hammerstein fit of the reflex nonlinearity by separable least squares, then the
    intervals. By default the structure (IRF half-width, basis orders, reflex delay and the
    optional terms) is chosen by cross-validation over the record's position levels. The
    fitted model is ``model_`` (:class:`lpvpc.LPVPCModel <lpvpc.models.model.LPVPCModel>`). Why each default is what it is,
    with the evidence, is in the documentation's design notes.

    Parameters
    ----------
    irf_lags : int or None, default None
        Half-width L of the two-sided intrinsic IRF in samples (lags -L..L); overrides
        ``irf_length``. Keep it at most the reflex delay, where the pathways' regressors
        stay independent.
    basis : {"chebyshev", "legendre", "gaussian"}, default "chebyshev"
        Basis family in the scheduling variable (joint position).
    intrinsic_order : int, default 5
        Basis order in position of each IRF weight (order 5 follows an exponential K(theta)).
    reflex_order : int, default 2
        Basis order in position of the reflex nonlinearity's coefficients.
    velocity_order : int, default 4
        Basis order in delayed velocity of the reflex nonlinearity.
    velocity_basis : {"chebyshev", "hinge"}, default "chebyshev"
        Its family; both continue linearly beyond the identified velocity range.
    reflex_delay : float, default 0.040
        Reflex delay in s (rounded to samples).
    state_order : int or None, default None
        Order m of the reflex dynamics; None chooses it from the data.
    min_state_order, max_state_order : int, default 1 and 4
        Orders considered when choosing it.
    horizon : int, default 6
        Block rows of the MOESP Hankel matrices.
    causal_lags : int or None, default None
        Lc: the causal IRF of the closed-loop form spans lags 0..Lc (None: L + 2).
    tol : float, default 1e-6
        Relative-change stopping rule of the separable least squares.
    max_iter : int, default 100
        Its iteration limit.
    refine : bool, default True
        Refine the MOESP poles by variable projection.
    effects : tuple of str, default ``()``
        Effects of :data:`lpvpc.models.effects.CATALOG` always included (an extended model);
        the data must carry the signals they need.
    irf_length : float, default 0.040
        Half-width of the intrinsic IRF in s, used when ``irf_lags`` is None.
    stationary_range : float, default 0.010
        A scheduling variable spanning less (rad) makes the trial stationary: one operating
        position, the LTI parallel cascade.
    causal_derivatives : {"central5", "central3"}, default "central5"
        Difference stencil of the velocity and acceleration of the causal form (latency 2
        or 1 sample in the default FMU).
    stationary_delays : tuple of float, optional
        On a stationary trial, the reflex delays (s) among which BIC chooses, with the IRF
        half-width equal to it (``()``: off). Default ``(0.04, 0.05, 0.06, 0.07, 0.08)``.
    high_rate_velocity_basis : {"chebyshev", "legendre", "hinge"}, default "hinge"
        Velocity basis of the reflex nonlinearity on the file's own rate (``high_rate_reflex``).
    high_rate_velocity_order : int, default 8
        Its order.
    high_rate_reflex : bool, default False
        Identify the reflex nonlinearity on the delayed velocity at the file's own rate (e.g.
        1 kHz), where the rectifier's threshold is observable. With ``structure="cv"`` and
        the setting not given, the cross-validation chooses it per record.
    elastic_curvature : bool, default True
        Include the elastic torque's second-order term 0.5 K'(theta) p^2, tied to the IRF's
        own K(theta) (no extra parameters; not in the paper).
    max_reflex_time_constant : float or None, default 1.0
        Longest time constant (s) the refined reflex poles may take (None: up to stability);
        keeps slow unmodelled torque out of the reflex dynamics.
    structure : {"cv", "fixed"}, default "cv"
        "cv": the settings the caller did not give are chosen by leave-one-level-out
        cross-validation with the one-standard-error rule (:mod:`lpvpc.identification.selection`),
        recorded in ``model.fit["structure_selection"]``; "fixed": the settings as given.
    structure_fixed : tuple of str or None, default None
        With ``structure="cv"``, the settings the selection leaves as given (None: every
        setting named in the call).
    scheduling_extrapolation : {"clip", "linear"}, default "clip"
        Beyond the identified position range the bases are held at the boundary, or
        continued along their tangent.
    allow_effects : tuple of str, optional
        Effects the cross-validation may switch on (``()``: none). Default
        ``("stress_relaxation",)``.
    relaxation_times : tuple of float or None, default None
        Stress relaxation's averaging times (s); None: chosen with the effect.
    relaxation_order : int or None, default None
        Order in position of stress relaxation's weights; None: chosen with the effect.

    Attributes
    ----------
    model_ : lpvpc.models.model.LPVPCModel
        The fitted model (after :meth:`fit`).

    See Also
    --------
    lpvpc.identification.identify.identify : the same, as one call returning the model.

    Examples
    --------
    Fit a 30-s record of the virtual subject (100 Hz) and score a trial of another seed
    (VAF in percent; it leaves the identified range a quarter of the time, where the model
    is held at the range's edge): it comes within 2 points of that trial's noise ceiling.

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.errors import OutOfRangeWarning
    >>> from lpvpc.models.model import vaf
    >>> from lpvpc.simulation.simulate import simulate_pair
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
        # scikit-learn's rule: __init__ stores each setting under its own name and nothing else
        given = locals()
        for name in self._param_names():
            setattr(self, name, given[name])

    @classmethod
    def _param_names(cls) -> tuple:
        """The settings: the parameters of ``__init__``, in order (the one declaration)."""
        import inspect

        return tuple(name for name in inspect.signature(cls.__init__).parameters if name != "self")

    def get_params(self, deep: bool = True) -> dict:
        """The estimator's settings as a dict (scikit-learn convention; ``deep`` is ignored:
        no nested estimators)."""
        return {k: getattr(self, k) for k in self._param_names()} | {"structure_fixed": self._given_settings()}

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
        from ..models.model import vaf

        return vaf(np.asarray(data.torque, dtype=float), self.predict(data))

    def _fitted(self):
        if not hasattr(self, "model_"):
            raise IdentificationError("this LPVPCEstimator is not fitted yet: call fit(data) first")
        return self.model_

    # ------------------------------------------------------------------------------------
    def fit(self, data) -> "LPVPCEstimator":
        """Identify the model from a record, or from several trials jointly.

        With ``high_rate_reflex``, data that keep their file's higher rate (``high_rate``) get
        the reflex nonlinearity identified on the high-rate velocity; when that fit is not
        determined (too few stretch velocities for its basis) it is identified on the
        model-rate velocity instead, with an :class:`~lpvpc.errors.LpvpcWarning`. The
        physiology warnings are those of the final model (candidate fits warn in their own
        numbers, which are never shown).

        Parameters
        ----------
        data : lpvpc.io.PerturbationData or list of lpvpc.io.PerturbationData
            The record (or any object with ``position``, ``torque``, ``scheduling`` arrays
            and ``fs``), or a list of them: several trials fitted jointly
            (:func:`lpvpc.io.join_trials <lpvpc.io.identification_data.join_trials>`).

        Returns
        -------
        LPVPCEstimator
            This estimator, fitted: the model is ``model_``.

        Raises
        ------
        lpvpc.errors.DataError
            The record is unusable (or the settings contradict each other).
        lpvpc.errors.InsufficientExcitationError
            The record cannot determine the requested parameters.
        lpvpc.errors.IdentificationError
            The algorithm failed on data that passed the checks.

        Examples
        --------
        >>> from lpvpc.io import pair_trials
        >>> from lpvpc.simulation.simulate import simulate_pair
        >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
        >>> est = LPVPCEstimator(intrinsic_order=3).fit(pair_trials(sim.pt, sim.ut))
        >>> est.model_.intrinsic_basis.order, bool(est.model_.fit["vaf"] > 90.0)
        (3, True)
        """
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            self._fit_from(data, WarmStart(), stacklevel=3)
        _physiology_of_final(self.model_, caught)
        return self

    def _fit_from(self, data, warm: WarmStart, stacklevel: int = 2) -> "LPVPCEstimator":
        """:meth:`fit` from a warm start (:class:`WarmStart`). ``stacklevel``: the frame, counted
        from this one, that the warnings about the record point at (2: this method's caller)."""
        from ..linalg import one_blas_thread

        with one_blas_thread():  # in this frame: the warnings' stacklevels count from here
            if isinstance(data, (list, tuple)):
                from ..io import join_trials

                data = join_trials(data)
            self.check_settings()
            if not self._lines_up(data, warm):
                self._fit_once(data, warm, stacklevel)
                self._record_channel_skew(data, warm, stacklevel)
                return self
            # The record can be read again from its files: a late torque channel found by the
            # scan is lined up at the files' rate and the model fitted again (the first fit's
            # warnings are shown only when it stands).
            with warnings.catch_warnings(record=True) as caught:
                self._fit_once(data, warm, stacklevel)
                found = self._scan_channel_skew(data, warm)
            if found is not None and found.chosen:
                self._fit_once(data.reload(channel_skew=found.chosen), warm, stacklevel)
                self.model_.fit["channel_skew"] = found.to_dict()
            else:
                for w in caught:
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
            return self

    def _fit_once(self, data, warm: WarmStart, stacklevel: int = 2) -> None:
        """One fit of the record: selected (structure="cv", whose fits have their own warm
        starts) or as given from ``warm``; on the high-rate path, the model-rate one when the
        high-rate fit is not determined. ``stacklevel`` as in :meth:`_fit_from`."""
        if self.structure == "cv":
            self._fit_selected(data)
            return
        try:
            self._fit(data, warm)
        except InsufficientExcitationError as exc:
            if getattr(data, "high_rate", None) is None or self.effects or not self.high_rate_reflex:
                raise
            from dataclasses import replace

            from ..errors import LpvpcWarning

            warnings.warn(f"the reflex nonlinearity could not be identified on the {data.high_rate.fs:g} Hz "
                          f"velocity ({exc}); identified on the {data.fs:g} Hz velocity instead (its threshold "
                          f"is biased)", LpvpcWarning, stacklevel=stacklevel + 1)
            self._fit(replace(data, high_rate=None), warm)

    def _lines_up(self, data, warm: WarmStart) -> bool:
        """Whether this fit lines a late torque channel up itself: a top-level fit of a record
        that can be read again from its files (``data.origin``) and whose channel skew the
        loader was not given."""
        origin = getattr(data, "origin", None)
        meta = getattr(data, "meta", {}) or {}
        return (origin is not None and "channel_skew" not in origin.given and warm.scan_skew
                and not warm.bare and "position_delay_s" not in meta)

    def _record_channel_skew(self, data, warm: WarmStart, stacklevel: int = 2) -> None:
        """Scan for a channel skew (:meth:`_scan_channel_skew`) and warn, naming the fix, when
        lining the channels up would remove at least MIN_RESIDUAL_REDUCTION of the residual
        variance: for records this fit cannot read again, or whose skew was given."""
        found = self._scan_channel_skew(data, warm)
        if found is not None and found.chosen:
            from ..errors import LpvpcWarning

            warnings.warn(f"the torque channel lags the position channel by about {found.chosen * 1e3:.2f} ms (a "
                          f"recording artefact: lining them up removes {100 * found.residual_reduction:.1f} % of the "
                          f"residual variance); load the files with channel_skew={found.chosen:.5f}, or leave "
                          f"channel_skew out of load_identification_data and identify lines them up itself",
                          LpvpcWarning, stacklevel=stacklevel + 2)

    def _scan_channel_skew(self, data, warm: WarmStart):
        """The channel skew the fitted model sees in its data
        (:func:`lpvpc.identification.skew_scan.scan_channel_skew`, about one least-squares
        solve), recorded in ``model.fit["channel_skew"]``; None where no scan applies: the
        fits inside identify, data already aligned, stationary records and models with
        effects (where the scan takes the misfit for a skew)."""
        meta = getattr(data, "meta", {}) or {}
        if warm.bare or not warm.scan_skew \
                or "channel_skew_s" in meta or "position_delay_s" in meta or not hasattr(data, "meta"):
            return None
        if self.model_.effects or float(np.ptp(np.asarray(data.scheduling, dtype=float))) < self.stationary_range:
            return None
        from .skew_scan import scan_channel_skew

        found = scan_channel_skew(self.model_, data)
        self.model_.fit["channel_skew"] = found.to_dict()
        return found

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
        structure is chosen by cross-validation with them held (lpvpc.identification.selection); the
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
        with warnings.catch_warnings():  # the model kept gives its own warnings
            warnings.simplefilter("ignore")
            first._fit(data, WarmStart(bare=True))  # no intervals, causal form or scores: computed once, for the model kept
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
                # the order chosen without them can hold a slow pole that took the relaxation
                chosen["state_order"] = None
        est = LPVPCEstimator(**{**base, **chosen})
        warm = WarmStart(subspace=first.subspace_)
        if effect_poles is not None and "effects" in chosen:  # the effects' own subspace step
            # (the first fit's poles take part of a relaxation), unless their terms changed since
            A_e = effect_poles[0]
            warm = (WarmStart(subspace=effect_poles[1], poles={A_e.shape[0]: A_e})
                    if effects_cv["settings"] == effect_poles[2] else WarmStart())
        elif sel.chosen != {k: start[k] for k in sel.chosen} or order != bic_order:  # another structure: its
            # refinement starts at the first fit's poles of that order (fewer steps than from MOESP's)
            warm = WarmStart(subspace=first.subspace_, poles={order: first._order_dynamics[order][0]})
        if path is not None and path.chosen["high_rate_reflex"]:
            est = self._fit_high_rate_chosen(data, est, path, first, order)
        else:  # effects chosen: joined in the subspace step, as in the fit whose dynamics the CV held
            # (fitted after the reflex instead, the reflex takes the relaxing torque: design notes)
            est._fit(data, warm, late=False if "effects" in chosen else None)
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
            # (lpvpc.identification.structural_uncertainty): the search continued from the chosen structure, so its
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
        had taken part of the relaxation and the effect looked useless (docs/design_notes.md,
        "Effects in the structure selection"). Scored after the
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
        # catalog's, which can leave the effect off on a record that relaxes)
        terms, tried = dict(terms or {}), []
        while True:
            fit = LPVPCEstimator(**{**fit_settings, "effects": tuple(offered), **terms})
            if terms and self.state_order is None:  # BIC's order with the chosen terms (_fit_selected)
                fit.state_order = None
            # its own subspace step: started from the first fit's (no effect columns) the pole refinement
            # stays near poles that take the relaxation; bare: the model is not kept
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fit._fit(data, WarmStart(bare=True), late=False)
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
            # it: the held dynamics had taken part of the other term's misfit
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
                est = LPVPCEstimator(**{**settings, "effects": tuple(entry["chosen"]), **entry["settings"]})
                if entry["settings"] and self.state_order is None:  # BIC's order with them (_fit_selected)
                    est.state_order = None
                warm = _INNER  # the effects' dynamics, unless their terms changed since
                if entry["settings"] == dyn[2]:
                    warm = WarmStart(subspace=dyn[1], poles={dyn[0].shape[0]: dyn[0]}, scan_skew=False)
                est._fit_from(data, warm)
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
        (:func:`lpvpc.identification.selection.compare_reflex_paths`); None when it is not a candidate (no
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
        warm = WarmStart(subspace=first.subspace_, poles={order: first._order_dynamics[order][0]})
        try:
            est._fit(data, warm)
        except InsufficientExcitationError as exc:
            fallback = LPVPCEstimator(**{**est.get_params(), "high_rate_reflex": False})
            fallback._fit(data, warm)
            path.chosen = {"high_rate_reflex": False}
            path.fallback = f"the high-rate fit was not determined ({exc}): model-rate velocity"
            return fallback
        return est

    def _choose_forced_relaxation_term(self, data, base) -> None:
        """Stress relaxation forced (``effects=("stress_relaxation",)``, its term not given),
        the structure as given: its term (lpvpc.identification.selection.RELAXATION_VARIANTS) chosen as when
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
            est = LPVPCEstimator(**{**base, **entry["settings"]})._fit_from(data, _INNER)
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
        est = LPVPCEstimator(**base)._fit_from(data, _INNER)
        est.model_.settings["structure"] = "cv"
        est.model_.fit["structure_selection"] = {"skipped": reason}
        self.model_, self.subspace_, self.n_features_ = est.model_, est.subspace_, est.n_features_
        return self

    def _fit_both_ways(self, data, warm: WarmStart = WarmStart()) -> "LPVPCEstimator":
        """Effects that may be fitted ``after_reflex`` (lpvpc.models.effects.Effect): the fit with
        them in the subspace step's intrinsic regressor and the fit with them joining only
        the final solve, the identified reflex held; the better in-sample fit is kept (same
        parameter count). Why both: on the virtual subject with stress relaxation the first
        predicts better (novel VAF 97.7-97.9 against 97.1-97.6 %); on the lab's stationary
        trial z_pf the slow columns took the reflex's slow response there (fit VAF 86.2 %
        against 87.0 %)."""
        def fit(late):  # its warnings, told only for the fit kept (each fit warns alike, in other numbers)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self._fit(data, warm, late=late)
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

    def _fit(self, data, warm: WarmStart = WarmStart(), late=None) -> "LPVPCEstimator":
        """Identify the model at the settings as given, as the paper's steps in order.

        Parameters
        ----------
        data : lpvpc.io.PerturbationData
            The record, or trials joined (nothing crosses a seam).
        warm : WarmStart, default WarmStart()
            What an earlier fit of the same record gives this one (the structure selection's
            refits start from it instead of repeating it).
        late : bool or None, default None
            Effects' columns in the final solve only (True) or also in the subspace step
            (False); None: both fits for effects that may come after the reflex, else False.

        Returns
        -------
        LPVPCEstimator
            self, with ``model_``, ``subspace_`` and ``n_features_``.
        """
        from ..models.effects import CATALOG

        t0 = time.perf_counter()
        timings = {}
        if self._searches_delay(data):  # (fit joined a list of trials)
            return self._fit_stationary_delays(data)
        if late is None and any(CATALOG[n].after_reflex for n in self.effects if n in CATALOG):
            return self._fit_both_ways(data, warm)
        reg = self._build_regressors(data, late)
        timings["regressors"] = time.perf_counter() - t0

        t = time.perf_counter()
        sub = self._moesp(reg, warm)
        timings["moesp"] = time.perf_counter() - t

        t = time.perf_counter()
        fits, failed = self._fit_orders(reg, sub, self._candidate_orders(sub), warm)
        m_best, bic = self._choose_order(fits, len(reg.y))
        best = fits[m_best]
        self._order_dynamics = {m: (f["A"], np.reshape(f["C"], (1, -1)), np.append(f["hammerstein"].b, f["hammerstein"].d))
                                for m, f in fits.items() if m in bic}  # (structure selection compares them)
        timings["projection_and_reflex"] = time.perf_counter() - t

        H, curvature = self._intrinsic_irf(reg, best)
        causal, H_causal = self._causal_form(reg, best, warm.bare)
        Omega, high_nl = self._reflex_nonlinearity(reg, best)
        model = self._new_model(reg, best, H, curvature, causal, H_causal, Omega, high_nl)
        signals = self._finish_effects(reg, model, best)
        if not warm.bare:  # the selection's first fit: only its dynamics and order are used
            t = time.perf_counter()
            self._intervals(reg, model, best)
            timings["uncertainty"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - t0
        scores = (float("nan"), float("nan")) if warm.bare else self._scores(reg, model, signals)
        model.fit = self._fit_summary(reg, model, sub, best, m_best, bic, failed, scores, warm.bare, timings)
        if reg.design is not None and any(fe.name == "stress_relaxation" for fe in model.effects):
            from ..models.effects import relaxation_stiffness_entry

            model.fit["stiffness"] = relaxation_stiffness_entry(model)  # short-range and relaxed, labelled
        if not warm.bare:
            check_physiology(model)
        self.model_ = model
        self.subspace_ = sub
        self.n_features_ = reg.Psi_i.shape[1] + reg.U_r.shape[1]
        return self

    # The steps of _fit, in order ---------------------------------------------------------
    def _build_regressors(self, data, late) -> _Regressors:
        """The regressors of both pathways: the intrinsic Psi_i (eq. 9-11, with the elastic
        curvature and the effects' columns) and the reflex inputs U_r (eq. 17), checked for
        rank. Why first: a record that cannot determine them fails before the costly steps."""
        from ..models.effects import CATALOG
        from ..models.reflex import reflex_input_regressor

        p, y, rho, fs = self._checked(data)
        seg = Segments.of(data, len(y))  # several trials: nothing crosses a seam (lpvpc.io.segments)
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
        U_r = U_r_model = reflex_input_regressor(V_b.evaluate(dvel), Gr_val)
        high = _high_rate_input(self, data, G_r)  # None unless the file's rate exceeds the model's
        if high is not None:  # the rectifier acts on the high-rate velocity (lpvpc.models.reflex.high_rate_input)
            U_r = high.U_r
        design = None
        if self.effects and len(seg) > 1:
            raise DataError(f"effects are identified from one trial; got {len(seg)} trials")
        if self.effects:  # extended model: the effects' columns join the intrinsic regressor
            from ..models.effects import RELAXATION_TIMES, EffectDesign, default_signals, signals_from_data

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
        from ..linalg import check_full_rank, triangular_factor

        check_full_rank(triangular_factor(Psi_i), "intrinsic")
        check_full_rank(triangular_factor(U_r), "reflex input")
        return _Regressors(data=data, p=p, y=y, rho=rho, fs=fs, seg=seg, delay=delay, L=L, lags=lags, dvel=dvel,
                           rho_orders=rho_orders, G_i=G_i, G_r=G_r, V_b=V_b, Gi_val=Gi_val, Psi_irf=Psi_irf,
                           Psi_i=Psi_i, n_base=n_base, U_r=U_r, U_r_model=U_r_model, high=high, design=design)

    def _moesp(self, reg: _Regressors, warm: WarmStart):
        """MOESP on the MISO form (eq. 21-23): the subspace of the reflex dynamics, from which
        A_r and C_r of each state order are read. Why reused from ``warm``: its poles do not
        depend on the structure's columns, and it is a quarter of a fit."""
        from .subspace import po_moesp

        if warm.subspace is not None:
            return warm.subspace
        return po_moesp(reg.U_r, reg.Psi_i, reg.y, self.horizon, segments=reg.seg)

    def _candidate_orders(self, sub) -> list:
        """The reflex state orders to fit: ``state_order`` if given, else those at the two
        largest gaps of the singular values and always 2 and 3, within the allowed range. Why
        2 and 3: a well-damped reflex pole pair often shows as one gap at order 1."""
        from .subspace import candidate_orders

        if self.state_order is not None:
            return [int(self.state_order)]
        # BIC of the complete fit decides among them (which needs each order's Hammerstein fit
        # at its best minimum: lpvpc.models.reflex.fit_hammerstein)
        orders = sorted(set(candidate_orders(sub.singular_values, self.max_state_order)) | {2, 3})
        return [m for m in orders if self.min_state_order <= m <= self.max_state_order]

    def _fit_orders(self, reg: _Regressors, sub, orders, warm: WarmStart):
        """The complete fit at each candidate order (:meth:`_fit_given_order`): (fits by order,
        errors of the orders the data cannot support); the first order's error when none fits.
        Why each complete: the order is chosen by the BIC of the whole model."""
        from .subspace import STABLE_POLE_RADIUS, PoleRefinement

        orientation = np.sign(reg.dvel) @ reg.U_r  # makes Omega's output grow with stretch velocity
        max_radius = (np.exp(-1.0 / (self.max_reflex_time_constant * reg.fs)) if self.max_reflex_time_constant
                      else STABLE_POLE_RADIUS)
        refinement = (PoleRefinement(reg.U_r, reg.Psi_i, reg.y, segments=reg.seg, max_radius=max_radius)
                      if self.refine else None)  # (its N-row factors freed on return)
        starts = warm.poles or {}
        fits, failed = {}, {}
        for m in orders:
            try:
                fits[m] = self._fit_given_order(sub, m, refinement, reg.U_r, reg.Psi_i, reg.y, orientation, reg.seg,
                                                start=starts.get(m), joint=reg.high is not None)
            except InsufficientExcitationError as err:  # a candidate order the data cannot support
                failed[m] = err
        if not fits:  # every order failed: report the first
            raise failed[orders[0]]
        return fits, failed

    @staticmethod
    def _choose_order(fits: dict, n: int):
        """The state order of least BIC among the stable fits: (order, BIC by order). Why only
        the stable ones: an unstable reflex (MOESP can return a pole on or outside the unit
        circle, which the pole refinement cannot leave) fits the identification record yet
        diverges on any later one, and the model file refuses it; unstable orders compete only
        when no order is stable."""
        stable = {m for m, f in fits.items() if np.max(np.abs(np.linalg.eigvals(f["A"]))) < 1.0}
        bic = {m: n * np.log(f["rss"] / n) + f["n_params"] * np.log(n) for m, f in fits.items()
               if m in stable or not stable}
        return min(bic, key=bic.get), bic

    def _intrinsic_irf(self, reg: _Regressors, best: dict):
        """The two-sided intrinsic IRF weights H (lags x basis functions) of the chosen fit, and
        the elastic curvature tied to its K(theta) (None when ``elastic_curvature`` is off)."""
        H = best["theta_i"][:reg.n_base].reshape(len(reg.lags), reg.G_i.size)
        return H, (curvature_from_irf(H, reg.G_i) if self.elastic_curvature else None)

    def _causal_form(self, reg: _Regressors, best: dict, bare: bool):
        """The causal intrinsic IRF (lags 0..Lc, plus velocity and acceleration terms): (its lags,
        its weights), fitted to the two-sided IRF's torque. Why: closed loop (the default FMU)
        cannot use future positions. Zeros for a bare fit (``WarmStart.bare``)."""
        causal = list(range(0, (self.causal_lags if self.causal_lags is not None else reg.L + 2) + 1))
        if bare:
            return causal, np.zeros((len(causal) + 2, reg.G_i.size))  # (no causal form)
        S_c = reg.seg.map(eq.causal_signals, reg.p, fs=reg.fs, lags=causal, stencil=self.causal_derivatives)
        Psi_c = (S_c[:, :, None] * reg.Gi_val[:, None, :]).reshape(len(reg.p), -1)
        # the causal form is fitted to the IRF's torque; the curvature term, static in pos(k), is shared
        H_causal = np.linalg.lstsq(Psi_c, reg.Psi_irf @ best["theta_i"][:reg.n_base],
                                   rcond=None)[0].reshape(S_c.shape[1], reg.G_i.size)
        return causal, H_causal

    @staticmethod
    def _reflex_nonlinearity(reg: _Regressors, best: dict):
        """The Hammerstein fit's reflex nonlinearity: (Omega at the model rate, the high-rate
        nonlinearity or None). On the high-rate path Omega is its model-rate stand-in, for
        exports and predictions from model-rate records."""
        Omega = best["hammerstein"].omega.reshape(-1, reg.G_r.size)
        if reg.high is None:
            return Omega, None
        from ..models.model import HighRateNonlinearity

        high = reg.high
        high_nl = HighRateNonlinearity(fs=high.fs, delay=high.delay, velocity_basis=high.velocity_basis, Omega=Omega)
        return _model_rate_stand_in(reg.U_r_model, reg.U_r, best, reg.seg, reg.G_r.size), high_nl

    def _new_model(self, reg: _Regressors, best: dict, H, curvature, causal, H_causal, Omega, high_nl) -> LPVPCModel:
        """The model of the chosen fit, with the settings as used at this rate and range and
        the record's provenance and conventions (applied whenever it reads a record)."""
        from ..models.model import LPVPCModel

        hf = best["hammerstein"]
        return LPVPCModel(
            fs=reg.fs, lags=reg.lags, H=H, intrinsic_basis=reg.G_i, causal_lags=causal, H_causal=H_causal,
            delay=reg.delay, velocity_basis=reg.V_b, reflex_rho_basis=reg.G_r, Omega=Omega, high_rate=high_nl,
            A=best["A"], B=hf.b, C=best["C"].ravel(), D=hf.d, causal_derivatives=self.causal_derivatives,
            curvature=curvature,
            settings={**self.get_params(), "irf_lags": reg.L, **reg.rho_orders,  # as used at this rate and range
                      "stationary_delays": [float(c) for c in self.stationary_delays],  # JSON: lists
                      "structure_fixed": list(self.structure_fixed or ()),
                      "allow_effects": ([self.allow_effects] if isinstance(self.allow_effects, str)
                                        else list(self.allow_effects or ()))},
            provenance=_provenance(reg.data),
            conventions=_conventions(reg.data),
        )

    @staticmethod
    def _finish_effects(reg: _Regressors, model, best: dict) -> dict:
        """An extended model's effect terms from the final solve
        (:func:`lpvpc.models.effects.finish_extended_fit`); returns the keywords its predictions
        need (the effects' signals), empty without effects."""
        if reg.design is None:
            return {}
        from ..models.effects import finish_extended_fit

        finish_extended_fit(reg.design, model, best["theta_i"][reg.n_base:], reg.Psi_i[:, :reg.n_base], reg.y,
                            Psi_irf=reg.Psi_irf)
        return {"signals": reg.design.signals}

    @staticmethod
    def _intervals(reg: _Regressors, model, best: dict) -> None:
        """The model's confidence intervals (:func:`lpvpc.models.uncertainty.fit_uncertainty`),
        set as ``model.uncertainty``; when they cannot be computed the model stands without
        them, with a warning."""
        from ..models.reflex import reflex_regressor
        from ..models.uncertainty import fit_uncertainty

        p, Gi_val, n_base, seg = reg.p, reg.Gi_val, reg.n_base, reg.seg
        Psi_u, theta_u, omega_u = reg.Psi_i, best["theta_i"], best["hammerstein"].omega
        if reg.design is not None:  # extended: the effects' columns as the final fit has them, fitted with
            # the base ones (whose block of the full covariance is then marginal); the model-rate
            # nonlinearity as refitted there (lpvpc.models.effects.finish_extended_fit)
            X_e, theta_e = reg.design.extension
            Psi_u = np.hstack([reg.Psi_i[:, :n_base], X_e])
            theta_u, omega_u = np.concatenate([model.H.ravel(), theta_e]), model.Omega.ravel()
        # the model's reflex dynamics: the base fit's, or as an effect refitted them
        A_u, C_u = model.A, np.reshape(model.C, (1, -1))
        try:
            model.uncertainty = fit_uncertainty(
                model, Psi_u, reflex_regressor(reg.U_r, A_u, C_u, seg), reg.y, np.append(model.B, model.D),
                omega_u, theta_u, reg.U_r, A_u, truncated_irf(p, Gi_val, reg.L, seg), segments=seg,
                richer=richer_basis_irf(p, reg.rho, reg.G_i, reg.lags, seg),
                curvature_torque=(None if model.curvature is None
                                  else eq.elastic_curvature_torque(p, Gi_val, model.curvature)),
                # the elastic torque's second-order term, free (not tied to the IRF's K')
                free_curvature=(p ** 2)[:, None] * Gi_val, n_base=n_base)
            if reg.high is not None:  # the rectifier's knee as this record's regressors round it
                from ..models.reflex_uncertainty import knee_rounding

                model.uncertainty["knee_rounding"] = knee_rounding(
                    model, reg.U_r, reg.high.dvel, int(round(reg.high.fs / reg.fs)),
                    segments=getattr(reg.data.high_rate, "segments", None))
        except np.linalg.LinAlgError as exc:  # the model stands; only its intervals are missing
            from ..errors import LpvpcWarning

            # (stacklevel: the frame _fit's warnings point at)
            warnings.warn(f"no confidence intervals for this model: {exc}", LpvpcWarning, stacklevel=4)

    @staticmethod
    def _scores(reg: _Regressors, model, signals: dict):
        """VAF (%) of the model's prediction of the identification record, sampled and causal
        forms, trial by trial (the high-rate path as identified)."""
        from ..models.model import vaf

        def predicted(causal):
            if reg.high is not None:  # the high-rate path, as identified
                return model.predict(reg.data, causal=causal, warn=False).total
            return reg.seg.map(lambda pp, rr: model.predict(pp, rr, causal=causal, warn=False, **signals).total,
                               reg.p, reg.rho)

        return vaf(reg.y, predicted(False)), vaf(reg.y, predicted(True))

    def _fit_summary(self, reg: _Regressors, model, sub, best, m_best, bic, failed, scores, bare, timings) -> dict:
        """``model.fit``: the scores, the record's extent and density, the state order and how
        it was chosen, the poles (MOESP's and the model's), the Hammerstein fit's convergence."""
        hf, high, dvel = best["hammerstein"], reg.high, reg.dvel
        n = len(reg.y)
        return {
            "vaf": scores[0],
            "vaf_causal": scores[1],
            "n_samples": int(n),
            "n_trials": len(reg.seg),
            # the top of the rectifier fit (model.reflex_gain_threshold). High rate: the top of the
            # basis's range (99.5th percentile of the 1 kHz velocities); a percentile of the positive
            # ones is fragile there (~90 % of the samples are holds whose 1e-7 rad/s velocities, or a
            # file's rounding, fall on either side of zero: 2.6 or 4.5 rad/s for one recording), and
            # beyond the range the curve is only the basis's linear continuation.
            "velocity_p99": _velocity_p99(dvel, reg.V_b) if high is None else high.velocity_basis.hi,
            "data_density": {} if bare else data_density(reg.rho, dvel, reg.G_i, reg.V_b) if high is None else
            data_density(high.rho, high.dvel, reg.G_i, high.velocity_basis),
            "state_order": int(m_best),
            "state_order_candidates": {str(m): float(b) for m, b in bic.items()},
            "state_orders_failed": {str(m): str(err) for m, err in failed.items()},
            "singular_values": sub.singular_values.tolist(),
            "moesp_poles": [[float(z.real), float(z.imag)] for z in best["moesp_poles"]],
            # the model's own: the reflex dynamics effect refits them (lpvpc.models.effects.finish_extended_fit)
            "poles": [[float(z.real), float(z.imag)] for z in np.linalg.eigvals(model.A)],
            "stationary": bool(np.ptp(reg.rho) < self.stationary_range),
            "hammerstein_iterations": int(hf.iterations),
            "hammerstein_converged": bool(hf.converged),
            "timings_s": timings,
        }

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
            est = LPVPCEstimator(**{**self.get_params(), "reflex_delay": c, "irf_length": c, "stationary_delays": ()})
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    est._fit_from(data, _INNER)
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
        """The complete fit at reflex state order ``m``: the reflex dynamics, the orthogonal
        projection, the Hammerstein fit; a dict with A, C, MOESP's poles, the intrinsic
        parameters, the Hammerstein fit, the residual sum of squares and the parameter count."""
        A, C, moesp_poles = self._reflex_dynamics(sub, m, refinement, start)
        blocks_c, Psi_i_c, y_c, theta_i = self._orthogonal_projection(U_r, A, C, Psi_i, y, segments)
        theta_i, hf, rss = self._hammerstein(blocks_c, Psi_i_c, y_c, theta_i, orientation, joint)
        n_params = Psi_i.shape[1] + U_r.shape[1] + m + 1 + 2 * m
        return {"A": A, "C": C, "moesp_poles": moesp_poles, "theta_i": theta_i, "hammerstein": hf, "rss": rss, "n_params": n_params}

    @staticmethod
    def _reflex_dynamics(sub, m, refinement, start=None):
        """A_r, C_r of order ``m`` from the subspace step, their poles refined by variable
        projection on the complete fit (from ``start``, the A of a fit at a neighbouring
        structure, when given), and MOESP's poles. Why refined: MOESP with ~70 inputs leaves a
        bias in the poles that leaks reflex torque into the intrinsic estimate."""
        A, C = sub.system(m)
        moesp_poles = np.linalg.eigvals(A)
        if refinement is not None:
            A, C, _ = refinement.refine(A if start is None else start)
        return A, C, moesp_poles

    @staticmethod
    def _orthogonal_projection(U_r, A, C, Psi_i, y, segments=None):
        """The orthogonal projection (eq. 27-28): the reflex regressor Psi_r (eq. 25: U_r filtered
        through C_r (zI - A_r)^-1) projected out, the intrinsic parameters by least squares on
        what remains (Frisch-Waugh). Returns the triangular factor's reflex blocks, intrinsic
        columns and torque, and the intrinsic parameters."""
        from ..linalg import project_out_and_solve, triangular_factor
        from ..models.reflex import reflex_regressor

        blocks = reflex_regressor(U_r, A, C, segments)
        # Every fit below is a least-squares problem in the columns of [Psi_r, Psi_i, y]:
        # solved on their triangular factor, at ~100 rows instead of N, with the same
        # solutions and residual norms.
        k_r = sum(blk.shape[1] for blk in blocks)
        R = triangular_factor(blocks + [Psi_i, y])  # (stacked a block of rows at a time)
        blocks_c, Psi_i_c, y_c = np.hsplit(R[:, :k_r], len(blocks)), R[:, k_r:-1], R[:, -1]
        theta_i = project_out_and_solve(R[:, :k_r], Psi_i_c, y_c)
        return blocks_c, Psi_i_c, y_c, theta_i

    def _hammerstein(self, blocks_c, Psi_i_c, y_c, theta_i, orientation, joint=False):
        """The reflex torque (eq. 29) and separable least squares for B, d and Omega (the
        Hammerstein fit of the reflex nonlinearity); with ``joint``, then intrinsic and reflex
        together. Returns (intrinsic parameters, Hammerstein fit, residual sum of squares)."""
        from ..models.reflex import fit_hammerstein, refit_jointly

        tq_r = y_c - Psi_i_c @ theta_i
        hf = fit_hammerstein(blocks_c, tq_r, orientation, tol=self.tol, max_iter=self.max_iter)
        # On the high-rate path, then intrinsic and rank-1 reflex together: the projection's
        # unstructured reflex space can take up elastic torque there (lpvpc.models.reflex.refit_jointly;
        # at the model rate it predicted left-out levels worse, so not there)
        if joint:
            theta_i, hf = refit_jointly(blocks_c, Psi_i_c, y_c, hf, orientation)
        resid = y_c - Psi_i_c @ theta_i - sum(c * (blk @ hf.omega) for c, blk in zip(np.append(hf.b, hf.d), blocks_c))
        return theta_i, hf, float(resid @ resid)

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
            StationaryWarning, stacklevel=4)  # (from _build_regressors: the frame _fit's warnings point at)
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


def _check_reflex_path_settings(est) -> None:
    """ValueError naming a bad high-rate setting (before any fit)."""
    from ..models.basis import FAMILIES
    from ..models.modelfile import MAX_BASIS_ORDER

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
    from ..models.modelfile import MAX_RELAXATION_S

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
    from ..models.modelfile import MAX_BASIS_ORDER

    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 0 <= order <= MAX_BASIS_ORDER:
        raise ValueError(f"{name} must be an integer in 0..{MAX_BASIS_ORDER}, got {order!r}")


def _high_rate_input(est, data, rho_basis):
    """The reflex regressor from the data's high-rate signals (:class:`lpvpc.io.HighRate`),
    or None when the data have none (100 Hz files, or loaded with ``target_fs=None``)."""
    hr = getattr(data, "high_rate", None)
    if hr is None or est.effects or not est.high_rate_reflex:  # extended models keep the model-rate one
        return None
    from ..models.reflex import high_rate_input

    q = int(round(hr.fs / float(data.fs)))
    return high_rate_input(hr, q, est.reflex_delay, rho_basis, est.high_rate_velocity_basis,
                           est.high_rate_velocity_order)


def _model_rate_stand_in(U_r_model, U_r_high, best, segments, n_r):
    """Omega of the model-rate nonlinearity (exports, predictions from model-rate records):
    least squares of the high-rate path's reflex drive through the identified dynamics, as
    seen from the model-rate velocity basis (the dynamics and rho basis are shared)."""
    from ..models.reflex import reflex_regressor

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

    >>> from lpvpc.models.basis import Basis
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
    by trial: the structural term of the intrinsic intervals (lpvpc.models.uncertainty).

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
    (lpvpc.models.uncertainty). None for a position-independent fit (order 0) and at the file
    format's largest order.

    >>> from lpvpc.models.basis import basis_from_data
    >>> rho = np.linspace(-0.4, 0.2, 500)  # rad
    >>> p = np.random.default_rng(0).uniform(-0.04, 0.04, 500)  # rad
    >>> basis, Psi = richer_basis_irf(p, rho, basis_from_data(rho, "chebyshev", 5), [-1, 0, 1])
    >>> basis.order, Psi.shape
    (6, (500, 21))
    """
    from ..models.basis import Basis

    from ..models.modelfile import MAX_BASIS_ORDER

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
    zero; a time base that is probably wrong (``_check_time_base``); a reflex gain whose
    interval lies below zero (``_check_reflex_gain``).

    A torque recorded with the opposite sign gives a negative stiffness, and a warning:

    >>> import warnings
    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
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


#: The sign warning's words (what ``_physiology_of_final`` looks for in a candidate fit's warnings).
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
            **({"time_unit": meta["time_unit"]} if meta.get("time_unit", "s") != "s" else {}),
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
    (lpvpc.identification.selection.effect_candidates): its times and its weights' order in position."""
    from ..models.effects import model_relaxation_times

    fe = next(f for f in model.effects if f.name == "stress_relaxation")
    return {"relaxation_times": model_relaxation_times(model), "relaxation_order": fe.basis.order}


def _catalog_terms(cands: dict, intrinsic_basis) -> dict:
    """The estimator settings of the candidates (lpvpc.identification.selection.effect_candidates) whose
    columns are the catalog's own terms (stress relaxation: lpvpc.models.effects.RELAXATION_TIMES at
    the catalog's order in position), {} when none is."""
    from ..models.effects import CATALOG, RELAXATION_TIMES, effect_basis

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
    :class:`lpvpc.identification.selection.StructureSearch` held at ``chosen`` with the ``offered`` effects'
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
    (:func:`~lpvpc.models.effects.with_model_activation`), as predict, diagnose and improve estimate them.
    Without it the extended model was fitted on the velocity-hinge estimate and
    evaluated on the drive's. Unchanged otherwise (no such effect, no EMG, estimates stored).

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import simulate_pair
    >>> sim = simulate_pair("multilevel", seed=0, duration=30.0, fs_out=100.0)
    >>> data = pair_trials(sim.pt, sim.ut)
    >>> with_base_model_activation(data, {"effects": ("stress_relaxation",)}) is data  # reads no activation
    True
    """
    from ..models.effects import _has_backgrounds, reads_activation, with_model_activation

    extra = getattr(data, "extra", None) or {}
    if (not reads_activation(settings.get("effects") or ()) or not ({"emg", "emg_ut"} & set(extra))
            or _has_backgrounds(extra)):
        return data
    base = LPVPCEstimator(**{**settings, "effects": ()})._fit_from(data, _INNER).model_
    return with_model_activation(data, base)


def identify(data, **settings) -> LPVPCModel:
    """Identify an LPV-PC model with the given estimator settings; returns the model.

    The same fit as ``lpvpc identify``: ``LPVPCEstimator(**settings).fit(data).model_``, with
    the background activation estimated once from the EMG when the data carry it and an
    effect reads it.

    Parameters
    ----------
    data : lpvpc.io.PerturbationData or list of lpvpc.io.PerturbationData
        The record (:func:`lpvpc.load_identification_data <lpvpc.io.identification_data.load_identification_data>`),
        or several trials fitted jointly.
    **settings
        Estimator settings, as :class:`LPVPCEstimator` takes them (its defaults where not
        given).

    Returns
    -------
    lpvpc.models.model.LPVPCModel
        The identified model; it carries the record's conventions (units, torque sign,
        channel skew), which every door applies to the records it reads later.

    Raises
    ------
    lpvpc.errors.DataError
        The record is unusable (NaN, a rate that is not the model's, too short).
    lpvpc.errors.InsufficientExcitationError
        The record cannot determine the requested parameters (too little movement or
        too few samples for the bases and lags asked for).
    lpvpc.errors.IdentificationError
        The algorithm failed on data that passed the checks.
    TypeError
        A setting the estimator does not have.

    See Also
    --------
    LPVPCEstimator : the same, as a scikit-learn style estimator.

    Examples
    --------
    Thirty seconds of the virtual subject at 100 Hz; the stiffness found against the
    subject's own:

    >>> from lpvpc.io import pair_trials
    >>> from lpvpc.simulation.simulate import SubjectParams, simulate_pair
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
        from .. import linalg

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
